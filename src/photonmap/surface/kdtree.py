"""Left-balanced kd-tree photon map in heap order (Steinhurst 2007 §2.6.1, §4.2; Jensen 1996).

The photon record and heap layout of §3.5 and §4.2, the k-NN gather with a maximum radius and a
normal test of §7.3.4.1: the structure the dissertation's bandwidth model assumes. Same
interface and same results as :class:`photonmap.core.hashgrid.HashGrid`; :mod:`photonmap.core.knn`
defines the result (ties broken by photon index), the normal test and the k-best heap.

**Tree.** ``N`` photons fill heap slots ``1..N`` exactly: slot ``i`` has children ``2i`` and
``2i + 1`` (a slot > N does not exist), so no pointers are stored (the "priority heap" of Steinhurst
§4.2). Left-balanced (Jensen): a node's left subtree holds the number of photons that keeps the
tree complete, and the node's photon is the one of that rank along the node's split axis — the axis
of largest extent of the subtree's photons. Every photon of the left subtree has a coordinate ≤ the
node's on the split axis, every photon of the right subtree ≥ it. Built level by level with NumPy:
one stable sort of 64-bit ``(subtree, coordinate)`` keys orders all subtrees of a level at once.

**Memory layout** (``N`` photons; arrays indexed by heap slot − 1):

==========  =====  ===========================================================================
array       bytes  content
==========  =====  ===========================================================================
``record``  16 N   node i at ``[4(i−1), 4i)``: float32 x, y, z of its photon, then a uint32 with
                   the original photon index (bits 0–29) and the split axis (bits 30–31)
``order``   4 N    uint32 original photon index of each node
``axis``    4 N    uint32 split axis of each node (0 = x, 1 = y, 2 = z; leaves: 0)
==========  =====  ===========================================================================

``record`` is what a gather reads: one 16-byte record per visited node, the counterpart of
Jensen's 20-byte photon (position, power, direction, split flag; Steinhurst §3.5). ``order`` and
``axis`` repeat its last field for callers. A cache simulator maps node ``i`` to a memory address
with either record size (``line(i) = (i − 1) div ⌊line_bytes / record_bytes⌋``).

**Search** (Jensen's locate, iterative): a symbolic loop per query with an explicit stack in local
memory. At a node: offer its photon to the k-best heap, go on to the near child (the side of the
split plane holding the query) and push the far child with its plane distance ``δ² = (q_a − s)²``
if ``δ² ≤ min(max_radius², d²_k)``. Without a near child, pop entries until one still satisfies
that bound. Ties are kept (``≤``), so a photon at exactly the k-th distance with a lower index is
still found, and float32 rounding is monotone, so ``δ²`` never exceeds a far-side photon's ``d²``:
the results are exact. The stack holds at most one entry per tree level (≤ 32).

**Address trace** (:meth:`KDTree.visits`): the same search also counts the nodes each query visits
and can write their heap slots, in visiting order, to a buffer — the exact stream of record reads of
a gather (Steinhurst §3.2: the renderer notes every photon-map access). The cache simulator runs a
compiled copy of this search (:mod:`photonmap.analysis.kdwalk`), tested slot for slot against this
one.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import to_jit, to_numpy
from ..core.errors import ParameterError
from ..core.knn import (
    COS_NORMAL,
    PhotonSearch,
    accept,
    finish,
    heap_bound2,
    new_heap,
    offer,
    pack_records,
    photon_key,
    read_record,
    squared_distance,
    squared_radius,
)

STACK_SIZE = 32
"""Traversal stack entries per lane: at most one per tree level."""
INDEX_MASK = (1 << 30) - 1
MAX_PHOTONS = INDEX_MASK
"""Photons a tree can hold: a record's 4th field packs the photon index (30 bits) and the axis."""


def _orderable(values: np.ndarray) -> np.ndarray:
    """float32 → uint64 with the same order (for sort keys)."""
    bits = values.astype(np.float32).view(np.uint32)
    flipped = np.where(bits >> 31, ~bits, bits | np.uint32(0x80000000))
    return flipped.astype(np.uint64)


