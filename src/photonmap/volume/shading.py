"""S9 at an opaque surface: what a camera ray that ends on one adds (ours, for Sun et al. 2008
Fig. 1's caustic on the table and any surface of the user's scene).

The viewing pass (``view.py``) marches the camera ray through the grid to the first opaque surface
(:class:`~.surfaces.Surfaces`) and, with the weight ``colScale·T`` it reached it with, adds the
radiance leaving the surface point ``x`` towards the camera:

    L_o(x, ω_o) = L_e(x, ω_o)                                           (an area light's shape)
                + Σ_lights ∫ f(ω_i, ω_o) L_light(ω_i) T_grid(x, ω_i) V(x, ω_i) cos θ_i dω_i
                + Σ_p f(ω_p, ω_o) Φ_p / (π r²)

- **direct light**, straight from every light of the scene as the volume method holds it
  (``VolumeScene.lights``, so that ``set_light`` edits count): point and spot lights (their
  intensity and falloff), directional light, and area and environment emitters by emitter
  sampling and BSDF sampling combined by the power heuristic (Veach & Guibas 1995), ``samples``
  of each per hit. The shadow rays carry the **grid's** transmittance ``exp(−∫κ)`` (κ trilinear,
  one-voxel midpoint steps; vacuum outside the grid), the extinction the photons and the camera
  rays meet — not the Mitsuba media, which ``set_material``, ``set_volume`` and painting do not
  change — and stop at opaque shapes and refractive objects (whose light arrives as photons);
  only the smooth (diffuse, glossy) lobes are evaluated;
- **the photons on the surface** (Jensen 1996 §3, Steinhurst 2007 Eq 2.6): the ``k`` nearest
  :class:`~.surfaces.SurfacePhotons` within ``max_radius`` that passed the normal test, ``r`` the
  distance of the k-th (or ``max_radius`` where fewer were found), ``f(ω_p, ω_o)`` the smooth
  lobes: the caustics of refractive objects, the light the fog scattered onto the surface, the
  light other surfaces reflected (multiple scattering). Light straight from the lights is never
  among them, so nothing is counted twice.

Why not the radiance grid at the surface for the light the fog scatters onto it: ``C`` is the
fluence through a voxel from all directions, the light the shadow rays already count included,
with one mean direction — an irradiance needs the half arriving from above the surface. Measured
on a lamp in an isotropic fog box on a floor (albedo 0.85, σ_t 0.4): the photons' indirect
irradiance on the floor is 0.245 ``φ_s``, ``φ_s`` the scattered fluence in the bottom voxel layer
(``C`` of multiple minus single scattering: two marches), close to an isotropic field's ``φ/4``;
but that holds only for a near-isotropic field inside the grid, where the photons hold any phase
function, the surfaces outside the grid and the light other surfaces reflect. With
``scattering="single"`` (Sun's model) no photon scatters and that light is missing: the pipeline
says so in a warning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.direct import power_heuristic
from ..core.grid import trilinear_packed
from ..core.sampling import rng as make_rng
from .emit import box_entry, spot_falloff
from .surfaces import SurfacePhotons, Surfaces

SMOOTH = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.Smooth)


@dataclass(eq=False)
class SurfaceShading:
    """What S9 needs at opaque surfaces: the surfaces, the lights (world units), the photons
    recorded on the surfaces, the gather's ``k`` and ``max_radius`` (world units), the light
    ``samples`` per hit for area and environment lights, and the grid's κ (voxel units),
    packed (``ViewGrids.kappa``) on the grid of extent ``dims``."""

    surfaces: Surfaces
    lights: list
    photons: SurfacePhotons | None
    k: int
    max_radius: float
    samples: int
    kappa: mi.Float
    dims: tuple


def shade(
    sh: SurfaceShading, si: mi.SurfaceInteraction3f, seed: int, active, emitted=True
) -> mi.Color3f:
    """Radiance leaving ``si`` towards ``si.wi`` (module docstring), 0 where not ``active``;
    an area light's own emission only where ``emitted`` (``hide_emitters``)."""
    active = mi.Bool(active) & si.is_valid()
    gen = make_rng(dr.width(si.p), seed, 0x5EED)
    L = _emitted(sh, si, active & emitted)
    L += _direct(sh, si, gen, active)
    if sh.photons is not None and sh.photons.count > 0:
        L += photon_radiance(sh.photons, si, sh.k, sh.max_radius, active)
    return dr.select(active, L, 0.0)


