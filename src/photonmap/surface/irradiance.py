"""Irradiance precomputed at photon positions (Christensen 1999, "Faster photon map global
illumination"; Jensen 2001 §7): the final gather's secondary lookups without a k-NN gather each.

At every ``every``-th photon of the global map the irradiance ``E = Σ ΔΦ_p / (π r²)`` of its k
nearest photons is stored once per photon map. A final-gather ray that hits a non-specular point y
then looks up the single nearest precomputed point facing the same way within one cell edge of
the points' hash grid (about 8 points a cell; on the Cornell box all but 0.01 % of the lookups
find one, the others return zero) and returns the diffuse radiance ``L(y → x) = ρ(y)/π · E``
(ρ: the diffuse reflectance of y's BSDF). That holds for diffuse y only: Christensen's method
would reduce a glossy y to its diffuse part — zero for a rough metal, whose reflection of the
room then goes missing from every final gather that sees it (the lower walls of a box with a
rough aluminium floor were 16 % dark against Mitsuba's ``path``). So hits on a surface with a
glossy lobe take the exact k-NN radiance estimate with y's BSDF instead
(:func:`with_glossy_estimates`; scenes without glossy shapes keep the single fused lookup). This
replaces the dissertation's naive per-ray k-NN gather, which costs minutes per frame on two cores
(DESIGN.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.bsdf import diffuse_albedo
from ..core.hashgrid import HashGrid
from ..core.knn import NO_PHOTON
from ..core.order import morton3_order
from .gather import irradiance_estimate, radiance_estimate
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
    rho = diffuse_albedo(bsdf, si, found)
    return dr.select(found, rho * E / math.pi, 0.0)


def with_glossy_estimates(L, pmap: PhotonMap, si, bsdf, k: int, max_radius: float, active):
    """``L`` with the k-NN radiance estimate (:func:`.gather.radiance_estimate`, y's own BSDF)
    at the hits whose BSDF has a glossy lobe, where ``ρ/π · E`` does not describe the light that
    leaves y towards x."""
    glossy = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Glossy)
    dr.eval(si, L, glossy)  # one tracing kernel for both lookups
    lanes = dr.compress(glossy)
    if dr.width(lanes) == 0:
        return L
    at = dr.gather(type(si), si, lanes)
    estimate = radiance_estimate(pmap, at, at.bsdf(), k, max_radius, True)
    dr.scatter(L, estimate, lanes)
    return L
