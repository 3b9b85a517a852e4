"""Hash grid photon map: exact k-nearest and fixed-radius photon gathers (Dr.Jit).

Steinhurst 2007 §2.6.2 (the k-NN gather) and Ch. 4 (the uniform grid, whose k-NN "expands to
neighbouring cells in distance order"). The default search structure of
the photon maps; :class:`photonmap.surface.kdtree.KDTree` is the dissertation's kd-tree with the
same interface (:class:`~photonmap.core.knn.PhotonSearch`) and the same results.

The gather interface, its result (ties broken by photon index, exact against a float32 NumPy brute
force), the candidate and normal tests and the k-best heap are :mod:`photonmap.core.knn`'s; this
module is the grid and its search.

**Memory layout** of a grid over ``N`` photons with ``T`` table slots and ``D_a`` cells along axis a:

=================  ==================  ==============================================================
array              bytes               content
=================  ==================  ==============================================================
``record``         16 N                stored photon i at ``[4i, 4i+4)``: float32 x, y, z and the
                                       uint32 original index (bit pattern); sorted by table slot
``order``          4 N                 uint32 original index of stored photon i (``record``'s 4th
                                       field; kept for permuting per-photon data)
``cell_start``     4 (T + 1)           uint32; slot s holds stored photons ``cell_start[s] ..
                                       cell_start[s+1] − 1`` (the count is the difference)
``slab_bounds[a]`` 8 D_a               per axis a and cell slab m: float32 (min, max) of the photon
                                       coordinates a in that slab (+∞, −∞ when empty)
``beyond_lo[a]``   4 (D_a + 1)         min coordinate a over the slabs ≥ m (+∞ at m = D_a)
``below_hi[a]``    4 (D_a + 1)         max coordinate a over the slabs < m (−∞ at m = 0)
=================  ==================  ==============================================================

A gather reads one 16-byte record per candidate photon (one packet gather; measured 15–20% faster
than three separate coordinate arrays plus ``order``).

A photon's cell is ``c = clamp(⌊(p − origin) · inv_cell⌋, 0, D − 1)``, its cell number the row-major
``(c_z·D_y + c_y)·D_x + c_x`` and its slot that number modulo ``T``, the power of two ≥ max(2N, 64);
cells sharing a slot are told apart by recomputing each photon's cell. A grid with no more cells
than that has a slot per cell (``T`` = number of cells). Row-major slots keep the photons of
neighbouring cells in a row next to each other in memory. Photon normals and directions for the
normal test are permuted into the same order as 16-byte ``(x, y, z, 0)`` records. Measured on 1M
photons on the walls of a Cornell box (2.7M cells), hashed and per-cell tables gather equally fast.

**Search** (one symbolic loop per query over cells, an inner loop over a cell's photons): visit the
cells of ring R = 0, 1, 2, … — the shell of the cube of cells at Chebyshev distance R from the
query's cell (clamped into the grid, so far-away queries start at the nearest cell), clipped to the
grid — and skip a cell whose box distance exceeds the current bound ``min(max_radius², d²_k)``.
After ring R stop when the nearest photon outside the visited cube is farther than the bound (or
none is left). Box and ring distances use the photon extents of the cell slabs, not the cell planes,
so pruning is exact in float32 (subtraction, squaring and addition round monotonically: a photon's
computed ``d²`` is never below the computed bound of a cell it lies in); the search stays exact when
the k-th neighbour lies several cells away.

**Cell size**: ``cell_size``, or by default the edge at which occupied cells hold about
``photons_per_cell`` = 8 photons, estimated from the occupancy at two coarse trial sizes (which
adapts to photons on surfaces as well as in volumes). Measured on 1M photons, 2 to 32 photons per
cell are within 30% of the best for k = 10–100; 8 is best or close for both point sets.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from .arrays import to_jit, to_numpy
from .errors import ParameterError
from .knn import (
    COS_NORMAL,
    NO_PHOTON,
    PhotonSearch,
    accept,
    finish,
    heap_bound2,
    jit_records,
    new_heap,
    offer,
    photon_key,
    read_record,
    squared_distance,
    squared_radius,
)

PHOTONS_PER_CELL = 8.0
"""Occupancy that sets the automatic cell size."""
MAX_CELLS_PER_AXIS = 1024
"""Cells per axis at most (cell numbers fit in 32 bits); a smaller cell size is raised to fit."""


class HashGrid(PhotonSearch):
    """Photons sorted by cell over a hash table of cells (module docstring: layout and search).

    ``positions``: the photon positions (N). ``cell_size``: the cell edge in world units, or None
    for the automatic size (about ``photons_per_cell`` photons per occupied cell); at most
    :data:`MAX_CELLS_PER_AXIS` cells per axis.
    """

    def __init__(
        self,
        positions: mi.Point3f,
        cell_size: float | None = None,
        photons_per_cell: float = PHOTONS_PER_CELL,
    ):
        super().__init__()
        positions = mi.Point3f(positions)
        count = dr.width(positions)
        if cell_size is not None and not (math.isfinite(cell_size) and cell_size > 0):
            raise ParameterError(f"cell_size must be positive and finite, got {cell_size!r}")
        if not photons_per_cell > 0:
            raise ParameterError(f"photons_per_cell must be positive, got {photons_per_cell!r}")
        lo, hi = np.zeros(3, np.float32), np.zeros(3, np.float32)
        if count:
            bounds = [[r(positions[a], axis=None) for a in range(3)] for r in (dr.min, dr.max)]
            finite = dr.all(dr.all(dr.isfinite(positions)), axis=None)  # (min and max skip NaN)
            dr.eval(bounds, finite)
            if not finite[0]:
                raise ParameterError("photon positions must be finite")
            lo, hi = (np.array([c[0] for c in b], np.float32) for b in bounds)
        span = hi - lo
        extent = float(span.max())
        if cell_size is None:
            points = to_numpy(positions).reshape(3, count).T
            cell_size = _automatic_cell_size(points, lo, extent, photons_per_cell)
        self.cell_size = max(float(cell_size), extent / (MAX_CELLS_PER_AXIS - 1), 1e-30)
        self.origin = tuple(float(c) for c in lo)
        self.inv_cell = float(np.float32(1.0 / self.cell_size))
        self.dims = tuple(int(d) + 1 for d in np.floor(span * np.float32(self.inv_cell)))
        cells = math.prod(self.dims)
        # a power-of-two table of >= 2N slots; a grid with no more cells uses a slot per cell
        table = 1 << max(2 * count - 1, 63).bit_length()
        self.hashed = cells > table
        self.table_size = table if self.hashed else cells
        # kernel inputs as opaque values (one compiled kernel for every grid)
        self._origin = dr.opaque(mi.Point3f, self.origin)
        self._inv_cell = dr.opaque(mi.Float, self.inv_cell)
        self._dims = dr.opaque(mi.Point3i, self.dims)
        self._slot_mask = dr.opaque(mi.UInt32, self.table_size - 1)

        # the photons sorted by slot (the cell arithmetic of the queries; Dr.Jit's radix sort is
        # stable: a slot's photons in their original order), their records and the slot starts
        counts = dr.zeros(mi.UInt32, self.table_size + 1)
        self.order = dr.zeros(mi.UInt32, 0)
        cell = None
        if count:  # (Dr.Jit refuses arithmetic between width 0 and a literal)
            cell = self._cell(positions)
            slot = self._slot(self._cell_number(cell))
            self.order = dr.argsort(slot)
            dr.scatter_reduce(dr.ReduceOp.Add, counts, 1, slot, mode=dr.ReduceMode.Local)
        self.record = jit_records(dr.gather(mi.Point3f, positions, self.order), self.order)
        self.cell_start = dr.prefix_sum(counts)  # exclusive: slot s starts at cell_start[s]
        self._build_slab_bounds(positions, cell)
        dr.eval(self.order, self.record, self.cell_start)  # built here, not in the first query
        # Iteration cap of the cell loop: each cell of the grid lies on one shell, and each
        # (row, ring) pair adds at most two positions outside the grid.
        rings = max(self.dims) + 1
        self.iteration_cap = min(
            cells + 2 * self.dims[1] * self.dims[2] * rings + 2, np.iinfo(np.uint32).max
        )
        self._iteration_cap = dr.opaque(mi.UInt32, self.iteration_cap)

    def _build_slab_bounds(self, positions: mi.Point3f, cell: mi.Point3i | None):
        """Per axis: the photon extent of each cell slab and its running min / max (``cell``:
        each photon's; None without photons)."""
        self.slab_bounds, self.beyond_lo, self.below_hi = [], [], []
        for a in range(3):
            lo = dr.full(mi.Float, dr.inf, self.dims[a])
            hi = dr.full(mi.Float, -dr.inf, self.dims[a])
            if cell is not None:
                index, local = mi.UInt32(cell[a]), dr.ReduceMode.Local
                dr.scatter_reduce(dr.ReduceOp.Min, lo, positions[a], index, mode=local)
                dr.scatter_reduce(dr.ReduceOp.Max, hi, positions[a], index, mode=local)
            lo, hi = np.array(lo), np.array(hi)
            beyond = np.minimum.accumulate(np.append(lo, np.inf)[::-1])[::-1]
            below = np.maximum.accumulate(np.insert(hi, 0, -np.inf))
            self.slab_bounds.append(to_jit(mi.Float, np.stack([lo, hi], axis=1).ravel()))
            self.beyond_lo.append(to_jit(mi.Float, beyond))
            self.below_hi.append(to_jit(mi.Float, below))

    # --- cell arithmetic (the same float32 operations at build and query time)
    def _cell(self, p: mi.Point3f) -> mi.Point3i:
        """The cell of ``p``, clamped into the grid."""
        u = dr.floor((p - self._origin) * self._inv_cell)
        return mi.Point3i(dr.clip(u, 0, mi.Point3f(self._dims - 1)))

    def _cell_number(self, c: mi.Point3i) -> mi.UInt32:
        dims = self._dims
        return mi.UInt32((c.z * dims.y + c.y) * dims.x + c.x)

    def _slot(self, number: mi.UInt32) -> mi.UInt32:
        if self.hashed:
            return number & self._slot_mask
        return number

    def _cell_bound2(self, c: mi.Point3i, q: mi.Point3f, active: mi.Bool) -> mi.Float:
        """Lower bound on ``d²`` of the photons in cell ``c`` (+∞ if its slabs are empty)."""
        gap = []
        for a in range(3):
            lo_hi = dr.gather(mi.Vector2f, self.slab_bounds[a], mi.UInt32(c[a]), active)
            gap.append(dr.maximum(dr.maximum(lo_hi.x - q[a], q[a] - lo_hi.y), 0.0))
        return gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2]

    def _box_bound2(self, c: mi.Point3i, q: mi.Point3f) -> mi.Float:
        """A lower bound on ``d²`` from ``q`` to the photons of cell ``c``: the distance to the
        cell's box, shrunk by 10⁻³ of a cell so that a photon that float rounding placed in ``c``
        from just outside its box is never skipped."""
        lo = self._origin + mi.Point3f(c) / self._inv_cell
        gap = dr.maximum(
            dr.maximum(lo - q, q - (lo + 1 / self._inv_cell)) - 1e-3 / self._inv_cell, 0
        )
        return dr.squared_norm(gap)

    def _outside_bound2(self, q: mi.Point3f, c0: mi.Point3i, ring: mi.Int32) -> mi.Float:
        """Lower bound on ``d²`` of the photons outside the cube of ``ring`` around cell ``c0``
        (+∞ when the cube covers the grid)."""
        dims = self._dims
        bound = dr.full(mi.Float, dr.inf, dr.width(ring))
        for a in range(3):
            above = mi.UInt32(dr.minimum(c0[a] + ring + 1, dims[a]))
            gap_hi = dr.maximum(dr.gather(mi.Float, self.beyond_lo[a], above) - q[a], 0.0)
            below = mi.UInt32(dr.maximum(c0[a] - ring, 0))
            gap_lo = dr.maximum(q[a] - dr.gather(mi.Float, self.below_hi[a], below), 0.0)
            bound = dr.minimum(bound, dr.minimum(gap_hi * gap_hi, gap_lo * gap_lo))
        return bound

    def _candidate(self, j, query, number, radius2, query_normal, normals, directions, cos_normal):
        """Stored photon ``j`` as a candidate of the cell numbered ``number`` for ``query`` (traced
        inside the search loops): ``(d², original index, ok)``, ``ok`` where it lies within the
        radius, in that cell (cells share slots of a hashed table) and passes the normal test
        (``normals``/``directions``: stored records or None)."""
        p, index = read_record(self.record, j)
        d2 = squared_distance(p, query)
        same_cell = self._cell_number(self._cell(p)) == number if self.hashed else True
        ok = accept(d2, radius2, query_normal, normals, directions, j, cos_normal, same_cell)
        return d2, index, ok

    @dr.syntax
    def _search(self, query, k, radius2, query_normal, normals, directions, cos_normal):
        lanes = dr.width(query)
        heap = new_heap(k, lanes)
        found = dr.zeros(mi.UInt32, lanes)
        dims = self._dims
        c0 = self._cell(query)
        # the current cell is c0 + (ox, oy, oz) on the shell of the cube of ``ring``
        ring = dr.zeros(mi.Int32, lanes)
        ox = dr.full(mi.Int32, -1, lanes)  # one before the first cell of ring 0
        oy = dr.zeros(mi.Int32, lanes)
        oz = dr.zeros(mi.Int32, lanes)
        iterations = dr.zeros(mi.UInt32, lanes)
        active = dr.all(dr.isfinite(query))  # a query at infinity or NaN finds nothing
        while active:
            # ---- step to the next cell of the shell, clipped to the grid, or to the next ring
            bound = dr.minimum(radius2, heap_bound2(heap, k, found))
            interior = (dr.abs(oy) < ring) & (dr.abs(oz) < ring)  # a row crossing the cube
            ox += 1
            ox = dr.select(interior & (ox > -ring) & (ox < ring), ring, ox)
            next_row = ox > dr.minimum(ring, dims.x - 1 - c0.x)
            oy = dr.select(next_row, oy + 1, oy)
            next_layer = oy > dr.minimum(ring, dims.y - 1 - c0.y)
            oy = dr.select(next_layer, dr.maximum(-ring, -c0.y), oy)
            oz = dr.select(next_layer, oz + 1, oz)
            if oz > dr.minimum(ring, dims.z - 1 - c0.z):
                outside2 = self._outside_bound2(query, c0, ring)
                active = (outside2 <= bound) & (outside2 < dr.inf)
                ring += 1
                oy = dr.maximum(-ring, -c0.y)
                oz = dr.maximum(-ring, -c0.z)
            if next_row:
                first_x = dr.maximum(-ring, -c0.x)
                interior = (dr.abs(oy) < ring) & (dr.abs(oz) < ring)
                ox = dr.select(interior & (first_x > -ring), ring, first_x)
            c = c0 + mi.Point3i(ox, oy, oz)
            visit = active & dr.all((c >= 0) & (c < dims))
            visit &= self._cell_bound2(c, query, visit) <= bound
            number = self._cell_number(c)
            slot = self._slot(number)
            j = dr.gather(mi.UInt32, self.cell_start, slot, visit)
            j_end = dr.gather(mi.UInt32, self.cell_start, slot + 1, visit)
            # ---- the photons of the cell
            while j < j_end:
                d2, index, ok = self._candidate(
                    j, query, number, radius2, query_normal, normals, directions, cos_normal
                )
                found = offer(heap, k, found, photon_key(d2, index), ok)
                j += 1
            iterations += 1
            active &= iterations < self._iteration_cap
        index, radius2_found = finish(heap, k, found, lanes)
        return index, found, radius2_found

    def nearest(
        self,
        query: mi.Point3f,
        radius: float,
        query_normal: mi.Vector3f | None = None,
        normals: mi.Vector3f | None = None,
        cos_normal: float = COS_NORMAL,
        active: mi.Bool | bool = True,
    ) -> tuple[mi.UInt32, mi.Float]:
        """The nearest photon within ``radius ≤ cell_size`` of each query that passes the normal
        test on ``normals``: ``(index, d²)``, :data:`NO_PHOTON` and +∞ where there is none.

        Every photon within one cell edge of the query lies in the 3×3×3 cells around the query's
        cell, so a fixed scan of those cells is exact — no rings, no k-best heap. The result is
        lazy (nothing is evaluated), so the scan fuses into the caller's kernel (the final gather's
        Christensen lookups). Ties go to the lower photon index, as in :meth:`knn`.
        """
        if not 0 <= radius <= self.cell_size:
            raise ParameterError(
                f"nearest() searches one cell around the query: the radius must lie in "
                f"[0, {self.cell_size}] (the cell size), got {radius!r}"
            )
        normals = self._stored(normals) if query_normal is not None else None
        radius2 = dr.opaque(mi.Float, squared_radius(radius))
        return self._nearest(
            query, radius2, query_normal, normals, dr.opaque(mi.Float, cos_normal), active
        )

    @dr.syntax
    def _nearest(self, query, radius2, query_normal, normals, cos_normal, active):
        lanes = dr.width(query)
        dims = self._dims
        c0 = self._cell(query)
        best_key = dr.full(mi.UInt64, 0xFFFFFFFFFFFFFFFF, lanes)
        best2 = mi.Float(radius2)
        # the query's own cell first (n = 13), then the others: offset (n % 3, n // 3 % 3, n // 9) − 1
        step = dr.zeros(mi.Int32, lanes)
        searching = active & dr.all(dr.isfinite(query)) & dr.full(mi.Bool, True, lanes)
        while searching & (step < 27):
            neighbour = (step + 13) % 27
            c = c0 + mi.Point3i(neighbour % 3, neighbour // 3 % 3, neighbour // 9) - 1
            visit = dr.all((c >= 0) & (c < dims))
            visit &= self._box_bound2(c, query) <= best2  # skip cells beyond the best so far
            number = self._cell_number(c)
            slot = self._slot(number)
            j = dr.gather(mi.UInt32, self.cell_start, slot, visit)
            j_end = dr.gather(mi.UInt32, self.cell_start, slot + 1, visit)
            while visit & (j < j_end):
                d2, index, ok = self._candidate(
                    j, query, number, radius2, query_normal, normals, None, cos_normal
                )
                key = photon_key(d2, index)
                better = ok & (key < best_key)
                best_key = dr.select(better, key, best_key)
                best2 = dr.select(better, d2, best2)
                j += 1
            step += 1
        none = best_key == 0xFFFFFFFFFFFFFFFF
        index = dr.select(none, NO_PHOTON, mi.UInt32(best_key & NO_PHOTON))
        d2 = dr.select(none, dr.inf, dr.reinterpret_array(mi.Float, mi.UInt32(best_key >> 32)))
        return index, d2

    def sum_within(self, query: mi.Point3f, radius2: mi.Float, term, zero, active, span: int = 3):
        """``Σ term(j, near)`` over the stored photons ``j`` with ``‖p_j − query‖² < radius2`` in
        the ``span``³ cells around the query — every photon within the radius when the radius is
        at most :attr:`cell_size` (``span=3``: the query's cell and its neighbours) or at most
        half of it (``span=2``: the 2 × 2 × 2 cells the radius's box can reach, chosen by the
        half of its cell the query lies in; 8 cells visited instead of 27, which pays where
        most cells are empty). ``term(j, near)`` returns the photon's share (``zero``'s type),
        read from per-photon arrays in storage order (``dr.gather(..., grid.order)``); it is
        traced inside the scan, so the sum fuses into the caller's kernel (callable inside the
        caller's own symbolic loops). Sums are in a fixed photon order: deterministic."""

        def add(j, near, total):
            return total + dr.select(near, term(j, near), zero)

        return self._scan(query, radius2, add, zero, active, span)

    def pairs_within(
        self, query: mi.Point3f, radius2: mi.Float, active, span: int = 2
    ) -> tuple[mi.UInt32, mi.UInt32]:
        """Every (query, photon) pair with ``‖p − query‖² < radius2`` (the radius bounded by the
        cell size as in :meth:`sum_within`): ``(query index, original photon index)``, a query's
        pairs adjacent and in :meth:`sum_within`'s photon order (deterministic). Two scans: the
        counts, then the pairs written from each query's exclusive prefix sum."""
        lanes = dr.width(query)
        one = mi.UInt32(1)
        counts = self.sum_within(
            query, radius2, lambda j, near: one, dr.zeros(mi.UInt32, lanes), active, span
        )
        offsets = dr.prefix_sum(counts)  # exclusive
        total = int(dr.sum(counts, axis=None)[0]) if lanes else 0
        photon, owner = dr.zeros(mi.UInt32, total), dr.zeros(mi.UInt32, total)
        if total == 0:
            return owner, photon
        lane = dr.arange(mi.UInt32, lanes)

        def write(j, near, slot):
            dr.scatter(photon, dr.gather(mi.UInt32, self.order, j, near), slot, near)
            dr.scatter(owner, lane, slot, near)
            return slot + mi.UInt32(near)

        self._scan(query, radius2, write, offsets, active, span)
        dr.eval(owner, photon)
        return owner, photon

    @dr.syntax
    def _scan(self, query: mi.Point3f, radius2: mi.Float, visit, state, active, span: int):
        """``state ← visit(j, near, state)`` for every stored photon ``j`` of the ``span``³ cells
        around each query (:meth:`sum_within`), ``near`` where it lies within the radius."""
        if span not in (2, 3):
            raise ValueError(f"span must be 2 or 3, got {span!r}")
        lanes = dr.width(query)
        dims = self._dims
        if span == 3:
            c0 = self._cell(query) - 1
        else:  # not clamped: a query beyond the grid visits no cell
            c0 = mi.Point3i(dr.floor((query - self._origin) * self._inv_cell - 0.5))
        step = dr.zeros(mi.UInt32, lanes)
        scanning = active & dr.all(dr.isfinite(query)) & dr.full(mi.Bool, True, lanes)
        while scanning & (step < span**3):
            offset = mi.Point3i(
                mi.Int32(step % span), mi.Int32(step // span % span), mi.Int32(step // span**2)
            )
            c = c0 + offset
            visit_cell = scanning & dr.all((c >= 0) & (c < dims))
            number = self._cell_number(c)
            slot = self._slot(number)
            j = dr.gather(mi.UInt32, self.cell_start, slot, visit_cell)
            j_end = dr.gather(mi.UInt32, self.cell_start, slot + 1, visit_cell)
            while visit_cell & (j < j_end):
                p, _ = read_record(self.record, j)
                near = squared_distance(p, query) < radius2
                if dr.hint(self.hashed, mode="scalar"):
                    near &= self._cell_number(self._cell(p)) == number  # slots shared by cells
                state = visit(j, near, state)
                j += 1
            step += 1
        return state


def _automatic_cell_size(
    points: np.ndarray, lo: np.ndarray, extent: float, per_cell: float
) -> float:
    """The cell edge at which occupied cells hold about ``per_cell`` photons.

    The mean occupancy ``m(h)`` of the occupied cells grows like ``h^d`` (d = 3 in a volume, 2 on
    surfaces): measured on grids of ``2g`` and ``g`` cells per axis (about 16 photons per cell of
    the fine grid if the photons filled the box), it gives ``d`` and the edge
    ``h · (per_cell / m(h))^(1/d)``.
    """
    count = len(points)
    if count < 2 or extent <= 0:
        return max(extent, 1.0)
    coarse = int(np.clip(round((count / 16) ** (1 / 3) / 2), 1, 64))
    occupancy = []
    for grid in (2 * coarse, coarse):
        cell = np.minimum(((points - lo) * (grid / extent)).astype(np.int64), grid - 1)
        number = (cell[:, 2] * grid + cell[:, 1]) * grid + cell[:, 0]
        occupancy.append(count / np.count_nonzero(np.bincount(number, minlength=grid**3)))
    dimension = float(np.clip(np.log2(occupancy[1] / occupancy[0]), 1.0, 3.0))
    return extent / (2 * coarse) * (per_cell / occupancy[0]) ** (1.0 / dimension)