def _emitted(sh, si, active) -> mi.Color3f:
    """``L_e`` of the area lights' shapes seen at ``si`` (times the light's intensity factor)."""
    L = dr.zeros(mi.Color3f, dr.width(si.p))
    for light in sh.lights:
        if light.kind == "area":
            on = active & (si.shape == mi.ShapePtr(light.shape))
            L += dr.select(on, light.emitter.eval(si, on) * _rgb(light.intensity), 0.0)
    return L


def _rgb(value) -> mi.Color3f:
    return mi.Color3f(*[dr.opaque(mi.Float, float(c)) for c in np.asarray(value).reshape(3)])


def _world(value) -> mi.Point3f:
    return mi.Point3f(*[dr.opaque(mi.Float, float(c)) for c in np.asarray(value).reshape(3)])


def _direct(sh, si, gen, active) -> mi.Color3f:
    """Light straight from every light, through the grid's κ (module docstring)."""
    bsdf = si.bsdf()
    L = dr.zeros(mi.Color3f, dr.width(si.p))
    for light in sh.lights:
        if light.kind in ("point", "spot"):
            p = _world(light.position)
            to_light = p - si.p
            dist = dr.norm(to_light)
            wi = to_light / dist
            I = _rgb(light.intensity)
            if light.kind == "spot":
                axis = np.asarray(light.direction) / np.linalg.norm(light.direction)
                I *= spot_falloff(dr.dot(-wi, _world(axis)), light.cos_inner, light.cos_outer)
            lit = active & ~sh.surfaces.occluded(si.spawn_ray_to(p), active)
            f = bsdf.eval(SMOOTH, si, si.to_local(wi), lit)
            T = transmittance(sh, si.p, wi, dist, lit)
            L += dr.select(lit, f * I * T / dr.square(dist), 0.0)
        elif light.kind == "directional":
            wi = -dr.normalize(_world(light.direction))
            ray = si.spawn_ray(mi.Vector3f(wi))
            lit = active & ~sh.surfaces.occluded(ray, active)
            f = bsdf.eval(SMOOTH, si, si.to_local(wi), lit)
            T = transmittance(sh, si.p, wi, dr.inf, lit)
            L += dr.select(lit, f * _rgb(light.intensity) * T, 0.0)
        else:
            for _ in range(sh.samples):
                L += _emitter_mis(sh, light, si, bsdf, gen, active) / sh.samples
    return L


def _emitter_mis(sh, light, si, bsdf, gen, active) -> mi.Color3f:
    """One emitter sample and one BSDF sample of an area or environment light, weighted by the
    power heuristic."""
    emitter, scale = light.emitter, _rgb(light.intensity)
    environment = light.kind == "environment"
    # emitter sampling
    ds, weight = emitter.sample_direction(
        si, mi.Point2f(gen.next_float32(), gen.next_float32()), active
    )
    lit = active & (ds.pdf > 0)
    ray = si.spawn_ray(ds.d)
    if not environment:
        ray.maxt = ds.dist * (1.0 - mi.math.ShadowEpsilon)
    lit &= ~sh.surfaces.occluded(ray, lit)
    f, pdf_bsdf = bsdf.eval_pdf(SMOOTH, si, si.to_local(ds.d), lit)
    T = transmittance(sh, si.p, ds.d, dr.inf if environment else ds.dist, lit)
    w = power_heuristic(ds.pdf, pdf_bsdf)
    L = dr.select(lit, w * f * mi.Color3f(weight) * T, 0.0)
    # BSDF sampling
    bs, f_bs = bsdf.sample(
        SMOOTH, si, gen.next_float32(), mi.Point2f(gen.next_float32(), gen.next_float32()), active
    )
    sampled = active & (bs.pdf > 0)
    ray = si.spawn_ray(si.to_world(bs.wo))
    si_e = sh.surfaces.towards_light(ray, sampled)
    if environment:
        hits = sampled & ~si_e.is_valid()
    else:
        hits = sampled & si_e.is_valid() & (si_e.shape == mi.ShapePtr(light.shape))
    L_e = emitter.eval(si_e, hits)
    pdf_e = emitter.pdf_direction(si, mi.DirectionSample3f(sh.surfaces.scene, si_e, si), hits)
    T = transmittance(sh, si.p, ray.d, dr.inf if environment else si_e.t, hits)
    w = power_heuristic(bs.pdf, pdf_e)
    L += dr.select(hits, w * mi.Color3f(f_bs) * L_e * T, 0.0)
    return L * scale


