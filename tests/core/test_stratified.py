"""Stratified samples of the eye pass and final gather (core.sampling.rotated_hammersley)."""

import numpy as np

from photonmap import dr, mi
from photonmap.core.sampling import rotated_hammersley


def test_a_query_s_directions_are_stratified_and_each_is_uniform():
    rays, queries = 16, 4000
    rng = np.random.default_rng(0)
    offset = mi.Point2f(*rng.random((2, queries)).astype(np.float32))
    lane = dr.arange(mi.UInt32, rays * queries)
    shift = dr.gather(mi.Point2f, offset, lane // rays)
    u = np.array(rotated_hammersley(rays, lane % rays, shift)).reshape(2, queries, rays)
    assert u.min() >= 0 and u.max() < 1
    for axis in (0, 1):  # one sample in each 1/N strip along either axis (a (0, m, 2)-net)
        strips = np.sort(np.floor(u[axis] * rays), axis=1)
        np.testing.assert_array_equal(strips, np.broadcast_to(np.arange(rays), strips.shape))
    # each sample position is uniform over the queries (the random shift): chi-square on 8×8 bins
    counts, _, _ = np.histogram2d(u[0, :, 5], u[1, :, 5], bins=8, range=[[0, 1], [0, 1]])
    chi2 = ((counts - queries / 64) ** 2 / (queries / 64)).sum()
    assert chi2 < 110  # 63 degrees of freedom: p ≈ 2e-4
