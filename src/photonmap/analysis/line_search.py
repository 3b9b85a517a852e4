"""k-NN gathers over line-organised photon structures (Steinhurst 2007 Ch. 4): the Numba
kernels and argument checks shared by :mod:`.kdbtree` and :mod:`.blockhash`.

A gather keeps the ``k`` smallest keys ``(d², photon index)`` of the photons with
``d² ≤ max_radius²`` that pass the normal test of :func:`photonmap.core.knn.accept`, in a max-heap
of 64-bit keys (the float32 bits of ``d²`` above the index), in float32 arithmetic without fused
multiply-adds — the gather of :mod:`photonmap.core.knn`, photon for photon. Photon records are
Jensen's compact 20-byte photons (Jensen 2001 §6.3); a leaf or block of one cache line holds an
8-byte header and as many of them as fit (6 in 128 bytes).
"""

from __future__ import annotations

import numba
import numpy as np

from ..core.errors import ParameterError
from ..core.knn import squared_radius

RECORD_BYTES = 20  # Jensen's compact photon: position, power, direction, split flag
HEADER_BYTES = 8  # a leaf block's bookkeeping (6 photons + 8 bytes in 128 B)
QUERY_CHUNK = 1 << 15  # queries per compiled call


def leaf_capacity(line_bytes: int) -> int:
    """Photons per leaf block, ``⌊(L − 8)/20⌋`` (6 at 128 B)."""
    m = (int(line_bytes) - HEADER_BYTES) // RECORD_BYTES
    if m < 1:
        raise ParameterError(
            f"a {line_bytes}-byte line cannot hold an {HEADER_BYTES}-byte header and one "
            f"{RECORD_BYTES}-byte photon; use lines of at least {HEADER_BYTES + RECORD_BYTES} B"
        )
    return m


@numba.njit(cache=True)
def float_bits(value, scratch):
    """The bit pattern of float32 ``value`` (through the one-element float32 ``scratch``)."""
    scratch[0] = value
    return np.uint64(scratch.view(np.uint32)[0])


@numba.njit(cache=True)
def offer(heap, found, k, key):
    """Offer ``key`` to the k-best max-heap ``heap[:found]``; returns the new count."""
    if found < k:
        i = found
        while i > 0:
            parent = (i - 1) // 2
            if heap[parent] >= key:
                break
            heap[i] = heap[parent]
            i = parent
        heap[i] = key
        return found + 1
    if key < heap[0]:
        sift_down(heap, k, key)
    return found


@numba.njit(cache=True)
def sift_down(heap, size, key):
    """Put ``key`` at the root of the max-heap ``heap[:size]`` and sift it down."""
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and heap[child + 1] > heap[child]:
            child += 1
        if heap[child] <= key:
            break
        heap[i] = heap[child]
        i = child
    heap[i] = key


@numba.njit(cache=True)
def heap_bound2(heap, found, k, radius2, scratch):
    """``min(max_radius², d²_k)`` (``d²_k`` = +∞ until k photons are kept)."""
    if found < k:
        return radius2
    scratch.view(np.uint32)[0] = np.uint32(heap[0] >> np.uint64(32))
    worst = scratch[0]
    return worst if worst < radius2 else radius2


@numba.njit(cache=True)
def candidate(photons, i, q, qn, radius2, cos_normal, scratch):
    """``(key, ok)`` of stored photon ``i`` (of ``photons``, :func:`stored_photons`) for query
    ``q`` — :func:`photonmap.core.knn.accept`'s rule."""
    p, nrm, drc, _ = photons
    dx = p[i, 0] - q[0]
    dy = p[i, 1] - q[1]
    dz = p[i, 2] - q[2]
    d2 = dx * dx + dy * dy + dz * dz
    ok = d2 <= radius2
    if ok:
        ok = drc[i, 0] * qn[0] + drc[i, 1] * qn[1] + drc[i, 2] * qn[2] < np.float32(0)
    if ok:
        ok = nrm[i, 0] * qn[0] + nrm[i, 1] * qn[1] + nrm[i, 2] * qn[2] >= cos_normal
    return float_bits(d2, scratch), ok


@numba.njit(cache=True)
def emit_nearest(heap, found, k, out, row):
    """Heap-sort ``heap[:found]`` into ``out[row]`` nearest first (photon indices; -1 unused)."""
    for size in range(found - 1, 0, -1):
        last = heap[size]
        heap[size] = heap[0]
        sift_down(heap, size, last)
    for j in range(k):
        out[row, j] = np.int64(heap[j] & np.uint64(0xFFFFFFFF)) if j < found else -1


@numba.njit(cache=True)
def insert_sorted(order, used, value, keys):
    """Insert ``value`` into ``order[:used]``, kept ascending by ``keys[value]`` (stable)."""
    i = used
    while i > 0 and keys[order[i - 1]] > keys[value]:
        order[i] = order[i - 1]
        i -= 1
    order[i] = value


@numba.njit(cache=True)
def grow(buffer, used, extra):
    """``buffer`` with room for ``extra`` more entries after ``used`` (a copy twice as large
    when it has not)."""
    if used + extra <= len(buffer):
        return buffer
    bigger = np.empty(max(2 * len(buffer), used + extra), buffer.dtype)
    bigger[:used] = buffer[:used]
    return bigger


def gather_args(query, query_normal, k, max_radius, cos_normal) -> tuple:
    """The checked arguments of a gather as the kernels take them: queries and their normals
    (Q, 3) float32, ``k``, ``max_radius²`` and the normal test's cosine."""
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= k <= 1024:
        raise ParameterError(f"k must be an integer in 1..1024, got {k!r}")
    if not max_radius >= 0:
        raise ParameterError(f"the gather radius must be >= 0 (or inf), got {max_radius!r}")
    q = np.ascontiguousarray(query, np.float32).reshape(-1, 3)
    n = np.ascontiguousarray(query_normal, np.float32).reshape(-1, 3)
    if len(n) != len(q):
        raise ParameterError(f"{len(n)} query normals for {len(q)} queries")
    return q, n, int(k), squared_radius(max_radius), np.float32(cos_normal)


def as_positions(positions) -> np.ndarray:
    """Photon positions as a contiguous float32 (N ≥ 1, 3) array of finite values."""
    points = np.ascontiguousarray(positions, np.float32)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ParameterError(f"expected photon positions of shape (N >= 1, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ParameterError("photon positions must be finite")
    return points


def stored_photons(points, perm, normals, directions) -> tuple:
    """The kernels' photon arrays in storage order: positions, normals, directions (N, 3)
    float32 and original indices (uint64)."""
    stored = []
    for values in (normals, directions):
        values = np.asarray(values, np.float32)
        if values.shape != (len(perm), 3):
            raise ParameterError(
                f"photon normals/directions of shape {values.shape}, need ({len(perm)}, 3)"
            )
        stored.append(np.ascontiguousarray(values[perm]))
    return points, *stored, perm.astype(np.uint64)


def chunked(search, queries: int):
    """Run ``search(slice)`` over chunks of the queries and join the results."""
    found, reads, lines = [], [], []
    for start in range(0, max(queries, 1), QUERY_CHUNK):
        f, r, w = search(slice(start, start + QUERY_CHUNK))
        found.append(f)
        reads.append(r)
        lines.append(w)
    return np.concatenate(found), np.concatenate(reads), np.concatenate(lines)
