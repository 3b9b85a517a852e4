"""S9 viewing pass (spec seed-000-002 §5.6, oracles 24–29)."""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy.special import erf

from photonmap.core.arrays import columns
from photonmap.core.grid import GridBox
from photonmap.volume.view import ViewGrids, ViewSettings, isosurface_hit, render_view, schlick

N = 128
BOX = GridBox((0.0, 0.0, 0.0), float(N), N)  # h = 1: world = voxel units


def view_grids(ior=1.0, sigma_s=0.0, kappa=0.0, C=0.0, D=(1.0, 0.0, 0.0), n=N, grad=None):
    def grid(value, channels):
        a = np.asarray(value, np.float32)
        if a.ndim <= 1:
            return np.ascontiguousarray(np.broadcast_to(a, (n, n, n, channels)))
        return a.reshape(n, n, n, -1) if a.ndim == 3 else a

    ior = grid(ior, 1)
    if grad is None:
        gz, gy, gx = np.gradient(ior[..., 0].astype(np.float64), edge_order=1)
        grad = np.stack([gx, gy, gz], -1).astype(np.float32)
    return ViewGrids.build(ior, grad, grid(kappa, 3), grid(sigma_s, 3), grid(C, 3), grid(D, 3))


def sensor(origin, target, width=1, height=1, fov=30.0, up=(0, 1, 0), rfilter="box"):
    """A camera whose pixels are the view pass's rays through their centres (box filter; the
    film's own filter is applied to the image, test_the_films_filter_is_applied_to_the_view)."""
    return mi.load_dict(
        {
            "type": "perspective",
            "fov": fov,
            "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=up),
            "film": {"type": "hdrfilm", "width": width, "height": height,
                     "rfilter": {"type": rfilter}},
        }
    )  # fmt: skip


def constant_env(value):
    return mi.load_dict({"type": "constant", "radiance": {"type": "rgb", "value": value}})


def pixel(img):
    return np.array(img)[0, 0]


# ---- oracle 24 -------------------------------------------------------------------------------
@pytest.mark.parametrize("k", [-0.5, 0.0, 0.3, 0.9])
def test_schlick_phase_function_is_normalised(k):
    mu = np.linspace(-1, 1, 200001)
    p = np.array(schlick(k, mi.Float(mu)), dtype=np.float64)
    assert 2 * math.pi * np.trapezoid(p, mu) == pytest.approx(1.0, abs=1e-5)


def test_isotropic_schlick_is_one_over_four_pi():
    assert float(schlick(0.0, mi.Float(0.3))[0]) == pytest.approx(1 / (4 * math.pi))


# ---- oracle 25: analytic single scattering ---------------------------------------------------
def test_single_scattering_sum_matches_the_discrete_formula():
    kappa, x0 = 0.01, 64.5
    xc = np.arange(N) + 0.5
    C = np.broadcast_to(np.exp(-kappa * xc)[None, None, :, None], (N, N, N, 3))
    g = view_grids(sigma_s=kappa, kappa=kappa, C=C)
    cam = sensor([x0, 64.5, -20.0], [x0, 64.5, 10.0])
    # each unit step adds its exact integral (κ and the source constant over it): the continuous
    # single-scattering integral
    value = pixel(render_view(g, BOX, cam, None, ViewSettings(phase_k=0.0)))
    continuous = kappa / (4 * math.pi) * math.exp(-kappa * x0) * (1 - math.exp(-kappa * N)) / kappa
    assert np.allclose(value, continuous, rtol=1e-5)
    # fidelity "paper" (Listing A.4): T updated before adding, the discrete sum (0.5% lower here)
    paper = pixel(render_view(g, BOX, cam, None, ViewSettings(phase_k=0.0, paper=True)))
    steps = np.arange(1, N + 1)
    expected = kappa / (4 * math.pi) * math.exp(-kappa * x0) * np.sum(np.exp(-kappa * steps))
    assert np.allclose(paper, expected, rtol=1e-5)


# ---- oracle 26: transmittance ----------------------------------------------------------------
def test_background_through_an_empty_grid_is_unchanged():
    g = view_grids()
    env = constant_env([0.2, 0.5, 0.7])
    img = np.array(
        render_view(
            g, BOX, sensor([60.0, 70.0, -40.0], [64.0, 64.0, 64.0], 8, 6, 60), env, ViewSettings()
        )
    )
    assert np.allclose(img, [0.2, 0.5, 0.7], rtol=1e-6)


