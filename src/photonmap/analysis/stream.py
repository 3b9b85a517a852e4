"""The photon-map address stream of a render's final gathers (Steinhurst 2007 §3.2, §3.5, §4.2).

A render of the surface method with exact k-NN final gathers on the heap-order kd-tree
(``lookup="knn"``, ``structure="kdtree"``) keeps its request batches
(:class:`~photonmap.surface.gather_batch.GatherBatch`) without running the gathers. Each request's
gather is then run by the compiled walk of :mod:`.kdwalk`, which visits the heap slots the
renderer's traversal visits (:meth:`~photonmap.surface.kdtree.KDTree.visits`), in visiting order:
the exact record reads of that gather. A gather order is a permutation of the requests, so the
stream of an order is the concatenation of the requests' visit lists in that order; it is either
materialised (small traces: :meth:`GatherTrace.lines`) or streamed straight into the caches
(:meth:`GatherTrace.simulate`, the full 512 × 512 image).

**Address model** (Steinhurst 2007 §3.5, §4.2): Jensen's 20-byte photon records in heap order, node
``i`` (1-based) in line ``(i − 1) div ⌊line_bytes / 20⌋`` (no record straddles two lines; the rest
of a line is the "bookkeeping" slack, 6 photons per 128-byte line). The **uncached naive** bandwidth
of the dissertation ("20 bytes reads of single photons scattered across memory", §3.5) is 20 bytes
per visited node. The stream holds the indirect (final-gather) gathers only, the ones the
dissertation's reorderings act on (whether its figures count the caustic gathers is explicit only in
Ch. 7; they are left out here: one per pixel at ``x``, they read their own map in a disjoint address
range and are the same in every order).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import mitsuba as mi
import numpy as np

from ..core.arrays import to_numpy
from ..core.errors import ParameterError
from ..core.knn import COS_NORMAL, squared_radius
from ..surface.gather_batch import GatherBatch, OrderParams, gather_order
from ..surface.pipeline import SurfacePipeline
from . import kdwalk
from .cache import simulate_reads

RECORD_BYTES = 20  # Jensen's compact photon (Steinhurst 2007 §3.5)
MAX_SLOTS = 200_000_000  # node visits :attr:`GatherTrace.slots` may hold (8 bytes each)
READS_BUDGET = 4 << 30  # bytes :meth:`GatherTrace.store_reads` may keep


@dataclass(frozen=True)
class KDRecords:
    """What a gather reads, as host arrays for the compiled walk (:mod:`.kdwalk`): the tree's
    16-byte records in heap order (``record`` (N, 4) float32: x, y, z, and photon index | split
    axis << 30 as uint32 bits), the photons' ``normal`` and ``direction`` (N, 3) in heap order for
    the normal test, ``k``, the maximum gather radius and the normal test's cosine (float32)."""

    record: np.ndarray
    normal: np.ndarray
    direction: np.ndarray
    k: int
    radius: float
    cos_normal: np.float32

    @classmethod
    def of(cls, photon_map, k: int, radius: float) -> KDRecords:
        tree = photon_map.structure
        record = tree.record.numpy().reshape(-1, 4)
        order = tree.order.numpy()

        def heap(v):
            return np.ascontiguousarray(to_numpy(mi.Vector3f(v))[:, order].T)

        return cls(
            np.ascontiguousarray(record, np.float32),
            heap(photon_map.photons.normal),
            heap(photon_map.photons.direction),
            int(k),
            float(radius),
            np.float32(COS_NORMAL),
        )

    def args(self) -> tuple:
        """``(tree, gather)`` as :func:`.kdwalk.walk` takes them."""
        tree = (self.record, self.record.view(np.uint32), self.normal, self.direction)
        return tree, (self.k, squared_radius(self.radius), self.cos_normal)


