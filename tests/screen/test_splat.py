"""Photon splatting (spec seed-004 §2.5, §2.6, Eq 1; oracles O2, O4, O5)."""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from photonmap import ParameterError
from photonmap.screen.gbuffer import GBuffer
from photonmap.screen.light_photons import ScreenPhotons
from photonmap.screen.splat import splat_icosahedra, splat_quads

EYE, FORWARD = np.zeros(3), np.array([0.0, 0.0, 1.0])


def make_gbuffer(W, H, f_px, pos, nrm, valid, albedo=0.5) -> GBuffer:
    """A G-buffer from NumPy (W·H, 3) arrays seen from an eye at the origin looking along +z."""
    valid = np.asarray(valid, bool)
    pos, nrm = np.where(valid[:, None], pos, 0), np.where(valid[:, None], nrm, 0)
    albedo = np.where(valid[:, None], np.broadcast_to(albedo, (W * H, 3)), 0)
    f32 = lambda a: np.ascontiguousarray(np.asarray(a, np.float32).T)  # noqa: E731
    return GBuffer(
        W, H, mi.Point3f(f32(pos)), mi.Normal3f(f32(nrm)), mi.Float(f32(pos[:, 2])),
        mi.Color3f(f32(albedo)), mi.Bool(valid), mi.ScalarPoint3f(EYE),
        mi.ScalarVector3f(FORWARD), float(f_px),
    )  # fmt: skip


def eye_rays(W, H, f_px):
    x, y = np.meshgrid(np.arange(W) + 0.5 - W / 2, np.arange(H) + 0.5 - H / 2)
    return np.stack([x / f_px, -y / f_px, np.ones_like(x)], -1).reshape(-1, 3)


def plane(W, H, f_px, Z):
    """The fronto-parallel plane z = Z filling the image (pixel footprint (Z/f_px)²)."""
    n = np.tile([0.0, 0.0, -1.0], (W * H, 1))
    return make_gbuffer(W, H, f_px, eye_rays(W, H, f_px) * Z, n, np.ones(W * H, bool))


def make_photons(pos, nrm, power, density=None, valid=None) -> ScreenPhotons:
    n = len(pos)
    f32 = lambda a: np.ascontiguousarray(np.asarray(a, np.float32).T)  # noqa: E731
    return ScreenPhotons(
        mi.Point3f(f32(pos)), mi.Normal3f(f32(nrm)), mi.Color3f(f32(power)),
        mi.Float(np.ones(n) if density is None else np.asarray(density, np.float32)),
        mi.Bool(np.ones(n, bool) if valid is None else np.asarray(valid, bool)),
    )  # fmt: skip


def reference(gb, pos, nrm, valid, albedo, ph, radius, tau, mode):
    """Per-photon NumPy (float64) loop over all pixels: Eq 1 with the spec's kernels."""
    E = np.zeros((len(pos), 3))
    for s_p, n_p, phi, rho_path, ok in zip(*ph, strict=True):
        if not ok or np.dot(EYE - s_p, n_p) <= 0:
            continue
        r = np.clip(radius / np.sqrt(rho_path), radius / 8, radius)
        delta = pos - s_p
        h = delta @ n_p
        if mode == "sphere":
            rho, covered = np.linalg.norm(delta, axis=1), True
        else:
            rho = np.linalg.norm(delta - h[:, None] * n_p, axis=1)
            covered = np.abs(h) <= tau * r
        kappa = 3 / (np.pi * r * r) * np.maximum(0, 1 - rho / r) * covered * (rho < r)
        E += (np.maximum(nrm @ n_p, 0) * kappa)[:, None] * phi
    E[~valid] = 0
    return albedo / np.pi * E, E


def two_planes(W=16, H=12, f_px=12.0):
    """A fronto-parallel plane (left) meeting a tilted one (right); the top-left pixel is
    background."""
    d = eye_rays(W, H, f_px)
    n_back, n_tilt = np.array([0, 0, -1.0]), np.array([-0.6, 0.0, -0.8])
    t_back = 2.0 / d[:, 2]
    t_tilt = (np.array([0.1, 0, 2.0]) @ n_tilt) / (d @ n_tilt)
    tilted = (d[:, 0] * t_back > 0.1)[:, None]
    pos = np.where(tilted, d * t_tilt[:, None], d * t_back[:, None])
    nrm = np.where(tilted, n_tilt, n_back)
    valid = np.ones(W * H, bool)
    valid[0] = False
    albedo = np.random.default_rng(1).uniform(0.2, 0.9, (W * H, 3))
    return make_gbuffer(W, H, f_px, pos, nrm, valid, albedo), pos, nrm, valid, albedo


