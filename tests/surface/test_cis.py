"""Importance sampling of final-gather directions (spec seed-001 §2.10, oracles
O6, O7, O10, O11): the 1-D teaching example, the tabular pdfs of Jensen's method and CIS, and
the unbiasedness of every sampling strategy on the glossy-floor box."""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from photonmap.core.arrays import to_jit
from photonmap.core.camera import pixel_rays
from photonmap.core.errors import ParameterError
from photonmap.scenes import cornell
from photonmap.surface.cis import (
    CELLS,
    brdf_table,
    cdf_of,
    cell_direction,
    cell_of,
    normalised,
    photon_table,
    sample_cell,
    sample_table,
    sampling_table,
)
from photonmap.surface.pipeline import SurfacePipeline


# ----------------------------------------------------------------- O10: the 1-D teaching example
def g(x):
    """Steinhurst Fig 6.1 (spec §2.10.1 [DERIVED]): 1 on [0, 0.75), 8 on [0.75, 1]."""
    return np.where(x < 0.75, 1.0, 8.0)


def teaching_cdf(cells=CELLS):
    """p = 0.5 on [0, 0.5), 1.5 on [0.5, 1] as a one-query table of ``cells`` equal bins."""
    p = np.where((np.arange(cells) + 0.5) / cells < 0.5, 0.5, 1.5) / cells
    return cdf_of(to_jit(mi.Float, p))


def test_teaching_example_numbers():
    """∫g = 2.75, σ_g = 3.031 (doc 3.03); blind MC error halves from N = 10 to 40."""
    x = (np.arange(1 << 20) + 0.5) / (1 << 20)  # midpoint quadrature on [0, 1]
    assert g(x).mean() == pytest.approx(2.75)
    assert g(x).std() == pytest.approx(3.031, abs=5e-4)
    rng = np.random.default_rng(0)
    rms = [np.sqrt(np.mean((g(rng.random((500, n))).mean(1) - 2.75) ** 2)) for n in (10, 40)]
    assert rms[0] / rms[1] == pytest.approx(2.0, rel=0.15)  # 500 trials as in the doc


def test_teaching_example_by_the_table_sampler():
    """The module's cdf inversion (Alg 6.2) draws x with density p: the unweighted mean of g is
    the doc's biased 3.625, the weighted one 2.75, σ_{g/p} = 2.067 (doc prints 2.29, spec A10)
    and the IS / blind variance ratio 0.465."""
    n = 1 << 18
    cdf = teaching_cdf()
    zeta = (np.arange(n) + 0.5) / n  # stratified: the estimates below are near exact
    cell, s, p_cell = sample_cell(cdf, dr.zeros(mi.UInt32, n), to_jit(mi.Float, zeta))
    x = (cell.numpy() + s.numpy()) / CELLS
    pdf = CELLS * p_cell.numpy()
    assert np.allclose(pdf, np.where(x < 0.5, 0.5, 1.5), rtol=1e-5)
    assert g(x).mean() == pytest.approx(3.625, rel=1e-3)
    assert (g(x) / pdf).mean() == pytest.approx(2.75, rel=1e-3)
    assert (g(x) / pdf).std() == pytest.approx(2.067, abs=2e-3)
    assert (g(x) / pdf).var() / 3.031**2 == pytest.approx(0.465, abs=2e-3)