def left_balanced_order(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heap-order layout of a left-balanced kd-tree over ``points`` (N, 3).

    Returns ``(order, axis)``: ``order[i − 1]`` is the index of the photon at heap slot ``i`` and
    ``axis[i − 1]`` its split axis.
    """
    count = len(points)
    size = np.zeros(2 * count + 2, np.int64)  # subtree sizes by heap slot (0 beyond N)
    size[1 : count + 1] = 1
    levels = count.bit_length()
    for level in range(levels - 2, -1, -1):
        nodes = np.arange(1 << level, min(2 << level, count + 1))
        size[nodes] += size[2 * nodes] + size[2 * nodes + 1]
    start = np.zeros(2 * count + 2, np.int64)  # first in-order position of each subtree
    axis = np.zeros(count + 1, np.uint32)
    # photon index and coordinates at each in-order position, refined level by level
    inorder = np.arange(count)
    coords = [np.array(points[:, a], np.float32) for a in range(3)]  # copies, refined in place
    for level in range(levels):
        nodes = np.arange(1 << level, min(2 << level, count + 1))
        seg_start, seg_size = start[nodes], size[nodes]
        offsets = np.cumsum(seg_size) - seg_size
        segment = np.repeat(np.arange(len(nodes)), seg_size)
        position = np.arange(len(segment)) - np.repeat(offsets - seg_start, seg_size)
        values = [c[position] for c in coords]
        extent = [np.maximum.reduceat(v, offsets) - np.minimum.reduceat(v, offsets) for v in values]
        seg_axis = np.argmax(np.stack(extent), axis=0)
        chosen = seg_axis[segment]
        along = np.where(chosen == 0, values[0], np.where(chosen == 1, values[1], values[2]))
        key = (segment.astype(np.uint64) << np.uint64(32)) | _orderable(along)
        ranked = position[np.argsort(key, kind="stable")]
        inorder[position] = inorder[ranked]
        for c in coords:
            c[position] = c[ranked]
        axis[nodes] = seg_axis
        left_size = size[2 * nodes]
        start[2 * nodes] = seg_start
        start[2 * nodes + 1] = seg_start + left_size + 1
    slots = np.arange(1, count + 1)
    return inorder[start[slots] + size[2 * slots]].astype(np.uint32), axis[1:]


class KDTree(PhotonSearch):
    """Left-balanced kd-tree in heap order over ``positions`` (N); see the module docstring."""

    def __init__(self, positions: mi.Point3f):
        super().__init__()
        positions = mi.Point3f(positions)
        count = dr.width(positions)
        if count > MAX_PHOTONS:
            raise ParameterError(f"a kd-tree holds at most {MAX_PHOTONS} photons, got {count}")
        points = to_numpy(positions).T
        if not np.all(np.isfinite(points)):
            raise ParameterError("photon positions must be finite")
        order, axis = left_balanced_order(points)
        self.order = to_jit(mi.UInt32, order)
        self.axis = mi.UInt32(axis)
        self.record = pack_records(points.T[:, order], order | (axis << 30))
        self._count = dr.opaque(mi.UInt32, count)

    def visits(self, query, k, radius, query_normal, normals, directions):
        """The nodes each query's gather visits, as NumPy ``(count (Q,), slots)``: query ``q``'s
        heap slots in visiting order are ``slots[o_q : o_q + count[q]]``, ``o`` the exclusive
        prefix sum of ``count``. Same arguments as :meth:`knn` with the normal test (one pass
        counts, a second writes; fewer than 2³² visits per call)."""
        args = (
            mi.Point3f(query),
            int(k),
            dr.opaque(mi.Float, squared_radius(radius)),
            mi.Vector3f(query_normal),
            self._stored(normals),
            self._stored(directions),
            dr.opaque(mi.Float, COS_NORMAL),
        )
        count = self._search(*args, trace=(None, None))[-1].numpy().astype(np.int64)
        offset = np.cumsum(count) - count
        buffer = dr.zeros(mi.UInt32, max(int(count.sum()), 1))
        self._search(*args, trace=(buffer, to_jit(mi.UInt32, offset)))
        dr.eval(buffer)
        return count, buffer.numpy()[: count.sum()]

    @dr.syntax
    def _search(self, query, k, radius2, query_normal, normals, directions, cos_normal, trace=None):
        lanes = dr.width(query)
        heap = new_heap(k, lanes)
        found = dr.zeros(mi.UInt32, lanes)
        stack = dr.alloc_local(mi.UInt64, STACK_SIZE, dr.zeros(mi.UInt64, lanes))
        depth = dr.zeros(mi.UInt32, lanes)
        count = self._count
        node = dr.ones(mi.UInt32, lanes)  # heap slot of the next node; 0: pop the stack
        iterations = dr.zeros(mi.UInt32, lanes)
        cap = 2 * count + 2  # every node is visited and popped at most once
        active = dr.all(dr.isfinite(query))  # a query at infinity or NaN finds nothing
        visited = dr.zeros(mi.UInt32, lanes)
        buffer, offset = trace if trace is not None else (None, None)
        while active:
            bound = dr.minimum(radius2, heap_bound2(heap, k, found))
            if node != 0:
                # ---- visit: offer the node's photon, go to the near child, push the far child
                if dr.hint(buffer is not None, mode="scalar"):
                    dr.scatter(buffer, node, offset + visited)
                visited += 1
                p, flag = read_record(self.record, node - 1)
                d2 = squared_distance(p, query)
                ok = accept(d2, radius2, query_normal, normals, directions, node - 1, cos_normal)
                found = offer(heap, k, found, photon_key(d2, flag & INDEX_MASK), ok)
                axis = flag >> 30
                delta = dr.select(
                    axis == 0, query.x - p.x, dr.select(axis == 1, query.y - p.y, query.z - p.z)
                )
                near = 2 * node + dr.select(delta < 0, 0, 1)
                far = 2 * node + dr.select(delta < 0, 1, 0)
                plane2 = delta * delta
                if (far <= count) & (plane2 <= bound):
                    stack[dr.minimum(depth, STACK_SIZE - 1)] = photon_key(plane2, far)
                    depth += 1
                node = dr.select(near <= count, near, 0)
            else:
                # ---- pop: resume at the entry if it is still within the bound
                if depth > 0:
                    depth -= 1
                    entry = stack[depth]
                    entry_plane2 = dr.reinterpret_array(mi.Float, mi.UInt32(entry >> 32))
                    node = dr.select(entry_plane2 <= bound, mi.UInt32(entry & 0xFFFFFFFF), 0)
                else:
                    active = mi.Bool(False)
            iterations += 1
            active &= iterations < cap
        index, radius2_found = finish(heap, k, found, lanes)
        return (index, found, radius2_found) + ((visited,) if trace is not None else ())
