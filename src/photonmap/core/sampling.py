"""Low-discrepancy and stratified 2D point sets on the unit square (Dr.Jit arrays).

Pfeuti §4.1 (Table 4.1, Fig 4.1) compares random, grid, jittered, Halton and Hammersley photon
distributions on the photon plane and finds Hammersley best in quality and speed. Here the
Hammersley point ``i`` of ``N`` is ``((i + ½)/N, Φ₂(i) + ½/N)`` with ``Φ₂`` the base-2 radical
inverse (Wong, Luk & Heng 1997 use ``(i/N, Φ₂(i))``; Pfeuti's listing is unclear): the ½ offsets
keep photons off voxel faces and preserve the (0, m, 2)-net property (tested).
Every random choice takes a seed.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from .errors import ParameterError
from .order import morton_cells, morton_order

SAMPLERS = ("hammersley", "halton", "grid", "jittered", "random")


def rng(count: int, seed: int, stream: int, lanes: mi.UInt32 | None = None) -> mi.PCG32:
    """``count`` PCG32 generators, one per lane, decorrelated by hashing (seed, stream) and then
    (key, lane) with TEA: distinct (seed, stream) pairs give unrelated sequences. The key is
    opaque, so new seeds and streams reuse compiled kernels. ``lanes``: the generators of these
    lanes of the ``count`` only (the same sequences as theirs in the whole wavefront)."""
    v0, v1 = (mi.UInt32(x & 0xFFFFFFFF) for x in (seed, stream))
    key = dr.opaque(mi.UInt32, mi.sample_tea_32(v0, v1, 8)[0][0])
    if lanes is None:
        state, sequence = mi.sample_tea_32(key, dr.arange(mi.UInt32, count))
        return mi.PCG32(count, mi.UInt64(state), mi.UInt64(sequence))
    state, sequence = mi.sample_tea_32(key, lanes)
    # PCG32 adds each generator's index in the array to its state and sequence: the lane's own
    shift = mi.UInt64(lanes) - mi.UInt64(dr.arange(mi.UInt32, dr.width(lanes)))
    return mi.PCG32(dr.width(lanes), mi.UInt64(state) + shift, mi.UInt64(sequence) + shift)


def radical_inverse_2(i: mi.UInt32) -> mi.Float:
    """Base-2 radical inverse Φ₂(i): the bits of ``i`` mirrored about the binary point."""
    return mi.radical_inverse_2(i, mi.UInt32(0))


PRIMES = (2, 3, 5, 7)


def radical_inverse(base: int, i: mi.UInt32, count: int) -> mi.Float:
    """Φ_b(i) for ``i < count``: the base-``b`` digits of ``i`` mirrored about the point (one
    fused kernel, ``⌈log_b count⌉`` digits)."""
    if base == 2:
        return radical_inverse_2(i)
    out, x, scale = dr.zeros(mi.Float, dr.width(i)), mi.UInt32(i), 1.0 / base
    for _ in range(max(1, math.ceil(math.log(max(count, 2)) / math.log(base)))):
        digit = x % base
        x = x // base
        out += mi.Float(digit) * scale
        scale /= base
    return out


def hammersley_nd(count: int, dims: int, seed: int) -> list[mi.Float]:
    """The ``dims``-dimensional Hammersley set ``((i+½)/N, Φ₂(i), Φ₃(i), Φ₅(i), …)``, every
    dimension but the first shifted modulo 1 by a random offset drawn from ``seed``
    (Cranley–Patterson rotation: each point uniform, the set stratified)."""
    i = dr.arange(mi.UInt32, count)
    shift = np.random.default_rng(seed).random(dims)
    out = [(mi.Float(i) + 0.5) / count]
    for k in range(dims - 1):
        x = radical_inverse(PRIMES[k], i, count) + dr.opaque(mi.Float, float(shift[k]))
        out.append(x - dr.floor(x))
    return out


def rotated_hammersley(count: int, i: mi.UInt32, shift: mi.Point2f) -> mi.Point2f:
    """Point ``i`` of the ``count``-point Hammersley set ``(i/N, Φ₂(i))`` shifted by ``shift``
    modulo 1 (a Cranley–Patterson rotation). With a uniform random shift per pixel or query point,
    each point is uniform — estimates stay unbiased — and the N points are stratified."""
    u = mi.Point2f(mi.Float(i) / count, radical_inverse_2(i)) + shift
    return u - dr.floor(u)


def hammersley(count: int, offset: bool = True) -> tuple[mi.Float, mi.Float]:
    """The 2D Hammersley set of ``count`` points; with ``offset`` the ½-cell offsets (module
    docstring)."""
    i = dr.arange(mi.UInt32, count)
    u = mi.Float(i) / count
    w = radical_inverse_2(i)
    if offset:
        u += 0.5 / count
        w += 0.5 / count
    return u, w


def hammersley_morton(count: int) -> tuple[mi.Float, mi.Float]:
    """The offset Hammersley set of ``count = 4^m`` points listed in Morton order of their cells.

    With ``s = 2^m`` the point ``i = a·s + r`` lies in column ``a = ⌊u·s⌋`` and row
    ``b = ⌊Φ₂(i)·s⌋ = rev_m(r)`` (the (0, m, 2)-net puts one point in every cell), so walking the
    cells ``(a, b)`` in Morton order and taking ``i = a·s + rev_m(b)`` orders the points without a
    sort — the same order :func:`photonmap.core.order.morton_order` gives.
    """
    side = math.isqrt(count)
    a, b = morton_cells(side)
    r = mi.UInt32(radical_inverse_2(b) * side)  # rev_m(b)
    i = a * side + r
    return (mi.Float(i) + 0.5) / count, radical_inverse_2(i) + 0.5 / count


def is_power_of_four(count: int) -> bool:
    return count > 0 and count & (count - 1) == 0 and (count.bit_length() - 1) % 2 == 0


def coherent_points(name: str, count: int, seed: int = 0) -> tuple[mi.Float, mi.Float]:
    """:func:`points` listed in Morton order of their position (spatially coherent SIMD lanes)."""
    if name == "hammersley" and is_power_of_four(count):
        return hammersley_morton(count)
    u, w = points(name, count, seed)
    order = morton_order(u, w)
    return dr.gather(mi.Float, u, order), dr.gather(mi.Float, w, order)


def halton(count: int, seed: int = 0) -> tuple[mi.Float, mi.Float]:
    """The first ``count`` points of the 2D Halton sequence (bases 2, 3), skipping ``seed`` points."""
    ri = mi.RadicalInverse()
    i = dr.arange(mi.UInt64, count) + seed + 1
    return ri.eval(0, i), ri.eval(1, i)


def _side(count: int, name: str) -> int:
    side = math.isqrt(count)
    if side * side != count:
        raise ParameterError(
            f"the {name!r} photon sampler needs a square photon count (e.g. {side * side} or "
            f"{(side + 1) ** 2}), got {count}"
        )
    return side


def grid(count: int) -> tuple[mi.Float, mi.Float]:
    """Cell centres of a √count × √count grid, row-first order."""
    side = _side(count, "grid")
    i = dr.arange(mi.UInt32, count)
    return (mi.Float(i % side) + 0.5) / side, (mi.Float(i // side) + 0.5) / side


def jittered(count: int, seed: int = 0, amount: float = 1.0) -> tuple[mi.Float, mi.Float]:
    """A √count × √count grid, each point jittered uniformly within ±amount/2 of its cell."""
    side = _side(count, "jittered")
    i = dr.arange(mi.UInt32, count)
    rng = mi.PCG32(count, mi.UInt64(seed), dr.arange(mi.UInt64, count))
    ju, jw = rng.next_float32() - 0.5, rng.next_float32() - 0.5
    u = (mi.Float(i % side) + 0.5 + amount * ju) / side
    w = (mi.Float(i // side) + 0.5 + amount * jw) / side
    return u, w


def uniform_random(count: int, seed: int = 0) -> tuple[mi.Float, mi.Float]:
    """Independent uniform points from a seeded PCG32 stream per point."""
    rng = mi.PCG32(count, mi.UInt64(seed), dr.arange(mi.UInt64, count))
    return rng.next_float32(), rng.next_float32()


def points(name: str, count: int, seed: int = 0) -> tuple[mi.Float, mi.Float]:
    """Dispatch by sampler name (one of :data:`SAMPLERS`)."""
    if count < 1:
        raise ParameterError(f"photon count must be at least 1, got {count}")
    if name == "hammersley":
        return hammersley(count)
    if name == "halton":
        return halton(count, seed)
    if name == "grid":
        return grid(count)
    if name == "jittered":
        return jittered(count, seed)
    if name == "random":
        return uniform_random(count, seed)
    raise ParameterError(f"unknown photon sampler {name!r}; choose one of {', '.join(SAMPLERS)}")
