"""Image-space soft shadows (spec seed-004 §2.7, Eqs 2–5; oracles O15–O18)."""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from photonmap import ParameterError
from photonmap.core.arrays import to_jit
from photonmap.screen.gbuffer import GBuffer
from photonmap.screen.soft_shadow import _boundary_pixels, lattice, soft_visibility


def make_gbuffer(W, H, f_px, depth, valid=None) -> GBuffer:
    """Fronto-parallel pixels at per-pixel depth ``depth`` (eye at the origin, looking along +z)."""
    x, y = np.meshgrid(np.arange(W) + 0.5 - W / 2, np.arange(H) + 0.5 - H / 2)
    z = np.broadcast_to(depth, (H, W)).ravel()
    pos = np.stack([x.ravel() / f_px * z, -y.ravel() / f_px * z, z])
    valid = np.ones(W * H, bool) if valid is None else np.asarray(valid, bool).ravel()
    nrm = np.tile([[0.0], [0.0], [-1.0]], (1, W * H))
    return GBuffer(
        W, H, mi.Point3f(pos.astype(np.float32)), mi.Normal3f(nrm.astype(np.float32)),
        to_jit(mi.Float, z), mi.Color3f(np.full((3, W * H), 0.5, np.float32)),
        mi.Bool(valid), mi.ScalarPoint3f(0, 0, 0), mi.ScalarVector3f(0, 0, 1), float(f_px),
    )  # fmt: skip


def edge_scene(W=160, H=128, f_px=600.0, Z=1.0, L=0.1, light_height=2.0, h=0.5, angle=0.0):
    """O17: a receiver plane at depth Z, a disk light of radius L at ``light_height`` above it and
    an occluding half-plane at height h whose edge makes ``angle`` with the image's y axis;
    penumbra width w = L·h/(light_height − h). Returns the signed distance u of each pixel from
    the shadow edge (world units) as the last-but-one item."""
    gb = make_gbuffer(W, H, f_px, Z)
    x, y = gb.pos.x.numpy(), gb.pos.y.numpy()
    u = x * math.cos(angle) + y * math.sin(angle)
    D = np.sqrt(x**2 + y**2 + light_height**2)
    hard = (u >= 0).astype(np.float32)
    d = np.where(hard == 0, D * h / light_height, 0)
    return gb, mi.Float(hard), mi.Float(d), mi.Float(D), u, L * h / (light_height - h)


def circular_segment(u):
    """Visible fraction of a disk light through a straight edge at signed offset u = x/w."""
    u = np.clip(u, -1, 1)
    return 0.5 + (u * np.sqrt(1 - u * u) + np.arcsin(u)) / np.pi


def reference(gb, hard, d, D, L, diag, samples, sigma, fixed=None):
    """NumPy (float64) ISG over every pixel, the same taps and rounding as the module."""
    W, H, f = gb.width, gb.height, gb.f_px
    pos = gb.pos.numpy().T.astype(np.float64)
    z, valid = gb.depth.numpy().astype(np.float64), gb.valid.numpy()
    hard, d, D = hard.numpy(), d.numpy().astype(np.float64), D.numpy().astype(np.float64)
    x0, y0 = np.arange(W * H) % W, np.arange(W * H) // W

    def gather(offsets, radius, use):  # γ-weighted sums of ``use(j)`` and of 1, over taps
        sum_w, sum_v = np.zeros(W * H), np.zeros(W * H)
        for ox, oy in offsets:
            x = np.floor(x0 + ox * radius + 0.5)
            y = np.floor(y0 + oy * radius + 0.5)
            inside = (x >= 0) & (x < W) & (y >= 0) & (y < H)
            j = np.where(inside, y * W + x, 0).astype(int)
            t2 = np.sum((pos[j] - pos) ** 2, axis=1) / diag**2
            w = np.exp(-t2 / sigma) * (inside & valid[j])
            value, counted = use(j)
            sum_w += w * counted
            sum_v += w * value
        return sum_w, sum_v

    if fixed is None:
        shadowed = lambda j: (d[j], hard[j] < 0.5)  # noqa: E731
        sum_w, sum_wd = gather(lattice(samples[0]), L * f / z, shadowed)
        g = sum_wd / np.maximum(sum_w, 1e-30)
        radius = f * L * g / (np.maximum(D - g, 1e-4 * diag) * z)
        blur = (sum_w > 0) & (radius >= 0.5)
    else:
        radius = f * fixed / z
        blur = radius >= 0.5
    sum_w, sum_v = gather(lattice(samples[1]), radius, lambda j: (hard[j], 1.0))
    return np.where(blur & valid & (sum_w > 0), sum_v / np.maximum(sum_w, 1e-30), hard)


def test_zero_light_size_is_the_hard_shadow():
    """O15: L = 0 (and mode "hard", and a zero fixed blur radius) return V_h bitwise."""
    gb, hard, d, D, *_ = edge_scene(64, 48)
    for kwargs in (
        {"radius": 0.0},
        {"radius": 0.1, "mode": "hard"},
        {"radius": 0.0, "mode": "fixed_radius"},
    ):
        V = soft_visibility(gb, (hard, d, D), scene_diag=3.0, **kwargs)
        np.testing.assert_array_equal(V.numpy(), hard.numpy())


