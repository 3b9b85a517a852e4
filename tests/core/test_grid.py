"""``core.grid.filter_separable``: a separable 3D filter with clamp-to-edge indices against a NumPy
convolution, and one compiled kernel for every axis and grid size (stride and extent opaque)."""

import drjit as dr
import mitsuba as mi
import numpy as np

import photonmap  # noqa: F401  (selects the Mitsuba variant)
from photonmap.core.arrays import to_jit
from photonmap.core.grid import filter_axis, filter_separable

TAPS = [0.25, 0.5, 0.25, 0.125, 0.0]  # asymmetric, with a zero tap (skipped)


def reference(values: np.ndarray, taps, axes=(0, 1, 2)) -> np.ndarray:
    """Clamp-to-edge convolution along each axis in turn, centred on the middle tap."""
    r = (len(taps) - 1) // 2
    out = values.astype(np.float64)
    for axis in axes:
        n = out.shape[axis]
        acc = np.zeros_like(out)
        for o, w in zip(range(-r, r + 1), taps, strict=True):
            index = np.clip(np.arange(n) + o, 0, n - 1)
            acc += w * np.take(out, index, axis=axis)
        out = acc
    return out


def test_filter_separable_matches_numpy():
    rng = np.random.default_rng(3)
    values = rng.uniform(0, 1, (5, 7, 6, 2)).astype(np.float32)
    got = np.array(filter_separable(to_jit(mi.TensorXf, values), TAPS))
    np.testing.assert_allclose(got, reference(values, TAPS), rtol=2e-6, atol=1e-6)


def test_one_kernel_for_every_axis_and_size():
    def kernels(shape) -> set:
        t = to_jit(mi.TensorXf, np.ones(shape, np.float32))
        dr.eval(t)
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history()
            for axis in range(3):
                dr.eval(filter_axis(t, TAPS, axis))
            return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}

    one = kernels((4, 5, 6, 3))
    assert len(one) == 1
    assert kernels((8, 3, 2, 1)) == one
