"""Irradiance caching for the final gather: Ward's sequential cache and Steinhurst's tiled cache
with R_avg precomputed at photons (Steinhurst 2007 Ch. 5).

A cache decides, before any final gather, which eye-ray hits gather (and become *records*) and
which *interpolate* the irradiance of earlier records (Eqs 5.7–5.10). Only purely Lambertian hits
take part (``L_r = ρ/π · E``, Eq 5.4); every other hit runs its own full final gather.

**Error and weights** (Ward's form without ``E(x')``, as Steinhurst §5.3 drops it; Eqs 5.7 and
5.9 disagree on the 4/π and the normal term, so their common form is taken)::

    ε_j(x) = ||x − x_j|| / R_j + sqrt(max(0, 1 − n_x·n_j))        w_j(x) = 1 / max(ε_j, 10⁻⁶)

Record ``j`` is valid at ``x`` iff ``ε_j(x) < ε_max``, ``n_x·n_j > 0`` and x is not behind it
(Ward's "in front" test ``(x − x_j)·(n_x + n_j)/2 ≥ −0.1 ||x − x_j||``). A hit with at least one
valid earlier record interpolates ``E(x) = Σ w_j E(x_j) / Σ w_j`` over all of them (Eq 5.10);
otherwise it gathers and is inserted as a record.

**Modes**:

- ``ward`` (§5.1, the baseline): one cache for the whole image, hits taken in scanline order,
  ``R_j`` the harmonic mean distance (Eq 5.8) of ``RAVG_RAYS`` cosine rays cast at the record
  itself. Steinhurst takes R_j from the record's own final-gather rays; distances from separate
  rays of the same distribution make the same decisions in distribution and let every ``R`` be
  known before any decision. The dependence stays sequential (one SIMD lane walks the image).
- ``tiled`` (§5.2, §5.3): a new empty cache per ``TILE × TILE`` pixel tile, and ``R`` read
  from the nearest (facing the same way) of the points at every ``RAVG_EVERY``-th photon where it
  was precomputed once per photon map (:func:`precompute_ravg`; the subset and ray count are not
  given: 1/8 of the photons as Christensen 1999's radiance photons, 64 rays, misses add
  ``1/R = 0``). All decisions of a tile are then known before any gather.

**Decisions, vectorised**: the pairs (x_i, record candidate x_j) of one cache with ``j`` before
``i`` — every pair of a tile (NumPy, a block of tiles at a time), or for Ward's image-wide cache
the lanes within ``ε_max · R_j`` of each ``j`` (a k-d tree on the host) — are kept where the test
above holds. What remains is sequential only along each
cache's order — "i gathers iff no earlier candidate gathers" — and runs as one Dr.Jit loop with a
SIMD lane per cache (per tile; a single lane for Ward's whole-image cache), each step reading the
decisions of its candidates. The interpolation links (pixel, record, weight) follow by array
operations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.spatial import cKDTree

from ..core.arrays import to_jit
from ..core.bsdf import intersect_visible
from ..core.errors import ParameterError
from ..core.hashgrid import HashGrid
from ..core.sampling import rng, rotated_hammersley
from .photon_map import PhotonMap

MODES = ("none", "ward", "tiled")
TILE = 16  # pixels per tile side (Steinhurst's 16 × 16)
RAVG_EVERY = 8  # R_avg precomputed at every 8th photon (Christensen 1999's ratio)
RAVG_RAYS = 64  # cosine rays per R_avg
RAVG_CLAMP = (0.001, 2.0)  # R_avg limits × the cube root of the scene box's volume
PAIRWISE_RUN = 4096  # caches up to this many lanes enumerate all their pairs
PAIR_BLOCK = 1 << 22  # pairs examined at a time
QUERY_BLOCK = 4096  # k-d tree queries at a time
IN_FRONT = 0.1  # Ward's in-front tolerance, × ||x − x_j||
RAVG_STREAM = 1 << 20  # RNG streams of the R_avg rays


def ravg_limits(scene: mi.Scene) -> tuple[float, float]:
    """``RAVG_CLAMP`` × (scene box volume)^(1/3). pbrt-v1 clamps at 0.125;
    in the Cornell box the median R_avg of the eye-ray hits is 0.65 × that size (measured), so
    that limit would make R_avg a constant on most hits. The upper limit here, about the box's
    diagonal, only bounds points that see mostly sky."""
    box = scene.bbox()
    extent = np.maximum(np.array(box.max) - np.array(box.min), 1e-6).ravel()
    size = float(np.prod(extent)) ** (1 / 3)
    return RAVG_CLAMP[0] * size, RAVG_CLAMP[1] * size


def harmonic_mean_distance(
    scene: mi.Scene,
    position: mi.Point3f,
    normal: mi.Vector3f,
    rays: int,
    seed: int,
    limits: tuple[float, float],
    null_shapes: bool | None = None,
) -> mi.Float:
    """``R_avg = N / Σ 1/R_i`` (Eq 5.8) over ``rays`` cosine-distributed rays at each point, a
    miss adding ``1/R = 0``, clamped to ``limits``."""
    position, normal = mi.Point3f(position), mi.Vector3f(normal)
    count = dr.width(position)
    lanes = count * rays
    point = dr.arange(mi.UInt32, lanes) // rays
    si = dr.zeros(mi.SurfaceInteraction3f, lanes)
    si.p = dr.gather(mi.Point3f, position, point)
    si.n = dr.gather(mi.Vector3f, normal, point)
    shifts = rng(count, seed, RAVG_STREAM)
    shift = mi.Point2f(shifts.next_float32(), shifts.next_float32())
    u = rotated_hammersley(
        rays, dr.arange(mi.UInt32, lanes) % rays, dr.gather(mi.Point2f, shift, point)
    )
    direction = mi.Frame3f(si.n).to_world(mi.warp.square_to_cosine_hemisphere(u))
    hit = intersect_visible(scene, si.spawn_ray(direction), True, null_shapes)
    inverse = dr.select(hit.is_valid(), 1.0 / dr.maximum(hit.t, 1e-30), 0.0)
    dr.eval(inverse)
    total = dr.block_reduce(dr.ReduceOp.Add, inverse, rays)
    R = dr.select(total > 0, rays / dr.maximum(total, 1e-30), limits[1])
    R = dr.clip(R, limits[0], limits[1])
    dr.eval(R)
    return R


@dataclass
class RavgPoints:
    """R_avg precomputed at a subset of photons (§2.9.3 step 1) with a grid to find them."""

    normal: mi.Vector3f
    ravg: mi.Float
    grid: HashGrid | None

    def lookup(self, si: mi.SurfaceInteraction3f, active, radius: float, fallback: float):
        """R_avg of the nearest point facing the same way as ``si`` within ``radius``
        (``fallback`` — the smallest R, so the hit gathers — where there is none)."""
        if self.grid is None:
            return dr.full(mi.Float, fallback, dr.width(si.p))
        nb = self.grid.knn(
            si.p, k=1, max_radius=radius, query_normal=si.sh_frame.n, normals=self.normal
        )
        found = mi.Bool(active) & (nb.count > 0)
        return dr.select(found, dr.gather(mi.Float, self.ravg, nb.index, found), fallback)


def precompute_ravg(
    scene: mi.Scene, pmap: PhotonMap, seed: int, null_shapes: bool | None = None
) -> RavgPoints:
    """R_avg at every ``RAVG_EVERY``-th photon of ``pmap`` (Steinhurst §5.3)."""
    if pmap.size == 0:
        return RavgPoints(dr.zeros(mi.Vector3f, 0), dr.zeros(mi.Float, 0), None)
    index = dr.arange(mi.UInt32, 0, pmap.size, RAVG_EVERY)
    position = dr.gather(mi.Point3f, pmap.photons.position, index)
    normal = dr.gather(mi.Vector3f, pmap.photons.normal, index)
    limits = ravg_limits(scene)
    R = harmonic_mean_distance(scene, position, normal, RAVG_RAYS, seed, limits, null_shapes)
    dr.eval(position, normal)
    return RavgPoints(normal, R, HashGrid(position))


@dataclass
class CachePlan:
    """The decisions of an irradiance cache over the ``N`` lanes of an eye pass.

    ``gather``: lanes that run a final gather (records and non-Lambertian hits), ``record``
    (bool per ``gather`` entry): whether that gather is a record (it returns irradiance);
    ``interpolate``: lanes that interpolate; ``link_*``: one entry per (interpolating lane,
    record lane) pair with the normalised weight ``w_j / Σ w``."""

    gather: np.ndarray
    record: np.ndarray
    interpolate: np.ndarray
    link_lane: np.ndarray
    link_record: np.ndarray
    link_weight: np.ndarray

    @property
    def hit_rate(self) -> float:
        """R_IC: the fraction of the cache's pixels (records + interpolating) that interpolate."""
        cached = len(self.interpolate) + int(self.record.sum())
        return len(self.interpolate) / cached if cached else 0.0