def test_transmittance_is_the_product_over_unit_steps():
    kappa = np.array([0.01, 0.02, 0.005])
    g = view_grids(kappa=kappa)
    cam = sensor([64.5, 64.5, -20.0], [64.5, 64.5, 10.0])
    value = pixel(render_view(g, BOX, cam, constant_env([1.0, 1.0, 1.0]), ViewSettings()))
    assert np.allclose(value, np.exp(-kappa * N), rtol=1e-5)


# ---- oracle 27: straight rays take chord/h steps ---------------------------------------------
def test_constant_index_rays_take_one_step_per_voxel_of_chord():
    kappa = 0.01
    g = view_grids(ior=1.33, kappa=kappa)
    cam = sensor([150.0, 170.0, -90.0], [64.0, 60.0, 64.0], 12, 9, 40)
    img = np.array(render_view(g, BOX, cam, constant_env([1.0, 1.0, 1.0]), ViewSettings()))
    steps = -np.log(img[..., 0]) / kappa
    film = cam.film()
    w, h = film.size()
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    uu, vv = np.meshgrid(u, v)
    ray, _ = cam.sample_ray(0.0, 0.5, mi.Point2f(uu.ravel(), vv.ravel()), mi.Point2f(0.5))
    o, d = np.array(ray.o).T, np.array(ray.d).T
    with np.errstate(divide="ignore"):
        t0, t1 = (0 - o) / d, (N - o) / d
    chord = np.clip(np.min(np.maximum(t0, t1), 1) - np.max(np.minimum(t0, t1), 1), 0, None)
    chord = chord.reshape(h, w)
    hit = chord > 1
    assert hit.sum() > 20
    # unit steps, the last one cut at the exit face: the optical depth of the chord itself
    # (whole last steps, as before box grids: up to one voxel more)
    assert np.all(np.abs(steps[hit] - chord[hit]) < 0.01)


def test_the_films_filter_is_applied_to_the_view():
    """One ray per pixel centre (spp 1): the image of a gaussian-filter film is the box film's
    image filtered with the gaussian at integer offsets, cut at the image's edges (with spp > 1
    the rays importance-sample the filter through pixel_rays: tests/core/test_film_filter.py)."""
    from photonmap.core.film_filter import filter_image

    g = view_grids(ior=1.33, kappa=0.01)
    args = ([150.0, 170.0, -90.0], [64.0, 60.0, 64.0], 12, 9, 40)
    env = constant_env([1.0, 1.0, 1.0])
    box = np.array(render_view(g, BOX, sensor(*args), env, ViewSettings()), dtype=np.float64)
    gauss = sensor(*args, rfilter="gaussian")
    image = np.array(render_view(g, BOX, gauss, env, ViewSettings()), dtype=np.float64)
    np.testing.assert_allclose(image, filter_image(box, gauss.film()), rtol=1e-5)
    assert np.abs(image - box).max() > 0.02  # the filter changed the image (by 0.08 here)


# ---- oracle 28: the reflective table ---------------------------------------------------------
def test_table_reflects_and_adds_the_lit_table():
    g = view_grids(C=1.0, D=(0.0, -1.0, 0.0))
    env = constant_env([0.1, 0.1, 0.1])
    cam = sensor([64.0, 100.0, 64.0 - 60.0], [64.0, 0.0, 64.0])  # looks down onto the table
    with_table = pixel(render_view(g, BOX, cam, env, ViewSettings(table=(0.8, 0.8, 0.8))))
    assert np.allclose(with_table, 0.1 + 0.8 / math.pi, rtol=1e-5)  # T = 1, σ_s = 0
    paper = pixel(render_view(g, BOX, cam, env, ViewSettings(table=(0.8, 0.8, 0.8), paper=True)))
    assert np.allclose(paper, 0.1 + 0.8, rtol=1e-5)