@pytest.mark.parametrize(
    "mode, call",
    [
        ("gbuffer", lambda g, p, r: splat_quads(g, p, r)),
        ("sphere", lambda g, p, r: splat_icosahedra(g, p, r)),
        ("gbuffer", lambda g, p, r: splat_icosahedra(g, p, r, compression=0.25)),
    ],
)
def test_matches_numpy_brute_force(mode, call):
    gb, pos, nrm, valid, albedo = two_planes()
    rng = np.random.default_rng(7)
    pick = rng.integers(1, len(pos), 60)
    n_ph = nrm[pick] + rng.normal(0, 0.15, (60, 3))
    n_ph /= np.linalg.norm(n_ph, axis=1, keepdims=True)
    n_ph[:5] *= -1  # back faces
    radius = 0.35
    p_ph = pos[pick] + rng.uniform(-0.1, 0.1, (60, 3)) * radius
    power = rng.uniform(0, 1, (60, 3))
    density = rng.choice([1.0, 2.0, 4.0, 100.0], 60)
    ok = rng.uniform(size=60) > 0.1
    tau = 1.0 if mode == "sphere" else 0.25
    L, E = call(gb, make_photons(p_ph, n_ph, power, density, ok), radius)
    L_ref, E_ref = reference(gb, pos, nrm, valid, albedo, (p_ph, n_ph, power, density, ok),
                             radius, tau, mode)  # fmt: skip
    assert E_ref.max() > 1 and np.count_nonzero(E_ref.sum(1)) > 100
    np.testing.assert_allclose(E.numpy().T, E_ref, rtol=2e-4, atol=1e-4)
    np.testing.assert_allclose(L.numpy().T, L_ref, rtol=2e-4, atol=1e-4)


@pytest.mark.parametrize(
    "call",
    [
        lambda g, p, r: splat_quads(g, p, r),
        lambda g, p, r: splat_icosahedra(g, p, r),
    ],
)
def test_single_photon_integrates_to_its_power(call):
    """O2: Σ E·A_px = Φ and Σ L·A_px = ρΦ/π (r = 15 px, perspective head-on view)."""
    W, H, f_px, Z = 96, 80, 100.0, 2.0
    phi = np.array([1.0, 2.0, 3.0])
    photons = make_photons([[0.013, -0.021, Z]], [[0, 0, -1.0]], [phi])
    L, E = call(plane(W, H, f_px, Z), photons, 0.3)
    area = (Z / f_px) ** 2
    np.testing.assert_allclose(E.numpy().sum(axis=1) * area, phi, rtol=0.01)
    np.testing.assert_allclose(L.numpy().sum(axis=1) * area, 0.5 * phi / np.pi, rtol=0.01)


def test_quads_and_icosahedra_agree_on_a_plane():
    """O4: on a plane, in-plane distance = 3D distance; photons away from the edges."""
    W, H, f_px, Z = 64, 48, 40.0, 2.0
    rng = np.random.default_rng(3)
    pos = np.column_stack(
        [rng.uniform(-0.8, 0.8, 200), rng.uniform(-0.5, 0.5, 200), np.full(200, Z)]
    )
    photons = make_photons(pos, np.tile([0, 0, -1.0], (200, 1)), rng.uniform(0, 1, (200, 3)))
    gb = plane(W, H, f_px, Z)
    quad = splat_quads(gb, photons, 0.25)[1].numpy()
    ico = splat_icosahedra(gb, photons, 0.25)[1].numpy()
    np.testing.assert_allclose(quad, ico, rtol=1e-5, atol=1e-6 * ico.max())


