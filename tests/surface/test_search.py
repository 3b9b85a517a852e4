"""Contracts of the k-NN kit (:mod:`photonmap.core.knn`) shared by the two photon search
structures — the hash grid (:mod:`photonmap.core.hashgrid`) and the kd-tree
(:mod:`photonmap.surface.kdtree`) — tested once over both (spec seed-001 §2.4, §2.8, O1/O2, O5)."""

import drjit as dr
import numpy as np
import pytest

from knn_reference import assert_same, brute_force, lattice, to_mi
from photonmap.core.hashgrid import HashGrid
from photonmap.surface.photon_map import STRUCTURES

RADIUS = 5 / 16  # exact in float32, as are the squared distances of the lattice points below
STEP = 2.0**-10  # the lattice


def points_around(query: np.ndarray) -> np.ndarray:
    """Points at exactly ``RADIUS`` from ``query`` (along the axes and on 3-4-5 diagonals), one
    lattice step inside and outside it, and random lattice points."""
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    diagonal = np.array([[3, 4, 0], [0, -3, 4], [-4, 0, -3], [4, 3, 0]]) / 16
    rng = np.random.default_rng(5)
    return lattice(
        np.concatenate(
            [
                query + RADIUS * axes,
                query + diagonal,
                query + (RADIUS - STEP) * axes[:2],
                query + (RADIUS + STEP) * axes[2:4],
                rng.random((500, 3)),
            ]
        )
    )


@pytest.mark.parametrize("structure", list(STRUCTURES))
def test_a_photon_exactly_at_the_radius_is_found(structure):
    """Photons with ``d² = radius²`` are within the gather radius (``d² ≤ r²``); one lattice step
    farther they are not."""
    query = np.array([[0.5, 0.5, 0.5]], np.float32)
    points = points_around(query[0])
    search = STRUCTURES[structure](to_mi(points))
    reference = brute_force(points, query, 64, RADIUS)
    assert reference[1][0] >= 10 + 2  # the ten boundary photons and the two inside
    assert_same(search.knn(to_mi(query), k=64, max_radius=RADIUS), reference)
    within = search.within(to_mi(query), RADIUS, k=64).numpy()
    np.testing.assert_array_equal(within[0], reference[0])
    # only boundary photons: the k nearest end exactly at the radius
    boundary = points[:10]
    found = STRUCTURES[structure](to_mi(boundary)).knn(to_mi(query), k=10, max_radius=RADIUS)
    assert found.numpy()[1][0] == 10 and found.numpy()[2][0] == np.float32(RADIUS) ** 2


def test_nearest_finds_a_photon_exactly_at_the_radius():
    """The hash grid's 27-cell scan (Christensen lookups) with the radius one cell edge: a photon
    exactly that far is found, one lattice step farther is not."""
    query = np.array([[0.5, 0.5, 0.5]], np.float32)
    for offset, found in ((RADIUS, True), (RADIUS + STEP, False)):
        points = lattice(query + offset * np.array([[1.0, 0, 0], [0, 0, -1.0]]))
        points = np.concatenate([points, lattice([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])])
        grid = HashGrid(to_mi(points), cell_size=RADIUS)
        index, d2 = grid.nearest(to_mi(query), RADIUS)
        assert (index.numpy()[0] == 0) == found and (d2.numpy()[0] == RADIUS**2) == found


@pytest.mark.parametrize("structure", list(STRUCTURES))
def test_queries_are_a_batch_in_any_order(structure):
    """Reordering a batch of gathers permutes the results and changes nothing else (spec O1/O2)."""
    rng = np.random.default_rng(1)
    points = lattice(rng.random((3000, 3)))
    queries = lattice(rng.uniform(-0.1, 1.1, (300, 3)))
    search = STRUCTURES[structure](to_mi(points))
    permutation = rng.permutation(len(queries))
    index, count, radius2 = search.knn(to_mi(queries), k=10).numpy()
    index_p, count_p, radius2_p = search.knn(to_mi(queries[permutation]), k=10).numpy()
    np.testing.assert_array_equal(index_p, index[permutation])
    np.testing.assert_array_equal(count_p, count[permutation])
    np.testing.assert_array_equal(radius2_p, radius2[permutation])
    assert dr.width(search.knn(to_mi(queries), k=10).index) == 10 * len(queries)
