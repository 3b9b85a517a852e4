"""Spatial orders (core/order.py) against NumPy bit-interleaving references."""

import numpy as np

from photonmap import mi
from photonmap.core.order import morton3_order, morton_cells


def interleave(coords: np.ndarray, bits: int) -> np.ndarray:
    """Morton codes of integer coordinates (D, N): bit b of axis a goes to bit D·b + a."""
    code = np.zeros(coords.shape[1], np.uint64)
    for b in range(bits):
        for a in range(len(coords)):
            code |= ((coords[a].astype(np.uint64) >> b) & 1) << (len(coords) * b + a)
    return code


def test_morton_cells_list_a_grid_in_z_order():
    a, b = (c.numpy() for c in morton_cells(16))
    np.testing.assert_array_equal(interleave(np.stack([a, b]), 4), np.arange(256))


def test_morton3_order_sorts_by_the_interleaved_code():
    rng = np.random.default_rng(1)
    cells = rng.integers(0, 1024, (3, 5000))
    cells[:, :2] = [[0, 1023], [0, 1023], [0, 1023]]  # the bounding box spans 0..1023
    points = cells.astype(np.float32) + 0.5  # (p − min) · 1023 / extent is exact
    order = morton3_order(mi.Point3f(*points)).numpy()
    np.testing.assert_array_equal(np.sort(order), np.arange(5000))
    code = interleave(cells, 10)
    assert np.all(np.diff(code[order].astype(np.int64)) >= 0)
