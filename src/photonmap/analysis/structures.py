"""The alternative photon-map data structures of Steinhurst 2007 Ch. 4 for the cache simulator:
the **kdB-tree** (Robinson 1981) and **block hashing** (Ma & McCool 2002), beside the heap-order
kd-tree of :mod:`.stream` (spec seed-001 §2.8, §3.4 Table 4.1 and Fig 4.1, oracle O21,
ambiguities A7, A21).

Both structures are *line-organised*: every node or block is exactly one cache line of
``L`` bytes, so the structure itself depends on the line size and is built once per line size.
A gather reads whole nodes, and its recorded stream is the line id of every node it reads, in
reading order. With a fully associative LRU cache the misses depend only on that sequence of ids,
not on where the lines lie; the layouts below matter only for the set-associative option.

**kdB-tree** (:class:`KDBTree`). Leaf block: an 8-byte header and ``m = ⌊(L − 8)/20⌋`` of
Jensen's 20-byte photons (spec §2.3: 6 at 128 B). Region node: ``F = ⌊L/28⌋`` entries of a child
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

**Block hashing** (:class:`BlockHash`, Ma & McCool 2002, approximate k-NN). Photons sorted along a
3D Hilbert curve (10 bits per axis over their bounding box) are cut into blocks of ``m`` photons,
one line each (block ``b`` in line ``b``). ``tables`` (4) locality-sensitive hash functions, each a
random rotation and a random shift of a cubic grid of cell edge ``w`` (random projections
quantised; ``w`` = twice the median distance of a photon to its k-th nearest photon, measured on a
sample of 256 photons), map a point to a bucket of its table; a bucket is one line of
``⌊L/4⌋`` 4-byte block pointers (buckets after the blocks, table by table). Every block goes into
the bucket of each cell its photons fall in; a full bucket keeps the blocks with the most photons
in that cell (ties: lower block id) and drops the others; a block in no bucket is *orphaned* (the
dissertation's remark on small lines). A query reads its bucket in every table, ranks the blocks
found by votes (tables listing the block; ties by first appearance) and reads at most ``A`` of
them (the accuracy parameter, A = 20 as in [DOC §4.4]; Ma & McCool suggest 10–16), keeping the
k nearest accepted photons among them. The stream is the bucket lines and block lines read.

Ma & McCool's paper was not at hand: their hash functions use per-axis thresholds adapted to the
photon distribution and their own bucket sizes; the choices above (rotated shifted grids, one-line
buckets, vote ranking) follow the same scheme — blocks of spatially coherent photons, several LSH
tables, a bounded number ``A`` of blocks read — and are documented as ours.

Each structure's trace (:class:`StructureTrace`) has the interface of
:class:`~photonmap.analysis.stream.GatherTrace` (``lines``, ``uncached_bytes``,
``footprint_lines``) over the same final-gather requests, so :mod:`.bandwidth` works unchanged.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..core.errors import ParameterError
from ..core.knn import COS_NORMAL, squared_radius
from ..core.order import hilbert3_index
from ..surface.gather_batch import OrderParams, gather_order
from .bandwidth import counts
from .stream import permuted_stream

RECORD_BYTES = 20  # Jensen's compact photon (spec §2.3)
HEADER_BYTES = 8  # a leaf block's bookkeeping (spec §2.3: 6 photons + 8 bytes in 128 B)
ENTRY_BYTES = 28  # a region entry: child AABB (6 float32) + 4-byte pointer
POINTER_BYTES = 4  # a hash bucket's block pointer
REFERENCE_LINE = 128  # line size of the uncached byte counts (the dissertation's line)
QUERY_CHUNK = 1 << 15  # queries per compiled call
ACCURACY = 20  # block hashing's A [DOC §4.4]
TABLES = 4  # block hashing's hash tables


def leaf_capacity(line_bytes: int) -> int:
    """Photons per leaf block, ``⌊(L − 8)/20⌋`` (spec §2.8: 6 at 128 B)."""
    m = (int(line_bytes) - HEADER_BYTES) // RECORD_BYTES
    if m < 1:
        raise ParameterError(
            f"a {line_bytes}-byte line cannot hold an {HEADER_BYTES}-byte header and one "
            f"{RECORD_BYTES}-byte photon; use lines of at least {HEADER_BYTES + RECORD_BYTES} B"
        )
    return m


def fan_out(line_bytes: int) -> int:
    """Child entries per region node, ``⌊L/28⌋`` (4 at 128 B)."""
    f = int(line_bytes) // ENTRY_BYTES
    if f < 2:
        raise ParameterError(
            f"a {line_bytes}-byte region node holds {f} {ENTRY_BYTES}-byte child entries; a "
            f"kdB-tree needs at least 2 (lines of at least {2 * ENTRY_BYTES} B)"
        )
    return f


# ------------------------------------------------------------------------------- shared kernels
@numba.njit(cache=True)
def _bits(value, scratch):
    scratch[0] = value
    return np.uint64(scratch.view(np.uint32)[0])


@numba.njit(cache=True)
def _offer(heap, found, k, key):
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
        _sift_down(heap, k, key)
    return found


@numba.njit(cache=True)
def _sift_down(heap, size, key):
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
def _bound(heap, found, k, radius2, scratch):
    """``min(max_radius², d²_k)`` (``d²_k`` = +∞ until k photons are kept)."""
    if found < k:
        return radius2
    scratch.view(np.uint32)[0] = np.uint32(heap[0] >> np.uint64(32))
    worst = scratch[0]
    return worst if worst < radius2 else radius2


@numba.njit(cache=True)
def _test(p, nrm, drc, i, q, qn, radius2, cos_normal, scratch):
    """``(key, ok)`` of stored photon ``i`` for query ``q`` — core.knn.accept's rule."""
    dx = p[i, 0] - q[0]
    dy = p[i, 1] - q[1]
    dz = p[i, 2] - q[2]
    d2 = dx * dx + dy * dy + dz * dz
    ok = d2 <= radius2
    if ok:
        ok = drc[i, 0] * qn[0] + drc[i, 1] * qn[1] + drc[i, 2] * qn[2] < np.float32(0)
    if ok:
        ok = nrm[i, 0] * qn[0] + nrm[i, 1] * qn[1] + nrm[i, 2] * qn[2] >= cos_normal
    return _bits(d2, scratch), ok


