"""The alternative photon-map data structures of Steinhurst 2007 Ch. 4 (Table 4.1, Fig 4.1) for
the cache simulator: the **kdB-tree** (Robinson 1981, :mod:`.kdbtree`) and **block hashing**
(Ma & McCool 2002, :mod:`.blockhash`), beside the heap-order kd-tree of :mod:`.stream`; the
kernels their gathers share are in :mod:`.line_search`.

Both structures are *line-organised*: every node or block is exactly one cache line of
``L`` bytes, so the structure itself depends on the line size and is built once per line size.
A gather reads whole nodes, and its recorded stream is the line id of every node it reads, in
reading order. With a fully associative LRU cache the misses depend only on that sequence of ids,
not on where the lines lie; the layouts matter only for the set-associative option.

Each structure's trace (:class:`StructureTrace`) has the interface of
:class:`~photonmap.analysis.stream.GatherTrace` (``lines``, ``uncached_bytes``,
``footprint_lines``) over the same final-gather requests, so :mod:`.bandwidth` works unchanged.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ParameterError
from ..surface.gather_batch import OrderParams, gather_order
from .bandwidth import counts
from .blockhash import BlockHash
from .kdbtree import KDBTree
from .stream import permuted_stream

REFERENCE_LINE = 128  # line size of the uncached byte counts (the dissertation's line)


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
    """Table 4.1's figure, "average number of memory-block fetches", read as fetches per distinct
    block of the structure (the only reading its Hilbert row fits; compare ratios within the
    table only): LRU misses of a fully associative cache over the distinct lines the gathers
    touch, with both counts."""
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