def plan_cache(
    position: np.ndarray,
    normal: np.ndarray,
    ravg: np.ndarray,
    lambertian: np.ndarray,
    found: np.ndarray,
    order: np.ndarray,
    cache: np.ndarray,
    error: float,
) -> CachePlan:
    """Decide every lane (arrays over the ``N`` lanes: ``position``/``normal`` (N, 3), ``ravg``,
    masks ``lambertian`` and ``found``). ``order``: the lanes in processing order; ``cache``: the
    cache (tile) of each lane — caches must be contiguous runs of ``order``."""
    if not (math.isfinite(error) and error > 0):
        raise ParameterError(f"ic_error must be a positive number, got {error!r}")
    n = len(position)
    eligible = lambertian & found
    i, j = _candidate_pairs(position, ravg, eligible, order, cache, error)
    offset = position[i] - position[j]
    distance = np.linalg.norm(offset, axis=1)
    cos = np.einsum("ij,ij->i", normal[i], normal[j])
    eps = distance / ravg[j] + np.sqrt(np.maximum(0.0, 1.0 - cos))
    front = np.einsum("ij,ij->i", offset, normal[i] + normal[j]) / 2 >= -IN_FRONT * distance
    keep = (eps < error) & (cos > 0) & front
    i, j, eps = i[keep], j[keep], eps[keep]
    record = _greedy_records(i, j, eligible, order, cache)
    # links: each non-record eligible lane to its valid records
    link = record[j] & ~record[i]
    i, j, w = i[link], j[link], 1.0 / np.maximum(eps[link], 1e-6)
    w /= np.bincount(i, w, minlength=n)[i]
    interpolate = np.flatnonzero(eligible & ~record)
    gather = np.flatnonzero(found & ~(eligible & ~record))
    return CachePlan(gather, record[gather], interpolate, i, j, w)


