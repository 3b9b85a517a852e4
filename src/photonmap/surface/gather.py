"""Photon gathers: radiance and irradiance estimates from the k nearest photons (Steinhurst 2007
§2.6.2 Eq 2.6, after Jensen)::

    L_r(y, ω_o) = Σ_{p=1..k} f_r(y, ω_p, ω_o) · ΔΦ_p / (π r²)          E(y) = Σ ΔΦ_p / (π r²)

with ``r`` the distance of the farthest of the k photons (a box kernel: "the area of the circle
defined by the radius required to find all k photons"). Queries are explicit batches (arrays of
query points), so a later stage may reorder them.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from .photon_map import PhotonMap


def radiance_estimate(
    pmap: PhotonMap,
    si: mi.SurfaceInteraction3f,
    bsdf: mi.BSDFPtr,
    k: int,
    max_radius: float,
    active: mi.Bool,
) -> mi.Spectrum:
    """Reflected radiance at ``si`` towards ``si.wi`` from the ``k`` nearest photons (Eq 2.6)."""
    if pmap.size == 0:
        return dr.zeros(mi.Spectrum, dr.width(si.p))
    neighbours = pmap.knn(si.p, si.sh_frame.n, k, max_radius)
    return _reflected(pmap, si, bsdf, k, neighbours, active)


@dr.syntax
def _reflected(pmap, si, bsdf, k, nb, active):
    """``Σ f_r(ω_p, ω_o) ΔΦ_p / (π r²)`` over the neighbours ``nb`` of each query."""
    count = dr.width(nb.count)
    active = active & dr.full(mi.Bool, True, count)  # a scalar mask means every query
    ctx = mi.BSDFContext()
    base = dr.arange(mi.UInt32, count) * k
    L = dr.zeros(mi.Spectrum, count)
    j = dr.zeros(mi.UInt32, count)
    while active & (j < nb.count):
        idx = dr.gather(mi.UInt32, nb.index, base + j)
        power = dr.gather(mi.Color3f, pmap.photons.power, idx, active)
        wo = si.to_local(-dr.gather(mi.Vector3f, pmap.photons.direction, idx, active))
        f = bsdf.eval(ctx, si, wo, active) / dr.maximum(dr.abs(mi.Frame3f.cos_theta(wo)), 1e-4)
        L += f * power
        j += 1
    area = math.pi * nb.radius2
    return dr.select(active & (nb.count > 0) & (area > 0), L / dr.maximum(area, 1e-30), 0.0)


@dr.syntax
def irradiance_estimate(
    pmap: PhotonMap, position: mi.Point3f, normal: mi.Vector3f, k: int, max_radius: float
) -> mi.Color3f:
    """Irradiance ``E = Σ ΔΦ_p / (π r²)`` at points with normals (the photons' own positions in
    the Christensen precomputation)."""
    count = dr.width(position.x)
    nb = pmap.knn(position, normal, k, max_radius)
    base = dr.arange(mi.UInt32, count) * k
    E = dr.zeros(mi.Color3f, count)
    j = dr.zeros(mi.UInt32, count)
    while j < nb.count:
        idx = dr.gather(mi.UInt32, nb.index, base + j)
        E += dr.gather(mi.Color3f, pmap.photons.power, idx)
        j += 1
    area = math.pi * nb.radius2
    return dr.select((nb.count > 0) & (area > 0), E / dr.maximum(area, 1e-30), 0.0)
