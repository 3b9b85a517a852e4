"""``core.volume_map.density_radius``: the radius of a sphere that holds about k points, against
a brute-force reference, and the bound where no sphere holds k of them."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from photonmap.core.volume_map import density_radius


def test_median_kth_nearest_distance_matches_brute_force():
    points = np.random.default_rng(3).uniform(-1, 1, (3, 2000)).astype(np.float32)
    got = density_radius(mi.Point3f(*(mi.Float(c) for c in points)), 16, bound=10.0)
    d = np.linalg.norm(points.T[:, None, :] - points.T[None, :, :], axis=-1)
    kth = np.sort(d, axis=1)[:, 15]  # the point itself is its own nearest, as in the grid
    assert got == pytest.approx(float(np.median(kth)), rel=0.02)


@pytest.mark.parametrize("count", [1, 5, 15])
def test_fewer_points_than_k_give_the_bound(count):
    """One point's nearest is itself (distance 0): a zero radius divided the estimates by zero."""
    points = mi.Point3f(*(dr.arange(mi.Float, count) * 0.1 for _ in range(3)))
    assert density_radius(points, 16, bound=0.25) == 0.25
