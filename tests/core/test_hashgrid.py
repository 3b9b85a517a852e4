"""Hash grid photon gathers (spec seed-001 §2.4, §2.8, oracle O5, A13): exact k-nearest and
fixed-radius results against ``scipy.spatial.cKDTree`` and a float32 NumPy brute force.

Points lie on a 2⁻¹⁰ lattice, so every squared distance is exact in float32 and in float64 (the
two references agree bit for bit) and ties are frequent: the tie-break by photon index is tested.
"""

import math

import mitsuba as mi
import numpy as np
import pytest

from knn_reference import assert_same, brute_force, ckdtree_reference, lattice, to_mi
from photonmap.core.errors import ParameterError
from photonmap.core.hashgrid import HashGrid
from photonmap.core.knn import NO_PHOTON


def uniform_points(n, seed):
    return lattice(np.random.default_rng(seed).random((n, 3)))


def clustered_points(n, seed):
    """Points on the five walls of the unit box and one axis-aligned box, with exact duplicates."""
    rng = np.random.default_rng(seed)
    p = rng.random((n, 3))
    wall = rng.integers(0, 6, n)
    p[wall == 0, 1] = 0.0
    p[wall == 1, 1] = 1.0
    p[wall == 2, 2] = 0.0
    p[wall == 3, 0] = 0.0
    p[wall == 4, 0] = 1.0
    box = wall == 5
    p[box] = 0.2 + 0.3 * p[box]
    p[box, rng.integers(0, 3, box.sum())] = 0.35
    p[n // 2 : n // 2 + n // 10] = p[: n // 10]  # duplicates
    return lattice(p)


# ------------------------------------------------------------------------------ exact kNN
@pytest.fixture(scope="module")
def uniform_case():
    points = uniform_points(3000, 1)
    queries = lattice(np.random.default_rng(2).uniform(-0.1, 1.1, (300, 3)))
    return points, queries, HashGrid(to_mi(points))


@pytest.fixture(scope="module")
def clustered_case():
    points = clustered_points(3000, 3)
    queries = np.concatenate([clustered_points(200, 4), points[:100]])  # on photons too
    return points, queries, HashGrid(to_mi(points))


@pytest.mark.parametrize("k", [1, 10, 100])
@pytest.mark.parametrize("radius", [math.inf, 0.11])
@pytest.mark.parametrize("case", ["uniform_case", "clustered_case"])
def test_knn_matches_ckdtree(case, k, radius, request):
    points, queries, grid = request.getfixturevalue(case)
    result = grid.knn(to_mi(queries), k=k, max_radius=radius)
    assert_same(result, ckdtree_reference(points, queries, k, radius))


@pytest.mark.parametrize("case", ["uniform_case", "clustered_case"])
def test_fixed_radius_matches_query_ball_point(case, request):
    points, queries, grid = request.getfixturevalue(case)
    radius = 0.05
    result = grid.within(to_mi(queries), radius, k=10)
    index, count, _ = ckdtree_reference(points, queries, 10, radius, fixed_radius=True)
    assert_same(result, (index, count, np.full(len(queries), np.float32(radius) ** 2)))


def test_unquantized_points_match_float32_brute_force():
    rng = np.random.default_rng(5)
    points = rng.normal(size=(2000, 3)).astype(np.float32)
    queries = rng.normal(size=(200, 3)).astype(np.float32)
    result = HashGrid(to_mi(points)).knn(to_mi(queries), k=10)
    assert_same(result, brute_force(points, queries, 10))


@pytest.mark.parametrize("cell_size", [0.03, 0.6])
def test_cell_size_does_not_change_results(uniform_case, cell_size):
    """0.03: more cells than table slots (hashed, cells share slots); 0.6: 8 cells."""
    points, queries, _ = uniform_case
    grid = HashGrid(to_mi(points), cell_size=cell_size)
    assert grid.hashed == (cell_size == 0.03)
    result = grid.knn(to_mi(queries), k=10, max_radius=0.2)
    assert_same(result, brute_force(points, queries, 10, 0.2))


def test_normal_test_matches_brute_force(clustered_case):
    points, queries, grid = clustered_case
    rng = np.random.default_rng(6)

    def unit(n):
        v = rng.normal(size=(n, 3))
        return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)

    normals, directions, query_normal = unit(len(points)), unit(len(points)), unit(len(queries))
    kwargs = dict(query_normal=to_mi(query_normal), normals=to_mi(normals))
    result = grid.knn(to_mi(queries), k=10, directions=to_mi(directions), **kwargs)
    reference = brute_force(points, queries, 10, math.inf, query_normal, normals, directions)
    assert_same(result, reference)
    result = grid.within(to_mi(queries), 0.2, k=100, cos_normal=0.0, **kwargs)
    index, count, _ = brute_force(points, queries, 100, 0.2, query_normal, normals, None, 0.0)
    assert_same(result, (index, count, np.full(len(queries), np.float32(0.2) ** 2)))