@pytest.mark.parametrize("f_px, angle", [(300.0, 0.0), (600.0, 0.0), (600.0, 0.5)])
def test_straight_edge_penumbra_matches_the_area_light(f_px, angle):
    """O17: the circular-segment profile of width w = L·h/(H − h) (10 or 20 px) within 0.03,
    monotone, exact 0 / 1 beyond the penumbra (O16)."""
    W, H = 160, 128
    gb, hard, d, D, u, w = edge_scene(W, H, f_px, angle=angle)
    V = soft_visibility(gb, (hard, d, D), 0.1, scene_diag=3.0, sigma=1e6).numpy()
    rows = slice(60 * W, 68 * W)
    v, u = V[rows], u[rows] / w
    assert w * f_px == pytest.approx(f_px / 30)
    assert np.max(np.abs(v - circular_segment(u))) < 0.03
    assert np.mean(np.abs(v - circular_segment(u))) < 0.005
    order = np.argsort(u[:W], kind="stable")
    assert np.all(np.diff(v[:W][order]) >= -1e-6)
    assert np.all(v[u < -1.05] == 0) and np.all(v[u > 1.05] == 1)


def test_penumbra_widens_with_the_occluder_distance():
    """Eq 5: w = L·h/(H − h) — half the occluder height above the receiver, a narrower penumbra
    of the predicted width."""
    row = slice(64 * 160, 65 * 160)
    width = {}
    for h in (0.5, 0.25):
        gb, hard, d, D, u, w = edge_scene(h=h)
        v = soft_visibility(gb, (hard, d, D), 0.1, scene_diag=3.0, sigma=1e6).numpy()[row]
        width[h] = np.count_nonzero((v > 0) & (v < 1))
        assert width[h] == pytest.approx(2 * w * 600, abs=2)
    assert width[0.25] < width[0.5]


def test_matches_numpy_reference_on_a_blob_shadow():
    """Both passes and the boundary-tile selection against a NumPy gather over every pixel:
    two depth layers, an invalid patch, an irregular shadow."""
    W, H, f_px = 176, 128, 70.0
    yy, xx = np.mgrid[0:H, 0:W]
    depth = np.where(xx < 30, 2.0, 3.0) + 0.004 * yy
    valid = ~((xx > 60) & (yy < 10))
    gb = make_gbuffer(W, H, f_px, depth, valid)
    blob = ((xx - 40) ** 2 + (yy - 28) ** 2 < 150) | ((xx < 12) & (yy > 40))
    hard = np.where(blob & valid, 0.0, 1.0).ravel()
    d = np.where(hard == 0, 0.4 + 0.005 * xx.ravel(), 0)
    D = np.full(W * H, 1.5)
    args = [to_jit(mi.Float, a) for a in (hard, d, D)]
    V = soft_visibility(gb, args, radius=0.3, scene_diag=8.0, samples=(3, 4))
    ref = reference(gb, *args, L=0.3, diag=8.0, samples=(3, 4), sigma=0.05**2)
    assert np.count_nonzero((ref > 0) & (ref < 1)) > 300
    selected = _boundary_pixels(gb, *args, 0.3 * f_px, 8e-4, "soft")
    assert dr.width(selected) < W * H / 2  # the tile test skips most pixels
    np.testing.assert_allclose(V.numpy(), ref, atol=2e-5)
    V = soft_visibility(gb, args, 0.1, 8.0, mode="fixed_radius")
    ref = reference(gb, *args, L=0.0, diag=8.0, samples=(4, 5), sigma=0.05**2, fixed=0.1)
    np.testing.assert_allclose(V.numpy(), ref, atol=2e-5)


def test_depth_discontinuity_rejects_background_shadow():
    """O18: toggling a shadow on a far background changes nothing on the foreground."""
    W, H, f_px = 64, 48, 60.0
    xx = np.mgrid[0:H, 0:W][1]
    depth = np.where(xx < 32, 1.0, 3.0)
    gb = make_gbuffer(W, H, f_px, depth)
    front = (xx < 32).ravel()
    results = []
    for shadow in (False, True):
        hard = np.where(~front & shadow, 0.0, 1.0).astype(np.float32)
        d = np.where(hard == 0, 0.5, 0).astype(np.float32)
        V = soft_visibility(
            gb, (mi.Float(hard), mi.Float(d), mi.Float(np.full(W * H, 2.0))), 0.1, 2.0
        )
        results.append(V.numpy()[front])
    assert np.max(np.abs(results[0] - results[1])) < 0.01


def test_lattice_tap_counts():
    assert [len(lattice(n)) for n in (4, 5, 7)] == [49, 81, 149]
    assert np.allclose(lattice(5)[40], 0) and np.max(np.hypot(*lattice(5).T)) <= 1 + 1e-12


def test_bad_input_raises():
    gb, hard, d, D, *_ = edge_scene(16, 12)
    ok = {"radius": 0.1, "scene_diag": 3.0}
    cases = [
        ({"samples": (0, 5)}, "samples must be two positive integers"),
        ({"samples": (4,)}, "samples must be two positive integers"),
        ({"samples": (4.0, 5)}, "samples must be two positive integers"),
        ({"radius": -0.1}, "radius must be >= 0"),
        ({"radius": math.nan}, "radius must be >= 0"),
        ({"scene_diag": 0.0}, "scene_diag must be positive"),
        ({"sigma": 0.0}, "sigma must be positive"),
        ({"mode": "pcss"}, "mode must be one of"),
    ]
    for kwargs, message in cases:
        with pytest.raises(ParameterError, match=message):
            soft_visibility(gb, (hard, d, D), **{**ok, **kwargs})
    with pytest.raises(ParameterError, match="hard has 3 entries"):
        soft_visibility(gb, (mi.Float(1, 1, 1), d, D), **ok)
