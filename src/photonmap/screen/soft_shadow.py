"""Image-space soft shadows by image space gathering (Yao 2011 §3.4, Eqs 2–5, Figs 3.10–3.11; after
Robison & Shirley 2009). The thesis leaves the units open: L is read as a world-space light radius
(times the focal length in pixels), t and σ in units of the scene diagonal, "samples 4+5" as radial
step counts on a disk lattice.

Inputs per pixel: the hard visibility V_h ∈ {0, 1}, the occluder distance d (from the receiver,
where V_h = 0) and the light distance D of the ray-traced shadow map (:mod:`.direct`). All radii are
in pixels.

1. Blocker search, Eqs (2)–(4): over the **shadowed** pixels p_i in the disk R_p = L·f_px/Z_eye,
   g = Σ γ_i d_i / Σ γ_i with the range weight γ = exp(−t²/σ), t the world distance of p_i and p_0
   in units of the scene diagonal (ω = 1). No blocker: V_s = V_h.
2. Penumbra, Eq (5): R_g = f_px·L·g / ((D − g)·Z_eye), D − g clamped ≥ 1e-4·diag; if R_g < 0.5 px
   V_s = V_h, else V_s = Σ γ_i V_h,i / Σ γ_i over **all** valid pixels in the disk R_g.

Each pass reads the taps (i, j)·R/n with i² + j² ≤ n² ("Samples 4+5": n = 4 and 5, 49 and 81 taps),
rounded to the nearest pixel; taps outside the image are skipped. The lattice is rotated by
:data:`LATTICE_ANGLE` so that screen-aligned straight edges do not line up with whole tap columns:
on a straight shadow edge (w = 10–40 px) the axis-aligned lattice is off the exact area-light
profile by up to 0.04–0.06, the rotated one by ≤ 0.02.

``mode="fixed_radius"`` skips step 1 and blurs every pixel with R_g = f_px·r/Z_eye for a world
radius r (Yao Ch. 5, "just apply blur in a certain radius alone the shadow edge"); ``"hard"``
returns V_h. L = 0 (r = 0) gives V_h exactly.

**Only pixels near a shadow boundary are gathered.** V_s ≠ V_h needs a shadowed and a lit pixel
within reach, so the image is cut into tiles of :data:`TILE` pixels and a tile is worked on only if
it holds lit pixels with a shadowed tile within its largest R_p, or shadowed pixels with a lit tile
within a bound on their R_g (R_g grows with g, and g ≤ the largest d within R_p); reaches are
rounded up to powers of two tiles. Those pixels are compressed into one batch; every other pixel
keeps V_h, which is what the full gather gives there.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.errors import ParameterError
from .gbuffer import GBuffer

MODES = ("soft", "hard", "fixed_radius")
"""``"soft"``: ISG, Eqs 2–5; ``"hard"``: V_h; ``"fixed_radius"``: a fixed world blur radius."""
TILE = 8
"""Tile edge (pixels) of the boundary search."""
LATTICE_ANGLE = 0.35
"""Rotation (radians) of the tap lattice."""
MIN_GAP = 1e-4
"""Lower clamp of D − g in Eq (5), in units of the scene diagonal."""


def lattice(n: int) -> np.ndarray:
    """The taps (i, j)/n with i² + j² ≤ n², rotated by :data:`LATTICE_ANGLE`: (count, 2) in the
    unit disk."""
    i, j = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1))
    keep = i * i + j * j <= n * n
    c, s = math.cos(LATTICE_ANGLE), math.sin(LATTICE_ANGLE)
    x, y = i[keep] / n, j[keep] / n
    return np.stack([c * x - s * y, s * x + c * y], axis=1)


def soft_visibility(
    gbuf: GBuffer,
    shadow_map: tuple,
    radius: float,
    scene_diag: float,
    samples: tuple[int, int] = (4, 5),
    sigma: float = 0.05**2,
    mode: str = "soft",
) -> mi.Float:
    """Soft visibility V_s ∈ [0, 1] per pixel of ``gbuf`` (module docstring) from its
    ``shadow_map = (hard, occluder_dist, light_dist)`` (:func:`~.direct.shade`'s V_h, d and D).

    ``radius``: world-space radius — L, the virtual area light's (``"soft"``), or r, the blur's
    (``"fixed_radius"``); 0 gives V_h; ``scene_diag``: the scene's bounding-box diagonal (unit of
    t); ``samples``: (n₁, n₂) lattice steps of the two passes; ``sigma``: σ of γ in diagonal
    units²; ``mode``: one of :data:`MODES`.
    """
    if mode not in MODES:
        raise ParameterError(f"soft-shadow mode must be one of {MODES}, got {mode!r}")
    hard, occluder_dist, light_dist = shadow_map
    if (
        not isinstance(samples, tuple | list)
        or len(samples) != 2
        or not all(isinstance(n, int | np.integer) and not isinstance(n, bool) for n in samples)
        or min(samples) < 1
    ):
        raise ParameterError(
            f"samples must be two positive integers (n1, n2), e.g. (4, 5), got {samples!r}"
        )
    if not (math.isfinite(radius) and radius >= 0):
        raise ParameterError(f"radius must be >= 0 (0 = hard shadows), got {radius!r}")
    if not (math.isfinite(scene_diag) and scene_diag > 0):
        raise ParameterError(f"scene_diag must be positive, got {scene_diag!r}")
    if not (math.isfinite(sigma) and sigma > 0):
        raise ParameterError(f"sigma must be positive (default 0.05**2), got {sigma!r}")
    W, H = gbuf.width, gbuf.height
    for name, a in (("hard", hard), ("occluder_dist", occluder_dist), ("light_dist", light_dist)):
        if dr.width(a) != W * H:
            raise ParameterError(f"{name} has {dr.width(a)} entries for a {W}×{H} G-buffer")
    hard = mi.Float(hard)
    if mode == "hard" or radius == 0:
        return hard

    f_px = gbuf.f_px
    gap = MIN_GAP * scene_diag
    idx = _boundary_pixels(gbuf, hard, occluder_dist, light_dist, f_px * radius, gap, mode)
    out = dr.copy(hard)
    if dr.width(idx) == 0:
        return out
    valid = gbuf.valid
    code = dr.select(valid, dr.select(hard < 0.5, occluder_dist, -1.0), -2.0)
    pos = mi.Point3f(gbuf.pos)
    rec = dr.ravel(mi.Vector4f(pos.x, pos.y, pos.z, code))  # (x, y, z, d | −1 lit | −2 none)
    taps = [mi.Float(lattice(n).ravel()) for n in samples]
    counts = [dr.opaque(mi.UInt32, len(lattice(n))) for n in samples]
    scales = (
        dr.opaque(mi.Float, f_px * radius),
        dr.opaque(mi.Float, 1.0 / (sigma * scene_diag * scene_diag)),
        dr.opaque(mi.Float, gap),
    )
    V = _gather(
        idx, (rec, gbuf.depth, light_dist), (taps, counts), (W, H), scales, mode == "soft"
    )
    dr.scatter(out, V, idx)
    dr.eval(out)
    return out


@dr.syntax
def _gather(idx, buffers, lattices, size, scales, isg):
    """V_s of the pixels ``idx`` (two passes of lattice taps; module docstring): ``buffers =
    (rec, depth, light_dist)`` per pixel, ``lattices = (taps, counts)`` of the two passes, the
    image ``size = (W, H)``, ``scales = (size_px, k_gamma, gap)``."""
    rec, depth, light_dist = buffers
    taps, counts = lattices
    W, H = size
    size_px, k_gamma, gap = scales
    lanes = dr.width(idx)
    x0 = mi.Float(idx % W)
    y0 = mi.Float(idx // W)
    c = dr.gather(mi.Vector4f, rec, idx)
    p0, v_hard = mi.Point3f(c.x, c.y, c.z), dr.select(c.w < -0.5, 1.0, 0.0)
    z0 = dr.gather(mi.Float, depth, idx)
    if dr.hint(isg, mode="scalar"):
        # step 1: γ-weighted mean occluder distance over the shadowed pixels within R_p
        radius = size_px / z0
        k = dr.zeros(mi.UInt32, lanes)
        sum_w, sum_wd = dr.zeros(mi.Float, lanes), dr.zeros(mi.Float, lanes)
        while k < counts[0]:
            q, ok = _tap(rec, taps[0], k, x0, y0, radius, W, H)
            ok &= q.w >= 0
            w = dr.exp(-dr.squared_norm(mi.Point3f(q.x, q.y, q.z) - p0) * k_gamma)
            sum_w += dr.select(ok, w, 0)
            sum_wd += dr.select(ok, w * q.w, 0)
            k += 1
        g = sum_wd / dr.maximum(sum_w, 1e-30)
        d_light = dr.gather(mi.Float, light_dist, idx)
        radius = size_px * g / (dr.maximum(d_light - g, gap) * z0)
        blur = (sum_w > 0) & (radius >= 0.5)
    else:
        radius = size_px / z0
        blur = radius >= 0.5
    # step 2: γ-weighted mean of V_h over the valid pixels within R_g
    k = dr.zeros(mi.UInt32, lanes)
    sum_w, sum_wv = dr.zeros(mi.Float, lanes), dr.zeros(mi.Float, lanes)
    while blur & (k < counts[1]):
        q, ok = _tap(rec, taps[1], k, x0, y0, radius, W, H)
        ok &= q.w > -1.5
        w = dr.exp(-dr.squared_norm(mi.Point3f(q.x, q.y, q.z) - p0) * k_gamma)
        sum_w += dr.select(ok, w, 0)
        sum_wv += dr.select(ok & (q.w < -0.5), w, 0)
        k += 1
    return dr.select(blur & (sum_w > 0), sum_wv / dr.maximum(sum_w, 1e-30), v_hard)


def _tap(rec, taps, k, x0, y0, radius, W, H):
    """The record of tap ``k`` at radius ``radius`` around pixel (x0, y0) and whether it lies in
    the image."""
    o = dr.gather(mi.Vector2f, taps, k)
    x = dr.floor(x0 + o.x * radius + 0.5)
    y = dr.floor(y0 + o.y * radius + 0.5)
    inside = (x >= 0) & (x < W) & (y >= 0) & (y < H)
    j = mi.UInt32(dr.select(inside, y * W + x, 0))
    return dr.gather(mi.Vector4f, rec, j, inside), inside


def _boundary_pixels(gbuf, hard, d, D, size_px, gap, mode) -> mi.UInt32:
    """Indices of the pixels whose V_s may differ from V_h (module docstring, tile test)."""
    W, H, T = gbuf.width, gbuf.height, TILE
    tw, th = -(-W // T), -(-H // T)
    stats = _tile_stats(gbuf.valid, hard, gbuf.depth, d, D, W, H, tw * th)
    dr.eval(stats)  # one kernel for all six
    shadow_t, lit_t, z_min, d_max, D_min, z_min_shadowed = (
        a.numpy().reshape(th, tw) for a in stats
    )
    shadow_t, lit_t = shadow_t > 0, lit_t > 0
    reach_t = _tile_reach(size_px / z_min)  # R_p (soft) or the fixed R_g
    candidate = lit_t & _dilate(shadow_t, reach_t)
    if mode == "soft":  # R_g ≤ size·d_near / ((D − d_near)·Z), d_near ≥ g of the tile's pixels
        d_near = _dilate(d_max, reach_t)
        bound = size_px * d_near / (np.maximum(D_min - d_near, gap) * z_min_shadowed)
        reach_t = _tile_reach(np.where(shadow_t, bound, 0))
    candidate |= shadow_t & _dilate(lit_t, reach_t)
    k = dr.arange(mi.UInt32, W * H)
    tile = (k // W // T) * tw + (k % W) // T
    return dr.compress(gbuf.valid & dr.gather(mi.Bool, mi.Bool(candidate.ravel()), tile))


@dr.syntax
def _tile_stats(valid, hard, depth, d, D, W, H, tiles):
    """Per tile of :data:`TILE`² pixels: any shadowed, any lit, min Z_eye (valid pixels), and over
    the shadowed pixels max d, min D, min Z_eye (0 / +∞ when there are none)."""
    t = dr.arange(mi.UInt32, tiles)
    tw = -(-W // TILE)
    x0, y0 = (t % tw) * TILE, (t // tw) * TILE
    shadow, lit = dr.zeros(mi.Float, tiles), dr.zeros(mi.Float, tiles)
    z_min, z_min_shadowed = dr.full(mi.Float, dr.inf, tiles), dr.full(mi.Float, dr.inf, tiles)
    d_max, D_min = dr.zeros(mi.Float, tiles), dr.full(mi.Float, dr.inf, tiles)
    k = dr.zeros(mi.UInt32, tiles)
    while k < TILE * TILE:
        x, y = x0 + k % TILE, y0 + k // TILE
        inside = (x < W) & (y < H)
        i = y * W + x
        ok = dr.gather(mi.Bool, valid, i, inside)
        dark = ok & (dr.gather(mi.Float, hard, i, ok) < 0.5)
        z = dr.gather(mi.Float, depth, i, ok)
        shadow = dr.select(dark, 1.0, shadow)
        lit = dr.select(ok & ~dark, 1.0, lit)
        z_min = dr.select(ok, dr.minimum(z_min, z), z_min)
        z_min_shadowed = dr.select(dark, dr.minimum(z_min_shadowed, z), z_min_shadowed)
        d_max = dr.select(dark, dr.maximum(d_max, dr.gather(mi.Float, d, i, dark)), d_max)
        D_min = dr.select(dark, dr.minimum(D_min, dr.gather(mi.Float, D, i, dark)), D_min)
        k += 1
    return shadow, lit, z_min, d_max, D_min, z_min_shadowed


def _tile_reach(radius_t: np.ndarray) -> np.ndarray:
    """Tiles a tap at ``radius`` pixels (+ rounding) can reach from a pixel of the tile, rounded
    up to a power of two (few distinct dilations)."""
    limit = max(radius_t.shape)
    reach = np.minimum(np.floor((np.minimum(radius_t, limit * TILE) + 1) / TILE), limit) + 1
    return np.exp2(np.ceil(np.log2(reach))).astype(np.int64)


def _dilate(a: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """Per tile t: the maximum of ``a`` over the tiles within Chebyshev distance ``reach[t]``."""
    out = np.zeros_like(a)
    for k in np.unique(reach):
        box = a
        for axis in (0, 1):
            pad = np.pad(box, [(k, k) if ax == axis else (0, 0) for ax in (0, 1)])
            box = np.lib.stride_tricks.sliding_window_view(pad, 2 * k + 1, axis).max(-1)
        out = np.where(reach == k, box, out)
    return out
