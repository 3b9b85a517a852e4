"""Left-balanced kd-tree in heap order (spec seed-001 §2.3, §2.4, §2.8, oracle O5, A13): the heap
layout and exact k-nearest / fixed-radius gathers against ``scipy.spatial.cKDTree`` and a float32
NumPy brute force.

Points lie on a 2⁻¹⁰ lattice, so every squared distance is exact in float32 and in float64 and ties
are frequent: the tie-break by photon index is tested.
"""

import math

import mitsuba as mi
import numpy as np
import pytest
from scipy.spatial import cKDTree

from knn_reference import assert_same, brute_force, ckdtree_reference, lattice, to_mi
from photonmap.core.errors import ParameterError
from photonmap.core.hashgrid import HashGrid
from photonmap.core.knn import NO_PHOTON
from photonmap.surface.kdtree import KDTree, left_balanced_order


def clustered_points(n, seed):
    """Points on three walls of the unit box, a quarter of them duplicated exactly."""
    rng = np.random.default_rng(seed)
    p = rng.random((n, 3))
    p[np.arange(n), rng.integers(0, 3, n)] = 0.0
    p[n // 2 : n // 2 + n // 4] = p[: n // 4]
    return lattice(p)


@pytest.fixture(scope="module")
def case():
    rng = np.random.default_rng(1)
    points = np.concatenate([lattice(rng.random((1500, 3))), clustered_points(1500, 2)])
    queries = np.concatenate([lattice(rng.uniform(-0.2, 1.2, (200, 3))), points[::30]])
    return points, queries, KDTree(to_mi(points))


# ------------------------------------------------------------------------------ heap layout
def subtree_checks(points, order, axis):
    """For every heap slot j and every ancestor a of j: the photon at j lies on a's side of a's
    split plane (≤ in the left subtree, ≥ in the right)."""
    count = len(order)
    p = points[order]
    slots = np.arange(1, count + 1)
    for shift in range(1, count.bit_length()):
        ancestor = slots >> shift
        inside = ancestor >= 1
        j, a = slots[inside], ancestor[inside]
        right = (j >> (shift - 1)) & 1
        split_axis = axis[a - 1]
        split = p[a - 1, split_axis]
        value = p[j - 1, split_axis]
        assert np.all(np.where(right == 1, value >= split, value <= split)), f"level {shift}"


@pytest.mark.parametrize("count", [1, 2, 3, 7, 8, 100, 1000, 4097])
def test_heap_layout_is_a_left_balanced_kd_tree(count):
    points = clustered_points(count, count) if count > 4 else lattice(np.random.rand(count, 3))
    order, axis = left_balanced_order(points)
    # slots 1..N hold every photon exactly once
    np.testing.assert_array_equal(np.sort(order), np.arange(count))
    subtree_checks(points, order, axis)
    # each split axis is the axis of largest extent of the node's subtree (Jensen)
    slots = np.arange(1, count + 1)
    for node in slots[: count // 2]:
        members = [node]
        frontier = [node]
        while frontier:
            frontier = [c for n in frontier for c in (2 * n, 2 * n + 1) if c <= count]
            members += frontier
        sub = points[order[np.array(members) - 1]]
        assert axis[node - 1] == np.argmax(sub.max(axis=0) - sub.min(axis=0))
        if node > 20:
            break


def test_tree_arrays(case):
    points, _, tree = case
    order = tree.order.numpy()
    axis = tree.axis.numpy()
    np.testing.assert_array_equal(np.sort(order), np.arange(len(points)))
    subtree_checks(points, order, axis)
    record = tree.record.numpy().reshape(-1, 4)
    np.testing.assert_array_equal(record[:, :3], points[order])
    flag = record[:, 3].view(np.uint32)
    np.testing.assert_array_equal(flag & ((1 << 30) - 1), order)
    np.testing.assert_array_equal(flag >> 30, axis)


# ------------------------------------------------------------------------------- exact gathers
@pytest.mark.parametrize("k", [1, 10, 100])
@pytest.mark.parametrize("radius", [math.inf, 0.11])
def test_knn_matches_ckdtree_and_the_hash_grid(case, k, radius):
    points, queries, tree = case
    result = tree.knn(to_mi(queries), k=k, max_radius=radius)
    expected = brute_force(points, queries, k, radius)
    assert_same(result, expected)
    # cKDTree (float64) finds as many photons with the same distance at every rank
    _, ckd_index = cKDTree(points.astype(np.float64)).query(
        queries.astype(np.float64), k=k, distance_upper_bound=radius
    )
    ckd_index = ckd_index.reshape(len(queries), k)
    found = ckd_index < len(points)
    np.testing.assert_array_equal(found.sum(axis=1), expected[1])

    def exact_d2(index):
        p = points[np.where(found, index, 0).astype(np.int64)].astype(np.float64)
        return np.where(found, ((p - queries[:, None, :]) ** 2).sum(axis=2), 0.0)

    np.testing.assert_array_equal(exact_d2(expected[0]), exact_d2(ckd_index))
    assert_same(HashGrid(to_mi(points)).knn(to_mi(queries), k=k, max_radius=radius), expected)


def test_fixed_radius_matches_query_ball_point(case):
    points, queries, tree = case
    radius, k = 0.05, 10
    result = tree.within(to_mi(queries), radius, k=k)
    index, count, _ = ckdtree_reference(points, queries, k, radius, fixed_radius=True)
    assert_same(result, (index, count, np.full(len(queries), np.float32(radius) ** 2)))


def test_normal_test_matches_brute_force(case):
    points, queries, tree = case
    rng = np.random.default_rng(3)
    directions = rng.normal(size=points.shape).astype(np.float32)
    query_normal = rng.normal(size=queries.shape).astype(np.float32)
    result = tree.knn(
        to_mi(queries), k=10, query_normal=to_mi(query_normal), directions=to_mi(directions)
    )
    assert_same(
        result, brute_force(points, queries, 10, math.inf, query_normal, directions=directions)
    )
    # a photon stored on a perpendicular surface fails the default normal test (cos 30°)
    normals = np.tile(np.float32([0, 0, 1]), (len(points), 1))
    normals[::2] = [1, 0, 0]
    up = np.tile(np.float32([0, 0, 1]), (len(queries), 1))
    index, count, _ = tree.knn(
        to_mi(queries), k=10, query_normal=to_mi(up), normals=to_mi(normals)
    ).numpy()
    assert np.all(count == 10) and np.all(index % 2 == 1)


# ------------------------------------------------------------------- degenerate and bad input
def test_degenerate_inputs():
    one = KDTree(to_mi([[0.5, 0.5, 0.5]]))
    index, count, radius2 = one.knn(to_mi([[0.0, 0.0, 0.0]]), k=3).numpy()
    np.testing.assert_array_equal(index, [[0, NO_PHOTON, NO_PHOTON]])
    assert count[0] == 1 and radius2[0] == 0.75

    same = np.full((50, 3), 0.25, np.float32)
    tree = KDTree(to_mi(same))
    index, count, radius2 = tree.knn(to_mi([[0.25, 0.25, 0.75]]), k=5).numpy()
    np.testing.assert_array_equal(index, [[0, 1, 2, 3, 4]])
    assert radius2[0] == 0.25

    points = clustered_points(300, 4)
    queries = np.array([[1000.0, -2000.0, 50.0], [0.5, 0.5, 0.5]], np.float32)
    tree = KDTree(to_mi(points))
    assert_same(tree.knn(to_mi(queries), k=10), brute_force(points, queries, 10))
    assert_same(tree.knn(to_mi(queries), k=400), brute_force(points, queries, 400))
    assert_same(tree.knn(to_mi(queries), k=5, max_radius=0.0), brute_force(points, queries, 5, 0.0))

    far = to_mi([[math.inf, 0.5, 0.5], [math.nan, 0.5, 0.5]])
    assert np.all(tree.knn(far, k=10).count.numpy() == 0)

    empty = KDTree(mi.Point3f())
    assert empty.size == 0
    index, count, _ = empty.knn(to_mi(queries), k=2).numpy()
    assert np.all(count == 0) and np.all(index == NO_PHOTON)


@pytest.mark.parametrize(
    "kwargs", [dict(k=0), dict(k=-1), dict(max_radius=-0.1), dict(max_radius=math.nan)]
)
def test_bad_input_raises(kwargs):
    tree = KDTree(to_mi(clustered_points(20, 5)))
    with pytest.raises(ParameterError):
        tree.knn(to_mi(clustered_points(3, 6)), **kwargs)
    with pytest.raises(ParameterError):
        tree.within(to_mi(clustered_points(3, 6)), radius=-1.0)
    with pytest.raises(ParameterError):
        KDTree(to_mi([[0.0, 0.0, math.inf]]))
