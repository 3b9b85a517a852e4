"""S7 — deposition of a marched photon segment into the voxel radiance grid, in 64-bit fixed
point (Sun et al. 2008 §4.4; Pfeuti 2009 §3.1.5 Fig 3.14). Fixed point makes the sums exact and
independent of thread scheduling, where Pfeuti's compare-and-swap drops deposits.

Every segment deposits into the voxels that contain its intersections with the major-axis
voxel-centre planes in the half-open range ``[s_a, e_a)`` (tested on exact crossings); see
:func:`deposit_segment`. Each deposit writes two packets of four 64-bit channels per voxel, which
a *tally* fills: :func:`radiance_tally` (C rgb, D xyz, two spare channels) and
:func:`weight_tally` (the spare channels count photons and sum their weights, Pfeuti §3.2.3).
Used by the marcher (``march.py``) and the pilot marcher (``pilot.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.grid import flat_index, grid_dims

FIXED_POINT_BITS = 32
WEIGHT_BITS = 20  # fixed-point bits of the photon weights 1/p summed by weight_tally
CHANNELS = 8  # accumulator stride per voxel: C rgb, D xyz, 2 spare (one 64-byte line per voxel)

Int64 = dr.int64_array_t(mi.Float)


def reduce_mode(expand: bool = True) -> dr.ReduceMode:
    """Per-thread copies of the accumulator (``Expand``) were 3–5× faster than atomics here, but
    every launch makes and sums the copies again (≈ 0.1 s and, measured at 160³, 190 B per voxel
    more peak memory per further launch): the scattered orders of multiple scattering
    (``expand`` False) use atomics (``Local``), into an array of their own. Dr.Jit 1.5's debug
    mode misreports (and drops) ``Expand`` packet scatters as out of range, so debug runs use
    ``Local``."""
    return dr.ReduceMode.Local if dr.flag(dr.JitFlag.Debug) or not expand else dr.ReduceMode.Expand


Float64 = dr.float64_array_t(mi.Float)
Vector4i64 = dr.int64_array_t(mi.Vector4f)
Vector4d = dr.float64_array_t(mi.Vector4f)


def radiance_tally(q: list, zero: Int64) -> tuple:
    """The packets of one deposit from its fixed-point energy ``q[0:3]`` and weighted direction
    ``q[3:6]``: (C rgb, D x), (D y, D z, 0, 0) (S8's grids)."""
    return Vector4i64(q[0], q[1], q[2], q[3]), Vector4i64(q[4], q[5], zero, zero)


def weight_tally(weight: mi.Float):
    """:func:`radiance_tally` plus, in the spare channels, one photon and the photon's weight
    ``1/p`` in fixed point (Pfeuti §3.2.3: ``cnt[v] += 1``, ``wsum[v] += w``)."""
    w = Int64(dr.round(weight * 2.0**WEIGHT_BITS))

    def tally(q, zero):
        return Vector4i64(q[0], q[1], q[2], q[3]), Vector4i64(q[4], q[5], zero + 1, w)

    tally.weights = weight  # per photon: multiple scattering re-gathers them for each order
    return tally


@dataclass
class Deposits:
    """Where and how a march deposits (S7): into the fixed-point accumulator ``acc``, each
    deposit's two packets made by ``tally``, into the grid ``2^shift`` times coarser
    (:func:`coarse_size`), with ``expand`` choosing the reduction (:func:`reduce_mode`)."""

    acc: Int64
    tally: Callable = radiance_tally
    shift: int = 0
    expand: bool = True


@dr.syntax
def deposit_segment(
    into: Deposits, n, segment, L_s, optical_depth, directions, constants, active=True
):  # fmt: skip
    """S7: deposit the ``segment = (s, e)`` (voxel units), its direction going from
    ``directions = (dir_s, dir_e)``, by :class:`Deposits` ``into``; ``constants = (scale,
    paper)``: the fixed-point scale and the papers' literal deposits.

    The voxels touched are those holding the segment's intersections with the major-axis centre
    planes ``c = m + ½`` in the half-open range ``[s_a, e_a)`` (Pfeuti's Fig 3.14 rasteriser).
    At parameter ``u`` the energy is ``L_s · exp(−optical_depth · u)`` (geometric interpolation,
    exact for a constant κ; linear interpolation errs by 21 % at κL = 1.28) or, with ``paper``, the
    papers' linear ``lerp(L_s, L_e, u)``; the direction is linear. Each deposit is weighted by
    ``‖δ‖ = 1/|v̂_a|`` (length weighting: the papers' one deposit per voxel biases diagonal
    directions by up to √3), or 1 with ``paper``. ``tally`` makes
    the two packets written per voxel; with ``shift > 0`` voxel ``v`` deposits into cell
    ``v >> shift`` of a grid ``2^shift`` times coarser (:func:`coarse_size`; the rasterisation
    stays at full resolution). ``n``: the grid's extent (``(n_x, n_y, n_z)``, or one ``n``).
    """
    acc, tally, shift, expand = into.acc, into.tally, into.shift, into.expand
    (s, e), (dir_s, dir_e), (scale, paper) = segment, directions, constants
    count = dr.width(s)
    L_e = L_s * dr.exp(-optical_depth)
    step, p0, u0, total, len_a = _centre_planes(s, e, active)
    # energy at u0 and its change per deposit, in fixed-point units, length weight included
    weight = scale * (1.0 if paper else dr.norm(step))
    du = 1.0 / len_a
    if paper:
        energy = weight * dr.lerp(L_s, L_e, u0)
        growth = weight * (L_e - L_s) * du
    else:
        energy = weight * L_s * dr.exp(-optical_depth * u0)
        growth = dr.exp(-optical_depth * du)
    direction = dr.lerp(dir_s, dir_e, u0)
    turn = (dir_e - dir_s) * du
    zero = dr.zeros(Int64, count)
    m = coarse_size(n, shift)
    nx, ny, nz = grid_dims(n)
    far = mi.Point3i(nx, ny, nz)

    j = dr.zeros(mi.Int32, count)
    while j < total:
        cell = mi.Point3i(dr.floor(p0 + mi.Float(j) * step))
        inside = dr.all((cell >= 0) & (cell < far))
        flux_dir = (energy.x + energy.y + energy.z) * direction
        q = [Int64(dr.round(c)) for c in (*energy, *flux_dir)]
        cell >>= shift
        packet = mi.UInt32(flat_index(cell.x, cell.y, cell.z, m)) * 2
        first, second = tally(q, zero)
        mode = reduce_mode(expand)
        dr.scatter_reduce(dr.ReduceOp.Add, acc, first, packet, active=inside, mode=mode)
        dr.scatter_reduce(dr.ReduceOp.Add, acc, second, packet + 1, active=inside, mode=mode)
        if paper:
            energy += growth
        else:
            energy *= growth
        direction += turn
        j += 1


def _centre_planes(s: mi.Point3f, e: mi.Point3f, active):
    """The crossings of the segment ``s → e`` with the major axis's voxel-centre planes in the
    half-open range ``[s_a, e_a)``: ``(δ, p₀, u₀, count, |e_a − s_a|)`` — the step ``δ`` from one
    crossing to the next (one voxel along the major axis), the first crossing ``p₀`` at segment
    parameter ``u₀``, how many there are (0 where not ``active`` or the segment has no length
    along the axis) and the segment's length along the axis."""
    delta = e - s
    ad = dr.abs(delta)
    along_x = (ad.x >= ad.y) & (ad.x >= ad.z)
    along_y = ~along_x & (ad.y >= ad.z)
    da = dr.select(along_x, delta.x, dr.select(along_y, delta.y, delta.z))
    sa = dr.select(along_x, s.x, dr.select(along_y, s.y, s.z))
    ea = dr.select(along_x, e.x, dr.select(along_y, e.y, e.z))
    len_a = dr.maximum(dr.abs(da), 1e-20)
    step = delta / len_a  # δ: one voxel along the major axis
    sgn = dr.sign(da)
    t_s = (dr.floor(sa) + 0.5 - sa) * sgn  # signed move of the start to its voxel's centre plane
    t_e = (dr.floor(ea) + 0.5 - ea) * sgn
    skip_first = t_s < 0  # the start moved backward: its voxel is not rasterised
    p0 = s + dr.select(skip_first, t_s + 1.0, t_s) * step
    u0 = dr.select(skip_first, t_s + 1.0, t_s) / len_a
    total = mi.Int32(dr.abs(dr.floor(ea) - dr.floor(sa)))
    total += dr.select(t_e < 0, 1, 0) - dr.select(skip_first, 1, 0)
    total = dr.select(active & (dr.abs(da) > 0), total, 0)
    return step, p0, u0, total, len_a


def coarse_size(n, shift: int) -> tuple[int, int, int]:
    """The extent ``(m_x, m_y, m_z)`` of the deposit grid ``2^shift`` times coarser than the grid
    of extent ``n`` (:func:`~.grid.grid_dims`): ``m = ⌈n / 2^shift⌉`` per axis."""
    return tuple((int(c) + (1 << shift) - 1) >> shift for c in grid_dims(n))
