"""Irradiance precomputed at photon positions (Christensen 1999, "Faster photon map global
illumination"; Jensen 2001 §7): the final gather's secondary lookups without a k-NN gather each.

At every ``every``-th photon of the global map the irradiance ``E = Σ ΔΦ_p / (π r²)`` of its k
nearest photons is stored once per photon map. A final-gather ray that hits a non-specular point y
then looks up the single nearest precomputed point facing the same way and returns the diffuse
radiance ``L(y → x) = ρ(y)/π · E`` (ρ: the diffuse reflectance of y's BSDF; glossy reflection at
y is approximated by its diffuse part, as in Christensen's method). This replaces the dissertation's
naive per-ray k-NN gather, which costs minutes per frame on two cores (DESIGN.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.hashgrid import HashGrid
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
    idx = dr.arange(mi.UInt32, 0, pmap.size, every) if pmap.size else dr.zeros(mi.UInt32, 0)
    position = mi.Point3f(*[dr.gather(mi.Float, c, idx) for c in pmap.photons.position])
    normal = mi.Vector3f(*[dr.gather(mi.Float, c, idx) for c in pmap.photons.normal])
    dr.eval(position, normal)
    if dr.width(idx) == 0:
        return PrecomputedIrradiance(position, normal, dr.zeros(mi.Color3f, 0), None)
    E = irradiance_estimate(pmap, position, normal, k, max_radius)
    dr.eval(E)
    return PrecomputedIrradiance(position, normal, E, HashGrid(position))


def lookup_radiance(
    points: PrecomputedIrradiance,
    si: mi.SurfaceInteraction3f,
    bsdf: mi.BSDFPtr,
    max_radius: float,
    active: mi.Bool,
) -> mi.Spectrum:
    """Diffuse radiance ``ρ(y)/π · E`` at ``si`` from the nearest precomputed point."""
    count = dr.width(active)
    if points.size == 0:
        return dr.zeros(mi.Spectrum, count)
    nb = points.grid.knn(
        si.p, k=1, max_radius=max_radius, query_normal=si.sh_frame.n, normals=points.normal
    )
    found = active & (nb.count > 0)
    E = mi.Color3f(*[dr.gather(mi.Float, c, nb.index, found) for c in points.irradiance])
    rho = bsdf.eval_diffuse_reflectance(si, found)
    return dr.select(found, rho * E / math.pi, 0.0)