@pytest.mark.parametrize(
    "call, rho, h",
    [
        (lambda g, p, r: splat_icosahedra(g, p, r, compression=0.9), 0.8, 0.8),
        (lambda g, p, r: splat_quads(g, p, r), 0.99, 0.24),
    ],
)
def test_edge_photon_is_found_wherever_the_grid_cells_fall(call, rho, h):
    """A photon at in-plane distance ρ < r_p and height h ≤ τ r_p (c r_p) covers the pixel though
    ‖Δ‖ = √(ρ² + h²) > r_p; with Δ along x the pixel must find it for every placement of the grid
    cells (shifted by a far-away second photon that sets the grid origin)."""
    r = 0.1
    s_p = np.array([0.0, 0.0, 2.0])
    n_p = np.array([h, 0.0, -rho]) / math.hypot(rho, h)  # Δ·n_p = h r, in-plane ρ r
    s = s_p + np.array([math.hypot(rho, h) * r, 0.0, 0.0])
    gb = make_gbuffer(1, 1, 10.0, s[None], n_p[None], [True])
    expected = 3 / (math.pi * r * r) * (1 - rho)
    for shift in np.linspace(0, r, 100, endpoint=False):
        anchor = s_p - np.array([0.5 + shift, 0.5, 0.5])  # grid origin; covers nothing
        photons = make_photons([s_p, anchor], [n_p, [0, 0, -1.0]], np.ones((2, 3)))
        E = call(gb, photons, r)[1].numpy()
        np.testing.assert_allclose(E[:, 0], expected, rtol=1e-4, err_msg=f"shift {shift}")


def test_back_facing_photons_contribute_nothing():
    gb = plane(32, 24, 30.0, 2.0)
    front = make_photons([[0, 0, 2.0]], [[0, 0, -1.0]], [[1, 1, 1]])
    both = make_photons([[0, 0, 2.0], [0.1, 0, 2.0]], [[0, 0, -1.0], [0, 0, 1.0]], [[1, 1, 1]] * 2)
    back_only = make_photons([[0.1, 0, 2.0]], [[0, 0, 1.0]], [[1, 1, 1]])
    for call in (splat_quads, splat_icosahedra):
        assert np.all(call(gb, back_only, 0.3)[1].numpy() == 0)
        np.testing.assert_array_equal(
            call(gb, both, 0.3)[1].numpy(), call(gb, front, 0.3)[1].numpy()
        )


def test_invalid_pixels_and_no_photons_give_zero():
    gb, pos, *_ = two_planes()
    photons = make_photons(pos[1:40], np.tile([0, 0, -1.0], (39, 1)), np.ones((39, 3)))
    L, E = splat_icosahedra(gb, photons, 1.0)
    assert np.all(E.numpy()[:, 0] == 0) and np.all(L.numpy()[:, 0] == 0)
    assert E.numpy().sum() > 0
    none = make_photons(pos[1:3], np.tile([0, 0, -1.0], (2, 1)), np.ones((2, 3)), valid=[0, 0])
    assert np.all(splat_quads(gb, none, 1.0)[1].numpy() == 0)


def test_bad_input_raises():
    gb = plane(8, 6, 10.0, 1.0)
    photons = make_photons([[0, 0, 1.0]], [[0, 0, -1.0]], [[1, 1, 1]])
    for radius in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ParameterError, match="radius must be a positive"):
            splat_quads(gb, photons, radius)
        with pytest.raises(ParameterError, match="radius must be a positive"):
            splat_icosahedra(gb, photons, radius)
    for c in (0.0, 1.5):
        with pytest.raises(ParameterError, match=r"compression must lie in \(0, 1\]"):
            splat_icosahedra(gb, photons, 0.1, compression=c)
    nan = make_photons([[0, 0, 1.0]], [[0, 0, -1.0]], [[1, np.nan, 1]])
    with pytest.raises(ParameterError, match="must be finite"):
        splat_quads(gb, nan, 0.1)
    short = GBuffer(9, 6, gb.pos, gb.nrm, gb.depth, gb.albedo, gb.valid, gb.eye, gb.forward, 10.0)
    with pytest.raises(ParameterError, match="width·height"):
        splat_quads(short, photons, 0.1)
    assert dr.width(splat_quads(gb, photons, 0.1)[0]) == 48