def transmittance(sh, p: mi.Point3f, d: mi.Vector3f, length, active) -> mi.Color3f:
    """``exp(−∫κ)`` of the grid along the world segment ``p → p + length·d`` (unit ``d``),
    one-voxel midpoint steps; 1 outside the grid (the volume method's vacuum)."""
    o = sh.surfaces.voxel(p)
    return _optical(sh.kappa, sh.dims, o, mi.Vector3f(d), sh.surfaces.in_voxels(length), active)


@dr.syntax
def _optical(kappa_grid, dims, o, d, length, active) -> mi.Color3f:
    enters, t, t_far = box_entry(o, d, dims)
    end = dr.minimum(t_far, length)
    tau = dr.zeros(mi.Color3f, dr.width(o))
    going = mi.Bool(active) & enters & (t < end)
    cap = int(math.ceil(math.hypot(*dims))) + 2
    steps = dr.zeros(mi.UInt32, dr.width(o))
    while going:
        dt = dr.minimum(end - t, 1.0)
        kappa = trilinear_packed(kappa_grid, dims, 1, o + (t + 0.5 * dt) * d)[0]
        tau += mi.Color3f(kappa.x, kappa.y, kappa.z) * dt
        t += dt
        steps += 1
        going &= (t < end) & (steps < cap)
    return dr.exp(-tau)


def photon_radiance(
    photons: SurfacePhotons, si: mi.SurfaceInteraction3f, k: int, max_radius: float, active
) -> mi.Color3f:
    """Jensen's radiance estimate ``Σ f(ω_p, ω_o) Φ_p / (π r²)`` at ``si`` from the ``k`` nearest
    surface photons within ``max_radius`` (world units) that passed the normal test (stored on a
    surface facing within 30° of ``si``'s, travelling towards its front): ``r`` the distance of
    the k-th, or ``max_radius`` where fewer were found (the disk that was searched)."""
    normal = si.sh_frame.n
    nb = photons.map.knn(
        si.p, k, max_radius, query_normal=normal, normals=photons.normal,
        directions=photons.direction,
    )  # fmt: skip
    radius2 = dr.select(nb.count < k, dr.opaque(mi.Float, max_radius**2), nb.radius2)
    L = _photon_sum(photons, si, nb, k, active)
    area = math.pi * radius2
    return dr.select(active & (nb.count > 0) & (area > 0), L / dr.maximum(area, 1e-30), 0.0)


def _photon_sum(photons, si, nb, k: int, active) -> mi.Color3f:
    return _photon_loop(photons.power, photons.direction, si, nb.index, nb.count, k, active)


@dr.syntax
def _photon_loop(powers, directions, si, index, found, k: int, active) -> mi.Color3f:
    count = dr.width(found)
    active = mi.Bool(active) & dr.full(mi.Bool, True, count)
    base = dr.arange(mi.UInt32, count) * k
    L = dr.zeros(mi.Color3f, count)
    bsdf = si.bsdf()
    j = dr.zeros(mi.UInt32, count)
    while active & (j < found):
        idx = dr.gather(mi.UInt32, index, base + j)
        power = dr.gather(mi.Color3f, powers, idx, active)
        wi = si.to_local(-dr.gather(mi.Vector3f, directions, idx, active))
        f = bsdf.eval(SMOOTH, si, wi, active) / dr.maximum(dr.abs(mi.Frame3f.cos_theta(wi)), 1e-4)
        L += mi.Color3f(f) * power
        j += 1
    return L
