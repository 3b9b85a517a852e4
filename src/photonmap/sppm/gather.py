"""SPPM gather and update (Hachisuka & Jensen 2009 §4, Eqs 6–8; Knaus & Zwicker 2011; spec
beyond-seeds §1 steps 2–4, §2).

**Gather.** The iteration's photons go into a hash grid (:class:`photonmap.core.hashgrid.HashGrid`)
whose cell edge is the largest current radius, so every photon within ``R_j`` of visible point
``x_j`` lies in the 3×3×3 cells around ``x_j``'s cell. One Dr.Jit loop per visible point scans
those cells (the photons in grid order, their powers and directions permuted alike) and sums

    φ_j = Σ_{‖x_j − y_p‖ < R_j} β_j · f(x_j, ω_o, ω_p) · Φ_p ,   M_j = #photons,

with ``f`` the BSDF without its cosine (Mitsuba's ``eval`` divided by ``|cos θ_p|``): one gather
per (point, photon) pair, no atomics, so the sums are deterministic.

**Progressive update** (SPPM, α ∈ (0, 1)):
``N ← N + α M``, ``R ← R · sqrt(N_new / (N_old + M))``, ``τ ← (τ + φ) · (R_new / R_old)²``.
The image after ``n`` iterations is ``L = L_d / n + τ / (n π R²)`` (the ``1/M`` of each
iteration is in the photon powers).

**Memoryless** (Knaus & Zwicker 2011): one global radius ``r_i`` per iteration; the iteration's
image is ``L_d,i + φ_i / (π r_i²)``, and the image the mean of the iteration images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.hashgrid import HashGrid
from ..core.knn import read_record, squared_distance
from .photons import Photons
from .visible import VisiblePoints


@dataclass
class Gathered:
    """Per visible point: the flux sum φ_j (RGB, β included) and the photon count M_j."""

    flux: mi.Color3f
    count: mi.Float


def gather(points: VisiblePoints, radius: mi.Float, photons: Photons) -> Gathered:
    """φ_j and M_j of every visible point within its ``radius`` (per point, or one value)."""
    lanes = dr.width(points.found)
    radius = mi.Float(radius) * dr.ones(mi.Float, lanes)
    if photons.count == 0:
        return Gathered(dr.zeros(mi.Color3f, lanes), dr.zeros(mi.Float, lanes))
    largest = dr.max(dr.select(points.found, radius, 0.0), axis=None)[0]
    grid = HashGrid(photons.position, cell_size=max(largest, 1e-6))
    power = dr.gather(mi.Color3f, photons.power, grid.order)
    direction = dr.gather(mi.Vector3f, photons.direction, grid.order)
    flux, count = _scan(grid, points, radius, power, direction)
    dr.eval(flux, count)
    return Gathered(flux, count)


@dr.syntax
def _scan(grid: HashGrid, points: VisiblePoints, radius, power, direction):
    """The 27-cell scan of :func:`gather` (a cell is at least as wide as any radius)."""
    si, active = points.si, points.found
    lanes = dr.width(active)
    bsdf = si.bsdf()
    ctx = mi.BSDFContext()
    radius2 = dr.square(radius)
    c0 = grid._cell(si.p)
    flux = dr.zeros(mi.Color3f, lanes)
    count = dr.zeros(mi.Float, lanes)
    step = dr.zeros(mi.UInt32, lanes)
    while active & (step < 27):
        c = c0 + mi.Point3i(mi.Int32(step % 3), mi.Int32(step // 3 % 3), mi.Int32(step // 9)) - 1
        visit = active & dr.all((c >= 0) & (c < grid._dims))
        number = grid._cell_number(c)
        slot = grid._slot(number)
        j = dr.gather(mi.UInt32, grid.cell_start, slot, visit)
        j_end = dr.gather(mi.UInt32, grid.cell_start, slot + 1, visit)
        while visit & (j < j_end):
            p, _ = read_record(grid.record, j)
            near = squared_distance(p, si.p) < radius2
            if dr.hint(grid.hashed, mode="scalar"):
                near &= grid._cell_number(grid._cell(p)) == number  # slots shared by cells
            wo = si.to_local(-dr.gather(mi.Vector3f, direction, j, near))
            f = bsdf.eval(ctx, si, wo, near) / dr.maximum(dr.abs(mi.Frame3f.cos_theta(wo)), 1e-4)
            flux += dr.select(near, f * dr.gather(mi.Color3f, power, j, near), 0.0)
            count += dr.select(near, 1.0, 0.0)
            j += 1
        step += 1
    return flux * points.beta, count


@dataclass
class PixelState:
    """The per-pixel statistics of progressive SPPM (Hachisuka & Jensen 2009 §4)."""

    radius: mi.Float  # R_j
    photons: mi.Float  # N_j
    tau: mi.Color3f  # τ_j (accumulated flux, radius-corrected)
    direct: mi.Color3f  # Σ over iterations of L_d,j
    iterations: int

    @classmethod
    def start(cls, pixels: int, radius: float) -> PixelState:
        return cls(
            dr.full(mi.Float, radius, pixels),
            dr.zeros(mi.Float, pixels),
            dr.zeros(mi.Color3f, pixels),
            dr.zeros(mi.Color3f, pixels),
            0,
        )

    def updated(self, points: VisiblePoints, got: Gathered, alpha: float) -> PixelState:
        """The state after one iteration (spec beyond-seeds §1 step 3); pixels without a visible
        point or without photons keep N, R and τ."""
        m = dr.select(points.found, got.count, 0.0)
        n_new = self.photons + alpha * m
        shrink = dr.select(m > 0, dr.sqrt(n_new / dr.maximum(self.photons + m, 1e-30)), 1.0)
        radius = self.radius * shrink
        tau = (self.tau + dr.select(points.found, got.flux, 0.0)) * dr.square(shrink)
        direct = self.direct + mi.Color3f(points.direct)
        dr.eval(radius, n_new, tau, direct)
        return PixelState(radius, n_new, tau, direct, self.iterations + 1)

    def image(self) -> mi.Color3f:
        """``L = L_d / n + τ / (n π R²)`` per pixel."""
        n = max(self.iterations, 1)
        return (self.direct + self.tau / (math.pi * dr.square(self.radius))) / n


def iteration_image(points: VisiblePoints, got: Gathered, radius: float) -> mi.Color3f:
    """One memoryless iteration's image ``L_d,i + φ_i / (π r_i²)`` (Knaus & Zwicker 2011)."""
    indirect = dr.select(points.found, got.flux, 0.0) / (math.pi * radius**2)
    return mi.Color3f(points.direct) + indirect


def memoryless_radius(r1: float, alpha: float, i: int) -> float:
    """``r_i = r_1 · i^((α − 1)/2)`` (Knaus & Zwicker 2011; i = 1, 2, …)."""
    return r1 * i ** ((alpha - 1.0) / 2.0)