# ------------------------------------------------------------------------------- layout
def test_layout_is_sorted_by_slot(clustered_case):
    points, _, grid = clustered_case
    order = grid.order.numpy()
    np.testing.assert_array_equal(np.sort(order), np.arange(len(points)))
    record = grid.record.numpy().reshape(-1, 4)
    np.testing.assert_array_equal(record[:, :3], points[order])
    np.testing.assert_array_equal(record[:, 3].view(np.uint32), order)
    start = grid.cell_start.numpy()
    assert start[0] == 0 and start[-1] == len(points) and np.all(np.diff(start.astype(int)) >= 0)
    slot = np.searchsorted(start, np.arange(len(points)), side="right") - 1
    origin = np.array(grid.origin, np.float32)
    cell = np.floor((points[order] - origin) * np.float32(grid.inv_cell)).astype(int)
    cell = np.minimum(np.maximum(cell, 0), np.array(grid.dims) - 1)
    number = (cell[:, 2] * grid.dims[1] + cell[:, 1]) * grid.dims[0] + cell[:, 0]
    np.testing.assert_array_equal(slot, number % grid.table_size)


def test_automatic_cell_size_targets_the_occupancy():
    for points in (uniform_points(20000, 7), clustered_points(20000, 8)):
        grid = HashGrid(to_mi(points))
        origin = np.array(grid.origin, np.float32)
        cell = np.floor((points - origin) * np.float32(grid.inv_cell)).astype(np.int64)
        occupancy = len(points) / len(np.unique(cell, axis=0))
        assert 4 <= occupancy <= 16


# ------------------------------------------------------------------- degenerate and bad input
def test_degenerate_inputs():
    one = HashGrid(to_mi([[0.5, 0.5, 0.5]]))
    index, count, radius2 = one.knn(to_mi([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]), k=3).numpy()
    np.testing.assert_array_equal(count, [1, 1])
    np.testing.assert_array_equal(index, [[0, NO_PHOTON, NO_PHOTON]] * 2)
    np.testing.assert_array_equal(radius2, [0.75, 0.75])

    same = np.full((50, 3), 0.25, np.float32)
    index, count, radius2 = HashGrid(to_mi(same)).knn(to_mi([[0.25, 0.25, 0.75]]), k=5).numpy()
    np.testing.assert_array_equal(index, [[0, 1, 2, 3, 4]])
    assert count[0] == 5 and radius2[0] == 0.25

    points = uniform_points(500, 9)
    queries = np.array([[1000.0, -2000.0, 50.0], [-1e6, 0.5, 0.5]], np.float32)
    grid = HashGrid(to_mi(points))
    assert_same(grid.knn(to_mi(queries), k=10), brute_force(points, queries, 10))
    assert_same(
        grid.knn(to_mi(queries), k=10, max_radius=100.0), brute_force(points, queries, 10, 100)
    )
    assert_same(grid.knn(to_mi(points[:20]), k=600), brute_force(points, points[:20], 600))

    far = to_mi([[math.inf, 0.5, 0.5], [math.nan, 0.5, 0.5], [0.5, -math.inf, 0.5]])
    assert np.all(grid.knn(far, k=10).count.numpy() == 0)

    empty = HashGrid(mi.Point3f())
    index, count, _ = empty.knn(to_mi(queries), k=2).numpy()
    assert np.all(count == 0) and np.all(index == NO_PHOTON)
    assert empty.knn(mi.Point3f(), k=2).count.numpy().size == 0


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(k=0),
        dict(k=-3),
        dict(k=2.5),
        dict(k=5000),
        dict(max_radius=-1.0),
        dict(max_radius=math.nan),
        dict(cos_normal=1.5),
        dict(normals=mi.Vector3f(0, 0, 1)),  # wrong length
        dict(query_normal=mi.Vector3f(0, 0, 1)),  # wrong length (query normal needs one per query)
    ],
)
def test_bad_queries_raise(kwargs):
    grid = HashGrid(to_mi(uniform_points(10, 10)))
    with pytest.raises(ParameterError):
        grid.knn(to_mi(uniform_points(4, 11)), **kwargs)


