"""Stage S4 (octree levels and step limits): oracles 11–13 of spec seed-000-002 §5.3."""

import mitsuba as mi
import numpy as np
import pytest

import photonmap  # noqa: F401  (selects the Mitsuba variant)
from photonmap.core.errors import ParameterError
from photonmap.volume.octree import build_octree

EPSILONS = [0.001, 0.005, 0.05, 0.15]


def octree_levels_reference(n_np: np.ndarray, eps: float, kappa=None, eps_kappa=np.inf):
    """Brute force: the largest k whose level-k cell (2^k aligned, clipped to the grid) holding
    the voxel has a range of n below ``eps`` (and of every κ channel below ``eps_kappa``)."""
    n = n_np.shape[0]
    depth = int(np.ceil(np.log2(n)))
    levels = np.zeros(n_np.shape, dtype=int)
    for k in range(depth + 1):
        s = 2**k
        for z in range(0, n, s):
            for y in range(0, n, s):
                for x in range(0, n, s):
                    cell = np.s_[z : z + s, y : y + s, x : x + s]
                    uniform = np.ptp(n_np[cell]) < eps
                    if kappa is not None:
                        uniform &= bool(np.all(np.ptp(kappa[cell], axis=(0, 1, 2)) < eps_kappa))
                    if uniform:
                        levels[cell] = k
    return levels


def field(kind: str, n: int) -> np.ndarray:
    rng = np.random.default_rng(n)
    if kind == "uniform":
        values = 1.0 + rng.uniform(0.0, 0.01, (n, n, n))
    elif kind == "smooth":
        values = 1.0 + np.cumsum(np.cumsum(rng.uniform(0.0, 0.01, (n, n, n)), 0), 2)
    else:  # blurred sphere
        c = np.arange(n) - 0.37 * n
        d = np.sqrt(c[:, None, None] ** 2 + c[None, :, None] ** 2 + c[None, None, :] ** 2)
        values = 1.0 + 0.5 / (1.0 + np.exp((d - 0.3 * n) / 1.5))
    return values.astype(np.float32)


def levels(values: np.ndarray, eps: float, eps2=None, **kwargs):
    octree = build_octree(mi.TensorXf(values), eps, eps2, **kwargs)
    assert octree.level.shape == octree.step_limit.shape == (*values.shape[:3], 1)
    return octree.level.numpy()[..., 0], octree.step_limit.numpy()[..., 0]


@pytest.mark.parametrize("n", [16, 12, 20])
@pytest.mark.parametrize("kind", ["uniform", "smooth", "sphere"])
def test_levels_equal_brute_force(kind, n):
    values = field(kind, n)
    counts = []
    for eps in EPSILONS:
        level, step_limit = levels(values, eps)
        np.testing.assert_array_equal(level, octree_levels_reference(values, eps))
        assert np.all(step_limit == np.inf)
        counts.append(len(np.unique(level)))
    assert max(counts) >= 2  # the fields are not trivially uniform or all-split


@pytest.mark.parametrize("n", [16, 12])
def test_constant_field_is_one_node(n):
    level, _ = levels(np.full((n, n, n), 1.33, np.float32), 0.005)
    assert np.all(level == int(np.ceil(np.log2(n))))


def test_single_voxel_perturbation_splits_its_ancestors():
    values = np.full((16, 16, 16), 1.2, np.float32)
    values[9, 4, 13] += 0.006
    level, _ = levels(values, 0.005)
    np.testing.assert_array_equal(level[8:10, 4:6, 12:14], 0)
    assert np.count_nonzero(level == 0) == 8
    assert level[0, 0, 0] == 3 and level[8, 4, 11] == 2 and level[9, 6, 13] == 1
    np.testing.assert_array_equal(level, octree_levels_reference(values, 0.005))
    assert np.all(levels(values, 0.007)[0] == 4)


