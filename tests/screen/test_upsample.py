"""Subsampling and geometry-aware upsampling (spec seed-004 §2.8, A16, A22; oracles O19–O21)."""

import mitsuba as mi
import numpy as np
import pytest

from photonmap import ParameterError
from photonmap.screen.gbuffer import GBuffer
from photonmap.screen.upsample import subsample, upsample


def make_gbuffer(W, H, depth, nrm=(0.0, 0.0, -1.0), valid=None, f_px=50.0) -> GBuffer:
    """Pixels at per-pixel depth ``depth`` (H, W) with normals ``nrm`` ((H, W, 3) or one)."""
    x, y = np.meshgrid(np.arange(W) + 0.5 - W / 2, np.arange(H) + 0.5 - H / 2)
    z = np.broadcast_to(depth, (H, W)).ravel()
    pos = np.stack([x.ravel() / f_px * z, -y.ravel() / f_px * z, z])
    n = np.broadcast_to(nrm, (H, W, 3)).reshape(-1, 3).T
    valid = np.ones(W * H, bool) if valid is None else np.asarray(valid, bool).ravel()
    f32 = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
    return GBuffer(
        W, H, mi.Point3f(f32(pos)), mi.Normal3f(f32(n)), mi.Float(f32(z)),
        mi.Color3f(f32(np.full((3, W * H), 0.5))), mi.Bool(valid), mi.ScalarPoint3f(0, 0, 0),
        mi.ScalarVector3f(0, 0, 1), f_px,
    )  # fmt: skip


