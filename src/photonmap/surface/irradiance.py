"""Irradiance precomputed at photon positions (Christensen 1999, "Faster photon map global
illumination"; Jensen 2001 §7): the final gather's secondary lookups without a k-NN gather each.

At every ``every``-th photon of the global map the irradiance ``E = Σ ΔΦ_p / (π r²)`` of its k
nearest photons is stored once per photon map. A final-gather ray that hits a non-specular point y
then looks up the single nearest precomputed point facing the same way within one cell edge of
the points' hash grid (about 8 points a cell; on the Cornell box all but 0.01 % of the lookups
find one, the others return zero) and returns the diffuse radiance ``L(y → x) = ρ(y)/π · E``
(ρ: the diffuse reflectance of y's BSDF; glossy reflection at y is approximated by its diffuse
part, as in Christensen's method). This replaces the dissertation's naive per-ray k-NN gather,
which costs minutes per frame on two cores (DESIGN.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.hashgrid import HashGrid
from ..core.knn import NO_PHOTON
from ..core.order import morton3_order
from .gather import irradiance_estimate
from .photon_map import PhotonMap


@dataclass
class PrecomputedIrradiance:
    position: mi.Point3f
    normal: mi.Vector3f
    irradiance: mi.Color3f
    grid: HashGrid

    @property
    def size(self) -> int:
        return dr.width(self.position.x)


def precompute_irradiance(
    pmap: PhotonMap, every: int, k: int, max_radius: float
) -> PrecomputedIrradiance:
    """Irradiance at every ``every``-th photon of ``pmap`` (Christensen 1999)."""
    if pmap.size == 0:
        empty = dr.zeros(mi.Point3f, 0)
        return PrecomputedIrradiance(empty, mi.Vector3f(empty), mi.Color3f(empty), None)
    idx = dr.arange(mi.UInt32, 0, pmap.size, every)
    # in Morton order: neighbouring queries read neighbouring photons
    idx = dr.gather(
        mi.UInt32, idx, morton3_order(dr.gather(mi.Point3f, pmap.photons.position, idx))
    )
    position = dr.gather(mi.Point3f, pmap.photons.position, idx)
    normal = dr.gather(mi.Vector3f, pmap.photons.normal, idx)
    dr.eval(position, normal)
    E = irradiance_estimate(pmap, position, normal, k, max_radius)
    dr.eval(E)
    return PrecomputedIrradiance(position, normal, E, HashGrid(position))


def lookup_radiance(
    points: PrecomputedIrradiance,
    si: mi.SurfaceInteraction3f,
    bsdf: mi.BSDFPtr,
    active: mi.Bool,
) -> mi.Spectrum:
    """Diffuse radiance ``ρ(y)/π · E`` at ``si`` from the nearest precomputed point facing the
    same way within one lookup-grid cell (zero where there is none). Lazy: it fuses into the
    final-gather kernel."""
    if points.size == 0:
        return dr.zeros(mi.Spectrum, dr.width(active))
    index, _ = points.grid.nearest(
        si.p, points.grid.cell_size, si.sh_frame.n, points.normal, active=active
    )
    found = active & (index != NO_PHOTON)
    E = dr.gather(mi.Color3f, points.irradiance, index, found)
    rho = bsdf.eval_diffuse_reflectance(si, found)
    return dr.select(found, rho * E / math.pi, 0.0)