def test_bad_construction_raises():
    with pytest.raises(ParameterError):
        HashGrid(to_mi(uniform_points(10, 12)), cell_size=-1.0)
    with pytest.raises(ParameterError):
        HashGrid(to_mi([[0.0, math.nan, 0.0]]))
    for bad in (math.nan, math.inf):  # one bad coordinate among many (a minimum skips a NaN)
        points = uniform_points(100, 14)
        points[37, 1] = bad
        with pytest.raises(ParameterError, match="finite"):
            HashGrid(to_mi(points), cell_size=0.1)
    grid = HashGrid(to_mi(uniform_points(10, 12)))
    with pytest.raises(ParameterError):
        grid.within(to_mi(uniform_points(2, 13)), -0.5)
    with pytest.raises(ParameterError):
        grid.knn(to_mi(uniform_points(2, 13)), normals=to_mi(uniform_points(10, 12)))


@pytest.mark.parametrize("cell_size", [0.03, 0.07, 0.25])
@pytest.mark.parametrize("with_normals", [False, True])
def test_nearest_matches_brute_force(clustered_case, cell_size, with_normals):
    """The fused 27-cell scan (Christensen lookups) finds the 1-NN within a cell edge exactly;
    0.03 is a hashed grid whose cells share table slots."""
    points, queries, _ = clustered_case
    grid = HashGrid(to_mi(points), cell_size=cell_size)
    radius = 0.9 * grid.cell_size
    rng = np.random.default_rng(8)
    normals = rng.normal(size=(len(points), 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    query_normal = normals[rng.integers(0, len(points), len(queries))]
    kwargs = (
        dict(query_normal=to_mi(query_normal), normals=to_mi(normals), cos_normal=0.5)
        if with_normals
        else {}
    )
    index, d2 = grid.nearest(to_mi(queries), radius, **kwargs)
    ref = brute_force(
        points, queries, 1, radius, *((query_normal, normals, None, 0.5) if with_normals else ())
    )
    np.testing.assert_array_equal(index.numpy(), ref[0][:, 0])
    expect = np.where(ref[1] > 0, ref[2], np.inf).astype(np.float32)
    np.testing.assert_array_equal(d2.numpy(), expect)
    assert (ref[1] > 0).mean() > 0.3  # the test sees hits and misses


def test_nearest_radius_beyond_the_cell_raises(uniform_case):
    points, queries, grid = uniform_case
    with pytest.raises(ParameterError, match="cell size"):
        grid.nearest(to_mi(queries), 2 * grid.cell_size)


@pytest.mark.parametrize("span, count, hashed", [(2, 3000, False), (2, 200, True), (3, 3000, True)])
def test_pairs_within_match_brute_force(span, count, hashed):
    """Every (query, photon) pair within the radius, each query's pairs adjacent, in a hashed
    table (more cells than slots) too; queries far outside the grid have none."""
    points = clustered_points(count, 5)  # hashed: more cells than table slots
    queries = np.concatenate([clustered_points(300, 6), points[:50], [[9.0, 9.0, 9.0]]])
    radius = 0.04
    grid = HashGrid(to_mi(points), cell_size=(2 if span == 2 else 1) * radius)
    assert grid.hashed == hashed
    owner, photon = grid.pairs_within(to_mi(queries), mi.Float(radius**2), mi.Bool(True), span)
    got = list(zip(owner.numpy().tolist(), photon.numpy().tolist(), strict=True))
    d2 = ((queries[:, None, :].astype(np.float32) - points[None, :, :]) ** 2).sum(-1)
    expected = set(zip(*np.nonzero(d2 < np.float32(radius**2)), strict=True))
    assert set(got) == {(int(q), int(p)) for q, p in expected} and len(got) == len(expected)
    assert np.all(np.diff(owner.numpy().astype(np.int64)) >= 0)  # grouped by query
    assert len(got) > 50  # the queries on photons find at least themselves
