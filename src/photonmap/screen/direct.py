"""Deferred direct lighting and the ray-traced shadow map (Yao 2011 §3.1, Fig 3.3, Ch. 4, §3.3 for
compositing). The material colour is read as ``f = ρ/π``, so direct and indirect light add as
radiance.

**Spot and point lights.** Per valid eye G-buffer pixel s with normal n and albedo ρ, for the light
position x_L:

    L_direct = ρ/π · I(ω) · max(0, n·l) / D²,   l = (x_L − s)/D,  D = ‖x_L − s‖,

and one shadow ray from s + εn toward x_L over t ∈ (0, D − 2ε) at full eye resolution (the shadow
map's resolution is not given). An any-hit test (the thesis's OptiX any-hit program) gives the hard
visibility V_h ∈ {0, 1}; the blocked rays only are cast again for their closest hit (the occluder
nearest the receiver, deterministic: an any-hit test returns an arbitrary one), which gives the
occluder distance d (from s; 0 where V_h = 1). On the Cornell box this costs ≈ half of closest-hit
rays for every pixel. Pixels facing away from the light (n·l ≤ 0) get V_h = 1 and L_direct = 0 (they
are no blockers for the soft-shadow search, :mod:`.soft_shadow`).

**Area lights** (rectangle, disk, sphere, mesh). Yao's area light softens only the shadows and
shades and emits from its centre; here it is sampled for direct light too. The light is not a point:
L_direct is the mean of :data:`LIGHT_SAMPLES` jittered-stratified samples y_k of the light from
Mitsuba's ``emitter.sample_direction`` (solid-angle sampling of a sphere's visible cap, area
sampling of rectangles and meshes; Le/p_ω per sample),

    L_direct = ρ/π · 1/K Σ_k Le(y_k) max(0, n·ω_k) / p_ω(y_k),

unshadowed. The shadow map's V_h, d and D refer to the light's centre x_L (the bounding-box centre,
as PCSS and the thesis's virtual area light do): a shadow ray toward x_L is blocked by anything but
the light's own shape (a ray toward a sphere light's centre always meets the sphere). With
``samples=True`` each sample also casts its own shadow ray, stopped 2ε short of y_k, which gives
the sampled shadowed radiance ``L_sampled`` = ρ/π · 1/K Σ_k V(y_k) Le(y_k) cos_k / p_ω(y_k) — the
``shadows="sampled"`` mode and the mirror / glass chains use it.

``null``-BSDF shapes (a fog box) block no shadow ray (:func:`~photonmap.core.bsdf.occluded`).
ε is relative to the scene diagonal.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.bsdf import has_null_shapes, intersect_visible, occluded
from .gbuffer import GBuffer
from .light_gbuffer import Light, intensity

EPSILON = 1e-4  # ray offset, × scene diagonal
LIGHT_SAMPLES = 16  # K: jittered-stratified samples (4 × 4) per shaded point on an area light


@dataclass
class DirectLight:
    """Unshadowed direct radiance ``L``, hard visibility ``hard`` (V_h), occluder distance
    ``occluder_dist`` (d) and light distance ``light_dist`` (D), per pixel; ``L_sampled``: the
    direct radiance with each light sample's own shadow ray (area lights, when asked for), or
    V_h·L (spot and point lights), or None."""

    L: mi.Color3f
    hard: mi.Float
    occluder_dist: mi.Float
    light_dist: mi.Float
    L_sampled: mi.Color3f | None = None


def shade(
    scene: mi.Scene, light: Light, points: tuple, eps, distances: bool = True,
    samples: bool = False, null_shapes: bool | None = None,
):  # fmt: skip
    """Unshadowed direct radiance L, the hard visibility V_h, the occluder distance d, the light
    distance D and the sampled shadowed radiance (None unless ``samples``; module docstring) at
    ``points = (p, n, albedo, active)``: positions ``p`` with normals ``n`` and diffuse
    ``albedo`` where ``active`` (for the eye G-buffer and for ray-traced glass,
    :mod:`.composite`). Shadow rays are any-hit tests, as the thesis's OptiX any-hit program; only
    the blocked rays are cast again for their closest hit, which gives d (module docstring).
    ``distances=False`` skips that second pass (d is then 0); for an area light with
    ``samples=True`` it skips the shadow map altogether (V_h = 1: the samples' rays shadow it)."""
    if null_shapes is None:
        null_shapes = has_null_shapes(scene)
    p, n, albedo, active = points
    to_light = light_point(light) - p
    dist = dr.norm(to_light)
    l = to_light / dr.maximum(dist, 1e-12)
    cos = dr.dot(n, l)
    lit = active & (cos > 0) & (dist > 2 * eps)
    sampled = None
    if light.kind == "area":
        radiance, sampled = _area_light(scene, light, points, eps, samples, null_shapes)
    else:
        radiance = albedo * dr.inv_pi * intensity(light, -l) * cos / dr.square(dist)
        radiance = dr.select(lit, radiance, 0.0)
    occluder = dr.zeros(mi.Float, dr.width(lit))
    light_dist = dr.select(active, dist, 0.0)
    if sampled is not None and not distances:  # the chains of .composite: no shadow map
        return radiance, dr.ones(mi.Float, dr.width(lit)), occluder, light_dist, sampled
    ray = mi.Ray3f(p + eps * n, l)
    ray.maxt = dr.maximum(dist - 2 * eps, 0.0)
    blocked = occluded(scene, ray, lit, null_shapes)
    own = light.kind == "area"  # a hit on the light's own shape is no occluder
    if distances or own:
        dr.eval(radiance, light_dist, ray, blocked)
        index = dr.compress(blocked)  # the shadowed pixels: one closest-hit ray each
        if dr.width(index):
            sub = dr.gather(mi.Ray3f, ray, index)
            si = intersect_visible(scene, sub, True, null_shapes)
            if own:
                mine = si.shape == mi.ShapePtr(light.shape)
                dr.scatter(blocked, False, index, mine)
            if distances:
                dr.scatter(occluder, dr.minimum(si.t, sub.maxt) + eps, index)
            occluder = dr.select(blocked, occluder, 0.0)
    hard = dr.select(blocked, 0.0, 1.0)
    if light.kind != "area":
        sampled = radiance * hard if samples else None
    return radiance, hard, occluder, light_dist, sampled


@dr.syntax
def _area_light(scene, light, points, eps, samples: bool, null_shapes: bool):
    """The unshadowed and (``samples``) the sampled shadowed direct radiance of an area light
    at ``points = (p, n, albedo, active)`` (module docstring): K jittered-stratified samples of
    ``emitter.sample_direction``, each with its own shadow ray when ``samples``."""
    p, n, albedo, active = points
    width = dr.width(active)
    lane = dr.arange(mi.UInt32, width)
    it = dr.zeros(mi.Interaction3f, width)
    it.p = mi.Point3f(p)
    it.n = mi.Normal3f(n)
    origin = p + eps * n
    side = int(round(LIGHT_SAMPLES**0.5))
    unshadowed = dr.zeros(mi.Color3f, width)
    shadowed = dr.zeros(mi.Color3f, width)
    k = dr.zeros(mi.UInt32, width)
    while k < LIGHT_SAMPLES:
        jitter = mi.Point2f(
            mi.sample_tea_float32(lane, 2 * k, 4), mi.sample_tea_float32(lane, 2 * k + 1, 4)
        )
        u = (mi.Point2f(mi.Float(k % side), mi.Float(k // side)) + jitter) / side
        ds, spec = light.emitter.sample_direction(it, u, active)
        contrib = mi.Color3f(spec) * dr.maximum(dr.dot(n, ds.d), 0.0)
        good = active & (dr.max(contrib) > 0)
        unshadowed += dr.select(good, contrib, 0.0)
        if samples:
            to_y = ds.p - origin
            d = dr.norm(to_y)
            ray = mi.Ray3f(origin, to_y / dr.maximum(d, 1e-12))
            ray.maxt = dr.maximum(d - 2 * eps, 0.0)  # stop short of the light's own surface
            seen = good & ~occluded(scene, ray, good, null_shapes)
            shadowed += dr.select(seen, contrib, 0.0)
        k += 1
    scale = albedo * dr.inv_pi / LIGHT_SAMPLES
    return scale * unshadowed, (scale * shadowed if samples else None)


def light_point(light: Light) -> mi.Point3f:
    """The light centre x_L as an opaque array (a moved light reuses the compiled kernels)."""
    return mi.Point3f(*(dr.opaque(mi.Float, float(c)) for c in light.position))


def direct_light(
    scene: mi.Scene, gbuf: GBuffer, light: Light, diagonal: float, samples: bool = False
) -> DirectLight:
    """Direct light and the shadow map (module docstring) over the eye G-buffer (evaluated);
    ``samples``: also the sampled shadowed radiance ``L_sampled`` (module docstring)."""
    eps = dr.opaque(mi.Float, EPSILON * diagonal)
    out = DirectLight(
        *shade(
            scene, light, (gbuf.pos, mi.Vector3f(gbuf.nrm), gbuf.albedo, gbuf.valid), eps,
            samples=samples,
        )  # fmt: skip
    )
    dr.eval(out.L, out.hard, out.occluder_dist, out.light_dist, out.L_sampled)
    return out