@numba.njit(cache=True)
def _emit(heap, found, k, out, row):
    """Heap-sort ``heap[:found]`` into ``out[row]`` nearest first (photon indices; -1 unused)."""
    for size in range(found - 1, 0, -1):
        last = heap[size]
        heap[size] = heap[0]
        _sift_down(heap, size, last)
    for j in range(k):
        out[row, j] = np.int64(heap[j] & np.uint64(0xFFFFFFFF)) if j < found else -1


@numba.njit(cache=True)
def _insert(order, used, value, keys):
    """Insert ``value`` into ``order[:used]``, kept ascending by ``keys[value]`` (stable)."""
    i = used
    while i > 0 and keys[order[i - 1]] > keys[value]:
        order[i] = order[i - 1]
        i -= 1
    order[i] = value


@numba.njit(cache=True)
def _grow(buffer, used, extra):
    if used + extra <= len(buffer):
        return buffer
    bigger = np.empty(max(2 * len(buffer), used + extra), buffer.dtype)
    bigger[:used] = buffer[:used]
    return bigger


# ------------------------------------------------------------------------------------ kdB-tree
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
    # binary splits inside one node: segment, leaves, children
    sa = np.zeros(128, np.int64)
    sb = np.zeros(128, np.int64)
    sl = np.zeros(128, np.int64)
    sg = np.zeros(128, np.int64)
    seg_a = np.zeros(fanout, np.int64)
    seg_b = np.zeros(fanout, np.int64)
    box_lo = np.zeros(3, np.float32)
    box_hi = np.zeros(3, np.float32)
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
def _kdb_search(
    qp, qn, k, radius2, cos_normal, kind, first, count, lo, hi, child, p, nrm, drc, index
):
    """Exact k-NN of every query; returns ``(found (Q, k), reads (Q,), lines)``."""
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
            if stack_d2[top] > _bound(heap, found, k, radius2, scratch):
                continue
            lines = _grow(lines, used, 1)
            lines[used] = node
            used += 1
            reads[r] += 1
            if kind[node] == 1:
                for j in range(first[node], first[node] + count[node]):
                    key, ok = _test(p, nrm, drc, j, q, qn[r], radius2, cos_normal, scratch)
                    if ok:
                        found = _offer(heap, found, k, (key << np.uint64(32)) | index[j])
                continue
            bound = _bound(heap, found, k, radius2, scratch)
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
                _insert(order, j, j, child_d2)
            for j in range(g - 1, -1, -1):  # nearest on top
                c = order[j]
                if child_d2[c] <= bound:
                    stack_node[top], stack_d2[top] = child[e0 + c], child_d2[c]
                    top += 1
        _emit(heap, found, k, found_out, r)
    return found_out, reads, lines[:used]


