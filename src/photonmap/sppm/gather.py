"""SPPM gather and update (Hachisuka & Jensen 2009 §4, Eqs 6–8; Knaus & Zwicker 2011).

**Gather.** The iteration's photons go into a hash grid (:class:`photonmap.core.hashgrid.HashGrid`)
whose cell edge is the largest current radius, so every photon within ``R_j`` of visible point
``x_j`` lies in the 3×3×3 cells around ``x_j``'s cell. One fused scan per visible point visits
those cells (:meth:`~photonmap.core.hashgrid.HashGrid.sum_within`; the photons in grid order, their
powers, directions and depths permuted alike) and sums

    φ_j = Σ_{‖x_j − y_p‖ < R_j} β_j · f(x_j, ω_o, ω_p) · Φ_p ,   M_j = #photons,

over the photons whose path fits ``max_depth`` with the eye path's (Mitsuba's path length), with
``f`` the BSDF without its cosine (Mitsuba's ``eval`` divided by ``|cos θ_p|``): one gather
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

from ..core.camera import pixel_means
from ..core.hashgrid import HashGrid
from ..core.settings import UNBOUNDED, PathSettings
from .photons import Photons
from .visible import VisiblePoints


@dataclass
class Gathered:
    """Per pixel: the flux sum φ_j (RGB, β included) and the photon count M_j, each the mean
    over the pixel's visible points of the iteration."""

    flux: mi.Color3f
    count: mi.Float


@dataclass
class PhotonGrid:
    """An iteration's photons in a hash grid whose cell edge is the largest gather radius, their
    power, direction and depth in the grid's storage order, for fused scans
    (:meth:`~photonmap.core.hashgrid.HashGrid.sum_within`)."""

    grid: HashGrid
    power: mi.Color3f
    direction: mi.Vector3f
    depth: mi.UInt32

    @classmethod
    def build(cls, photons: Photons, cell_size: float) -> PhotonGrid:
        grid = HashGrid(photons.position, cell_size=max(cell_size, 1e-6))
        return cls(
            grid,
            dr.gather(mi.Color3f, photons.power, grid.order),
            dr.gather(mi.Vector3f, photons.direction, grid.order),
            dr.gather(mi.UInt32, photons.depth, grid.order),
        )

    def reflected(self, si, bsdf, j, near, depth_left) -> tuple[mi.Color3f, mi.Bool]:
        """Stored photon ``j``'s ``f(x, ω_o, ω_p) Φ_p`` at ``si`` (the BSDF without its cosine:
        Mitsuba's ``eval`` over ``|cos θ_p|``) where it lies ``near`` and its depth is at most
        ``depth_left``, and whether it counts."""
        ok = near & (dr.gather(mi.UInt32, self.depth, j, near) <= depth_left)
        wo = si.to_local(-dr.gather(mi.Vector3f, self.direction, j, ok))
        f = bsdf.eval(mi.BSDFContext(), si, wo, ok) / dr.maximum(
            dr.abs(mi.Frame3f.cos_theta(wo)), 1e-4
        )
        return dr.select(ok, f * dr.gather(mi.Color3f, self.power, j, ok), 0.0), ok

    def radiance(self, si, radius: float, depth_left, active) -> mi.Spectrum:
        """``Σ f Φ_p / (π r²)`` over the photons within ``radius`` (at most the cell edge) of
        ``si`` — the reflected radiance towards ``si.wi``; lazy, it fuses into the caller's
        kernel (an eye-path loop)."""
        bsdf = si.bsdf()

        def share(j, near):
            return self.reflected(si, bsdf, j, near, depth_left)[0]

        zero = dr.zeros(mi.Spectrum, dr.width(si.p))
        total = self.grid.sum_within(si.p, dr.opaque(mi.Float, radius**2), share, zero, active)
        return total * dr.opaque(mi.Float, 1.0 / (math.pi * radius**2))


