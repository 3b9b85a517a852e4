"""Final-gather request batches and their orders (Steinhurst 2007 Ch. 3).

The eye pass emits its final-gather photon gathers as an explicit batch (:class:`GatherBatch`, the
deferred request record of Steinhurst 2007 §3.4: gather position ``y`` with its normal, destination
pixel, ray index and the world direction ``ω_i`` of the final-gather ray). Directions come from a
counter-based generator keyed by (pixel, ray index), so every order below is a *permutation* of one
fixed batch and the image does not depend on it (tested): the gathers are independent and each pixel
sums its rays in ray-index order after the gathers.

Orders (:data:`ORDERS`; ``tile`` × ``tile`` screen tiles, row-major over the image):

- ``naive`` — pixels in scanline order, each pixel's rays in index order (§3.1);
- ``tiled`` — tiles in row-major order, scanline order inside a tile (§3.3.1; the tiles' order is
  not given);
- ``tiled_dirbin`` — per tile, rays sorted by world-space direction bin (§3.3.2 gives no
  bin count or frame: ``bins`` = 32 world-space equal-solid-angle bins by default, 4 bands uniform
  in ``ω·up`` × 8 azimuth sectors), then pixel, then ray; pixels whose eye ray met a specular
  surface go last;
- ``hashed`` — the naive stream through ``queues`` (17) hashed queues of ``slots`` (128) over a
  ``grid``³ world grid, one stream for the whole image (§3.4.3);
- ``tiled_dirbin_hashed`` — ``tiled_dirbin`` through the hashed queues, flushed per tile (§3.4.4,
  §7.3.4);
- ``tiled_hilbert`` — per tile, stable sort by the 3D Hilbert index of ``y`` (§3.4.2);
- ``hilbert`` — the whole batch along the 3D Hilbert curve (§3.4.1).

**Hashed queues** (§3.4.3 names neither the hash nor what happens when a queue is full; ours): a
request goes to queue ``(i + G j + G² k) mod p`` of its grid cell (a prime ``p``, as there). If
that queue is full the fullest queue (lowest index on ties) is drained completely, in arrival
order, until it has room; at the end of a stream all queues drain, fullest first. Since every
drain empties a full queue, the simulation advances by one drain per step for every stream at once
(NumPy over a window of ``p·s + 1`` requests, which must contain the next overflow).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.errors import ParameterError
from ..core.order import hilbert3_index

ORDERS = (
    "naive",
    "tiled",
    "tiled_dirbin",
    "hashed",
    "tiled_dirbin_hashed",
    "tiled_hilbert",
    "hilbert",
)
DIR_BANDS, DIR_SECTORS = 4, 8  # 32 world-space direction bins (module docstring)
HILBERT_BITS = 16  # cells per axis of the Hilbert grid: 2^16 (§3.4.1: a grid finer than gathers)


@dataclass
class OrderParams:
    """The reordering parameters of Steinhurst §3.3–3.4 (defaults: the dissertation's where it
    gives them, §3.3.2 and §3.4.3; the direction bins ours)."""

    tile: int = 16  # tile edge in pixels
    queues: int = 17  # hashed queues p (a prime)
    slots: int = 128  # requests per queue s
    grid: int = 5  # world-grid intervals per axis for the hash (Cornell 5, Sponza 8)
    bins: int = DIR_BANDS * DIR_SECTORS  # direction bins, a power of two (8 … 128)

    def validate(self) -> None:
        for key in ("tile", "queues", "slots", "grid", "bins"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ParameterError(f"{key} must be a positive integer, got {value!r}")
        if self.bins & (self.bins - 1):
            raise ParameterError(f"bins must be a power of two (8, 16, 32, …), got {self.bins}")


@dataclass
class GatherBatch:
    """Final-gather requests (host arrays, one row per gather, in generation order: pixel-major,
    ray index minor). ``position`` (N, 3) float32: the gather point y, ``normal`` its shading normal
    (the k-NN normal test); ``direction`` (N, 3): the
    world direction ω_i of the ray that reached y; ``pixel`` (N,): destination pixel (scanline
    index); ``ray`` (N,): ray index within the pixel; ``specular`` (N,): the pixel's eye ray
    passed a specular surface. ``width``/``height``: the image; ``bounds``: the scene's AABB
    (lo, hi), the frame of the hash grid and the Hilbert grid."""

    position: np.ndarray
    normal: np.ndarray
    direction: np.ndarray
    pixel: np.ndarray
    ray: np.ndarray
    specular: np.ndarray
    width: int
    height: int
    bounds: tuple[np.ndarray, np.ndarray]

    def __len__(self) -> int:
        return len(self.pixel)


def gather_order(batch: GatherBatch, order: str, params: OrderParams | None = None) -> np.ndarray:
    """The permutation (int64 indices into ``batch``) that issues its gathers in ``order``."""
    params = params or OrderParams()
    params.validate()
    if order not in ORDERS:
        raise ParameterError(f"gather order must be one of {', '.join(ORDERS)}, got {order!r}")
    n = len(batch)
    index = np.arange(n)
    if order == "naive" or n == 0:
        return np.lexsort((batch.ray, batch.pixel))
    x, y = batch.pixel % batch.width, batch.pixel // batch.width
    t = params.tile
    tiles_x = -(-batch.width // t)
    tile = (y // t) * tiles_x + x // t
    in_tile = (y % t) * t + x % t
    if order == "hilbert":
        return np.argsort(_hilbert_keys(batch), kind="stable")
    if order == "hashed":
        naive = np.lexsort((batch.ray, batch.pixel))
        return naive[_hashed(np.zeros(n, np.int64), _queue(batch, params)[naive], params)]
    if order == "tiled":
        return np.lexsort((batch.ray, in_tile, tile))
    if order == "tiled_hilbert":
        return np.lexsort((index, _hilbert_keys(batch), tile))
    dbin = direction_bin(batch.direction, params.bins)
    binned = np.lexsort((batch.ray, in_tile, dbin, batch.specular, tile))
    if order == "tiled_dirbin":
        return binned
    return binned[_hashed(tile[binned], _queue(batch, params)[binned], params)]


def direction_bin(direction: np.ndarray, bins: int = DIR_BANDS * DIR_SECTORS) -> np.ndarray:
    """World-space direction bin (0 … bins − 1) of unit vectors (N, 3): bands of equal solid angle
    in ``d_y`` (+y is up) × azimuth sectors (module docstring); ``bins`` = 2^b splits into 2^⌊b/2⌋
    bands × 2^⌈b/2⌉ sectors (32 → 4 × 8, the default; 8 → 2 × 4; 128 → 8 × 16)."""
    bands = 1 << (int(bins).bit_length() - 1) // 2
    sectors = int(bins) // bands
    d = np.asarray(direction, np.float64)
    band = np.clip(((d[:, 1] + 1) * 0.5 * bands).astype(np.int64), 0, bands - 1)
    phi = np.arctan2(d[:, 2], d[:, 0]) + math.pi
    sector = np.clip((phi / (2 * math.pi) * sectors).astype(np.int64), 0, sectors - 1)
    return band * sectors + sector


def _cells(batch: GatherBatch, per_axis: int) -> np.ndarray:
    lo, hi = (np.asarray(b, np.float64) for b in batch.bounds)
    scale = per_axis / np.maximum(hi - lo, 1e-30)
    cell = np.floor((np.asarray(batch.position, np.float64) - lo) * scale)
    return np.clip(cell, 0, per_axis - 1).astype(np.int64)


def _hilbert_keys(batch: GatherBatch) -> np.ndarray:
    return hilbert3_index(_cells(batch, 1 << HILBERT_BITS), HILBERT_BITS)


def _queue(batch: GatherBatch, params: OrderParams) -> np.ndarray:
    """Hash queue ``(i + G j + G² k) mod p`` of each request's world-grid cell (module
    docstring)."""
    c = _cells(batch, params.grid)
    g = params.grid
    return (c[:, 0] + g * c[:, 1] + g * g * c[:, 2]) % params.queues


def _hashed(stream: np.ndarray, queue: np.ndarray, params: OrderParams) -> np.ndarray:
    """Service order of requests arriving in array order through the hashed queues; ``stream``
    (non-decreasing) splits the arrivals into independent streams, each flushed at its end."""
    n = len(queue)
    p, s = params.queues, params.slots
    if n == 0:
        return np.arange(0)
    starts = np.flatnonzero(np.r_[True, stream[1:] != stream[:-1]])
    ends = np.r_[starts[1:], n]
    streams = len(starts)
    sid = np.repeat(np.arange(streams), ends - starts)
    # occ[t]: arrivals of t's queue before t in its stream
    group = sid * p + queue
    by_group = np.lexsort((np.arange(n), group))
    first = np.r_[True, group[by_group][1:] != group[by_group][:-1]]
    run_start = np.maximum.accumulate(np.where(first, np.arange(n), 0))
    occ = np.empty(n, np.int64)
    occ[by_group] = np.arange(n) - run_start
    removed = np.zeros((streams, p), np.int64)  # arrivals of each queue already drained
    counts = np.zeros((streams, p), np.int64)  # requests waiting in each queue
    pos = starts.copy()
    window = np.arange(p * s + 1)
    events = []  # (stream, queue, cutoff): drains all of the queue's arrivals before cutoff
    active = np.arange(streams)
    while len(active):
        at = pos[active, None] + window
        valid = at < ends[active, None]
        at = np.minimum(at, n - 1)
        q = queue[at]
        over = valid & (occ[at] >= s + removed[active[:, None], q])
        hit = over.any(axis=1)
        upto = np.where(hit, over.argmax(axis=1), valid.sum(axis=1))
        arrived = valid & (window < upto[:, None])
        rows = np.repeat(np.arange(len(active)), arrived.sum(axis=1))
        counts[active] += np.bincount(rows * p + q[arrived], minlength=len(active) * p).reshape(
            -1, p
        )
        pos[active] += upto
        full = active[hit]
        drained = counts[full].argmax(axis=1)  # the fullest, lowest index on ties
        events.append(np.stack([full, drained, pos[full]], axis=1))
        removed[full, drained] += counts[full, drained]
        counts[full, drained] = 0
        active = active[pos[active] < ends[active]]
    # end of each stream: drain the remaining queues, fullest first
    st, qu = np.nonzero(counts)
    flush = np.lexsort((qu, -counts[st, qu], st))
    events.append(np.stack([st[flush], qu[flush], ends[st[flush]]], axis=1))
    events = np.concatenate(events)
    sequence = np.arange(len(events))
    # each request leaves with the first drain of its queue whose cutoff lies after it
    key = (events[:, 0] * p + events[:, 1]) * (n + 1) + events[:, 2]
    by_key = np.argsort(key)
    request_key = group * (n + 1) + np.arange(n)
    drain = by_key[np.searchsorted(key[by_key], request_key, side="right")]
    return np.lexsort((np.arange(n), sequence[drain], sid))


@dataclass
class RequestLayout:
    """What the final gather needs to emit its requests as a :class:`GatherBatch` and issue them
    in ``order``: the image (``width``, ``height``, ``spp`` eye samples per pixel, query point
    ``q`` belongs to pixel ``q // spp``), ``specular`` (per query point, NumPy bool: its eye ray
    passed a specular surface), the scene ``bounds``, the :class:`OrderParams`. With ``keep``, the
    batches issued are appended to ``batches`` (in generation order) for the cache simulator.
    ``lanes`` (NumPy int, optional): the query point of each final-gather lane, when only some
    query points gather (the irradiance cache's plan, Steinhurst Ch. 5). With ``record_only``
    the batches are kept but not gathered (their radiance is zero): the cache simulator needs the
    requests, not the image."""

    width: int
    height: int
    spp: int
    specular: np.ndarray
    bounds: tuple[np.ndarray, np.ndarray]
    order: str = "naive"
    params: OrderParams | None = None
    keep: bool = False
    batches: list | None = None
    lanes: np.ndarray | None = None
    record_only: bool = False

    def batch(self, query, ray, position, normal, direction) -> GatherBatch:
        """The batch of requests of query points ``query`` and ray indices ``ray`` (NumPy)."""
        query = np.asarray(query, np.int64)
        if self.lanes is not None:
            query = np.asarray(self.lanes, np.int64)[query]
        return GatherBatch(
            position=np.asarray(position, np.float32).reshape(-1, 3),
            normal=np.asarray(normal, np.float32).reshape(-1, 3),
            direction=np.asarray(direction, np.float32).reshape(-1, 3),
            pixel=query // self.spp,
            ray=(query % self.spp) * (1 << 20) + np.asarray(ray, np.int64),
            specular=self.specular[query],
            width=self.width,
            height=self.height,
            bounds=self.bounds,
        )