@pytest.mark.parametrize("kind", ["smooth", "sphere"])
def test_second_tolerance_and_step_limit(kind):
    values = field(kind, 16)
    for eps, eps2 in [(0.005, 0.02), (0.05, 0.15), (0.001, 0.05)]:
        basic, _ = levels(values, eps)
        level, step_limit = levels(values, eps, eps2, ds_max=8.0)
        np.testing.assert_array_equal(level, octree_levels_reference(values, eps2))
        assert np.all(level >= basic)
        np.testing.assert_array_equal(step_limit == np.inf, level == basic)
        assert set(np.unique(step_limit)) == {8.0, np.inf}
        same, step_limit = levels(values, eps, eps)
        np.testing.assert_array_equal(same, basic)
        assert np.all(step_limit == np.inf)


@pytest.mark.parametrize("kind", ["uniform", "smooth", "sphere"])
def test_levels_are_monotone_in_eps(kind):
    values = field(kind, 16)
    previous = levels(values, 1e-4)[0]
    for eps in [0.001, 0.002, 0.005, 0.01, 0.05, 0.15, 0.6, 2.0]:
        level = levels(values, eps)[0]
        assert np.all(level >= previous)
        previous = level
    assert np.all(previous == 4)


def test_kappa_tolerance_option():
    """A50: with ``kappa`` a node must also have an extinction range below ``eps_kappa``."""
    values = field("smooth", 16)
    kappa = np.zeros((16, 16, 16, 3), np.float32)
    kappa[3, 10, 5, 2] = 0.01
    level, _ = levels(values, 0.05)
    np.testing.assert_array_equal(levels(values, 0.05, kappa=mi.TensorXf(kappa))[0], level)
    with_kappa, _ = levels(values, 0.05, kappa=mi.TensorXf(kappa), eps_kappa=0.005)
    ref = octree_levels_reference(values, 0.05, kappa, 0.005)
    np.testing.assert_array_equal(with_kappa, ref)
    assert with_kappa[3, 10, 5] == 0 and not np.array_equal(with_kappa, level)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"eps": 0.0}, "tolerances"),
        ({"eps": 0.02, "eps2": 0.01}, "tolerances"),
        ({"ds_max": 0.0}, "ds_max"),
        ({"eps_kappa": -1.0}, "eps_kappa"),
    ],
)
def test_bad_parameters_raise(kwargs, message):
    with pytest.raises(ParameterError, match=message):
        build_octree(mi.TensorXf(field("smooth", 8)), **kwargs)


def test_a_grid_that_is_no_scalar_grid_raises():
    """(A box grid is fine: test_box_grid.py.)"""
    with pytest.raises(ParameterError, match="scalar grid"):
        build_octree(mi.TensorXf(np.ones((8, 8, 4, 2), np.float32)))


def test_tolerance_is_strict():
    """A9: a node whose range equals ε is split."""
    values = np.full((8, 8, 8), 1.0, np.float32)
    values[0, 0, 0] = 1.25
    assert np.all(levels(values, 0.25)[0][:2, :2, :2] == 0)
    assert np.all(levels(values, 0.2500001)[0] == 3)


def test_one_kernel_serves_every_level_of_every_grid():
    """The node ranges of each level come from the same compiled kernel whatever the level,
    the grid's size and its channel count (the sizes are opaque: literals made one per level)."""
    import drjit as dr

    from photonmap.volume.octree import _range_pyramid

    def reductions(values: np.ndarray) -> set:
        dr.eval()
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history()
            ranges = _range_pyramid(mi.TensorXf(values), 16)
            history = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
        assert len(ranges) == 5 and len(history) == 4 and float(dr.max(ranges[-1])[0]) > 0
        # the first level's kernel also pads the grid; a level of one value is a scalar to Dr.Jit
        return {k["hash"] for k in history[1:] if k["size"] > 1}

    one = reductions(field("sphere", 16)[..., None])  # levels of 8³ and 4³ nodes: one kernel
    assert len(one) == 1
    assert reductions(np.repeat(field("smooth", 12)[..., None], 3, axis=3)) == one
