"""Block hashing (Ma & McCool 2002) of Steinhurst 2007 Ch. 4 for the cache simulator:
approximate k-NN gathers over a line-organised photon map (:mod:`.structures`).

**Block hashing** (:class:`BlockHash`, Ma & McCool 2002, approximate k-NN). Photons sorted along a
3D Hilbert curve (10 bits per axis over their bounding box) are cut into blocks of ``m`` photons,
one line each (block ``b`` in line ``b``). ``tables`` (4) locality-sensitive hash functions, each a
random rotation and a random shift of a cubic grid of cell edge ``w`` (random projections quantised;
``w`` = twice the median distance of a photon to its k-th nearest photon, measured on a sample of
256 photons), map a point to a bucket of its table; a bucket is one line of ``⌊L/4⌋`` 4-byte block
pointers (buckets after the blocks, table by table). Every block goes into the bucket of each cell
its photons fall in; a full bucket keeps the blocks with the most photons in that cell (ties: lower
block id) and drops the others; a block in no bucket is *orphaned* (the dissertation's remark on
small lines). A query reads its bucket in every table, ranks the blocks found by votes (tables
listing the block; ties by first appearance) and reads at most ``A`` of them (the accuracy
parameter, A = 20 as in Steinhurst 2007 §4.4; Ma & McCool suggest 10–16), keeping the k nearest
accepted photons among them. The stream is the bucket lines and block lines read.

Ma & McCool's paper was not at hand: their hash functions use per-axis thresholds adapted to the
photon distribution and their own bucket sizes; the choices above (rotated shifted grids, one-line
buckets, vote ranking) follow the same scheme — blocks of spatially coherent photons, several LSH
tables, a bounded number ``A`` of blocks read — and are documented as ours.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..core.errors import ParameterError
from ..core.knn import COS_NORMAL
from ..core.order import hilbert3_index
from .line_search import (
    HEADER_BYTES,
    RECORD_BYTES,
    as_positions,
    candidate,
    chunked,
    emit_nearest,
    gather_args,
    grow,
    insert_sorted,
    leaf_capacity,
    offer,
    stored_photons,
)

POINTER_BYTES = 4  # a hash bucket's block pointer
ACCURACY = 20  # block hashing's A (Steinhurst 2007 §4.4)
TABLES = 4  # block hashing's hash tables


@numba.njit(cache=True)
def _bh_search(query, accuracy, qbucket, hash_tables, photons):
    """Approximate k-NN: ``(found (Q, k), reads (Q,), lines)``; ``query``: the queries as
    :func:`.line_search.gather_args` gives them, ``qbucket`` (Q, T): each query's bucket line per
    table (bucket id = line − blocks), ``hash_tables`` the tables' arrays, ``photons``
    (:func:`.line_search.stored_photons`)."""
    qp, qn, k, radius2, cos_normal = query
    bucket_first, bucket_count, entries, blocks, block_first, block_count = hash_tables
    index = photons[3]
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
            lines = grow(lines, used, tables + accuracy)
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
                    insert_sorted(order, chosen, j, rank)
                    chosen += 1
                elif rank[j] < rank[order[chosen - 1]]:
                    insert_sorted(order, chosen - 1, j, rank)
            for j in range(chosen):
                b = candidates[order[j]]
                lines[used] = b
                used += 1
                reads[r] += 1
                for i in range(block_first[b], block_first[b] + block_count[b]):
                    key, ok = candidate(photons, i, q, qn[r], radius2, cos_normal, scratch)
                    if ok:
                        found = offer(heap, found, k, (key << np.uint64(32)) | index[i])
            for j in range(n_cand):
                votes[candidates[j]] = 0
                seen[candidates[j]] = 0
        emit_nearest(heap, found, k, found_out, r)
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
        points = as_positions(positions)
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
        """``(found (Q, k), reads (Q,), lines)`` as :meth:`.kdbtree.KDBTree.knn`, approximate."""
        args = gather_args(query, query_normal, k, max_radius, cos_normal)
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
        photons = stored_photons(self.points, self.perm, normals, directions)
        return chunked(
            lambda s: _bh_search(
                (args[0][s], args[1][s], *args[2:]), self.accuracy, qbucket[s], tables, photons
            ),
            len(args[0]),
        )
