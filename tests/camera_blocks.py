"""Which 4 × 4 pixel blocks of an image see near a point: the test-side mask for leaving out a
light's own image (antialiasing noise, the same for every method) from block-error checks."""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from photonmap.core.image import block_means


def blocks_near(sensor: mi.Sensor, point, radius: float, width: int, height: int) -> np.ndarray:
    """The 4 × 4 blocks with a pixel whose camera ray (through its corners or centre) passes
    within ``radius`` of ``point``."""
    y, x = np.mgrid[0:height, 0:width]
    near = np.zeros((height, width), bool)
    for dx, dy in ((0.5, 0.5), (0, 0), (1, 0), (0, 1), (1, 1)):
        pos = mi.Point2f(((x + dx) / width).ravel(), ((y + dy) / height).ravel())
        ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        o, d = np.array(ray.o).T, np.array(ray.d).T
        rel = np.asarray(point) - o
        along = np.sum(rel * d, axis=1)
        miss = np.linalg.norm(rel - along[:, None] * d, axis=1)
        near |= (miss < radius).reshape(height, width)
    return block_means(near[..., None].astype(float))[..., 0] > 0
