"""Adaptive reconstruction (spec seed-000-002 §A6–A7, §5.7 oracles 31–32): the mipmap pyramids and
the level-selecting filter against NumPy references, and their invariants (constant fields stay
constant, counts preserved, zero weights ignored, the identity on a uniform field)."""

import mitsuba as mi
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from photonmap.volume import mipmap

N = 16  # max_level 2 → the centre-surround level is 0; 32 gives 3 levels to choose from


def tensor(a):
    return mi.TensorXf(np.ascontiguousarray(a, dtype=np.float32))


def shape3(n) -> tuple:
    """A grid's shape (n_z, n_y, n_x): ``n`` itself, or the cube ``(n, n, n)`` for an int."""
    return tuple(n) if isinstance(n, tuple) else (n, n, n)


def random_grids(n, seed=0):
    """Smooth-ish colour and direction fields, integer counts with holes, weights with zeros, on
    the cube n³ or a box grid of shape ``n = (n_z, n_y, n_x)``."""
    rng = np.random.default_rng(seed)
    shape = shape3(n)
    z, y, x = (a / max(shape) for a in np.mgrid[: shape[0], : shape[1], : shape[2]])
    base = 1 + np.sin(6 * x) * np.cos(5 * y) + (z > 0.5)
    C = base[..., None] * rng.uniform(0.5, 1.5, (*shape, 3))
    D = rng.normal(size=(*shape, 3))
    count = rng.integers(0, 4, shape).astype(float)
    weight = np.where(count > 0, rng.uniform(0.1, 3.0, shape), 0.0)
    return C, D, count, weight