class KDBTree:
    """kdB-tree over ``positions`` (N, 3) for ``line_bytes`` lines (module docstring)."""

    def __init__(self, positions: np.ndarray, line_bytes: int):
        self.line_bytes = int(line_bytes)
        self.leaf_capacity = leaf_capacity(line_bytes)
        self.fan_out = fan_out(line_bytes)
        points = _positions(positions)
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
        args = _gather_args(query, query_normal, k, max_radius, cos_normal)
        tree = (self.kind, self.first, self.count, self.lo, self.hi, self.child)
        photons = _photons(self.points, self.perm, normals, directions)
        return _chunked(
            lambda s: _kdb_search(args[0][s], args[1][s], *args[2:], *tree, *photons),
            len(args[0]),
        )


# ------------------------------------------------------------------------------- block hashing
@numba.njit(cache=True)
def _bh_search(
    qp,
    qn,
    k,
    radius2,
    cos_normal,
    accuracy,
    qbucket,
    bucket_first,
    bucket_count,
    entries,
    blocks,
    block_first,
    block_count,
    p,
    nrm,
    drc,
    index,
):
    """Approximate k-NN: ``(found (Q, k), reads (Q,), lines)``; ``qbucket`` (Q, T): each query's
    bucket line per table (bucket id = line − blocks)."""
    queries, tables = qbucket.shape
    found_out = np.empty((queries, k), np.int64)
    reads = np.zeros(queries, np.int64)
    lines = np.empty(max(32 * queries, 1024), np.int64)
    used = 0
    heap = np.zeros(k, np.uint64)
    votes = np.zeros(blocks, np.int64)
    seen = np.zeros(blocks, np.int64)  # first appearance + 1 in this query (0: not yet)
    candidates = np.zeros(entries.shape[0] + 1, np.int64)
    rank = np.zeros(entries.shape[0] + 1, np.int64)
    order = np.zeros(accuracy, np.int64)
    scratch = np.zeros(1, np.float32)
    for r in range(queries):
        q = qp[r]
        found = 0
        n_cand = 0
        if np.isfinite(q[0]) and np.isfinite(q[1]) and np.isfinite(q[2]):
            lines = _grow(lines, used, tables + accuracy)
            for t in range(tables):
                line = qbucket[r, t]
                lines[used] = line
                used += 1
                reads[r] += 1
                bucket = line - blocks
                for j in range(bucket_first[bucket], bucket_first[bucket] + bucket_count[bucket]):
                    b = entries[j]
                    if seen[b] == 0:
                        candidates[n_cand] = b
                        n_cand += 1
                        seen[b] = n_cand
                    votes[b] += 1
            chosen = 0  # the best ``accuracy`` by votes descending, then first appearance
            for j in range(n_cand):
                b = candidates[j]
                rank[j] = -votes[b] * (n_cand + 1) + seen[b]
                if chosen < accuracy:
                    _insert(order, chosen, j, rank)
                    chosen += 1
                elif rank[j] < rank[order[chosen - 1]]:
                    _insert(order, chosen - 1, j, rank)
            for j in range(chosen):
                b = candidates[order[j]]
                lines[used] = b
                used += 1
                reads[r] += 1
                for i in range(block_first[b], block_first[b] + block_count[b]):
                    key, ok = _test(p, nrm, drc, i, q, qn[r], radius2, cos_normal, scratch)
                    if ok:
                        found = _offer(heap, found, k, (key << np.uint64(32)) | index[i])
            for j in range(n_cand):
                votes[candidates[j]] = 0
                seen[candidates[j]] = 0
        _emit(heap, found, k, found_out, r)
    return found_out, reads, lines[:used]