def _candidate_pairs(position, ravg, eligible, order, cache, error):
    """Pairs ``(i, j)`` of eligible lanes of one cache with ``j`` before ``i`` that may pass the
    error test (``||x_i − x_j|| < ε_max · R_j``). Small caches (tiles) take every pair of the
    cache, a block of tiles at a time; a large one (Ward's image-wide cache) asks a k-d tree for
    the lanes within ``ε_max · R_j`` of each ``j``."""
    runs = np.flatnonzero(np.diff(cache[order], prepend=-1, append=-1) != 0)
    start, length = runs[:-1], np.diff(runs)
    longest = int(length.max()) if len(length) else 0
    if longest <= PAIRWISE_RUN:
        slots = np.full((len(start), longest), -1, np.int64)
        row = np.repeat(np.arange(len(start)), length)
        column = np.arange(len(order)) - np.repeat(start, length)
        slots[row, column] = np.where(eligible[order], order, -1)
        pairs = []
        block = max(1, PAIR_BLOCK // max(longest * longest, 1))
        for first in range(0, len(start), block):  # bounded memory: a block of tiles at a time
            s = slots[first : first + block]
            later = (s[:, :, None] >= 0) & (s[:, None, :] >= 0)
            later &= np.tri(longest, k=-1, dtype=bool)[None]  # column (j) before row (i)
            t, a, b = np.nonzero(later)
            i, j = s[t, a], s[t, b]
            near = np.sum((position[i] - position[j]) ** 2, axis=1) < (error * ravg[j]) ** 2
            pairs.append(np.stack([i[near], j[near]]))
        both = np.concatenate(pairs, axis=1) if pairs else np.zeros((2, 0), np.int64)
        return both[0], both[1]
    lanes = np.flatnonzero(eligible)
    if len(lanes) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    tree = cKDTree(position[lanes])
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    pairs = []
    for first in range(0, len(lanes), QUERY_BLOCK):  # bounded memory: a block of records
        j = lanes[first : first + QUERY_BLOCK]
        found = tree.query_ball_point(position[j], error * ravg[j], return_sorted=False)
        i = lanes[np.concatenate(found).astype(np.int64)]
        j = np.repeat(j, [len(f) for f in found])
        keep = (rank[j] < rank[i]) & (cache[i] == cache[j])
        pairs.append(np.stack([i[keep], j[keep]]))
    both = np.concatenate(pairs, axis=1)
    return both[0], both[1]


def _greedy_records(i, j, eligible, order, cache) -> np.ndarray:
    """``record[x]`` = eligible and no candidate ``j`` of ``x`` (earlier, in its cache) is a
    record — one Dr.Jit loop, a SIMD lane per cache walking its run of ``order``."""
    n = len(eligible)
    by_lane = np.argsort(i, kind="stable")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(i, minlength=n))]).astype(np.uint32)
    runs = np.flatnonzero(np.diff(cache[order], prepend=-1, append=-1) != 0)
    start, length = runs[:-1], np.diff(runs)
    record = _greedy(
        to_jit(mi.UInt32, order),
        to_jit(mi.UInt32, start),
        to_jit(mi.UInt32, length),
        mi.UInt32(ptr),
        to_jit(mi.UInt32, np.append(j[by_lane], 0)),  # never empty (Dr.Jit loops)
        mi.Bool(eligible),
        n,
    )
    return record.numpy() > 0