def test_zero_table_leaves_rays_that_stay_above_it_unchanged():
    rng = np.random.default_rng(3)
    C = rng.uniform(0.5, 1.0, (N, N, N, 3)).astype(np.float32)
    g = view_grids(sigma_s=0.01, kappa=0.01, C=C)
    cam = sensor([64.0, 300.0, -200.0], [64.0, 40.0, 64.0], 16, 12, 50)
    env = constant_env([0.3, 0.3, 0.3])
    off = np.array(render_view(g, BOX, cam, env, ViewSettings()))
    on = np.array(render_view(g, BOX, cam, env, ViewSettings(table=(1e-9, 1e-9, 1e-9))))
    same = np.all(np.isclose(on, off, rtol=1e-6), axis=-1)
    assert same.any() and not same.all()  # only rays that reach the bottom layer differ


# ---- oracle 29: the reflective isosurface ----------------------------------------------------
def test_isosurface_bisection_and_normal():
    n_obj, radius = 1.5, 40.0
    z, y, x = np.mgrid[0:N, 0:N, 0:N] + 0.5
    r = np.sqrt((x - 64) ** 2 + (y - 64) ** 2 + (z - 64) ** 2)
    ior = 1.0 + (n_obj - 1) * 0.5 * (1 - erf((r - radius) / (1.5 * math.sqrt(2))))
    g = view_grids(ior=ior.astype(np.float32))
    iso = 0.5 * (1 + n_obj)
    rng = np.random.default_rng(5)
    d = rng.normal(size=(256, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    x_old = 64 + d * (radius + 0.6)
    x_new = 64 + d * (radius - 0.4)
    old, new = (mi.Point3f(*columns(mi.Float, x)) for x in (x_old, x_new))
    t, normal = isosurface_hit(g, old, new, iso)
    hit = x_old + np.array(t)[:, None] * (x_new - x_old)
    # the n = n_iso isosurface of the trilinearly sampled field, found by dense NumPy search
    assert np.all(np.abs(np.linalg.norm(hit - 64, axis=1) - radius) < 0.02)  # 0.012 measured
    normal = np.array(normal).T
    angle = np.degrees(np.arccos(np.clip(np.sum(normal * d, 1), -1, 1)))
    assert np.all(angle < 2.0)


def test_isosurface_reflects_the_environment():
    n_obj, radius = 1.5, 40.0
    z, y, x = np.mgrid[0:N, 0:N, 0:N] + 0.5
    r = np.sqrt((x - 64) ** 2 + (y - 64) ** 2 + (z - 64) ** 2)
    ior = (1.0 + (n_obj - 1) * 0.5 * (1 - erf((r - radius) / (1.5 * math.sqrt(2))))).astype(
        np.float32
    )
    g = view_grids(ior=ior, kappa=0.0)
    cam = sensor([64.0, 64.0, -100.0], [64.0, 64.0, 64.0])
    env = constant_env([1.0, 1.0, 1.0])
    value = pixel(render_view(g, BOX, cam, env, ViewSettings(iso_ior=1.25, iso_reflect=0.04)))
    # R_iso of the environment plus (1 − R_iso) of what continues: a lossless medium → 1
    assert np.allclose(value, 1.0, rtol=1e-5)
    value = pixel(
        render_view(
            view_grids(ior=ior, kappa=0.01),
            BOX,
            cam,
            env,
            ViewSettings(iso_ior=1.25, iso_reflect=0.04),
        )
    )
    # κ = 0.01 everywhere: R_iso·T at the hit (24 voxels in) + (1 − R_iso)·T over the 128-voxel
    # chord (the axial ray is not bent); 1.0e-3 measured (the hit found between unit steps)
    expected = 0.04 * math.exp(-0.01 * 24) + 0.96 * math.exp(-0.01 * 128)
    assert value == pytest.approx(expected, rel=2e-3)


def test_camera_samples_are_deterministic_per_seed():
    g = view_grids(sigma_s=0.01, kappa=0.01, C=1.0)
    cam = sensor([64.0, 64.0, -100.0], [64.0, 64.0, 64.0], 8, 8, 60)
    a = np.array(render_view(g, BOX, cam, None, ViewSettings(spp=4, seed=1)))
    b = np.array(render_view(g, BOX, cam, None, ViewSettings(spp=4, seed=1)))
    assert np.array_equal(a, b) and np.all(np.isfinite(a))
    assert dr.width(mi.Float(a.ravel())) == 8 * 8 * 3