def _next_prime(n: int) -> int:
    n = max(int(n), 2)
    while any(n % d == 0 for d in range(2, int(math.isqrt(n)) + 1)):
        n += 1
    return n


class BlockHash:
    """Block hashing over ``positions`` (N, 3) for ``line_bytes`` lines (module docstring)."""

    def __init__(
        self,
        positions: np.ndarray,
        line_bytes: int,
        k: int = 100,
        tables: int = TABLES,
        accuracy: int = ACCURACY,
        seed: int = 0,
    ):
        for name, value in (("k", k), ("tables", tables), ("accuracy", accuracy)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ParameterError(
                    f"block hashing's {name} must be a positive integer, got {value!r}"
                )
        self.line_bytes = int(line_bytes)
        self.block_capacity = leaf_capacity(line_bytes)
        self.bucket_capacity = self.line_bytes // POINTER_BYTES
        self.tables, self.accuracy = int(tables), int(accuracy)
        points = _positions(positions)
        lo, hi = points.min(axis=0), points.max(axis=0)
        cells = np.clip((points - lo) / np.maximum(hi - lo, 1e-30) * 1024, 0, 1023).astype(np.int64)
        self.perm = np.argsort(hilbert3_index(cells, 10), kind="stable")
        self.points = points[self.perm]
        m = self.block_capacity
        self.blocks = -(-len(points) // m)
        self.block_first = np.arange(self.blocks, dtype=np.int64) * m
        self.block_count = np.minimum(m, len(points) - self.block_first)
        self.cell = self._cell_size(points, k, seed)
        rng = np.random.default_rng(seed)
        self.rotation = np.stack(
            [np.linalg.qr(rng.standard_normal((3, 3)))[0] for _ in range(self.tables)]
        )
        self.shift = rng.uniform(0, self.cell, (self.tables, 3))
        cell_ids = [self._cells(self.points, t) for t in range(self.tables)]
        occupied = max(len(np.unique(c, axis=0)) for c in cell_ids)
        self.buckets = _next_prime(2 * occupied)  # per table
        self._fill(cell_ids)

    def _cell_size(self, points, k, seed) -> float:
        """Twice the median distance of a photon to its k-th nearest (256 sampled photons)."""
        rng = np.random.default_rng(seed)
        sample = points[rng.choice(len(points), min(256, len(points)), replace=False)]
        kth = min(k, len(points) - 1)
        if kth < 1:
            return 1.0
        d2 = np.stack([((points - s) ** 2).sum(axis=1) for s in sample])
        return max(2.0 * float(np.median(np.sqrt(np.partition(d2, kth, axis=1)[:, kth]))), 1e-6)

    def _cells(self, points: np.ndarray, table: int) -> np.ndarray:
        """Integer grid cells (N, 3) of ``points`` in hash table ``table``."""
        moved = np.asarray(points, np.float64) @ self.rotation[table].T + self.shift[table]
        return np.floor(moved / self.cell).astype(np.int64)

    def _bucket(self, cells: np.ndarray, table: int) -> np.ndarray:
        """Bucket line of integer cells: ``blocks + table·S + hash(cell) mod S``."""
        c = cells.astype(np.uint64)
        h = (
            (c[:, 0] * np.uint64(73856093))
            ^ (c[:, 1] * np.uint64(19349663))
            ^ (c[:, 2] * np.uint64(83492791))
        )
        return self.blocks + table * self.buckets + (h % np.uint64(self.buckets)).astype(np.int64)

    def _fill(self, cell_ids) -> None:
        """Blocks into buckets: each block into the bucket of every cell its photons fall in; a
        full bucket keeps the blocks with most photons there (ties: lower block id)."""
        block_of = np.arange(len(self.points)) // self.block_capacity
        line, block, photons = [], [], []
        for t, cells in enumerate(cell_ids):
            pairs, hits = np.unique(
                np.stack([self._bucket(cells, t), block_of], axis=1), axis=0, return_counts=True
            )
            line.append(pairs[:, 0])
            block.append(pairs[:, 1])
            photons.append(hits)
        line, block, photons = (np.concatenate(x) for x in (line, block, photons))
        order = np.lexsort((block, -photons, line))
        line, block = line[order], block[order]
        start = np.r_[0, np.flatnonzero(line[1:] != line[:-1]) + 1]
        rank = np.arange(len(line)) - np.repeat(start, np.diff(np.r_[start, len(line)]))
        keep = rank < self.bucket_capacity
        self.dropped = int(np.count_nonzero(~keep))
        line, block = line[keep], block[keep]
        self.entries = block.astype(np.int64)
        bucket = line - self.blocks
        total = self.tables * self.buckets
        self.bucket_count = np.bincount(bucket, minlength=total).astype(np.int64)
        self.bucket_first = np.cumsum(self.bucket_count) - self.bucket_count
        self.orphaned = self.blocks - len(np.unique(self.entries))

    @property
    def lines(self) -> int:
        """Lines of the whole structure: blocks and buckets."""
        return self.blocks + self.tables * self.buckets

    def record_bytes(self) -> np.ndarray:
        """Bytes a reader uses of each line: a block's header and photons, a bucket's pointers."""
        return np.r_[
            HEADER_BYTES + RECORD_BYTES * self.block_count, POINTER_BYTES * self.bucket_count
        ]

    def knn(self, query, query_normal, normals, directions, k, max_radius, cos_normal=COS_NORMAL):
        """``(found (Q, k), reads (Q,), lines)`` as :meth:`KDBTree.knn`, approximate."""
        args = _gather_args(query, query_normal, k, max_radius, cos_normal)
        finite = np.all(np.isfinite(args[0]), axis=1)
        safe = np.where(finite[:, None], args[0], 0)
        qbucket = np.stack(
            [self._bucket(self._cells(safe, t), t) for t in range(self.tables)], axis=1
        )
        tables = (
            self.bucket_first,
            self.bucket_count,
            self.entries,
            self.blocks,
            self.block_first,
            self.block_count,
        )
        photons = _photons(self.points, self.perm, normals, directions)
        return _chunked(
            lambda s: _bh_search(
                args[0][s], args[1][s], *args[2:], self.accuracy, qbucket[s], *tables, *photons
            ),
            len(args[0]),
        )


# ------------------------------------------------------------------------------------- helpers
def _gather_args(query, query_normal, k, max_radius, cos_normal) -> tuple:
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= k <= 1024:
        raise ParameterError(f"k must be an integer in 1..1024, got {k!r}")
    if not max_radius >= 0:
        raise ParameterError(f"the gather radius must be >= 0 (or inf), got {max_radius!r}")
    q = np.ascontiguousarray(query, np.float32).reshape(-1, 3)
    n = np.ascontiguousarray(query_normal, np.float32).reshape(-1, 3)
    if len(n) != len(q):
        raise ParameterError(f"{len(n)} query normals for {len(q)} queries")
    return q, n, int(k), squared_radius(max_radius), np.float32(cos_normal)


def _positions(positions) -> np.ndarray:
    """Photon positions as a contiguous float32 (N ≥ 1, 3) array of finite values."""
    points = np.ascontiguousarray(positions, np.float32)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ParameterError(f"expected photon positions of shape (N >= 1, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ParameterError("photon positions must be finite")
    return points


def _photons(points, perm, normals, directions) -> tuple:
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


def _chunked(search, queries: int):
    """Run ``search(slice)`` over chunks of the queries and join the results."""
    found, reads, lines = [], [], []
    for start in range(0, max(queries, 1), QUERY_CHUNK):
        f, r, w = search(slice(start, start + QUERY_CHUNK))
        found.append(f)
        reads.append(r)
        lines.append(w)
    return np.concatenate(found), np.concatenate(reads), np.concatenate(lines)


# --------------------------------------------------------------------------------------- traces
STRUCTURES = ("kdtree", "kdbtree", "blockhash")


class StructureTrace:
    """The final gathers of a :class:`~photonmap.analysis.stream.GatherTrace` rerun on a
    line-organised structure (``"kdbtree"`` or ``"blockhash"``): the same interface, the stream
    of every line size built on first use and cached."""

    def __init__(self, trace, structure: str, **options):
        if structure not in ("kdbtree", "blockhash"):
            raise ParameterError(f"structure must be kdbtree or blockhash, got {structure!r}")
        if trace.photon_data is None:
            raise ParameterError("the gather trace carries no photon map (trace_final_gathers)")
        self.batch = trace.batch
        self.structure = structure
        self.k, self.radius = trace.k, trace.radius
        self.photon_data = trace.photon_data
        self.photons = trace.photons
        self.options = options
        self._built: dict[int, tuple] = {}

    def build(self, line_bytes: int) -> tuple:
        """``(structure, found, reads, offset, lines)`` for ``line_bytes`` lines (cached)."""
        line_bytes = int(line_bytes)
        if line_bytes not in self._built:
            position, normal, direction = self.photon_data
            if self.structure == "kdbtree":
                made = KDBTree(position, line_bytes)
            else:
                made = BlockHash(position, line_bytes, k=self.k, **self.options)
            found, reads, lines = made.knn(
                self.batch.position, self.batch.normal, normal, direction, self.k, self.radius
            )
            self._built[line_bytes] = (made, found, reads, np.cumsum(reads) - reads, lines)
        return self._built[line_bytes]

    def lines(self, order: str, line_bytes: int, params: OrderParams | None = None) -> np.ndarray:
        """The stream of line ids the gathers read when issued in ``order``."""
        _, _, reads, offset, lines = self.build(line_bytes)
        return permuted_stream(reads, offset, lines, gather_order(self.batch, order, params))

    def uncached_bytes(self) -> int:
        """Bytes of the records read without a cache, at the dissertation's 128-byte lines: a
        leaf's or block's header and photons, a region's entries, a bucket's pointers."""
        made, _, _, _, lines = self.build(REFERENCE_LINE)
        return int(made.record_bytes()[lines].sum())

    def footprint_lines(self, line_bytes: int) -> int:
        """Lines of the whole structure."""
        return self.build(line_bytes)[0].lines


def fetches_per_block(trace, order: str, cache_bytes: int, line_bytes: int, params=None) -> dict:
    """Table 4.1's figure (spec A7): LRU misses of a fully associative cache over the distinct
    lines of the structure the gathers touch, with both counts."""
    c = counts(trace, order, [line_bytes], [cache_bytes], 0, params)
    missed, distinct = int(c.misses[0, 0]), int(c.compulsory[0])
    return {"misses": missed, "distinct_lines": distinct, "fetches_per_block": missed / distinct}


def recall(found: np.ndarray, exact: np.ndarray) -> float:
    """Fraction of the exact k nearest (rows of photon indices, −1 unused) that ``found`` holds,
    over all queries (the accuracy of block hashing's approximate gathers)."""
    hits = sum(len(np.intersect1d(a[a >= 0], b[b >= 0])) for a, b in zip(found, exact, strict=True))
    return hits / max(int(np.count_nonzero(exact >= 0)), 1)


def structure_trace(trace, structure: str, **options):
    """``trace`` itself for ``"kdtree"``, else a :class:`StructureTrace` of its gathers."""
    if structure == "kdtree":
        return trace
    if structure not in STRUCTURES:
        raise ParameterError(f"structure must be one of {', '.join(STRUCTURES)}, got {structure!r}")
    return StructureTrace(trace, structure, **options)