@dataclass
class GatherTrace:
    """Final-gather requests of one render and the kd-tree they gather from. The node visits are
    recomputed by the compiled walk when asked: request ``r``'s heap slots are
    ``slots[offset[r] : offset[r] + count[r]]`` (held in memory only for small traces);
    :meth:`simulate` streams them through caches without storing them."""

    batch: GatherBatch
    tree: KDRecords
    _visits: int | None = None
    _reads: dict = field(default_factory=dict)

    @property
    def photons(self) -> int:
        return len(self.tree.record)

    @property
    def k(self) -> int:
        return self.tree.k

    @property
    def radius(self) -> float:
        return self.tree.radius

    @property
    def photon_data(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The global map's photons in their original order, (N, 3) float32 each: position,
        normal, direction — what other structures need to rerun the same gathers."""
        index = self.tree.record.view(np.uint32)[:, 3] & kdwalk.INDEX_MASK
        out = []
        for heap in (self.tree.record[:, :3], self.tree.normal, self.tree.direction):
            original = np.empty_like(heap)
            original[index] = heap
            out.append(original)
        return tuple(out)

    def _queries(self):
        return self.batch.position, self.batch.normal

    @cached_property
    def count(self) -> np.ndarray:
        return kdwalk.visit_counts(*self._queries(), *self.tree.args())

    @property
    def offset(self) -> np.ndarray:
        return np.cumsum(self.count) - self.count

    @cached_property
    def slots(self) -> np.ndarray:
        if self.visits > MAX_SLOTS:
            raise ParameterError(
                f"the final gathers visit {self.visits:,} kd-tree nodes, more than the "
                f"{MAX_SLOTS:,} a stored trace may hold; use the streaming simulation "
                "(GatherTrace.simulate) or trace a smaller crop"
            )
        return kdwalk.visit_slots(*self._queries(), *self.tree.args(), self.offset, self.visits)

    @property
    def visits(self) -> int:
        """Nodes visited by all gathers (known after any :meth:`simulate`)."""
        if "count" not in self.__dict__ and self._visits is not None:
            return self._visits
        return int(self.count.sum())

    def uncached_bytes(self) -> int:
        """The dissertation's naive figure: one 20-byte read per visited node (§3.5)."""
        return self.visits * RECORD_BYTES

    def footprint_lines(self, line_bytes: int) -> int:
        """Lines of the whole global map."""
        return -(-self.photons // photons_per_line(line_bytes))

    def lines(self, order: str, line_bytes: int, params: OrderParams | None = None) -> np.ndarray:
        """The stream of cache-line ids the gathers read when issued in ``order``."""
        perm = gather_order(self.batch, order, params)
        slots = permuted_stream(self.count, self.offset, self.slots, perm)
        return (slots - 1) // photons_per_line(line_bytes)

    def store_reads(self, line_bytes: int, budget: int = READS_BUDGET) -> bool:
        """Walk every gather once and keep its line reads (runs within a line merged) so that
        :meth:`simulate` at this line size only replays them, order after order, instead of
        walking the tree again (the walk is most of the cost). Returns False and keeps nothing
        when they would take more than ``budget`` bytes (estimated on 2,000 gathers)."""
        if line_bytes in self._reads:
            return True
        per_line = photons_per_line(line_bytes)
        kind = np.empty(0, np.uint16 if self.footprint_lines(line_bytes) < 1 << 16 else np.uint32)
        args = (*self.tree.args(), per_line, kind)
        pick = np.random.default_rng(0).choice(len(self.batch), min(2000, len(self.batch)), False)
        sample, *_ = kdwalk.read_lines(*(q[pick] for q in self._queries()), *args, 0)
        estimate = int(sample.mean() * len(self.batch) * 1.05) + 1024
        if estimate * kind.itemsize > budget:
            return False
        count, lines, used, visits = kdwalk.read_lines(*self._queries(), *args, estimate)
        self._reads[line_bytes] = (count, np.cumsum(count) - count, lines[:used])
        self._visits = int(visits)
        return True

    def simulate(
        self, order: str, lines_bytes, capacities_bytes, ways: int = 0, params=None
    ) -> CacheCounts:
        """Stream the gathers in ``order`` through fully associative LRU caches of every
        capacity and line size (and, with ``ways``, a ``ways``-way set-associative cache of the
        first capacity): walking the tree without storing the stream (:func:`.kdwalk.simulate`),
        or replaying the reads kept by :meth:`store_reads`."""
        perm = gather_order(self.batch, order, params)
        lines_bytes = [int(x) for x in lines_bytes]
        caps = np.array([[max(int(c) // x, 1) for c in capacities_bytes] for x in lines_bytes])
        distinct = np.unique(caps)
        per_line = np.array([photons_per_line(x) for x in lines_bytes], np.int64)
        segcap = np.tile(np.diff(distinct, prepend=0), (len(lines_bytes), 1))
        sets = np.array([max(1, c // ways) if ways else 0 for c in caps[:, 0]], np.int64)
        if len(lines_bytes) == 1 and lines_bytes[0] in self._reads:
            count, offset, lines = self._reads[lines_bytes[0]]
            m, sa, c = simulate_reads(perm, offset, count, lines, segcap[0], sets[0], max(ways, 1))
            misses, sa, compulsory, visits = m[None], np.array([sa]), np.array([c]), self._visits
        else:
            caches = (per_line, segcap, sets, max(ways, 1))
            misses, sa, compulsory, visits = kdwalk.simulate(
                perm, *self._queries(), *self.tree.args(), caches
            )
            self._visits = int(visits)
        at = np.searchsorted(distinct, caps)
        return CacheCounts(
            np.take_along_axis(misses, at, axis=1), sa if ways else None, compulsory, visits
        )


@dataclass
class CacheCounts:
    """Line misses of one gather order: ``misses[l, c]`` for line size ``l`` and capacity ``c``
    (in the order asked), ``set_associative[l]`` (or None), ``compulsory[l]``: distinct lines
    read, ``visits``: kd-tree nodes read (for an explicit line stream: its reads)."""

    misses: np.ndarray
    set_associative: np.ndarray | None
    compulsory: np.ndarray
    visits: int


def permuted_stream(count, offset, data, perm) -> np.ndarray:
    """The concatenation of each request's run ``data[offset[r] : offset[r] + count[r]]`` over
    the requests ``perm`` (a gather order's stream)."""
    count = count[perm]
    start = np.repeat(offset[perm] - (np.cumsum(count) - count), count)
    return data[start + np.arange(int(count.sum()))]


def photons_per_line(line_bytes: int) -> int:
    """``⌊line_bytes / 20⌋`` photon records per cache line (64 → 3, 128 → 6)."""
    per_line = int(line_bytes) // RECORD_BYTES
    if per_line < 1:
        raise ParameterError(
            f"a cache line must hold at least one {RECORD_BYTES}-byte photon, got {line_bytes} B"
        )
    return per_line


def trace_final_gathers(scene, **params) -> GatherTrace:
    """The final-gather requests of ``scene`` rendered by the surface method (``params``: its
    parameters and scene parameters) with exact k-NN final gathers on the kd-tree. Only the
    requests are recorded; the gathers themselves are not run (the image is not needed), so a
    full 512 × 512 image at N_FG = 100 takes seconds."""
    pipe = SurfacePipeline(
        scene, **{**params, "lookup": "knn", "structure": "kdtree", "gather_order": "naive"}
    )
    pipe.kept_requests = []
    pipe.requests_only = True
    pipe.render()
    batches = pipe.kept_requests
    if not batches:
        raise ParameterError("the render made no final-gather requests (nothing visible?)")
    batch = GatherBatch(
        *(np.concatenate([getattr(b, f) for b in batches]) for f in _ARRAYS),
        width=batches[0].width,
        height=batches[0].height,
        bounds=batches[0].bounds,
    )
    _, radius = pipe.radii()
    return GatherTrace(batch, KDRecords.of(pipe.photon_maps()[0], pipe.params.k, radius))


_ARRAYS = ("position", "normal", "direction", "pixel", "ray", "specular")


def cropped_scene(name: str, size: int, offset: tuple[int, int], crop: tuple[int, int], **params):
    """The built-in scene ``name`` rendered at ``size`` × ``size`` but only in the film crop at
    ``offset`` (x, y) of ``crop`` (w, h) pixels — a window of the dissertation's 512 × 512 image
    with its pixel footprint, so that each tile's gathers are as coherent as at full size (a
    down-scaled run keeps the photon map and the cache; only such runs compare with each other)."""
    from ..scenes import SCENES

    if name not in SCENES:
        raise ParameterError(f"no built-in scene named {name!r}")
    scene = SCENES[name].build(width=size, height=size, **params)
    film = scene["sensor"]["film"]
    if not (
        0 <= offset[0]
        and offset[0] + crop[0] <= size
        and 0 <= offset[1]
        and offset[1] + crop[1] <= size
    ):
        raise ParameterError(f"the crop {crop} at {offset} leaves the {size}² image")
    film.update(
        crop_offset_x=offset[0], crop_offset_y=offset[1], crop_width=crop[0], crop_height=crop[1]
    )
    return scene