@dr.syntax
def _greedy(order, start, length, ptr, candidates, eligible, n):
    caches = dr.width(start)
    record = dr.zeros(mi.UInt32, n)
    dr.make_opaque(record)
    pos = dr.zeros(mi.UInt32, caches)
    while pos < length:
        lane = dr.gather(mi.UInt32, order, start + pos)
        c = dr.gather(mi.UInt32, ptr, lane)
        end = dr.gather(mi.UInt32, ptr, lane + 1)
        covered = dr.zeros(mi.Bool, caches)
        while c < end:
            covered |= dr.gather(mi.UInt32, record, dr.gather(mi.UInt32, candidates, c)) > 0
            c += 1
        decided = dr.gather(mi.Bool, eligible, lane) & ~covered
        dr.scatter(record, mi.UInt32(decided), lane)
        pos += 1
    return record


def cache_order(mode: str, width: int, height: int, spp: int) -> tuple[np.ndarray, np.ndarray]:
    """Processing order and cache id of the ``width·height·spp`` lanes of an eye pass (a pixel's
    samples adjacent): scanline order in one cache (``ward``), or tile by tile in scanline order
    of the tiles, scanline order inside each tile, one cache per tile (``tiled``)."""
    lane = np.arange(width * height * spp)
    pixel = lane // spp
    x, y = pixel % width, pixel // width
    if mode == "ward":
        return lane, np.zeros(len(lane), np.int64)
    tiles_x = -(-width // TILE)
    tile = (y // TILE) * tiles_x + x // TILE
    order = np.lexsort((lane, tile))
    return order, tile


def apply_cache(
    plan: CachePlan, gathered: mi.Spectrum, rho: mi.Spectrum, count: int
) -> mi.Spectrum:
    """The indirect radiance at every lane: a non-Lambertian lane's own final gather, a record's
    ``ρ/π · E``, an interpolating lane's ``ρ/π · Σ w_j E(x_j)`` (Eq 5.10). ``gathered``: the final
    gathers of ``plan.gather`` in that order (irradiance at records); ``rho``: ρ per lane."""
    result = dr.zeros(mi.Spectrum, count)
    lanes = to_jit(mi.UInt32, plan.gather)
    dr.scatter(result, gathered, lanes)
    E = dr.zeros(mi.Spectrum, count)  # at the records
    dr.scatter(E, gathered, lanes, mi.Bool(plan.record))
    dr.eval(E)
    interpolated = dr.zeros(mi.Spectrum, count)
    if len(plan.link_lane):
        term = dr.gather(mi.Spectrum, E, to_jit(mi.UInt32, plan.link_record))
        weight = to_jit(mi.Float, plan.link_weight)
        link_lane = to_jit(mi.UInt32, plan.link_lane)
        dr.scatter_reduce(dr.ReduceOp.Add, interpolated, term * weight, link_lane)
    E += interpolated
    cached = np.zeros(count, bool)
    cached[plan.gather[plan.record]] = True
    cached[plan.interpolate] = True
    return dr.select(mi.Bool(cached), rho * E / math.pi, result)