def numpy_gauss_level(a):
    for axis in range(3):
        size = a.shape[axis]
        idx = 2 * np.arange((size + 1) // 2)
        a = sum(
            w * np.take(a, np.clip(idx + k - 1, 0, size - 1), axis=axis)
            for k, w in enumerate(mipmap.GAUSS4)
        )
    return a


def numpy_weight_level(count, weight):
    h = [(m + 1) // 2 for m in count.shape]
    pad = [(0, 2 * a - m) for a, m in zip(h, count.shape, strict=True)]
    blocks = (h[0], 2, h[1], 2, h[2], 2)
    c = np.pad(count, pad).reshape(blocks).sum((1, 3, 5))
    w = np.pad(weight, pad).reshape(blocks)
    k = (w > 0).sum((1, 3, 5))
    return c, np.where(k > 0, w.sum((1, 3, 5)) / np.maximum(k, 1), 0.0)


def numpy_pyramid(C, D, count, weight):
    """Levels (C, D, count, weight); D stays at level 0 (no direction pyramid)."""
    levels = [(C, D, count, weight)]
    for _ in range(mipmap.max_level(max(C.shape[:3]))):
        c, _, cnt, w = levels[-1]
        levels.append((numpy_gauss_level(c), D, *numpy_weight_level(cnt, w)))
    return levels


def unpack(pyramid, level, what):
    """Level ``level`` ≥ 1 of ``fields`` or ``colors`` (4 channels each) as a NumPy grid."""
    k = 4
    (mx, my, mz), start = pyramid.sizes[level], pyramid.offsets[level]
    data = np.array(getattr(pyramid, what))[k * start : k * (start + mx * my * mz)]
    return data.reshape(mz, my, mx, k)


def build(C, D, count, weight):
    return mipmap.build_pyramid(tensor(C), tensor(D), tensor(count), tensor(weight))


def test_gaussian_taps_are_the_spec_values():
    assert np.allclose(mipmap.GAUSS4, [0.21891, 0.28109, 0.28109, 0.21891], atol=1e-5)
    assert mipmap.max_level(128) == 5 and mipmap.max_level(4) == 0


@pytest.mark.parametrize("n", [16, 12, (6, 13, 16)])  # cubes and a box grid
def test_pyramid_matches_numpy(n):
    grids = random_grids(n)
    pyramid = build(*grids)
    reference = numpy_pyramid(*grids)
    assert pyramid.max_level == len(reference) - 1 == mipmap.max_level(max(shape3(n)))
    for level in range(1, pyramid.max_level + 1):
        c, _, count, weight = reference[level]
        fields, colors = unpack(pyramid, level, "fields"), unpack(pyramid, level, "colors")
        assert np.allclose(colors[..., :3], c, rtol=1e-5) and np.all(colors[..., 3] == 0)
        assert np.allclose(fields[..., 0], c.sum(-1), rtol=1e-5)
        assert np.array_equal(fields[..., 1], count)
        assert np.allclose(fields[..., 2], weight, rtol=1e-6)


def test_mipmap_invariants():
    """Oracle 31: constant stays constant, counts keep their total, zero weights are ignored."""
    n = 32
    C = np.full((n, n, n, 3), [0.3, 0.2, 0.1])
    count = np.random.default_rng(1).integers(0, 5, (n, n, n)).astype(float)
    weight = np.zeros((n, n, n))
    weight[:2, :2, :2] = [[[0, 2], [4, 0]], [[0, 0], [0, 0]]]  # one block: mean of 2 and 4
    pyramid = build(C, C, count, weight)
    for level in range(1, pyramid.max_level + 1):
        fields, colors = unpack(pyramid, level, "fields"), unpack(pyramid, level, "colors")
        assert np.allclose(colors[..., :3], [0.3, 0.2, 0.1], rtol=1e-5)
        assert fields[..., 1].sum() == count.sum()
    level1 = unpack(pyramid, 1, "fields")[..., 2]
    assert level1[0, 0, 0] == 3.0 and np.count_nonzero(level1) == 1
    assert unpack(pyramid, pyramid.max_level, "fields")[0, 0, 0, 2] == 3.0


def filter_level(w, delta_weight, top, blend):
    """Pfeuti's ⌊w/Δweight⌋ or the blended w/Δweight − ½, clamped to [0, top]."""
    return np.clip(w / delta_weight - 0.5 if blend else np.floor(w / delta_weight), 0, top)


def read_levels(sample, levels, level):
    """C at fractional ``level`` per voxel: (1 − t)·C_⌊ℓ⌋ + t·C_⌊ℓ⌋+1, with D of level 0."""
    top = len(levels) - 1
    out = np.stack([sample(levels[lvl][0], lvl) for lvl in range(top + 1)])
    lower = np.floor(level).astype(int)
    t = (level - lower)[:, None]
    c_lo = np.take_along_axis(out, lower[None, :, None], 0)[0]
    c_hi = np.take_along_axis(out, np.minimum(lower + 1, top)[None, :, None], 0)[0]
    return np.concatenate([(1 - t) * c_lo + t * c_hi, levels[0][1].reshape(-1, 3)], -1)


def centre_surround(d, top):
    """Listing B.3's centre-surround level from the differences ``d[k] = |Y_k − Y_{k+1}|``: rise
    from 0 to ``k`` while ``d[k] ≤ d[k−1]``, at most ``top − 2``."""
    cen = np.zeros(len(d[0]), int)
    if top >= 2:
        cur, nxt, going = d[0], d[1], np.ones(len(d[0]), bool)
        for k in range(1, top - 1):
            going &= nxt <= cur
            cen[going] = k
            cur = np.where(going, nxt, cur)
            nxt = np.where(going, d[k + 1], nxt)
    return cen


def numpy_filter(levels, delta_weight, blend=False):
    """Listing B.3 (as resolved in spec A7/A46) on NumPy levels read with trilinear interpolation
    at the voxel centres (scipy's map_coordinates, order 1, edges replicated)."""
    shape = levels[0][0].shape[:3]
    top = len(levels) - 1
    v = np.indices(shape).reshape(3, -1) + 0.5

    def sample(grid, level):
        coords = v / 2**level - 0.5
        if grid.ndim == 3:
            return map_coordinates(grid, coords, order=1, mode="nearest")
        return np.stack([sample(grid[..., c], level) for c in range(grid.shape[-1])], -1)

    Y = [sample(c.sum(-1), lvl) for lvl, (c, _, _, _) in enumerate(levels)]
    count = [sample(cnt, lvl) for lvl, (_, _, cnt, _) in enumerate(levels)]
    weight = [sample(w, lvl) for lvl, (_, _, _, w) in enumerate(levels)]
    wl = np.zeros(v.shape[1], int)
    while True:  # lowest level with count ≥ 1 (or the top)
        more = (np.take_along_axis(np.stack(count), wl[None], 0)[0] < 1) & (wl < top)
        if not more.any():
            break
        wl += more
    w = np.take_along_axis(np.stack(weight), wl[None], 0)[0]
    w_level = filter_level(w, delta_weight, top, blend)
    d = [np.abs(Y[k] - Y[k + 1]) for k in range(top)]
    cen = centre_surround(d, top)
    level = np.minimum(w_level, cen)
    return level, read_levels(sample, levels, level)


def assert_matches(C, D, level, ref_level, ref) -> np.ndarray:
    """The filter's levels and its (C, D) output equal the NumPy reference's (up to float ties in
    the level comparisons, at most 0.1% of the voxels); returns the levels as NumPy."""
    level = np.array(level)
    same = np.isclose(level, ref_level, rtol=0, atol=1e-4)
    assert np.mean(same) > 0.999
    assert len(set(level)) > 1
    out = np.concatenate([np.array(C), np.array(D)], -1).reshape(-1, 6)
    assert np.allclose(out[same], ref[same], rtol=1e-4, atol=1e-5)
    return level


@pytest.mark.parametrize("n", [32, 64, (20, 37, 64)])
@pytest.mark.parametrize("empty", [False, True])
@pytest.mark.parametrize("blend", [False, True])
@pytest.mark.parametrize("delta_weight", [0.2, 0.7, 1.2])
def test_filter_matches_numpy(delta_weight, blend, empty, n):
    """Per voxel; ``empty``: a slab no photon crossed, whose voxels find their weight at a coarse
    level (Listing B.3) and may still be read at a finer one. At 64³ (5 levels) most voxels take
    the loop-free path (``mipmap._dense_levels``), the others the level loop; the box grid
    has levels of different extents per axis."""
    grids = random_grids(n, seed=2)
    if empty:
        grids[2][:, :, shape3(n)[2] // 4 :] = 0
        grids[3][:, :, shape3(n)[2] // 4 :] = 0
    C, D, level = mipmap.reconstruct(build(*grids), delta_weight, blend=blend)
    ref_level, ref = numpy_filter(numpy_pyramid(*grids), delta_weight, blend)
    level = assert_matches(C, D, level, ref_level, ref)


@pytest.mark.parametrize("blend", [False, True])
@pytest.mark.parametrize("delta_weight", [0.3, 1.0, 5.0])
def test_uniform_field_is_reconstructed_unchanged(delta_weight, blend):
    """Oracle 32: constant C → every centre-surround difference is 0, cenLevel = max_level − 2;
    uniform sampling → w̄ = 1, wLevel = ⌊1/Δweight⌋ (blended: 1/Δweight − ½); the output equals
    the input. The identity also holds for any weights."""
    n = 32
    C = np.full((n, n, n, 3), [0.5, 0.25, 2.0])
    D = np.full((n, n, n, 3), [0.0, -1.0, 0.5])
    ones = np.ones((n, n, n))
    out_C, out_D, level = mipmap.reconstruct(build(C, D, ones, ones), delta_weight, blend=blend)
    top = mipmap.max_level(n)
    w_level = max(1 / delta_weight - 0.5, 0) if blend else int(1 / delta_weight)
    assert np.allclose(np.array(level), min(w_level, top - 2), atol=1e-6)
    assert np.allclose(np.array(out_C), C, rtol=1e-6) and np.allclose(np.array(out_D), D, atol=1e-6)
    rng = np.random.default_rng(5)
    weights = rng.uniform(0, 4, (n, n, n)) * (rng.random((n, n, n)) > 0.3)
    out_C, _, level = mipmap.reconstruct(build(C, D, ones, weights), delta_weight, blend=blend)
    assert np.allclose(np.array(out_C), C, rtol=1e-6)


def test_zero_photon_voxels_take_the_weight_of_a_coarser_level():
    """Listing B.3: where no photon passed, the weight filter reads the first level whose count
    is ≥ 1 — here level 1 of a grid whose odd voxels are empty."""
    n = 16
    C = np.ones((n, n, n, 3))
    count = np.zeros((n, n, n))
    count[::2, ::2, ::2] = 1
    weight = 2.5 * count
    _, _, level = mipmap.reconstruct(build(C, C, count, weight), delta_weight=1.0)
    level = np.array(level).reshape(n, n, n)
    top = mipmap.max_level(n)
    assert np.all(level == min(2, top - 2))  # w̄ = 2.5 everywhere → wLevel 2, cen = top − 2


def test_weight_step_follows_the_photon_density():
    """Δweight holds at 16 photons per voxel column (Pfeuti's 262144 at 128³) and scales with the
    square root of the budget (the photon noise's 1/√N)."""
    assert mipmap.weight_step(1.0, 512**2, 128) == 1.0
    assert mipmap.weight_step(0.5, 2048**2, 128) == 2.0
    assert mipmap.weight_step(1.0, 256**2, 128) == 0.5
    assert mipmap.weight_step(1.0, 16 * 32**2, 32) == 1.0


# ---- per-block level selection (mip_block = 2, our extension) --------------------------------
def numpy_block_filter(levels, delta_weight, blend=False):
    """The block variant of :func:`numpy_filter`: one level per 2×2×2 block, read at the block
    centre (level 1: the block's own cell), the weight filter decided at level 0 by the block's
    crossed voxels (smallest level), d₀ = mean over the block of |Y₀(v) − Y₁|; every voxel then
    reads its block's level at its own centre."""
    shape = levels[0][0].shape[:3]
    top = len(levels) - 1
    nb = tuple((m + 1) // 2 for m in shape)
    centres = (np.indices(nb).reshape(3, -1) * 2 + 1.0).astype(float)

    def sample(grid, level, points):
        coords = points / 2**level - 0.5
        if grid.ndim == 3:
            return map_coordinates(grid, coords, order=1, mode="nearest")
        return np.stack([sample(grid[..., c], level, points) for c in range(grid.shape[-1])], -1)

    C0, _, count0, weight0 = levels[0]
    pad = [(0, 2 * b - m) for b, m in zip(nb, shape, strict=True)]
    blocks = (nb[0], 2, nb[1], 2, nb[2], 2)
    inside = np.pad(np.ones(shape, bool), pad).reshape(blocks)
    Y0 = np.pad(C0.sum(-1), pad).reshape(blocks)
    crossed = np.pad(count0 >= 1, pad).reshape(blocks)
    own = filter_level(np.pad(weight0, pad), delta_weight, top, blend).reshape(blocks)
    found = crossed.any((1, 3, 5)).ravel()
    w_own = np.where(crossed, own, top).min((1, 3, 5)).ravel()
    Y = [None] + [sample(c.sum(-1), lvl, centres) for lvl, (c, _, _, _) in enumerate(levels)][1:]
    count = [None] + [sample(cnt, lvl, centres) for lvl, (_, _, cnt, _) in enumerate(levels)][1:]
    weight = [None] + [sample(w, lvl, centres) for lvl, (_, _, _, w) in enumerate(levels)][1:]
    wl = np.where(found, 0, 1)
    for lvl in range(1, top):  # lowest level ≥ 1 with count ≥ 1 (or the top)
        wl = np.where((wl == lvl) & (count[lvl] < 1), lvl + 1, wl)
    coarse_w = np.take_along_axis(np.stack(weight[1:]), wl[None] - 1, 0)[0]
    coarse_level = filter_level(coarse_w, delta_weight, top, blend)
    w_level = np.where(found, w_own, coarse_level)
    Y1 = Y[1].reshape(nb[0], 1, nb[1], 1, nb[2], 1)
    spread = np.where(inside, np.abs(Y0 - Y1), 0).sum((1, 3, 5)) / inside.sum((1, 3, 5))
    d = [spread.ravel()] + [np.abs(Y[k] - Y[k + 1]) for k in range(1, top)]
    cen = centre_surround(d, top)
    block_level = np.minimum(w_level, cen).reshape(nb)
    level = block_level.repeat(2, 0).repeat(2, 1).repeat(2, 2)
    level = level[: shape[0], : shape[1], : shape[2]].ravel()
    v = np.indices(shape).reshape(3, -1) + 0.5
    return level, read_levels(lambda grid, lvl: sample(grid, lvl, v), levels, level)


@pytest.mark.parametrize(
    "n, delta_weight, blend",
    [(32, 0.2, False), (32, 0.7, False), (32, 1.2, False), (33, 0.7, False), (32, 0.7, True),
     (33, 0.2, True), ((17, 24, 33), 0.7, True)],
)  # fmt: skip
def test_block_filter_matches_numpy(n, delta_weight, blend):
    grids = random_grids(n, seed=4)
    empty = shape3(n)[0] // 3  # a region no photon crossed: the weight of a coarser level decides
    grids[2][empty:] = 0
    grids[3][empty:] = 0
    C, D, level = mipmap.reconstruct(build(*grids), delta_weight, block=2, blend=blend)
    ref_level, ref = numpy_block_filter(numpy_pyramid(*grids), delta_weight, blend)
    level = assert_matches(C, D, level, ref_level, ref)
    blocks = level.reshape(shape3(n))
    odd = blocks[1::2, 1::2, 1::2]
    assert np.array_equal(
        blocks[::2, ::2, ::2][: odd.shape[0], : odd.shape[1], : odd.shape[2]], odd
    )


@pytest.mark.parametrize("delta_weight", [0.3, 1.0, 5.0])
def test_block_filter_keeps_a_uniform_field(delta_weight):
    """Oracle 32 for the block filter: the same levels as per voxel, the output equals the input."""
    n = 32
    C = np.full((n, n, n, 3), [0.5, 0.25, 2.0])
    D = np.full((n, n, n, 3), [0.0, -1.0, 0.5])
    ones = np.ones((n, n, n))
    out_C, out_D, level = mipmap.reconstruct(build(C, D, ones, ones), delta_weight, block=2)
    assert np.all(np.array(level) == min(int(1 / delta_weight), mipmap.max_level(n) - 2))
    assert np.allclose(np.array(out_C), C, rtol=1e-6) and np.allclose(np.array(out_D), D, atol=1e-6)


def test_bad_block_raises():
    grids = random_grids(16)
    with pytest.raises(mipmap.ParameterError, match="block must be one of"):
        mipmap.reconstruct(build(*grids), 1.0, block=4)
