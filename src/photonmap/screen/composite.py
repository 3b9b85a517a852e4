"""Final compositing and glass seen through eye-ray refraction (Yao 2011 §3.3, §3.5, Ch. 5; spec
seed-004 §2.9, A27, ``glass_eye="raytrace"``).

    L_out = V_s · L_direct + Up(L_ind) + L_e                     (diffuse / glossy pixels)
    L_out = Σ_branches T · (L_direct(hit) + L_e(hit))             (mirror / glass pixels)

L_e is the radiance of an area light seen at the pixel (or at the chain's end: the light in a
mirror or through glass). With ``shadows="sampled"`` V_s · L_direct is the sampled shadowed direct
light of :mod:`.direct`.

Glass and mirror pixels are ray-traced with direct light only at the end of the chain, as the
thesis's environment map holds the scene "with direct light only": the refracted chain is followed
through up to ``levels`` delta interfaces with throughput T = weight·pdf of the transmitted
branch (1 − F; TIR reflects), plus the Fresnel-weighted reflection (F) at the front face, followed
the same way. Both branches are deterministic (no noise); the shading at the diffuse end point uses
the hard shadow of :func:`.direct.shade` (spot and point lights) or the area light's sampled shadow
rays. Mitsuba's dielectric gives F, Snell's law and the radiance scaling by η² across the
interface. The chains pass through ``null``-BSDF shapes.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.bsdf import diffuse_albedo, has_null_shapes, intersect_visible, is_specular
from .direct import EPSILON, shade
from .gbuffer import GBuffer
from .light_gbuffer import Light

LEVELS = 4
REFLECT, TRANSMIT = 0.0, 1.0 - 1e-6  # dielectric sample1: below F reflects, above refracts


def _chain(scene, light, si, throughput, active, first: float, levels: int, eps, null_shapes):
    """Follow delta interactions from ``si`` (first choice ``first``, then transmission) and
    return the throughput-weighted direct light and emission at the first non-delta surface."""
    ctx = mi.BSDFContext(mi.TransportMode.Radiance)
    L = dr.zeros(mi.Color3f, dr.width(active))
    choice = first
    for _ in range(levels):  # a few unrolled levels: one kernel
        bsdf = si.bsdf()
        bs, weight = bsdf.sample(ctx, si, choice, mi.Point2f(0.5), active)
        throughput = throughput * weight * bs.pdf  # the branch's expected contribution
        active &= bs.pdf > 0
        ray = si.spawn_ray(si.to_world(bs.wo))
        si = intersect_visible(scene, ray, active, null_shapes)
        active &= si.is_valid()
        bsdf = si.bsdf(ray)
        end = active & ~is_specular(bsdf, active)
        n = mi.Vector3f(si.sh_frame.n)
        n = dr.select(dr.dot(n, ray.d) > 0, -n, n)
        albedo = diffuse_albedo(bsdf, si, end)
        *_, lit = shade(scene, light, si.p, n, albedo, end, eps, distances=False, samples=True,
                        null_shapes=null_shapes)  # fmt: skip
        lit += si.emitter(scene).eval(si, end)
        L += dr.select(end, throughput * lit, 0.0)
        active &= ~end
        choice = TRANSMIT
    return L


def glass_eye(
    scene: mi.Scene,
    gbuf: GBuffer,
    specular: mi.Bool,
    light: Light,
    diagonal: float,
    levels: int = LEVELS,
) -> mi.Color3f | None:
    """Radiance of the mirror / glass pixels (``specular``) by eye-ray refraction and Fresnel
    reflection, 0 elsewhere; None when no pixel sees a mirror or glass."""
    eps = dr.opaque(mi.Float, EPSILON * diagonal)
    index = dr.compress(specular)  # only the specular pixels are traced
    if dr.width(index) == 0:
        return None  # no mirror or glass in view
    eye = mi.Point3f(*(dr.opaque(mi.Float, float(c)) for c in gbuf.eye))
    ray = mi.Ray3f(eye, dr.normalize(dr.gather(mi.Point3f, gbuf.pos, index) - eye))
    null_shapes = has_null_shapes(scene)
    si = intersect_visible(scene, ray, True, null_shapes)
    active = si.is_valid()
    one = dr.ones(mi.Color3f, dr.width(index))
    L = _chain(scene, light, si, one, active, TRANSMIT, levels, eps, null_shapes)
    glass = active & mi.has_flag(si.bsdf(ray).flags(), mi.BSDFFlags.DeltaTransmission)
    L += _chain(scene, light, si, one, glass, REFLECT, levels, eps, null_shapes)  # mirrors: 1
    out = dr.zeros(mi.Color3f, dr.width(specular))
    dr.scatter(out, L, index)
    dr.eval(out)
    return out


def composite(
    direct: mi.Color3f,
    visibility: mi.Float | None,
    indirect: mi.Color3f,
    glass: mi.Color3f | None,
    emission: mi.Color3f | None = None,
) -> mi.Color3f:
    """L_out = V_s·L_direct + Up(L_ind) + L_e (+ the ray-traced specular pixels);
    ``visibility=None``: ``direct`` is already shadowed (``shadows="sampled"``)."""
    out = (direct if visibility is None else visibility * direct) + indirect
    if emission is not None:
        out += emission
    if glass is not None:
        out += glass
    dr.eval(out)
    return out
