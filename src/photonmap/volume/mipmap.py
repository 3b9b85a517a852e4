"""A6–A7 — reconstruction of Pfeuti's adaptive pipeline: mipmap pyramids and the per-voxel level
selection (Pfeuti 2009 §3.2.4, Listings B.2, B.3): stages A6–A7 of the pipeline (:mod:`.pipeline`).
The thesis gives the filters' names, not all their details; the choices are said below.

**A6 mipmaps.** Level ℓ+1 from level ℓ, per axis, for the colour ``C``: a 4-tap Gaussian of variance
4 (fine voxels) at offsets −1.5 … +1.5 around the coarse cell centre, weights :data:`GAUSS4` =
[0.21891, 0.28109, 0.28109, 0.21891], clamped edges, then decimation by 2 ("4x4x4 with variance
four", cascaded level to level). Photon counts: the sum of the 2×2×2 children (so a count ≥ 1 means
some photon crossed the region). Average photon weights: the mean over the children with weight > 0,
0 if none (Listing B.2). Levels up to ``max_level = log₂N − 2`` (4³ for 128³: the thesis skips "the
last few levels").

The direction sums ``D`` get no pyramid (Pfeuti filters them like ``C``): every voxel keeps its
level-0 ``D``, and the pipeline does not even S8-smooth it. ``D̂`` only orients the phase function
and is smooth already. On the SPHERE / CUBE / MESH scenes at 131072 photons the image RMSE is
0.00604 / 0.01034 / 0.01266 with level-0 directions against 0.00606 / 0.01035 / 0.01267 with
filtered ones (integer per-block levels, Δweight scaled linearly), and the pyramid and the filter's
colour reads halve (≈ 30 ms of ≈ 100 at 128³); without S8 on ``D`` it is 0.00497 / 0.00900 /
0.01189 against 0.00504 / 0.00900 / 0.01189 (blended per-voxel levels), ≈ 20 ms less.

**A7 filter.** Every level is read at the voxel centres of the full grid with trilinear
interpolation. Per voxel:

- photon-weight filter: the lowest level ``l`` whose count is ≥ 1 gives the weight ``w̄_l``;
  ``wLevel = clamp(⌊w̄_l / Δweight⌋, 0, max_level)`` (the pipeline scales Δweight with the photon
  budget, :func:`weight_step`);
- centre-surround filter on ``Y = R+G+B``, ``d_k = |Y_k − Y_{k+1}|``: the level rises from 0 to
  ``k`` while ``d_k ≤ d_{k−1}`` and ``k + 1 < max_level`` (Listing B.3, whose typos are read as: the
  count loop updates ``pc``, ``curDiff`` starts from levels 0 and 1);
- ``level = min(wLevel, cenLevel)``; the output is ``C_level`` at the voxel (and its ``D``).

Cost (the thesis paid ~30 ms of its 48 ms overhead here): the Gaussian levels are separable
Dr.Jit passes over shrinking grids; the filter is one symbolic loop over the levels per voxel,
reading one packed (ΣRGB, count, weight) vector per corner and level, and a voxel leaves the loop
as soon as its level is decided — at once where photons of weight below Δweight crossed it
(``wLevel = 0``), else when its weight is known and the centre-surround level has stopped or
reached ``⌈wLevel⌉``. A second pass reads the colour of the chosen level(s) (levels ≥ 1 only;
reading the colours inside the level loop instead was no faster at 128³, 72 ms either way: the
loop's extra state costs what the second pass saves). Most voxels never take the loop: a crossed
voxel with ``wLevel ≤ 2`` needs only levels 1–3, which :func:`_dense_levels` reads once for every
voxel, their colours serving both the centre-surround test and the output (SPHERE, 131072 photons,
128³: 74 → 53 ms for the filter, the same levels and colours).

**Blended levels** (``blend``, the pipeline's default ``mip_blend``; our extension): the
photon-weight level is not quantised, ``wLevel = clamp(w/Δweight − ½, 0, max_level)`` — the
piecewise-linear interpolation of Pfeuti's steps ``⌊w/Δweight⌋`` through their midpoints — and a
fractional level ``ℓ + t`` reads ``(1 − t)·C_ℓ + t·C_{ℓ+1}``, as a GPU's trilinear mipmap lookup
does. Pfeuti's steps switch a voxel between no blur and a whole level of it at a weight threshold,
which leaves seams along the pdf's contours. Measured at 131072 photons, 128³, per voxel
(``benchmarks/adaptive_vs_reference.py`` scenes, √-scaled Δweight = 1): image RMSE 0.00518 →
0.00504 SPHERE, 0.00915 → 0.00900 CUBE, 0.01253 → 0.01189 MESH.

**Per-block levels** (``block = 2``; our extension, ``1`` is Pfeuti's per-voxel filter and the
pipeline's default ``mip_block``): the level loop runs once per 2×2×2 block at the block centre.
The block's photon-weight level is decided at level 0 by its crossed voxels (the smallest of their
levels, so a caustic voxel keeps its block sharp), its level-1 centre-surround difference is the
mean of ``|Y_0(v) − Y_1|`` over its voxels; every voxel is then read at its block's level at its
own centre, so the output stays trilinear. Measured as above with blended levels: the filter takes
≈ 48 ms instead of ≈ 56 ms per voxel (SPHERE, in the pipeline), but the image RMSE is 0.00560 /
0.00851 / 0.01257 against 0.00504 / 0.00900 / 0.01189 per voxel (SPHERE / CUBE / MESH).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import concat
from ..core.errors import ParameterError
from ..core.grid import flat_index, grid_shape, trilinear_packed, voxel_count, voxel_of

# the 4-tap Gaussian of variance 4 at these offsets (fine voxels from the coarse cell centre),
# normalised: [0.21891, 0.28109, 0.28109, 0.21891]
GAUSS4_OFFSETS = np.array([-1.5, -0.5, 0.5, 1.5])
GAUSS4 = tuple(
    float(w) for w in np.exp(-(GAUSS4_OFFSETS**2) / 8) / np.exp(-(GAUSS4_OFFSETS**2) / 8).sum()
)


REFERENCE_DENSITY = 16  # photons per voxel column of the grid face: Pfeuti's 262144 at 128³


def weight_step(delta_weight: float, photons: int, n: int) -> float:
    """Δweight for the weights ``w = 1/p`` of ``photons`` importance photons on an ``n³`` grid.

    The user's Δweight holds at the reference density of :data:`REFERENCE_DENSITY` photons per
    voxel column and scales with ``√photons`` from there. Pfeuti's weight ``1/(p·A·N)`` falls as
    ``1/N`` (linear scaling here); a budget-free ``w = 1/p`` would keep the levels (and
    their blur) at any budget. The photon noise of a voxel falls as ``1/√N`` while the bias of a
    level's blur does not depend on N, so the weight at which a level pays grows as ``√N``.
    Measured (``benchmarks/adaptive_vs_reference.py`` scenes, 128³): at half the reference density
    √ scaling lowers the image RMSE of Pfeuti's integer filter on SPHERE / CUBE by 4% / 15% (MESH
    +6%), and the blended filter's best Δweight is then 1.0–1.2 at 131072, 262144 and 524288
    photons alike (it was 1.5–2 / 1 / < 1 with linear scaling).
    """
    return delta_weight * math.sqrt(photons / (REFERENCE_DENSITY * n * n))


def max_level(n: int) -> int:
    """The top level built for an ``n³`` grid: 4³ cells, at least level 0. A box grid builds
    the levels of its longest side ``n``."""
    return max(0, int(math.floor(math.log2(n))) - 2)


def _layout(shape, axis: int, extent: int):
    """For an output of ``shape`` (with ``extent`` input cells along ``axis``): each output
    element's coordinate along ``axis`` and the flat input index of its coordinate 0."""
    size = int(np.prod(shape))
    inner = int(np.prod(shape[axis + 1 :]))
    idx = dr.arange(mi.UInt32, size)
    coord = (idx // inner) % shape[axis]
    base = (idx // (inner * shape[axis])) * (inner * extent) + idx % inner
    return mi.Int32(coord), base, inner


def reduce_axis(t: mi.TensorXf, axis: int) -> mi.TensorXf:
    """Halve ``t`` along ``axis`` with the 4-tap Gaussian: ``out[c] = Σ_k GAUSS4[k] ·
    t[clamp(2c − 1 + k)]``."""
    shape = list(t.shape)
    extent = shape[axis]
    shape[axis] = (extent + 1) // 2
    coord, base, inner = _layout(shape, axis, extent)
    out = dr.zeros(mi.Float, int(np.prod(shape)))
    for k, w in enumerate(GAUSS4):
        f = dr.clip(2 * coord + k - 1, 0, extent - 1)
        out += w * dr.gather(mi.Float, t.array, base + mi.UInt32(f) * inner)
    out = mi.TensorXf(out, tuple(shape))
    dr.eval(out)
    return out


def _gaussian_level(t: mi.TensorXf) -> mi.TensorXf:
    for axis in (0, 1, 2):
        t = reduce_axis(t, axis)
    return t


def _channels(t: mi.TensorXf) -> list:
    """The channels of a (..., c) tensor as flat arrays."""
    c = t.shape[-1]
    idx = dr.arange(mi.UInt32, dr.width(t.array) // c) * c
    return [dr.gather(mi.Float, t.array, idx + k) for k in range(c)]


def _interleave(arrays) -> mi.Float:
    """Flat per-cell arrays → one array with ``len(arrays)`` channels per cell."""
    k = len(arrays)
    out = dr.zeros(mi.Float, dr.width(arrays[0]) * k)
    idx = dr.arange(mi.UInt32, dr.width(arrays[0])) * k
    for c, a in enumerate(arrays):
        dr.scatter(out, a, idx + c)
    return out


def _weight_level(count: mi.Float, weight: mi.Float, m: tuple) -> tuple[mi.Float, mi.Float]:
    """Next level of the count and average-weight grids (extent ``m = (m_x, m_y, m_z)`` →
    ``⌈m/2⌉`` per axis): the sum of the 2×2×2 children's counts and the mean of their non-zero
    weights (Listing B.2), 0 where all are 0."""
    half = tuple((c + 1) // 2 for c in m)
    cell = dr.arange(mi.UInt32, voxel_count(half))
    x, y, z = (2 * c for c in voxel_of(cell, half))
    total, wsum, nonzero = mi.Float(0), mi.Float(0), mi.Float(0)
    for dz in (0, 1):
        for dy in (0, 1):
            for dx in (0, 1):
                inside = (x + dx < m[0]) & (y + dy < m[1]) & (z + dz < m[2])
                child = flat_index(x + dx, y + dy, z + dz, m)
                w = dr.gather(mi.Float, weight, child, inside)
                total += dr.gather(mi.Float, count, child, inside)
                wsum += w
                nonzero += dr.select(w > 0, 1.0, 0.0)
    weight = wsum / dr.maximum(nonzero, 1.0)
    dr.eval(total, weight)
    return total, weight


@dataclass
class Pyramid:
    """Levels 0 … max_level of the phase-2 grids. Level 0 as marched: ``C``, ``D``
    (n_z, n_y, n_x, 3), ``count``, ``weight`` (n_z, n_y, n_x). Levels ℓ ≥ 1 packed for vector
    gathers and concatenated, from cell ``offsets[ℓ]`` on, of extent ``sizes[ℓ]`` (cells along
    x, y, z): ``fields`` = (ΣRGB, count, average weight, 0) per cell; ``colors`` = (C rgb, 0) per
    cell."""

    C: mi.TensorXf
    D: mi.TensorXf
    count: mi.TensorXf
    weight: mi.TensorXf
    fields: mi.Float
    colors: mi.Float
    offsets: list
    sizes: list

    @property
    def max_level(self) -> int:
        return len(self.sizes) - 1


def build_pyramid(
    C: mi.TensorXf, D: mi.TensorXf, count: mi.TensorXf, weight: mi.TensorXf, levels=None
) -> Pyramid:
    """A6: the colour, count and weight pyramids of the phase-2 grids (``D`` is kept at level 0,
    see the module notes)."""
    dims = _dims(C)
    levels = max_level(max(dims)) if levels is None else levels
    c, cnt, w, m = C, count.array, weight.array, dims
    fields, colors, offsets, sizes = [], [], [0, 0], [dims]
    for _ in range(levels):
        c = _gaussian_level(c)
        cnt, w = _weight_level(cnt, w, m)
        m = _dims(c)
        sizes.append(m)
        offsets.append(offsets[-1] + voxel_count(m))
        rgb, zero = _channels(c), dr.zeros(mi.Float, voxel_count(m))
        fields.append(_interleave([rgb[0] + rgb[1] + rgb[2], cnt, w, zero]))
        colors.append(_interleave([*rgb, zero]))
        dr.eval(fields[-1], colors[-1])
    fields = concat(fields) if fields else dr.zeros(mi.Float, 4)
    colors = concat(colors) if colors else dr.zeros(mi.Float, 4)
    dr.eval(fields, colors)
    return Pyramid(C, D, count, weight, fields, colors, offsets[: len(sizes)], sizes)


def _dims(t: mi.TensorXf) -> tuple[int, int, int]:
    """The extent ``(n_x, n_y, n_z)`` of a grid tensor (n_z, n_y, n_x[, c])."""
    return tuple(int(c) for c in t.shape[:3])[::-1]


def _voxel_centres(n: tuple, voxel: mi.UInt32 | None = None) -> mi.Point3f:
    """The centres of the voxels with flat indices ``voxel`` (default: every voxel, in order) of a
    grid of extent ``n``."""
    voxel = dr.arange(mi.UInt32, voxel_count(n)) if voxel is None else voxel
    return mi.Point3f(*(mi.Float(c) for c in voxel_of(voxel, n))) + 0.5


def _size_table(pyramid: Pyramid) -> list:
    """Per axis, the extent of every mip level (three ``mi.Int32`` indexed by level)."""
    return [mi.Int32([s[axis] for s in pyramid.sizes]) for axis in range(3)]


def _level_dims(table: list, level: mi.Int32) -> tuple:
    """The extent of mip level ``level`` per lane, from :func:`_size_table`."""
    return tuple(dr.gather(mi.Int32, t, level) for t in table)


BLOCKS = (1, 2)  # reconstruction granularity: per voxel (Pfeuti) or per 2×2×2 block


def _children(n: tuple, block: int):
    """Per block of ``block³`` voxels (flat [z, y, x] over the ``⌈n/block⌉`` blocks per axis of
    a grid of extent ``n``): the block coordinates and, per child offset ``o`` (x fastest), the
    child's flat voxel index (clamped) and whether it lies inside the grid."""
    nb = tuple((c + block - 1) // block for c in n)
    b = mi.Point3u(*voxel_of(dr.arange(mi.UInt32, voxel_count(nb)), nb))
    far = mi.Point3u(*n)
    children = []
    for oz in range(block):
        for oy in range(block):
            for ox in range(block):
                v = b * block + mi.Point3u(ox, oy, oz)
                inside = dr.all(v < far)
                v = dr.minimum(v, far - 1)
                children.append((flat_index(v.x, v.y, v.z, n), inside))
    return b, children


def _spread(fine_Y: list, fine_in: list):
    """``Y_1 ↦`` the mean of ``|Y_0(v) − Y_1|`` over a block's voxels inside the grid."""
    inside = sum(dr.select(mask, 1.0, 0.0) for mask in fine_in)

    def spread(Y1):
        total = sum(
            dr.select(mask, dr.abs(y - Y1), 0.0) for y, mask in zip(fine_Y, fine_in, strict=True)
        )
        return total / dr.maximum(inside, 1.0)

    return spread


def _filter_level(w, dw, top: int, blend: bool) -> mi.Float:
    """The photon-weight filter's level of average weight ``w``: ``clamp(⌊w/Δweight⌋, 0, top)``
    (Pfeuti's, stage A7) or, with ``blend``, ``clamp(w/Δweight − ½, 0, top)`` — the piecewise-linear
    interpolation of Pfeuti's steps through their midpoints."""
    if blend:
        return dr.clip(w / dw - 0.5, 0.0, top)
    return dr.clip(dr.floor(w / dw), 0.0, top)


@dr.syntax
def _levels(pyramid, centre, Y, spread, found, w_level, dw, blend) -> mi.Float:
    """The Listing B.3 level loop (stage A7) from level 1 on, at ``centre`` (fine voxel units), given the
    level-0 state: ``Y`` (ΣRGB), ``found`` / ``w_level`` (photon-weight filter decided at level 0).
    With ``spread`` (:func:`_spread` of a block) the level-1 centre-surround difference is the mean
    of the block's voxels' ``|Y_0(v) − Y_1|``."""
    top = pyramid.max_level
    size = dr.width(centre)
    cen = dr.zeros(mi.Int32, size)
    cur_diff = dr.zeros(mi.Float, size)
    going = dr.full(mi.Bool, True, size)
    level = dr.full(mi.Int32, 1, size)
    offsets = mi.UInt32(pyramid.offsets)
    table = _size_table(pyramid)
    active = (level <= top) & (~found | (w_level > 0))
    while active:
        m = _level_dims(table, level)
        base = dr.gather(mi.UInt32, offsets, level)
        scale = dr.rcp(mi.Float(mi.Int32(1) << level))
        f = trilinear_packed(pyramid.fields, m, 1, centre * scale, base)[0]
        # photon-weight filter: the weight of the lowest level that photons crossed
        take = ~found & ((f.y >= 1) | (level == top))
        w_level = dr.select(take, _filter_level(f.z, dw, top, blend), w_level)
        found |= take
        # centre-surround filter: d = |Y_{level−1} − Y_level|; rise while d does not increase
        diff = dr.abs(Y - f.x)
        if spread is not None:
            diff = dr.select(level == 1, spread(f.x), diff)
        moved = going & (level >= 2) & (level - 1 <= top - 2) & (diff <= cur_diff)
        going = dr.select(level >= 2, moved, going)
        cen = dr.select(moved, level - 1, cen)
        cur_diff = dr.select((level == 1) | moved, diff, cur_diff)
        Y = f.x
        level += 1
        limit = dr.minimum(mi.Int32(dr.ceil(w_level)), top - 2)
        active = (level <= top) & (~found | (going & (level - 1 <= limit)))
    return dr.minimum(w_level, mi.Float(cen))


def select_levels(
    pyramid: Pyramid,
    delta_weight: float,
    block: int = 1,
    blend: bool = False,
    voxel: mi.UInt32 | None = None,
) -> mi.Float:
    """A7: the mip level of every voxel (``block = 1``, flat [z, y, x]) or of every 2×2×2 block
    (``block = 2``, flat over the ``⌈n/2⌉`` blocks per axis): the minimum of the photon-weight and the
    centre-surround filter, an integer, or with ``blend`` a fractional level (the photon-weight
    level unquantised, :func:`_filter_level`). A voxel stops reading coarser levels as soon as both
    are decided (its weight is found and the centre-surround level has stopped or reached
    ``⌈wLevel⌉``).

    Per block (our extension, 8× fewer level loops): the levels are read at the block centre;
    the photon-weight filter is decided at level 0 if any of its voxels was crossed (``wLevel`` =
    the smallest of those voxels' levels, so a caustic voxel keeps the block sharp); the level-1
    centre-surround difference is the mean of the voxels' ``|Y_0(v) − Y_1|``.

    ``voxel`` (per voxel only): the levels of the voxels with these flat indices.
    """
    if block not in BLOCKS:
        raise ParameterError(f"the reconstruction block must be one of {BLOCKS}, got {block!r}")
    n, top = pyramid.sizes[0], pyramid.max_level
    dw = dr.opaque(mi.Float, delta_weight)
    count, weight = pyramid.count.array, pyramid.weight.array
    if block == 1:
        idx = dr.arange(mi.UInt32, voxel_count(n)) if voxel is None else voxel
        Y = dr.sum(dr.gather(mi.Vector3f, pyramid.C.array, idx))
        found = dr.gather(mi.Float, count, idx) >= 1
        w = _filter_level(dr.gather(mi.Float, weight, idx), dw, top, blend)
        w_level = dr.select(found, w, top)
        return _levels(pyramid, _voxel_centres(n, idx), Y, None, found, w_level, dw, blend)
    b, children = _children(n, block)
    size = dr.width(b.x)
    found = dr.zeros(mi.Bool, size)
    w_level = dr.full(mi.Float, top, size)
    fine_Y, fine_in, Y = [], [], dr.zeros(mi.Float, size)
    for idx, inside in children:
        y = dr.sum(dr.gather(mi.Vector3f, pyramid.C.array, idx))
        crossed = inside & (dr.gather(mi.Float, count, idx) >= 1)
        own = _filter_level(dr.gather(mi.Float, weight, idx), dw, top, blend)
        w_level = dr.select(crossed, dr.minimum(w_level, own), w_level)
        found |= crossed
        fine_Y.append(y)
        fine_in.append(inside)
    centre = mi.Point3f(b) * block + 0.5 * block
    spread = _spread(fine_Y, fine_in)
    return _levels(pyramid, centre, Y, spread, found, w_level, dw, blend)


def block_to_voxels(level: mi.Float, n, block: int) -> mi.Float:
    """The level of every voxel (flat [z, y, x]) of a grid of extent ``n`` (``(n_x, n_y, n_z)``)
    from the level of every ``block³`` block."""
    n = tuple(n)
    nb = tuple((c + block - 1) // block for c in n)
    x, y, z = (c // block for c in voxel_of(dr.arange(mi.UInt32, voxel_count(n)), n))
    return dr.gather(mi.Float, level, flat_index(x, y, z, nb))


def _colour(pyramid: Pyramid, level, active=True, voxel: mi.UInt32 | None = None) -> mi.Vector3f:
    """``C`` of mip level ``level`` ≥ 1 (a Python int, or one per lane) read at the centres of the
    voxels ``voxel`` (flat indices, default all; trilinear, ``active`` lanes)."""
    if isinstance(level, int):
        m, base, scale = pyramid.sizes[level], pyramid.offsets[level], 0.5**level
    else:
        m = _level_dims(_size_table(pyramid), level)
        base = dr.gather(mi.UInt32, mi.UInt32(pyramid.offsets), level)
        scale = dr.rcp(mi.Float(mi.Int32(1) << level))
    p = _voxel_centres(pyramid.sizes[0], voxel) * scale
    a = trilinear_packed(pyramid.colors, m, 1, p, base, active)[0]
    return mi.Vector3f(a.x, a.y, a.z)


def _read_colours(pyramid: Pyramid, voxel: mi.UInt32, level: mi.Float) -> mi.Vector3f:
    """``C`` of the voxels ``voxel`` at their fractional levels ``ℓ + t``:
    ``(1 − t)·C_ℓ + t·C_{ℓ+1}`` (level 0: the voxel's own ``C``)."""
    lower = mi.Int32(dr.floor(level))
    t = level - mi.Float(lower)
    c = dr.gather(mi.Vector3f, pyramid.C.array, voxel)
    c = dr.select(lower >= 1, _colour(pyramid, lower, lower >= 1, voxel), c)
    upper = _colour(pyramid, dr.minimum(lower + 1, pyramid.max_level), t > 0, voxel)
    return dr.select(t > 0, dr.lerp(c, upper, t), c)


DENSE_TOP = 4  # the dense path needs levels 1–3 and Listing B.3's rise at level 3 (top ≥ 4)


def _dense_levels(pyramid: Pyramid, dw, blend: bool):
    """The per-voxel filter for the common voxels, without the level loop: ``(level, C, dense)``.

    A voxel crossed by photons whose photon-weight level is ``w ≤ 2`` needs at most levels 1–3:
    Listing B.3 moves ``cen`` to 1 at level 2 if ``d₂ ≤ d₁`` and to 2 at level 3 if also
    ``d₃ ≤ d₂``, and the loop stops there (it reads no level above ``⌈w⌉ + 1``), so
    ``level = min(w, cen)`` comes from ``C₁``, ``C₂`` read once for every voxel (they give both
    ``Y`` and the output colours) and ``Y₃`` where it can matter. The other voxels (``dense``
    false: not crossed, or ``w > 2``) take the loop (:func:`select_levels`)."""
    top = pyramid.max_level
    found = pyramid.count.array >= 1
    w = dr.select(found, _filter_level(pyramid.weight.array, dw, top, blend), top)
    dense = found & (w <= 2)
    c0 = dr.unravel(mi.Vector3f, pyramid.C.array)
    c1, c2 = _colour(pyramid, 1, dense & (w > 0)), _colour(pyramid, 2, dense & (w > 0))
    y0, y1, y2 = dr.sum(c0), dr.sum(c1), dr.sum(c2)
    d1, d2 = dr.abs(y0 - y1), dr.abs(y1 - y2)
    rise1 = d2 <= d1
    y3 = dr.sum(_colour(pyramid, 3, dense & rise1 & (w > 1)))
    rise2 = rise1 & (dr.abs(y2 - y3) <= d2)
    cen = dr.select(rise2, 2.0, dr.select(rise1, 1.0, 0.0))
    level = dr.minimum(w, cen)
    lower = dr.floor(level)
    t = level - lower
    c_low = dr.select(lower == 0, c0, dr.select(lower == 1, c1, c2))
    c_high = dr.select(lower == 0, c1, c2)
    return level, dr.select(t > 0, dr.lerp(c_low, c_high, t), c_low), dense


def reconstruct(
    pyramid: Pyramid, delta_weight: float, block: int = 1, blend: bool = False
) -> tuple[mi.TensorXf, mi.TensorXf, mi.Float]:
    """A7: the filtered ``C``, the unnormalised level-0 ``D`` (n_z, n_y, n_x, 3) and the level of every
    voxel. ``block = 2`` selects one level per 2×2×2 block (:func:`select_levels`); every voxel is
    then read at its block's level (trilinear at the voxel centre, as per voxel). A fractional
    level ``ℓ + t`` (``blend``) reads ``(1 − t)·C_ℓ + t·C_{ℓ+1}``, as a GPU's trilinear mipmap
    lookup blends two levels."""
    n = pyramid.sizes[0]
    if block == 1 and pyramid.max_level >= DENSE_TOP:
        level, c, dense = _dense_levels(pyramid, dr.opaque(mi.Float, delta_weight), blend)
        dr.eval(level, c, dense)
        rest = dr.compress(~dense)  # the voxels the level loop decides
        if dr.width(rest):
            dr.scatter(level, select_levels(pyramid, delta_weight, 1, blend, rest), rest)
    else:
        level = select_levels(pyramid, delta_weight, block, blend)
        if block > 1:
            level = block_to_voxels(level, n, block)
        c, rest = dr.zeros(mi.Vector3f, voxel_count(n)), dr.arange(mi.UInt32, voxel_count(n))
    dr.eval(level)
    if dr.width(rest):
        dr.scatter(c, _read_colours(pyramid, rest, dr.gather(mi.Float, level, rest)), rest)
    C = mi.TensorXf(dr.ravel(c), grid_shape(n, 3))
    dr.eval(C)
    return C, pyramid.D, level
