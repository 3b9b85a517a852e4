"""The kdB-tree (Robinson 1981) of Steinhurst 2007 Ch. 4 for the cache simulator: a
line-organised photon map, every node exactly one cache line of ``L`` bytes (:mod:`.structures`).

**kdB-tree** (:class:`KDBTree`). Leaf block: an 8-byte header and ``m = ⌊(L − 8)/20⌋`` of
Jensen's 20-byte photons (6 at 128 B). Region node: ``F = ⌊L/28⌋`` entries of a child
AABB (6 float32) and a 4-byte pointer (4 at 128 B). Built top-down over the photon positions
(bulk loading, the static photon map needs no insertions):

- a node of ``n ≤ m`` photons is a leaf; otherwise it has height ``h`` (the least with
  ``m·F^h ≥ n``), needs ``ℓ = ⌈n/m⌉`` leaves and gets ``g = ⌈ℓ / F^(h−1)⌉`` children;
- its photons are cut into the ``g`` children by binary kd splits (Robinson's region split):
  the axis of largest extent of the segment, at rank ``m·ℓ_left`` where ``ℓ_left`` is the
  leaf count of the left ``⌈g/2⌉`` children (the ``ℓ`` leaves spread evenly over the children),
  recursively — so every leaf is full but the last one (``⌈N/m⌉`` leaves, as compact as the
  kd-tree's ``⌈N/6⌉`` lines at 128 B);
- an entry's box is the tight AABB of its child's photons.

Layout: nodes in depth-first pre-order (a subtree is contiguous, siblings' subtrees follow each
other), node ``i`` in line ``i``, the root in line 0.

Search: exact k-NN branch and bound with the gather of :mod:`photonmap.core.knn` — photons with
``d² ≤ max_radius²`` that pass the normal test (:func:`photonmap.core.knn.accept`), the ``k``
smallest keys ``(d², photon index)``, float32 arithmetic without fused multiply-adds. A region
node's children are visited nearest box first (ties by entry order) and skipped when the box's
``d²`` exceeds ``min(max_radius², d²_k)``; equality is visited, and float32 rounding is monotone,
so a box's ``d²`` never exceeds that of a photon inside it: the result is the kd-tree's, photon for
photon (ties by index included).
"""

from __future__ import annotations

import numba
import numpy as np

from ..core.errors import ParameterError
from ..core.knn import COS_NORMAL
from .line_search import (
    HEADER_BYTES,
    RECORD_BYTES,
    as_positions,
    candidate,
    chunked,
    emit_nearest,
    gather_args,
    grow,
    heap_bound2,
    insert_sorted,
    leaf_capacity,
    offer,
    stored_photons,
)

ENTRY_BYTES = 28  # a region entry: child AABB (6 float32) + 4-byte pointer


def fan_out(line_bytes: int) -> int:
    """Child entries per region node, ``⌊L/28⌋`` (4 at 128 B)."""
    f = int(line_bytes) // ENTRY_BYTES
    if f < 2:
        raise ParameterError(
            f"a {line_bytes}-byte region node holds {f} {ENTRY_BYTES}-byte child entries; a "
            f"kdB-tree needs at least 2 (lines of at least {2 * ENTRY_BYTES} B)"
        )
    return f


@numba.njit(cache=True)
def _box(pts, a, b, lo, hi):
    """The AABB of ``pts[a:b]`` into ``lo``, ``hi``."""
    for ax in range(3):
        lo[ax] = pts[a, ax]
        hi[ax] = pts[a, ax]
    for i in range(a + 1, b):
        for ax in range(3):
            lo[ax] = min(lo[ax], pts[i, ax])
            hi[ax] = max(hi[ax], pts[i, ax])