def gather(
    points: VisiblePoints, radius: mi.Float, photons: Photons, settings: PathSettings
) -> Gathered:
    """φ_j and M_j of every pixel within its ``radius`` (per pixel, or one value): the mean over
    its visible points of the sums at each; a photon counts where its path and the eye path
    together fit Mitsuba's ``max_depth`` (``depth_p + depth_j ≤ max_depth``)."""
    lanes = dr.width(points.found)
    pixels = lanes // points.spp
    if isinstance(radius, float):
        radius = dr.opaque(mi.Float, radius, lanes)
    else:
        radius = dr.gather(mi.Float, mi.Float(radius), dr.arange(mi.UInt32, lanes) // points.spp)
    if photons.count == 0:
        return Gathered(dr.zeros(mi.Color3f, pixels), dr.zeros(mi.Float, pixels))
    largest = dr.max(dr.select(points.found, radius, 0.0), axis=None)[0]
    stored = PhotonGrid.build(photons, largest)
    max_depth = 2**31 - 1 if settings.max_depth == UNBOUNDED else settings.max_depth
    depth_left = dr.opaque(mi.UInt32, max_depth) - dr.minimum(points.depth, max_depth)
    si, bsdf = points.si, points.si.bsdf()

    def flux(j, near):
        value, ok = stored.reflected(si, bsdf, j, near, depth_left)
        return mi.Vector4f(*value, dr.select(ok, 1.0, 0.0))

    zero = dr.zeros(mi.Vector4f, lanes)
    total = stored.grid.sum_within(si.p, dr.square(radius), flux, zero, points.found)
    flux_sum = mi.Color3f(total.x, total.y, total.z) * points.beta
    dr.eval(flux_sum, total.w)
    per_pixel = pixel_means(mi.Spectrum(flux_sum), points.spp)
    count = dr.block_reduce(dr.ReduceOp.Add, mi.Float(total.w), points.spp) / points.spp
    dr.eval(per_pixel, count)
    return Gathered(mi.Color3f(per_pixel), count)


MAX_FIRST_SHRINK = 8.0  # the first iteration shrinks a radius by at most this factor


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

    def updated(
        self, points: VisiblePoints, got: Gathered, alpha: float, target: float | None = None
    ) -> PixelState:
        """The state after one iteration (the progressive update above); pixels without a visible
        point or without photons keep N, R and τ.

        ``target`` (the first iteration only): a pixel that found ``M`` photons may shrink its
        radius further, to the disk that would hold about ``target`` of them, ``R·sqrt(target/M)``
        (at most by :data:`MAX_FIRST_SHRINK`) — PPM's photon-density start (Hachisuka et al.
        2008 set the first radius from the photons). The update keeps the law's form: with
        ``s = R_new/R_old`` ≤ the SPPM value, ``N_new = (N + M)·s²`` and ``τ_new = (τ + φ)·s²``
        (the photons and flux inside the smaller disk, for a locally uniform density)."""
        m = got.count
        total = self.photons + m
        shrink2 = (self.photons + alpha * m) / dr.maximum(total, 1e-30)
        if target is not None:
            dense = dr.maximum(target / dr.maximum(m, 1e-30), MAX_FIRST_SHRINK**-2)
            shrink2 = dr.minimum(shrink2, dense)
        shrink2 = dr.select(m > 0, shrink2, 1.0)
        radius = self.radius * dr.sqrt(shrink2)
        n_new = total * shrink2
        tau = (self.tau + got.flux) * shrink2
        direct = self.direct + mi.Color3f(points.direct)
        dr.eval(radius, n_new, tau, direct)
        return PixelState(radius, n_new, tau, direct, self.iterations + 1)

    def image(self) -> mi.Color3f:
        """``L = L_d / n + τ / (n π R²)`` per pixel."""
        n = dr.opaque(mi.Float, max(self.iterations, 1))  # one kernel whatever the count
        return (self.direct + self.tau / (math.pi * dr.square(self.radius))) / n


def iteration_image(points: VisiblePoints, got: Gathered, radius: float) -> mi.Color3f:
    """One memoryless iteration's image ``L_d,i + φ_i / (π r_i²)`` (Knaus & Zwicker 2011)."""
    indirect = got.flux * dr.opaque(mi.Float, 1 / (math.pi * radius**2))
    return mi.Color3f(points.direct) + indirect
