"""Irradiance caching (spec seed-001 §2.9, oracles O3, O23, O24): the vectorised
decisions against a sequential reference, R_avg against an analytic case, and the cached renders
against the full final gather."""

import math

import mitsuba as mi
import numpy as np
import pytest

from photonmap.core.errors import ParameterError
from photonmap.scenes import cornell
from photonmap.surface import irradiance_cache
from photonmap.surface.irradiance_cache import (
    IN_FRONT,
    cache_order,
    harmonic_mean_distance,
    plan_cache,
)
from photonmap.surface.pipeline import SurfacePipeline


def sequential_reference(position, normal, ravg, eligible, order, cache, error):
    """Ward's algorithm as written (spec §2.9.1/§2.9.3), one pixel at a time: records of the
    pixel's own cache, valid by ε < ε_max, n·n_j > 0 and the in-front test."""
    records, weights = {}, {}
    for i in order:
        if not eligible[i]:
            continue
        valid = {}
        for j in records.get(cache[i], []):
            offset = position[i] - position[j]
            d = np.linalg.norm(offset)
            cos = normal[i] @ normal[j]
            eps = d / ravg[j] + math.sqrt(max(0.0, 1 - cos))
            if eps < error and cos > 0 and offset @ (normal[i] + normal[j]) / 2 >= -IN_FRONT * d:
                valid[j] = 1 / max(eps, 1e-6)
        if valid:
            total = sum(valid.values())
            weights[i] = {j: w / total for j, w in valid.items()}
        else:
            records.setdefault(cache[i], []).append(i)
    return {j for rs in records.values() for j in rs}, weights


@pytest.mark.parametrize("mode, pairwise", [("ward", True), ("ward", False), ("tiled", True)])
def test_decisions_match_the_sequential_algorithm(mode, pairwise, monkeypatch):
    """A 40 × 24 'image' over a floor and a wall meeting at a corner, with holes (no hit) and
    non-Lambertian pixels: the records and every interpolation weight are Ward's — with the
    candidate pairs enumerated per cache or found by the k-d tree (large caches)."""
    if not pairwise:
        monkeypatch.setattr(irradiance_cache, "PAIRWISE_RUN", 16)
        monkeypatch.setattr(irradiance_cache, "QUERY_BLOCK", 100)
    width, height = 40, 24
    rng = np.random.default_rng(4)
    x, y = np.meshgrid(np.arange(width), np.arange(height))
    on_wall = x >= 25
    position = np.stack(
        [np.minimum(x, 25) * 0.01, np.where(on_wall, 0, y * 0.01), (x - 25).clip(0) * 0.01 + 0], -1
    )
    position = position.reshape(-1, 3) + rng.normal(scale=1e-3, size=(width * height, 3))
    normal = np.where(on_wall.reshape(-1, 1), [1.0, 0, 0], [0, 1.0, 0])
    ravg = rng.uniform(0.05, 0.3, width * height)
    lambertian = rng.random(width * height) > 0.1
    found = rng.random(width * height) > 0.05
    order, cache = cache_order(mode, width, height, 1)
    plan = plan_cache(position, normal, ravg, lambertian, found, order, cache, 0.2)
    records, weights = sequential_reference(
        position, normal, ravg, lambertian & found, order, cache, 0.2
    )
    assert set(plan.gather[plan.record]) == records
    assert set(plan.interpolate) == set(weights)
    assert set(plan.gather[~plan.record]) == set(np.flatnonzero(found & ~lambertian))
    links = zip(plan.link_lane, plan.link_record, plan.link_weight, strict=True)
    got = {(i, j): w for i, j, w in links}
    want = {(i, j): w for i, ws in weights.items() for j, w in ws.items()}
    assert got.keys() == want.keys()
    assert np.allclose([got[key] for key in want], list(want.values()))
    assert 0.3 < plan.hit_rate < 1  # the test exercises both decisions
    if mode == "tiled":  # no record serves a pixel of another tile
        assert np.all(cache[plan.link_lane] == cache[plan.link_record])