@numba.njit(cache=True)
def _split(pts, perm, segment, leaves, g, m, out):
    """Cut the photons ``pts[a:b]``, ``segment = (a, b)``, (and ``perm`` alike) into ``g``
    children of ``leaves`` leaves by binary kd splits (module docstring), the children's
    segments into ``out = (seg_a, seg_b)`` in pre-order."""
    a, b = segment
    seg_a, seg_b = out
    # pending splits: segment, leaves, children
    sa = np.zeros(128, np.int64)
    sb = np.zeros(128, np.int64)
    sl = np.zeros(128, np.int64)
    sg = np.zeros(128, np.int64)
    box_lo = np.zeros(3, np.float32)
    box_hi = np.zeros(3, np.float32)
    top, made = 1, 0
    sa[0], sb[0], sl[0], sg[0] = a, b, leaves, g
    while top > 0:
        top -= 1
        ca, cb, cl, cg = sa[top], sb[top], sl[top], sg[top]
        if cg == 1:
            seg_a[made], seg_b[made] = ca, cb
            made += 1
            continue
        left_g = (cg + 1) // 2
        base, extra = cl // cg, cl % cg
        left_l = left_g * base + min(extra, left_g)
        mid = ca + left_l * m
        _box(pts, ca, cb, box_lo, box_hi)
        axis, widest = 0, np.float32(-1)
        for ax in range(3):
            if box_hi[ax] - box_lo[ax] > widest:
                axis, widest = ax, box_hi[ax] - box_lo[ax]
        order = ca + np.argsort(pts[ca:cb, axis], kind="mergesort")
        moved_perm = perm[order]
        for ax in range(3):
            column = pts[order, ax]
            pts[ca:cb, ax] = column
        perm[ca:cb] = moved_perm
        # right part below the left one on the stack: the left is split first (pre-order)
        sa[top], sb[top], sl[top], sg[top] = mid, cb, cl - left_l, cg - left_g
        sa[top + 1], sb[top + 1], sl[top + 1], sg[top + 1] = ca, mid, left_l, left_g
        top += 2


