"""Importance sampling of final-gather directions from tabular pdfs (Steinhurst 2007 Ch. 6:
Jensen's photon-map pdf, Algs 6.1–6.2, and Combined Importance Sampling, Alg 6.3, Eqs 6.10–6.11).

Every table lives on the **cosine-warped unit square** of the diffuse BRDF's warp
``T(u, v) = (θ = arccos √u, φ = 2πv)`` (Eq 6.8), cut into ``C_J = 4 × 8`` cells (4 in u, 8 in v;
cell ``iu·8 + iv``). Uniform points of the square map to the cosine-weighted hemisphere, so each
cell covers the projected solid angle π/C_J and a cell of probability ``P[c]`` has the
solid-angle density ``p(ω) = C_J · P[c] · cos θ / π`` (derived from Eq 6.8's warp).

- ``jensen`` (Alg 6.1): the k nearest photons of the global map at x (the gather of
  :mod:`photonmap.core.knn` with its normal test, so they arrive from above the tangent plane) add
  their energy (RGB mean of the flux) to the cell of their incoming direction; empty cells receive
  ``0.05 · total / C_J``; normalised. Only photons of the light the final gather integrates count —
  those that arrived after a diffuse bounce (Steinhurst's "indirect" map): a photon straight from a
  light (or through mirrors and glass) points where the final gather finds nothing, since direct
  light and caustics at x are computed separately. Measured on the glossy-floor box before this
  filter: Jensen needed 8× the rays of cosine sampling on the diffuse walls. - ``cis`` (Alg 6.3):
  the average, cell by cell, of Jensen's table and a BRDF table — the BRDF
  ``f(x, ω_c, ω_o)`` at each cell's centre direction ω_c, with the same donation to zero cells —
  a one-strategy balance-heuristic mixture with ``N_B/N = N_P/N = ½`` (Eq 6.10).

Sampling (Alg 6.2): ``ζ₁`` picks the cell by a binary search of the query's cdf, and its
remainder ``(ζ₁ − cdf[c−1]) / P[c]`` (uniform in [0, 1) given the cell) with ``ζ₂`` place the
direction inside the cell — Alg 6.2's ``ζ₂, ζ₃`` — so a 2D stratified point set stays
stratified. The estimator of Eq 6.11 divides by the single pdf lookup; every cell is positive
(donations, or the uniform table where no photon was found), so it is unbiased for any BRDF.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from ..core.arrays import channel_mean
from .photon_map import PhotonMap

CELLS_U, CELLS_V = 4, 8  # Jensen's 4 × 8 table (Steinhurst 2007 Table 7.1, C_J)
CELLS = CELLS_U * CELLS_V
DONATION = 0.05  # empty cells receive DONATION · total / C_J (Algs 6.1, 6.3)
TABLE_SAMPLING = ("jensen", "cis")


def cell_of(local: mi.Vector3f) -> mi.UInt32:
    """Cell of a local direction (z along the normal): ``u = cos²θ``, ``v = φ / 2π`` (T⁻¹)."""
    u = dr.clip(dr.square(local.z), 0.0, 1.0)
    v = dr.atan2(local.y, local.x) * (0.5 / math.pi)
    v = v - dr.floor(v)
    iu = dr.minimum(mi.UInt32(u * CELLS_U), CELLS_U - 1)
    iv = dr.minimum(mi.UInt32(v * CELLS_V), CELLS_V - 1)
    return iu * CELLS_V + iv


def cell_direction(cell: mi.UInt32, s: mi.Float, t: mi.Float) -> mi.Vector3f:
    """``T(u, v)`` at the point ``(s, t) ∈ [0, 1)²`` of ``cell`` (local frame, z = normal)."""
    u = (mi.Float(cell // CELLS_V) + s) / CELLS_U
    v = (mi.Float(cell % CELLS_V) + t) / CELLS_V
    cos_theta = dr.sqrt(u)
    sin_theta = dr.safe_sqrt(1.0 - u)
    phi = 2.0 * math.pi * v
    return mi.Vector3f(sin_theta * dr.cos(phi), sin_theta * dr.sin(phi), cos_theta)


def photon_table(
    pmap: PhotonMap, si: mi.SurfaceInteraction3f, active: mi.Bool, k: int, max_radius: float
) -> mi.Float:
    """Alg 6.1's energy table (``Q · C_J`` floats, query ``q`` at ``q·C_J``): the energy of the
    ``k`` nearest photons at each query binned by incoming direction."""
    count = dr.width(si.p)
    table = dr.zeros(mi.Float, count * CELLS)
    if pmap.size == 0:
        return table
    nb = pmap.knn(si.p, si.sh_frame.n, k, max_radius)
    lane = dr.arange(mi.UInt32, count * k)
    query, slot = lane // k, lane % k
    ok = dr.gather(mi.Bool, active, query) & (slot < dr.gather(mi.UInt32, nb.count, query))
    index = dr.gather(mi.UInt32, nb.index, lane, ok)
    frame = dr.gather(mi.Frame3f, si.sh_frame, query, ok)
    local = frame.to_local(-dr.gather(mi.Vector3f, pmap.photons.direction, index, ok))
    # only the light the final gather integrates: photons after a diffuse bounce, neither
    # straight from a light nor through mirrors and glass (direct light and caustics at x are
    # computed separately; the final gather finds nothing in those directions)
    depth = dr.gather(mi.UInt32, pmap.photons.depth, index, ok)
    ok &= (local.z > 0) & (depth > 1) & ~dr.gather(mi.Bool, pmap.photons.caustic, index, ok)
    energy = channel_mean(dr.gather(mi.Color3f, pmap.photons.power, index, ok))
    dr.scatter_reduce(dr.ReduceOp.Add, table, energy, query * CELLS + cell_of(local), ok)
    dr.eval(table)
    return table


def brdf_table(si: mi.SurfaceInteraction3f, active: mi.Bool) -> mi.Float:
    """Alg 6.3's evaluated-BRDF table: ``f(x, ω_c, ω_o)`` (RGB mean, no cosine) at the centre
    direction ω_c of every cell of every query."""
    count = dr.width(si.p)
    lane = dr.arange(mi.UInt32, count * CELLS)
    query = lane // CELLS
    ok = dr.gather(mi.Bool, active, query)
    x = dr.gather(mi.SurfaceInteraction3f, si, query, ok)
    wo = cell_direction(lane % CELLS, dr.full(mi.Float, 0.5, count * CELLS), 0.5)
    ctx = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.Smooth)
    f = x.bsdf().eval(ctx, x, wo, ok) / wo.z  # Mitsuba's eval includes the cosine
    table = dr.select(ok, dr.maximum(channel_mean(f), 0.0), 0.0)
    dr.eval(table)
    return table


@dr.syntax
def normalised(table: mi.Float) -> mi.Float:
    """Algs 6.1/6.3: every non-positive cell ← ``DONATION · total / C_J`` (total before the
    donations), then divided by the new total; a table with no energy becomes uniform."""
    count = dr.width(table) // CELLS
    base = dr.arange(mi.UInt32, count) * CELLS
    total = dr.zeros(mi.Float, count)
    empty = dr.zeros(mi.Float, count)
    c = dr.zeros(mi.UInt32, count)
    while c < CELLS:
        value = dr.gather(mi.Float, table, base + c)
        total += dr.maximum(value, 0.0)
        empty += dr.select(value > 0, 0.0, 1.0)
        c += 1
    donation = dr.select(total > 0, DONATION * total / CELLS, 1.0)
    lane = dr.arange(mi.UInt32, count * CELLS)
    query = lane // CELLS
    value = dr.select(table > 0, table, dr.gather(mi.Float, donation, query))
    new_total = dr.gather(mi.Float, dr.select(total > 0, total + empty * donation, CELLS), query)
    pdf = value / new_total
    dr.eval(pdf)
    return pdf


@dr.syntax
def cdf_of(pdf: mi.Float) -> mi.Float:
    """Inclusive per-query prefix sums of the cell probabilities (row-major, Alg 6.1's cdf
    without its leading 0: ``cdf[c] = P[0] + … + P[c]``)."""
    count = dr.width(pdf) // CELLS
    base = dr.arange(mi.UInt32, count) * CELLS
    cdf = dr.zeros(mi.Float, count * CELLS)
    running = dr.zeros(mi.Float, count)
    c = dr.zeros(mi.UInt32, count)
    while c < CELLS:
        running += dr.gather(mi.Float, pdf, base + c)
        dr.scatter(cdf, running, base + c)
        c += 1
    return cdf


def sampling_table(
    method: str,
    pmap: PhotonMap,
    si: mi.SurfaceInteraction3f,
    active: mi.Bool,
    k: int,
    max_radius: float,
) -> mi.Float:
    """The per-query cdf (``Q · C_J``) of ``method``: ``"jensen"`` (Alg 6.1) or ``"cis"``
    (Alg 6.3: ``(pdf_Li + pdf_BRDF) / 2``)."""
    pdf = normalised(photon_table(pmap, si, active, k, max_radius))
    if method == "cis":
        pdf = 0.5 * (pdf + normalised(brdf_table(si, active)))
    cdf = cdf_of(pdf)
    dr.eval(cdf)
    return cdf


def sample_cell(cdf: mi.Float, query: mi.UInt32, zeta: mi.Float):
    """Alg 6.2's cell choice for one lane per sample: the first cell of ``query`` whose cdf
    exceeds ``ζ · cdf[C_J − 1]`` (a binary search), the remainder ``s ∈ [0, 1)`` of ``ζ`` within
    that cell and the cell's probability: ``(cell, s, P[cell])``."""
    base = query * CELLS
    total = dr.gather(mi.Float, cdf, base + CELLS - 1)
    zeta = zeta * total
    cell = dr.zeros(mi.UInt32, dr.width(query))
    step = CELLS // 2
    while step >= 1:  # a fixed unrolled binary search (5 steps for 32 cells)
        probe = cell + step - 1
        cell = dr.select(dr.gather(mi.Float, cdf, base + probe) <= zeta, cell + step, cell)
        step //= 2
    cell = dr.minimum(cell, CELLS - 1)
    high = dr.gather(mi.Float, cdf, base + cell)
    low = dr.select(cell > 0, dr.gather(mi.Float, cdf, base + dr.maximum(cell, 1) - 1), 0.0)
    s = dr.clip((zeta - low) / dr.maximum(high - low, 1e-30), 0.0, 0.99999994)
    return cell, s, (high - low) / total


def sample_table(cdf: mi.Float, query: mi.UInt32, sample: mi.Point2f):
    """Alg 6.2 for the rays of ``query`` (one lane per ray): ``(local direction, solid-angle
    pdf C_J · P[c] · cos θ / π)``."""
    cell, s, p_cell = sample_cell(cdf, query, sample.x)
    wo = cell_direction(cell, s, sample.y)
    return wo, CELLS * p_cell * wo.z / math.pi
