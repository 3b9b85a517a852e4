"""``photonmap.core.arrays``: ``concat``, ``to_numpy`` and ``channel_mean`` give what
``dr.concat``, ``.numpy()`` and ``dr.mean(…, axis=0)`` give, and launch the same kernels (the same
hashes) whatever the widths — where Dr.Jit's own launch a kernel per width, which the same check
shows; ``aligned`` NumPy arrays launch the same kernel wherever NumPy put them, where a misaligned
one launches another."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from photonmap.core.arrays import (
    ALIGNMENT,
    aligned,
    channel_mean,
    columns,
    concat,
    to_jit,
    to_numpy,
)

WIDTHS = [(5, 3), (17, 9), (100, 2)]  # (a part of width 1 is a scalar to Dr.Jit: other code)


def kernels(fn) -> tuple:
    """The hashes of the kernels ``fn()`` launches."""
    dr.eval()
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        fn()
        return tuple(k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT)


def parts(n: int, m: int) -> list:
    a, b = dr.arange(mi.Float, n), 0.5 * dr.arange(mi.Float, m) + 1000
    dr.eval(a, b)
    return [a, b]


def point(n: int) -> mi.Point3f:
    i = dr.arange(mi.Float, n)
    p = mi.Point3f(i, 2 * i, -i)
    dr.eval(p)
    return p


def test_concat_matches_dr_concat():
    a, b = parts(7, 4)
    np.testing.assert_array_equal(np.array(concat([a, b])), np.array(dr.concat([a, b])))
    empty = dr.zeros(mi.Float, 0)
    np.testing.assert_array_equal(np.array(concat([empty, a, empty])), np.array(a))
    p, q = point(3), point(2)
    np.testing.assert_array_equal(to_numpy(concat([p, q])), np.concatenate([p.numpy(), q.numpy()], 1))
    si = concat([dr.zeros(mi.SurfaceInteraction3f, 3), dr.zeros(mi.SurfaceInteraction3f, 2)])
    assert dr.width(si) == 5


def test_to_numpy_matches_numpy():
    p = point(6)
    np.testing.assert_array_equal(to_numpy(p), p.numpy())
    np.testing.assert_array_equal(to_numpy(mi.Color3f(p)), mi.Color3f(p).numpy())
    np.testing.assert_array_equal(to_numpy(dr.arange(mi.UInt32, 4)), [0, 1, 2, 3])
    assert to_numpy(mi.Point3f(1, 2, dr.arange(mi.Float, 3))).shape == (3, 3)  # broadcast


def test_channel_mean_matches_dr_mean():
    c = mi.Color3f(point(9)) * 0.37 + 1.0
    np.testing.assert_allclose(np.array(channel_mean(c)), np.array(dr.mean(c, axis=0)), rtol=1e-6)
    assert dr.width(channel_mean(mi.Color3f(1, 2, dr.arange(mi.Float, 4)))) == 4


def colour_mean(mean, n: int) -> None:
    c = mi.Color3f(point(n))
    dr.eval(mean(c))


@pytest.mark.parametrize(
    "ours, theirs",
    [
        (lambda n, m: dr.eval(concat(parts(n, m))), lambda n, m: dr.eval(dr.concat(parts(n, m)))),
        (lambda n, m: to_numpy(point(n + m)), lambda n, m: point(n + m).numpy()),
        (lambda n, m: colour_mean(channel_mean, n + m),
         lambda n, m: colour_mean(lambda c: dr.mean(c, axis=0), n + m)),
    ],
    ids=["concat", "to_numpy", "channel_mean"],
)
def test_one_kernel_for_every_width(ours, theirs):
    assert len({kernels(lambda n=n, m=m: ours(n, m)) for n, m in WIDTHS}) == 1
    assert len({kernels(lambda n=n, m=m: theirs(n, m)) for n, m in WIDTHS}) == len(WIDTHS)


def misaligned(values: np.ndarray, offset: int) -> np.ndarray:
    """``values`` copied ``offset`` bytes past a :data:`ALIGNMENT`-byte boundary."""
    buffer = np.zeros(values.nbytes + 2 * ALIGNMENT, np.uint8)
    start = -buffer.ctypes.data % ALIGNMENT + offset
    out = buffer[start : start + values.nbytes].view(values.dtype)
    out[...] = values
    return out


def test_aligned_arrays_launch_one_kernel_wherever_numpy_put_them():
    values = np.arange(40, dtype=np.float32) * 0.5
    homes = [misaligned(values, offset) for offset in (0, 4, 16, 32)]
    assert [h.ctypes.data % ALIGNMENT for h in homes] == [0, 4, 16, 32]

    def launch(array):
        return lambda: dr.eval(mi.Float(array) * 3.0 + 1.0)

    assert len({kernels(launch(h)) for h in homes}) > 1  # Dr.Jit's own: a kernel per alignment
    copies = [aligned(h) for h in homes]
    assert all(c.ctypes.data % ALIGNMENT == 0 for c in copies)
    assert len({kernels(launch(c)) for c in copies}) == 1
    for c in copies:
        np.testing.assert_array_equal(c, values)
        np.testing.assert_array_equal(np.array(mi.Float(c)), values)
    assert aligned(copies[0]) is copies[0]  # already aligned: no copy
    grid = aligned(misaligned(np.arange(24, dtype=np.uint32), 8).reshape(2, 3, 4)[:, ::2])
    assert grid.flags.c_contiguous and grid.ctypes.data % ALIGNMENT == 0
    np.testing.assert_array_equal(grid, np.arange(24).reshape(2, 3, 4)[:, ::2])


def test_to_jit_casts_before_dr_jit_maps_the_memory():
    """A float64 array into ``mi.Float`` makes Dr.Jit map a cast temporary wherever ``malloc``
    put it (measured outside this test, with random-sized allocations in between: two kernels
    in twelve launches; the allocator here does not always reproduce it); :func:`to_jit` casts
    into an aligned home first, so one kernel serves every launch."""
    values = np.arange(40, dtype=np.float64) * 0.5
    cast = aligned(misaligned(values, 8), np.float32)
    assert cast.dtype == np.float32 and cast.ctypes.data % ALIGNMENT == 0
    np.testing.assert_array_equal(cast, values)
    shifts = []  # kept alive: each launch's temporaries land elsewhere

    def launch(h):
        shifts.append(np.empty(len(shifts) * 13 % 50 + 1))
        return lambda: dr.eval(to_jit(mi.Float, h) * 3.0 + 1.0)

    homes = [misaligned(values, offset) for offset in (0, 8, 16, 32)] * 3
    assert len({kernels(launch(h)) for h in homes}) == 1
    np.testing.assert_array_equal(np.array(to_jit(mi.UInt32, values[::2])), np.arange(20))
    points = np.stack([values, -values, 2 * values], 1)  # (N, 3): its columns are strided
    np.testing.assert_array_equal(np.array(mi.Point3f(*columns(mi.Float, points))).T, points)