def centres(size, s):
    """Full-resolution coordinate of each low sample: the centre of its (clipped) block."""
    i = np.arange(-(-size // s))
    return i * s + np.minimum(s, size - i * s) // 2


def reference(low, low_gb, full_gb, s, p_n=8.0, sigma_z=0.05):
    """NumPy (float64) upsampler: bilinear × normal^p_n × depth Gaussian, A22 fallback."""
    W, H = full_gb.width, full_gb.height
    w = low_gb.width
    cx, cy = centres(W, s), centres(H, s)
    low = low.numpy().T
    ln, lz, lv = low_gb.nrm.numpy().T, low_gb.depth.numpy(), low_gb.valid.numpy()
    fn, fz, fv = full_gb.nrm.numpy().T, full_gb.depth.numpy(), full_gb.valid.numpy()
    out = np.zeros((W * H, 3))
    for k in range(W * H):
        x, y = k % W, k // W
        i0 = np.clip(np.searchsorted(cx, x, side="right") - 1, 0, len(cx) - 1)
        j0 = np.clip(np.searchsorted(cy, y, side="right") - 1, 0, len(cy) - 1)
        i1, j1 = min(i0 + 1, len(cx) - 1), min(j0 + 1, len(cy) - 1)
        tx = np.clip((x - cx[i0]) / max(cx[i1] - cx[i0], 1), 0, 1)
        ty = np.clip((y - cy[j0]) / max(cy[j1] - cy[j0], 1), 0, 1)
        total, acc, best, best_sim = 0.0, np.zeros(3), np.zeros(3), -1.0
        for i, j, b in ((i0, j0, (1 - tx) * (1 - ty)), (i1, j0, tx * (1 - ty)),
                        (i0, j1, (1 - tx) * ty), (i1, j1, tx * ty)):  # fmt: skip
            q = j * w + i
            if not lv[q]:
                continue
            sim = max(0.0, fn[k] @ ln[q]) ** p_n * np.exp(
                -(((lz[q] - fz[k]) / (sigma_z * fz[k])) ** 2)
            )
            total, acc = total + b * sim, acc + b * sim * low[q]
            if sim > best_sim:
                best, best_sim = low[q], sim
        out[k] = (acc / total if total >= 1e-4 else best) if fv[k] else 0
    return out


def test_subsample_point_samples_block_centres():
    W, H = 21, 13
    rng = np.random.default_rng(0)
    gb = make_gbuffer(W, H, rng.uniform(1, 2, (H, W)), valid=rng.uniform(size=(H, W)) > 0.2)
    for s in (2, 3, 4, 8):
        low = subsample(gb, s)
        assert (low.width, low.height) == (-(-W // s), -(-H // s))
        idx = (centres(H, s)[:, None] * W + centres(W, s)[None, :]).ravel()
        for name in ("pos", "nrm", "albedo"):
            np.testing.assert_array_equal(
                getattr(low, name).numpy(), getattr(gb, name).numpy()[:, idx]
            )
        np.testing.assert_array_equal(low.depth.numpy(), gb.depth.numpy()[idx])
        np.testing.assert_array_equal(low.valid.numpy(), gb.valid.numpy()[idx])
        assert low.f_px == gb.f_px / s
    assert list(centres(21, 8)) == [4, 12, 18]
    assert subsample(gb, 1) is gb


def test_s1_is_the_identity():
    """O19."""
    gb = make_gbuffer(10, 7, np.random.default_rng(1).uniform(1, 2, (7, 10)))
    values = mi.Color3f(np.random.default_rng(2).uniform(size=(3, 70)).astype(np.float32))
    np.testing.assert_array_equal(upsample(values, subsample(gb, 1), gb, 1).numpy(), values.numpy())


def test_constant_and_linear_fields_are_reproduced():
    """O20: a constant stays constant; on one plane a field linear in screen space is reproduced
    between the sample centres."""
    W, H, s = 67, 45, 8
    gb = make_gbuffer(W, H, 2.0)
    low_gb = subsample(gb, s)
    n = low_gb.width * low_gb.height
    const = upsample(mi.Color3f(np.full((3, n), 0.7, np.float32)), low_gb, gb, s).numpy()
    np.testing.assert_allclose(const, 0.7, rtol=1e-6)
    cx, cy = centres(W, s), centres(H, s)
    lx, ly = np.meshgrid(cx, cy)
    field = lambda x, y: 0.1 + 0.01 * x - 0.02 * y  # noqa: E731
    low = mi.Color3f(np.tile(field(lx, ly).ravel().astype(np.float32), (3, 1)))
    out = upsample(low, low_gb, gb, s).numpy()[0].reshape(H, W)
    y, x = np.mgrid[0:H, 0:W]
    inner = (x >= cx[0]) & (x <= cx[-1]) & (y >= cy[0]) & (y <= cy[-1])
    np.testing.assert_allclose(out[inner], field(x, y)[inner], atol=1e-5)


def test_no_bleeding_across_a_depth_discontinuity():
    """O21: planes at depths 1 and 2 with values 1 and 0 across a vertical step, s = 8."""
    W, H, s = 64, 40, 8
    near = np.mgrid[0:H, 0:W][1] < 29
    gb = make_gbuffer(W, H, np.where(near, 1.0, 2.0))
    low_gb = subsample(gb, s)
    low = mi.Color3f(
        np.tile(np.where(low_gb.depth.numpy() < 1.5, 1.0, 0.0), (3, 1)).astype(np.float32)
    )
    truth = near.ravel().astype(float)
    geometry = upsample(low, low_gb, gb, s).numpy()[0]
    bilinear = upsample(low, low_gb, gb, s, p_n=0, sigma_z=1e9).numpy()[0]
    assert np.max(np.abs(geometry - truth)) < 0.01
    assert np.max(np.abs(bilinear - truth)) > 0.1


def test_matches_numpy_reference_with_fallbacks():
    """Random normals, depths and holes (A22 fallbacks: most similar sample; 0 with none)."""
    W, H, s = 19, 14, 4
    rng = np.random.default_rng(5)
    nrm = rng.normal(size=(H, W, 3)) + [0, 0, -2]
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    valid = rng.uniform(size=(H, W)) > 0.25
    gb = make_gbuffer(W, H, rng.uniform(1, 1.3, (H, W)), nrm, valid)
    low_gb = subsample(gb, s)
    low = mi.Color3f(rng.uniform(size=(3, low_gb.width * low_gb.height)).astype(np.float32))
    out = upsample(low, low_gb, gb, s).numpy().T
    np.testing.assert_allclose(out, reference(low, low_gb, gb, s), rtol=1e-4, atol=1e-6)
    assert np.all(out[~valid.ravel()] == 0)


def test_bad_input_raises():
    gb = make_gbuffer(16, 8, 1.0)
    low_gb = subsample(gb, 4)
    low = mi.Color3f(np.zeros((3, 8), np.float32))
    for s in (0, -2, 2.5, True, "4"):
        with pytest.raises(ParameterError, match="s must be a positive integer"):
            subsample(gb, s)
        with pytest.raises(ParameterError, match="s must be a positive integer"):
            upsample(low, low_gb, gb, s)
    with pytest.raises(ParameterError, match="needs a 8×4 low-resolution G-buffer"):
        upsample(low, low_gb, gb, 2)
    with pytest.raises(ParameterError, match="sigma_z > 0"):
        upsample(low, low_gb, gb, 4, sigma_z=0)
