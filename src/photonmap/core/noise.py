"""Seeded 3D gradient noise: Perlin's improved noise (Perlin 2002, "Improving Noise") in Dr.Jit.

Used to perturb materials, as in Pfeuti 2009's cube scene (Fig 4.9):
``n = 1.5 + 0.02·Perlin(x/16)``, with σ_s perturbed likewise.

The lattice hash is a seeded permutation of 0..255 (period 256 along each axis). The noise is zero
at integer lattice points, C² (quintic fade ``6t⁵ − 15t⁴ + 10t³``) and roughly in [−1, 1].
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np


def permutation(seed: int) -> np.ndarray:
    """Perlin's hash table for ``seed``: a permutation of 0..255, repeated once (512 entries)."""
    perm = np.random.default_rng(seed).permutation(256).astype(np.uint32)
    return np.concatenate([perm, perm])


def _fade(t: mi.Float) -> mi.Float:
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def _grad(hash: mi.UInt32, x: mi.Float, y: mi.Float, z: mi.Float) -> mi.Float:
    """Dot product of (x, y, z) with one of Perlin's 12 edge gradients, chosen by ``hash & 15``."""
    h = hash & 15
    u = dr.select(h < 8, x, y)
    v = dr.select(h < 4, y, dr.select((h == 12) | (h == 14), x, z))
    return dr.select((h & 1) == 0, u, -u) + dr.select((h & 2) == 0, v, -v)


def perlin3(p: mi.Point3f, seed: int) -> mi.Float:
    """Improved Perlin noise at the points ``p`` for the hash table of ``seed``."""
    perm = mi.UInt32(permutation(seed))
    cell = dr.floor(p)
    f = p - cell
    ci = mi.Point3u(mi.Point3i(cell) & 255)
    u, v, w = _fade(f.x), _fade(f.y), _fade(f.z)

    def hash(i, j, k):
        a = dr.gather(mi.UInt32, perm, ci.x + i)
        b = dr.gather(mi.UInt32, perm, a + ci.y + j)
        return dr.gather(mi.UInt32, perm, b + ci.z + k)

    def corner(i, j, k):
        return _grad(hash(i, j, k), f.x - i, f.y - j, f.z - k)

    x00 = dr.lerp(corner(0, 0, 0), corner(1, 0, 0), u)
    x10 = dr.lerp(corner(0, 1, 0), corner(1, 1, 0), u)
    x01 = dr.lerp(corner(0, 0, 1), corner(1, 0, 1), u)
    x11 = dr.lerp(corner(0, 1, 1), corner(1, 1, 1), u)
    return dr.lerp(dr.lerp(x00, x10, v), dr.lerp(x01, x11, v), w)
