"""Subsampled indirect light and geometry-aware upsampling (Yao 2011 §3.5, Figs 3.12–3.14; the
thesis gives neither the subsampling rule nor the weights: they are said below).

**Subsample**: the low-resolution G-buffer of factor s has ⌈W/s⌉×⌈H/s⌉ pixels; low pixel (i, j)
point-samples the full-resolution pixel at the centre of its block, X(i) = i·s + ⌊b/2⌋ with b the
block's width (s, or less for the last block when s does not divide W), likewise Y(j). Positions and
normals are never averaged.

**Upsample**: a full-resolution pixel with normal n and depth Z reads the four low samples around it
(the bilinear footprint, with the samples at their exact full-resolution coordinates X(i), Y(j)):

    w_k = b_k · max(0, n·n_k)^p_n · exp(−(Δz_k / (σ_z Z))²),    L = Σ w_k L_k / Σ w_k,

b_k the bilinear weights; invalid samples get w_k = 0. If Σ w_k < 1e-4 the pixel takes the valid
sample with the largest normal × depth similarity (ignoring b_k); with no valid sample, or on an
invalid pixel, it gets 0. s = 1 returns the input unchanged.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.errors import ParameterError
from .gbuffer import GBuffer

MIN_WEIGHT = 1e-4
"""Below this total weight the upsampler falls back to the most similar sample."""


def _check_factor(s) -> int:
    if isinstance(s, bool) or not isinstance(s, int | np.integer) or s < 1:
        raise ParameterError(
            f"the subsampling factor s must be a positive integer (1, 2, 4, 8, ...), got {s!r}"
        )
    return int(s)


def _low_size(width: int, height: int, s: int) -> tuple[int, int]:
    return -(-width // s), -(-height // s)


def _centre(i, s: int, size: int):
    """Full-resolution coordinate X(i) of low sample i (the centre of its possibly clipped block)."""
    return i * s + dr.minimum(s, size - i * s) // 2


def _left_sample(x, s: int, size: int):
    """The last low sample i with X(i) ≤ x (sample 0 for the pixels left of X(0))."""
    last = -(-size // s) - 1
    i = dr.clip((x - s // 2) // s, 0, last)
    return dr.select((i < last) & (x >= _centre(i + 1, s, size)), i + 1, i)  # clipped last block


def _power(x: mi.Float, p: float) -> mi.Float:
    """``x^p``; by repeated squaring for a small integer p (8× faster than ``dr.power``)."""
    if not (float(p).is_integer() and p <= 64):
        return dr.power(x, dr.opaque(mi.Float, p))
    result, p = mi.Float(1.0), int(p)
    while p:
        if p & 1:
            result = result * x
        x, p = x * x, p >> 1
    return result


def subsample(gbuf: GBuffer, s: int) -> GBuffer:
    """The ⌈W/s⌉×⌈H/s⌉ G-buffer that point-samples each s×s block's centre pixel (f_px → f_px/s)."""
    s = _check_factor(s)
    if s == 1:
        return gbuf
    w, h = _low_size(gbuf.width, gbuf.height, s)
    k = dr.arange(mi.Int32, w * h)
    x = _centre(k % w, s, gbuf.width)
    y = _centre(k // w, s, gbuf.height)
    idx = mi.UInt32(y * gbuf.width + x)
    take = lambda a: dr.gather(type(a), a, idx)  # noqa: E731
    low = GBuffer(
        w, h, take(gbuf.pos), take(gbuf.nrm), take(gbuf.depth), take(gbuf.albedo),
        take(gbuf.valid), gbuf.eye, gbuf.forward, gbuf.f_px / s,
    )  # fmt: skip
    dr.eval(low.pos, low.nrm, low.depth, low.albedo, low.valid)
    return low


def upsample(
    low: mi.Color3f,
    low_gbuf: GBuffer,
    full_gbuf: GBuffer,
    s: int,
    p_n: float = 8,
    sigma_z: float = 0.05,
) -> mi.Color3f:
    """Geometry-aware upsampling of ``low`` (one value per pixel of ``low_gbuf``, the
    :func:`subsample` of ``full_gbuf`` by ``s``) to the pixels of ``full_gbuf``."""
    s = _check_factor(s)
    W, H = full_gbuf.width, full_gbuf.height
    w, h = _low_size(W, H, s)
    if (low_gbuf.width, low_gbuf.height) != (w, h) or dr.width(low) != w * h:
        raise ParameterError(
            f"upsampling {W}×{H} by s = {s} needs a {w}×{h} low-resolution G-buffer and values; got "
            f"{low_gbuf.width}×{low_gbuf.height} and {dr.width(low)} values (use subsample())"
        )
    if not p_n >= 0 or not sigma_z > 0:
        raise ParameterError(f"need p_n >= 0 and sigma_z > 0, got p_n={p_n!r}, sigma_z={sigma_z!r}")
    if s == 1:
        return mi.Color3f(low)
    inv_sigma = dr.opaque(mi.Float, 1.0 / sigma_z)
    k = dr.arange(mi.Int32, W * H)
    x, y = k % W, k // W
    i0, j0 = _left_sample(x, s, W), _left_sample(y, s, H)
    i1, j1 = dr.minimum(i0 + 1, w - 1), dr.minimum(j0 + 1, h - 1)
    x0, x1 = _centre(i0, s, W), _centre(i1, s, W)
    y0, y1 = _centre(j0, s, H), _centre(j1, s, H)
    tx = dr.clip(mi.Float(x - x0) / mi.Float(dr.maximum(x1 - x0, 1)), 0, 1)
    ty = dr.clip(mi.Float(y - y0) / mi.Float(dr.maximum(y1 - y0, 1)), 0, 1)

    # per low sample two 16-byte records: (normal, depth or −1 if invalid) and (value, 0)
    low_n, low_z = mi.Vector3f(low_gbuf.nrm), dr.select(low_gbuf.valid, low_gbuf.depth, -1.0)
    geometry = dr.ravel(mi.Vector4f(low_n.x, low_n.y, low_n.z, low_z))
    values = dr.ravel(mi.Vector4f(low.x, low.y, low.z, 0))
    dr.eval(geometry, values)
    n, z = mi.Vector3f(full_gbuf.nrm), full_gbuf.depth
    total, weighted = mi.Float(0), mi.Color3f(0)
    best_sim, best = dr.full(mi.Float, -1, W * H), mi.Color3f(0)
    for i, j, b in ((i0, j0, (1 - tx) * (1 - ty)), (i1, j0, tx * (1 - ty)),
                    (i0, j1, (1 - tx) * ty), (i1, j1, tx * ty)):  # fmt: skip
        idx = mi.UInt32(j * w + i)
        g = dr.gather(mi.Vector4f, geometry, idx)
        ok = g.w >= 0
        dz = (g.w - z) * inv_sigma / z
        cos = dr.maximum(dr.dot(n, mi.Vector3f(g.x, g.y, g.z)), 0)
        sim = dr.select(ok, _power(cos, p_n) * dr.exp(-dz * dz), 0)
        v = dr.gather(mi.Vector4f, values, idx)
        value = mi.Color3f(v.x, v.y, v.z)
        total += b * sim
        weighted += b * sim * value
        better = ok & (sim > best_sim)
        best_sim = dr.select(better, sim, best_sim)
        best = dr.select(better, value, best)
    out = dr.select(total >= MIN_WEIGHT, weighted / dr.maximum(total, MIN_WEIGHT), best)
    out = dr.select(full_gbuf.valid, out, 0)
    dr.eval(out)
    return out