# ------------------------------------------------------------------------ O6, O7: the tables
def test_cells_round_trip_and_cover_equal_projected_solid_angle():
    rng = np.random.default_rng(1)
    n = 4096
    cell = to_jit(mi.UInt32, rng.integers(0, CELLS, n))
    s, t = (to_jit(mi.Float, rng.random(n)) for _ in range(2))
    d = cell_direction(cell, s, t)
    assert np.allclose(dr.norm(d).numpy(), 1, atol=1e-5)
    assert np.array_equal(cell_of(d).numpy(), cell.numpy())
    # uniform directions on the hemisphere: each cell gets cos-weighted mass 1/C_J of the total
    v = rng.normal(size=(1 << 18, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    cells = cell_of(mi.Vector3f(*v.T.astype(np.float32))).numpy()
    mass = np.bincount(cells, v[:, 2], CELLS) / v[:, 2].sum()
    assert np.allclose(mass, 1 / CELLS, atol=2e-3)


def test_donation_and_normalisation_follow_alg_6_1():
    rng = np.random.default_rng(2)
    table = rng.random((3, CELLS)) * (rng.random((3, CELLS)) < 0.5)
    table[2] = 0  # no photon at all: uniform
    pdf = normalised(to_jit(mi.Float, table.ravel())).numpy().reshape(3, CELLS)
    for row, expected in zip(table[:2], pdf[:2], strict=True):
        donation = 0.05 * row.sum() / CELLS
        filled = np.where(row > 0, row, donation)
        assert np.allclose(expected, filled / filled.sum(), rtol=1e-5)
    assert np.allclose(pdf[2], 1 / CELLS)
    assert np.all(pdf > 0) and np.allclose(pdf.sum(1), 1, rtol=1e-5)  # O6
    cdf = cdf_of(mi.Float(pdf.ravel())).numpy().reshape(3, CELLS)
    assert np.allclose(cdf[:, -1], 1, rtol=1e-5) and np.all(np.diff(cdf, axis=1) > 0)


def test_sampled_directions_follow_the_table_pdf():
    """Cells are drawn with their probabilities; the returned pdf is C_J·P·cos θ/π, and its
    integral over the hemisphere (mean of pdf/uniform pdf) is 1 (O6)."""
    rng = np.random.default_rng(3)
    p = rng.random(CELLS) + 0.1
    p /= p.sum()
    cdf = cdf_of(to_jit(mi.Float, p))
    n = 1 << 17
    u = mi.Point2f(*rng.random((2, n)).astype(np.float32))
    wo, pdf = sample_table(cdf, dr.zeros(mi.UInt32, n), u)
    cells = cell_of(wo).numpy()
    counts = np.bincount(cells, minlength=CELLS)
    assert np.all(np.abs(counts - n * p) < 5 * np.sqrt(n * p))
    z = wo.z.numpy()
    assert np.allclose(pdf.numpy(), CELLS * p[cells] * z / math.pi, rtol=1e-4)
    v = rng.normal(size=(1 << 18, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    c = cell_of(mi.Vector3f(*v.T.astype(np.float32))).numpy()
    assert np.mean(CELLS * p[c] * v[:, 2] / math.pi * 2 * math.pi) == pytest.approx(1, abs=0.01)


def test_diffuse_brdf_table_is_uniform():
    """O7: a constant BRDF gives the same value in every cell."""
    scene = mi.load_dict(
        {
            "type": "scene",
            "floor": {"type": "rectangle", "bsdf": {"type": "diffuse"}},
        }
    )
    ray = mi.Ray3f(mi.Point3f([0.1, -0.2], [0.0, 0.3], [2, 2]), mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(ray)
    table = brdf_table(si, si.is_valid()).numpy().reshape(2, CELLS)
    assert np.allclose(table, 0.5 / math.pi, rtol=1e-5)
    assert np.allclose(normalised(mi.Float(table.ravel())).numpy(), 1 / CELLS, rtol=1e-5)


# ------------------------------------------------------------- O11 on the glossy-floor scene
@pytest.fixture(scope="module")
def glossy_box():
    """The glossy-floor box (Phong-16-like roughness) with one photon map for every render."""
    scene = cornell.cornell_glossy_floor(40, 30, roughness=0.33)
    pipe = SurfacePipeline(scene, photons=20_000, caustic_photons=0, fg_rays=8, emitter_spp=0)
    pipe.set_params(fg_sampling="cosine", fg_rays=256)
    reference = np.array(pipe.render())
    return pipe, reference


@pytest.mark.parametrize("sampling", ["bsdf", "uniform", "jensen", "cis"])
def test_every_sampling_is_unbiased(glossy_box, sampling):
    """The image mean of each strategy at 8 rays agrees with cosine sampling at 256 rays within
    4 standard errors of the per-pixel differences (the direct light is the same in both)."""
    pipe, reference = glossy_box
    pipe.set_params(fg_sampling=sampling, fg_rays=8)
    diff = (np.array(pipe.render()) - reference).mean(axis=2).ravel()
    standard_error = diff.std() / math.sqrt(diff.size)
    assert abs(diff.mean()) < 4 * standard_error, (diff.mean(), standard_error)


def test_cis_table_averages_the_photon_and_brdf_pdfs(glossy_box):
    """Alg 6.3 at the eye-ray hits of the glossy box: the cdf of ``cis`` is the running sum of
    ½ (donated, normalised photon table + donated, normalised BRDF table), each per Alg 6.1."""
    pipe, _ = glossy_box
    ray, _ = pixel_rays(pipe.sensor, dr.arange(mi.UInt32, 40 * 30), mi.Point2f(0.5, 0.5))
    si = pipe.scene.ray_intersect(ray)
    gmap, radius = pipe.photon_maps()[0], pipe.radii()[1]

    def alg_6_1(table):
        table = table.numpy().reshape(-1, CELLS).astype(np.float64)
        total = table.sum(1, keepdims=True)
        filled = np.where(table > 0, table, np.where(total > 0, 0.05 * total / CELLS, 1.0))
        return filled / filled.sum(1, keepdims=True)  # no energy at all: uniform

    energy = photon_table(gmap, si, si.is_valid(), 100, radius)
    pdf = 0.5 * (alg_6_1(energy) + alg_6_1(brdf_table(si, si.is_valid())))
    cdf = sampling_table("cis", gmap, si, si.is_valid(), 100, radius).numpy().reshape(-1, CELLS)
    assert np.allclose(cdf, np.cumsum(pdf, axis=1), atol=2e-6)
    jensen = sampling_table("jensen", gmap, si, si.is_valid(), 100, radius).numpy()
    assert np.allclose(jensen.reshape(-1, CELLS), np.cumsum(alg_6_1(energy), axis=1), atol=2e-6)


def test_tables_gather_only_the_light_a_final_gather_finds(glossy_box, monkeypatch):
    """Under the ceiling light most photons near the floor came straight from the light, where a
    final-gather ray finds nothing: the tables are built from the map of the photons after a
    diffuse bounce (not caustic), so all k nearest photons count. That map holds exactly those
    global photons, and the final gather's tables are built from it."""
    pipe, _ = glossy_box
    records = pipe.photon_maps()[0].photons
    keep = (records.depth.numpy() > 1) & ~records.caustic.numpy()
    indirect = pipe.indirect_photons()
    assert 0 < indirect.size == int(keep.sum()) < records.count
    assert np.array_equal(
        np.sort(indirect.photons.position.numpy(), axis=1),
        np.sort(records.position.numpy()[:, keep], axis=1),
    )
    used = []
    monkeypatch.setattr(
        "photonmap.surface.pipeline.sampling_table",
        lambda method, pmap, *args: used.append(pmap) or sampling_table(method, pmap, *args),
    )
    pipe.set_params(fg_sampling="cis", fg_rays=4)
    pipe.render()
    assert used and all(pmap is indirect for pmap in used)


def test_bad_sampling_names_the_choices():
    pipe = SurfacePipeline(cornell.cornell_glossy_floor(8, 8), photons=1000, caustic_photons=0)
    with pytest.raises(ParameterError, match="fg_sampling"):
        pipe.set_params(fg_sampling="hey")
