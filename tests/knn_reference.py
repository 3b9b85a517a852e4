"""k-nearest-neighbour references shared by the hash-grid and kd-tree tests: a brute force in float32
arithmetic in the kernels' order and a ``scipy.spatial.cKDTree`` one, ties broken by photon index
(spec seed-001 O5)."""

import math

import mitsuba as mi
import numpy as np
from scipy.spatial import cKDTree

from photonmap.core.arrays import columns
from photonmap.core.knn import COS_NORMAL, NO_PHOTON


def lattice(values):
    return (np.floor(np.asarray(values) * 1024) / 1024).astype(np.float32)


def to_mi(a):
    """``a`` (N, 3) as a ``Point3f``, each coordinate from aligned memory (one kernel per test
    whatever the run: ``photonmap.core.arrays.aligned``)."""
    return mi.Point3f(*columns(mi.Float, a))


def dot32(a, n):
    """Row-wise ``a·n`` in float32, summed in the kernel's order."""
    return (a[:, 0] * n[0] + a[:, 1] * n[1]) + a[:, 2] * n[2]


def brute_force(
    points,
    queries,
    k,
    radius=math.inf,
    query_normal=None,
    normals=None,
    directions=None,
    cos_normal=COS_NORMAL,
):
    """The k smallest (d², index) within the radius passing the normal test, float32 arithmetic."""
    r2 = np.float32(radius) ** 2 if math.isfinite(radius) else np.float32(np.inf)
    index = np.full((len(queries), k), NO_PHOTON, np.uint32)
    count = np.zeros(len(queries), np.uint32)
    radius2 = np.zeros(len(queries), np.float32)
    for q in range(len(queries)):
        d = points - queries[q]
        d2 = (d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]
        ok = d2 <= r2
        if directions is not None:
            ok &= dot32(directions, query_normal[q]) < 0
        if normals is not None:
            ok &= dot32(normals, query_normal[q]) >= np.float32(cos_normal)
        candidates = np.nonzero(ok)[0]
        best = candidates[np.lexsort((candidates, d2[candidates]))][:k]
        index[q, : len(best)] = best
        count[q] = len(best)
        radius2[q] = d2[best[-1]] if len(best) else 0
    return index, count, radius2


def ckdtree_reference(points, queries, k, radius=math.inf, fixed_radius=False):
    """The same result from cKDTree: ``query`` finds the k-th distance (a fixed-radius gather
    takes the radius), ``query_ball_point`` every point at most that far, ordered by (d², index)."""
    tree = cKDTree(points.astype(np.float64))
    q64 = queries.astype(np.float64)
    if fixed_radius:
        reach = np.full(len(queries), radius)
    else:
        dist, _ = tree.query(q64, k=min(k, len(points)), distance_upper_bound=radius)
        dist = dist.reshape(len(queries), -1)
        reach = np.where(np.isfinite(dist), dist, -1.0).max(axis=1)  # -1: nothing in range
        reach *= 1 + 1e-9  # keep the ties at the k-th distance (lattice distances differ more)
    index = np.full((len(queries), k), NO_PHOTON, np.uint32)
    count = np.zeros(len(queries), np.uint32)
    radius2 = np.zeros(len(queries), np.float32)
    for q in np.nonzero(reach >= 0)[0]:
        near = np.array(tree.query_ball_point(q64[q], reach[q]), dtype=np.int64)
        d2 = ((points[near].astype(np.float64) - q64[q]) ** 2).sum(axis=1)
        order = np.lexsort((near, d2))[:k]
        index[q, : len(order)] = near[order]
        count[q] = len(order)
        radius2[q] = d2[order[-1]] if len(order) else 0
    return index, count, radius2


def assert_same(result, reference):
    index, count, radius2 = result.numpy()
    ref_index, ref_count, ref_radius2 = reference
    np.testing.assert_array_equal(count, ref_count)
    np.testing.assert_array_equal(index, ref_index)
    np.testing.assert_array_equal(radius2, ref_radius2.astype(np.float32))
