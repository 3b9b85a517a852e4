"""Final compositing and glass seen through eye-ray refraction (Yao 2011 §3.3, §3.5, Ch. 5). Yao
refracts eye rays into a dynamic environment map lit by direct light only; here they are ray traced
(the reference mode), and glass gets no photon splats.

    L_out = V_s · L_direct + Up(L_ind) + L_e                     (diffuse / glossy pixels)
    L_out = Σ_branches T · (L_direct(hit) + L_e(hit))             (mirror / glass pixels)

L_e is the radiance of an area light seen at the pixel (or at the chain's end: the light in a
mirror or through glass). With ``shadows="sampled"`` V_s · L_direct is the sampled shadowed direct
light of :mod:`.direct`.

Glass and mirror pixels are ray-traced: the refracted chain is followed through up to
:data:`MAX_LEVELS` delta interfaces (fewer where the file's ``max_depth`` is lower) with
throughput T = weight·pdf of the transmitted branch (1 − F; TIR reflects), plus the
Fresnel-weighted reflection (F) at the front face, followed the same way. Both branches are
deterministic (no noise); the shading at the diffuse end point uses the hard shadow of
:func:`.direct.shade` (spot and point lights) or the area light's sampled shadow rays. Mitsuba's
dielectric gives F, Snell's law and the radiance scaling by η² across the interface. The
chains pass through ``null``-BSDF shapes.

The thesis's environment map holds the scene "with direct light only"; here the chain's end
points (:class:`ChainEnds`) also gather the indirect light of the same photons, splatted at full
resolution (:func:`chain_indirect`) — the floor seen in a mirror ball, mostly in the ball's own
shadow, is lit by indirect light alone:

    L_out += Σ_branches T · L_ind(end),

where an end reached after m delta interactions takes the photons of at most B − m recorded
bounces when the file bounds the path length (m + 1 eye segments and k + 1 light segments meet
there: m + k + 2 ≤ max_depth).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.bsdf import diffuse_albedo, has_null_shapes, intersect_visible, is_specular
from ..core.settings import UNBOUNDED
from .direct import EPSILON, shade
from .gbuffer import GBuffer
from .light_gbuffer import Light

MAX_LEVELS = 16  # delta interactions followed at most (unrolled: one kernel)
REFLECT, TRANSMIT = 0.0, 1.0 - 1e-6  # dielectric sample1: below F reflects, above refracts


@dataclass
class ChainEnds:
    """The first non-delta surfaces the mirror and glass pixels' chains reach, both branches one
    after the other: ``points`` (a one-row :class:`GBuffer`: position, normal facing the chain's
    last ray, diffuse albedo, valid), the branch's throughput T, the number of delta interactions
    m before it, and the pixel each belongs to."""

    points: GBuffer
    throughput: mi.Color3f
    level: mi.UInt32
    pixel: mi.UInt32


def _chain(scene, light, start, max_depth: int, eps, null_shapes):
    """Follow delta interactions from ``start = (si, throughput, active, first)``: from ``si``
    with ``throughput`` where ``active`` (first choice ``first`` per lane, then transmission),
    and return the throughput-weighted direct light and emission at the first
    non-delta surface, with that surface's position, normal, albedo and the throughput reaching
    it. After m delta interactions the end's emission ends a path of m + 1 segments, its direct
    light one of m + 2: each is kept within ``max_depth`` (Mitsuba's; -1 unbounded)."""
    si, throughput, active, first = start
    bounded = max_depth != UNBOUNDED
    levels = min(max_depth - 1, MAX_LEVELS) if bounded else MAX_LEVELS
    ctx = mi.BSDFContext(mi.TransportMode.Radiance)
    lanes = dr.width(active)
    L = dr.zeros(mi.Color3f, lanes)
    end_p, end_n = dr.zeros(mi.Point3f, lanes), dr.zeros(mi.Vector3f, lanes)
    end_albedo, end_T = dr.zeros(mi.Color3f, lanes), dr.zeros(mi.Color3f, lanes)
    end_level = dr.zeros(mi.UInt32, lanes)
    choice = first
    for level in range(1, levels + 1):  # unrolled levels: one kernel
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
        lit = si.emitter(scene).eval(si, end)
        if not bounded or level + 2 <= max_depth:
            *_, direct = shade(scene, light, (si.p, n, albedo, end), eps, distances=False,
                               samples=True, null_shapes=null_shapes)  # fmt: skip
            lit += direct
        L += dr.select(end, throughput * lit, 0.0)
        end_p, end_n = dr.select(end, si.p, end_p), dr.select(end, n, end_n)
        end_albedo = dr.select(end, albedo, end_albedo)
        end_T = dr.select(end, throughput, end_T)
        end_level[end] = level
        active &= ~end
        choice = TRANSMIT
    return L, (end_p, end_n, end_albedo, end_T, end_level)


def glass_eye(
    scene: mi.Scene,
    gbuf: GBuffer,
    specular: mi.Bool,
    light: Light,
    diagonal: float,
    max_depth: int = UNBOUNDED,
) -> tuple[mi.Color3f, ChainEnds] | None:
    """Direct radiance of the mirror / glass pixels (``specular``) by eye-ray refraction and
    Fresnel reflection, 0 elsewhere, and the chains' ends (for :func:`chain_indirect`); None
    when no pixel sees a mirror or glass. ``max_depth``: Mitsuba's path length (-1 unbounded;
    at most :data:`MAX_LEVELS` delta interactions are followed)."""
    eps = dr.opaque(mi.Float, EPSILON * diagonal)
    index = dr.compress(specular)  # only the specular pixels are traced
    if dr.width(index) == 0:
        return None  # no mirror or glass in view
    count = dr.width(index)
    lane = dr.arange(mi.UInt32, 2 * count)
    transmitted = lane < count  # lanes [0, n): the transmitted branch; [n, 2n): the reflected
    pixel = dr.gather(mi.UInt32, index, lane % count)
    eye = mi.Point3f(*(dr.opaque(mi.Float, float(c)) for c in gbuf.eye))
    ray = mi.Ray3f(eye, dr.normalize(dr.gather(mi.Point3f, gbuf.pos, pixel) - eye))
    null_shapes = has_null_shapes(scene)
    si = intersect_visible(scene, ray, True, null_shapes)
    glass = mi.has_flag(si.bsdf(ray).flags(), mi.BSDFFlags.DeltaTransmission)
    active = si.is_valid() & (transmitted | glass)  # mirrors: only the first branch
    first = dr.select(transmitted, TRANSMIT, REFLECT)
    one = dr.ones(mi.Color3f, 2 * count)
    L, (p, n, albedo, T, level) = _chain(
        scene, light, (si, one, active, first), max_depth, eps, null_shapes
    )
    out = dr.zeros(mi.Color3f, dr.width(specular))
    dr.scatter_add(out, L, pixel)
    points = GBuffer(2 * count, 1, p, mi.Normal3f(n), dr.zeros(mi.Float, 2 * count), albedo,
                     level > 0, gbuf.eye, gbuf.forward, gbuf.f_px)  # fmt: skip
    ends = ChainEnds(points, T, level, pixel)
    dr.eval(out, points, ends.throughput, ends.level, ends.pixel)
    return out, ends


def chain_indirect(
    ends: ChainEnds,
    splat: Callable[[GBuffer, int], tuple[mi.Color3f, mi.Color3f]],
    bounces: Callable[[int], int],
    pixels: int,
) -> mi.Color3f:
    """Σ_branches T · L_ind(end) per pixel: ``splat(points, k)`` gathers the indirect radiance
    of the photons of at most k recorded bounces at the chains' end points (the eye G-buffer's
    kernel, at full resolution); an end after m delta interactions takes ``bounces(m)``."""
    out = dr.zeros(mi.Color3f, pixels)
    for level in range(1, int(dr.max(ends.level)[0]) + 1):
        k = bounces(level)
        at_level = ends.points.valid & (ends.level == level)
        if k <= 0 or not dr.any(at_level):
            continue
        L_end, _ = splat(dataclasses.replace(ends.points, valid=at_level), k)
        dr.scatter_add(out, ends.throughput * L_end, ends.pixel, at_level)
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
