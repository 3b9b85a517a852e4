"""Spatial orders for coherent SIMD work (Morton / Z-order).

Neighbouring SIMD lanes that touch neighbouring memory share cache lines. Steinhurst (2007) shows
this for photon gathers on a cache simulator; Pfeuti (2009, Table 4.1) sees the photon order change
the marching time on a GPU. Here sorting photons by the Morton code of their photon-plane position
makes the deposits of one SIMD packet land in nearby voxels (the accumulated result does not
depend on the order: deposits are summed in exact fixed point). The codes are Mitsuba's
``mi.math.morton_encode2/3`` (x in the lowest bit).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np


def morton_cells(side: int) -> tuple[mi.UInt32, mi.UInt32]:
    """The cells ``(a, b)`` of a ``side × side`` grid (side a power of two) in Morton order."""
    cell = mi.math.morton_decode2(dr.arange(mi.UInt32, side * side))
    return cell.x, cell.y


def morton2(u: mi.Float, w: mi.Float) -> mi.UInt32:
    """32-bit Morton code of points in the unit square (16 bits per axis)."""
    scale = float(1 << 16)
    a = mi.UInt32(dr.clip(u * scale, 0, scale - 1))
    b = mi.UInt32(dr.clip(w * scale, 0, scale - 1))
    return mi.math.morton_encode2(mi.Vector2u(a, b))


def morton_order(u: mi.Float, w: mi.Float) -> mi.UInt32:
    """The permutation that lists the points ``(u, w)`` in Morton (Z) order."""
    return dr.argsort(morton2(u, w))


def morton3_order(p: mi.Point3f) -> mi.UInt32:
    """The permutation that lists the points ``p`` in 3D Morton order (10 bits per axis over their
    bounding box): coherent query batches for photon gathers (Steinhurst 2007 Ch. 4)."""
    lo, hi = dr.min(p, axis=1), dr.max(p, axis=1)
    scale = 1023.0 / dr.maximum(dr.max(hi - lo), 1e-30)
    c = mi.Vector3u(dr.clip((p - lo) * scale, 0, 1023))
    return dr.argsort(mi.math.morton_encode3(c))


def hilbert3_index(cells: np.ndarray, bits: int) -> np.ndarray:
    """3D Hilbert-curve index (``3·bits`` bits, uint64) of integer cells ``(N, 3)`` in
    ``[0, 2^bits)³`` — Skilling's transpose algorithm ("Programming the Hilbert curve", AIP Conf.
    Proc. 707, 2004), vectorised over the cells with NumPy. Steinhurst (2007) §3.4.1 sorts photon
    gathers along this curve. The map is a bijection whose consecutive indices are face-adjacent
    cells (tested)."""
    x = [np.asarray(cells[:, a], np.uint64).copy() for a in range(3)]
    top = np.uint64(1 << (bits - 1))
    q = top
    while q > 1:  # inverse undo of the excess work
        p = q - np.uint64(1)
        for i in range(3):
            high = (x[i] & q) != 0
            x[0] = np.where(high, x[0] ^ p, x[0])
            t = np.where(high, np.uint64(0), (x[0] ^ x[i]) & p)
            x[0] ^= t
            x[i] ^= t
        q >>= np.uint64(1)
    for i in (1, 2):  # Gray encode
        x[i] ^= x[i - 1]
    t = np.zeros_like(x[0])
    q = top
    while q > 1:
        t = np.where((x[2] & q) != 0, t ^ (q - np.uint64(1)), t)
        q >>= np.uint64(1)
    index = np.zeros_like(x[0])
    for b in range(bits - 1, -1, -1):  # interleave the transposed bits, x[0] most significant
        for i in range(3):
            index = (index << np.uint64(1)) | (((x[i] ^ t) >> np.uint64(b)) & np.uint64(1))
    return index