@numba.njit(cache=True)
def _kdb_build(points, m, fanout):
    """Bulk-load the kdB-tree (module docstring). Returns ``(perm, kind, first, count, lo, hi,
    child)``: photon ``perm[j]`` at leaf position ``j``; node ``i`` (pre-order) is a leaf
    (``kind`` 1) of photons ``first..first+count`` or a region (``kind`` 0) of entries
    ``first..first+count`` with boxes ``lo``/``hi`` and child nodes ``child``."""
    n_total = points.shape[0]
    perm = np.arange(n_total)
    pts = points.copy()
    cap = 2 * (n_total // m + 2)
    kind = np.zeros(cap, np.int64)
    first = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    lo = np.zeros((cap, 3), np.float32)
    hi = np.zeros((cap, 3), np.float32)
    child = np.zeros(cap, np.int64)
    nodes = 0
    entries = 0
    # pending nodes: segment [a, b) of perm and the entry pointing at it (-1: the root)
    todo_a = np.zeros(cap, np.int64)
    todo_b = np.zeros(cap, np.int64)
    todo_e = np.zeros(cap, np.int64)
    todo = 1
    todo_a[0], todo_b[0], todo_e[0] = 0, n_total, -1
    seg_a = np.zeros(fanout, np.int64)  # the children's segments of perm
    seg_b = np.zeros(fanout, np.int64)
    while todo > 0:
        todo -= 1
        a, b, parent = todo_a[todo], todo_b[todo], todo_e[todo]
        node = nodes
        nodes += 1
        if parent >= 0:
            child[parent] = node
        n = b - a
        if n <= m:
            kind[node], first[node], count[node] = 1, a, n
            continue
        leaves = (n + m - 1) // m
        per_child = 1  # leaves a child subtree can hold: F^(h-1)
        while per_child * fanout < leaves:
            per_child *= fanout
        g = (leaves + per_child - 1) // per_child
        kind[node], first[node], count[node] = 0, entries, g
        _split(pts, perm, (a, b), leaves, g, m, (seg_a, seg_b))
        for j in range(g):
            _box(pts, seg_a[j], seg_b[j], lo[entries + j], hi[entries + j])
        for j in range(g - 1, -1, -1):  # first child on top: pre-order numbering
            todo_a[todo], todo_b[todo], todo_e[todo] = seg_a[j], seg_b[j], entries + j
            todo += 1
        entries += g
    return (
        perm,
        kind[:nodes],
        first[:nodes],
        count[:nodes],
        lo[:entries],
        hi[:entries],
        (child[:entries]),
    )


@numba.njit(cache=True)
def _kdb_search(query, tree, photons):
    """Exact k-NN of every ``query`` (:func:`.line_search.gather_args`) in the nodes ``tree``
    of ``photons`` (:func:`.line_search.stored_photons`); returns ``(found (Q, k), reads (Q,),
    lines)``."""
    qp, qn, k, radius2, cos_normal = query
    kind, first, count, lo, hi, child = tree
    index = photons[3]
    queries = qp.shape[0]
    found_out = np.empty((queries, k), np.int64)
    reads = np.zeros(queries, np.int64)
    lines = np.empty(max(64 * queries, 1024), np.int64)
    used = 0
    heap = np.zeros(k, np.uint64)
    # depth-first: at most F − 1 waiting siblings per level plus F children, < 64 levels
    stack_node = np.zeros(64 * max(count.max(), 2), np.int64)
    stack_d2 = np.zeros(len(stack_node), np.float32)
    child_d2 = np.zeros(max(count.max(), 1), np.float32)
    order = np.zeros(len(child_d2), np.int64)
    scratch = np.zeros(1, np.float32)
    for r in range(queries):
        q = qp[r]
        found = 0
        if np.isfinite(q[0]) and np.isfinite(q[1]) and np.isfinite(q[2]):
            top = 1
            stack_node[0], stack_d2[0] = 0, np.float32(0)
        else:
            top = 0
        while top > 0:
            top -= 1
            node = stack_node[top]
            if stack_d2[top] > heap_bound2(heap, found, k, radius2, scratch):
                continue
            lines = grow(lines, used, 1)
            lines[used] = node
            used += 1
            reads[r] += 1
            if kind[node] == 1:
                for j in range(first[node], first[node] + count[node]):
                    key, ok = candidate(photons, j, q, qn[r], radius2, cos_normal, scratch)
                    if ok:
                        found = offer(heap, found, k, (key << np.uint64(32)) | index[j])
                continue
            bound = heap_bound2(heap, found, k, radius2, scratch)
            e0, g = first[node], count[node]
            for j in range(g):
                e = e0 + j
                d2 = np.float32(0)
                for ax in range(3):
                    gap = np.float32(0)
                    if q[ax] < lo[e, ax]:
                        gap = lo[e, ax] - q[ax]
                    elif q[ax] > hi[e, ax]:
                        gap = q[ax] - hi[e, ax]
                    d2 = d2 + gap * gap  # (x² + y²) + z², as a photon's d²
                child_d2[j] = d2
            for j in range(g):
                insert_sorted(order, j, j, child_d2)
            for j in range(g - 1, -1, -1):  # nearest on top
                c = order[j]
                if child_d2[c] <= bound:
                    stack_node[top], stack_d2[top] = child[e0 + c], child_d2[c]
                    top += 1
        emit_nearest(heap, found, k, found_out, r)
    return found_out, reads, lines[:used]


class KDBTree:
    """kdB-tree over ``positions`` (N, 3) for ``line_bytes`` lines (module docstring)."""

    def __init__(self, positions: np.ndarray, line_bytes: int):
        self.line_bytes = int(line_bytes)
        self.leaf_capacity = leaf_capacity(line_bytes)
        self.fan_out = fan_out(line_bytes)
        points = as_positions(positions)
        self.perm, self.kind, self.first, self.count, self.lo, self.hi, self.child = _kdb_build(
            points, self.leaf_capacity, self.fan_out
        )
        self.points = points[self.perm]

    @property
    def lines(self) -> int:
        """Lines of the whole structure (one per node)."""
        return len(self.kind)

    def record_bytes(self) -> np.ndarray:
        """Bytes of each node a reader uses: a leaf's header and photons, a region's entries."""
        return np.where(
            self.kind == 1, HEADER_BYTES + RECORD_BYTES * self.count, ENTRY_BYTES * self.count
        )

    def knn(self, query, query_normal, normals, directions, k, max_radius, cos_normal=COS_NORMAL):
        """``(found (Q, k) original photon indices nearest first, −1 unused; reads (Q,); lines)``
        — the k-NN gather of :mod:`photonmap.core.knn` with the normal test (``normals``,
        ``directions``: (N, 3) per photon in the original order)."""
        args = gather_args(query, query_normal, k, max_radius, cos_normal)
        tree = (self.kind, self.first, self.count, self.lo, self.hi, self.child)
        photons = stored_photons(self.points, self.perm, normals, directions)
        return chunked(
            lambda s: _kdb_search((args[0][s], args[1][s], *args[2:]), tree, photons),
            len(args[0]),
        )