def test_harmonic_mean_distance_between_parallel_planes():
    """Cosine rays from a plane to a parallel plane at height h travel h / cos θ, so
    R_avg = h / E[cos θ] = 1.5 h (Eq 5.8)."""
    h = 0.5
    scene = mi.load_dict(
        {
            "type": "scene",
            "ceiling": {
                "type": "rectangle",
                "to_world": mi.ScalarTransform4f().translate([0, 0, h]).scale(1000),
            },
        }
    )
    n = 64
    position = mi.Point3f(np.linspace(-1, 1, n), np.zeros(n), np.zeros(n))
    normal = mi.Vector3f(np.zeros(n), np.zeros(n), np.ones(n))
    R = harmonic_mean_distance(scene, position, normal, 256, 0, (1e-3, 10.0)).numpy()
    assert np.mean(R) == pytest.approx(1.5 * h, rel=0.01)


@pytest.fixture(scope="module")
def bare_box():
    """The empty Cornell box (Steinhurst Fig 5.3's bare box) and its full-final-gather image."""
    scene = cornell.cornell_steinhurst(64, 48)
    for name in ("mirror_sphere", "glass_sphere"):
        del scene[name]
    pipe = SurfacePipeline(scene, photons=20_000, caustic_photons=0, fg_rays=32, emitter_spp=0)
    return pipe, np.array(pipe.render())


def render(pipe, **params):
    pipe.set_params(**params)
    return np.array(pipe.render()), dict(pipe.stats)


def relative_rmse(a, b):
    """Relative RMS difference over the pixels that do not show the light."""
    lit = (a.max(axis=2) < 1.0) & (b.max(axis=2) < 1.0)
    return float(np.sqrt(np.mean((a - b)[lit] ** 2)) / np.mean(b[lit]))


def test_cached_images_match_the_full_final_gather(bare_box):
    """Tiled and Ward caches at ε_max = 0.1 and 0.3 save gathers and stay close to the full
    final gather; the hit rate grows with ε_max (O23). Measured (mean deviation, relative RMSE):
    ε_max = 0.1: 0.14–0.20 %, 0.047–0.048 (the final gather's own noise, as other random
    streams, is most of it); 0.3: 0.69–0.79 %, 0.084–0.089."""
    pipe, full = bare_box
    bounds = {0.1: (0.004, 0.07), 0.3: (0.012, 0.13)}
    rates = {}
    for mode in ("tiled", "ward"):
        for error, (mean_bound, rmse_bound) in bounds.items():
            image, stats = render(pipe, irradiance_cache=mode, ic_error=error)
            rates[mode, error] = stats["ic_hit_rate"]
            assert abs(image.mean() / full.mean() - 1) < mean_bound
            assert relative_rmse(image, full) < rmse_bound
    assert 0 < rates["tiled", 0.1] < rates["tiled", 0.3]
    assert 0 < rates["ward", 0.1] < rates["ward", 0.3]
    assert rates["tiled", 0.3] <= rates["ward", 0.3]  # a tile's cache sees fewer records


def test_without_interpolation_records_return_the_final_gather(bare_box):
    """At a vanishing ε_max every Lambertian hit is a record: ρ/π · E(x) from the irradiance
    estimator equals the radiance estimator's image within its noise."""
    pipe, full = bare_box
    image, stats = render(pipe, irradiance_cache="tiled", ic_error=1e-6)
    assert stats["ic_hit_rate"] == 0 and stats["ic_records"] > 0
    assert abs(image.mean() / full.mean() - 1) < 0.0005  # measured 0.0002


def test_bad_cache_settings_name_the_parameter(bare_box):
    pipe, _ = bare_box
    with pytest.raises(ParameterError, match="irradiance_cache"):
        pipe.set_params(irradiance_cache="octree")
    with pytest.raises(ParameterError, match="ic_error"):
        pipe.set_params(ic_error=0.0)
    pipe.set_params(irradiance_cache="none", ic_error=0.05)
