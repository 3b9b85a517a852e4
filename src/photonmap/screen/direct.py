"""Deferred direct lighting and the ray-traced shadow map (Yao 2011 §3.1, Fig 3.3, Ch. 4; spec
seed-004 §2.3, §2.9, A11, A20, A21).

Per valid eye G-buffer pixel s with normal n and albedo ρ, for the light centre x_L:

    L_direct = ρ/π · I(ω) · max(0, n·l) / D²,   l = (x_L − s)/D,  D = ‖x_L − s‖,

and one shadow ray from s + εn toward x_L over t ∈ (0, D − 2ε) at full eye resolution (A21). An
any-hit test (``ray_test``, the thesis's OptiX any-hit program) gives the hard visibility
V_h ∈ {0, 1}; the blocked rays only are cast again for their closest hit (A20: the occluder
nearest the receiver, deterministic), which gives the occluder distance d (from s; 0 where
V_h = 1). On the Cornell box this costs ≈ half of closest-hit rays for every pixel.
Pixels facing away from the light (n·l ≤ 0) get V_h = 1 and L_direct = 0 (§2.3: they are no
blockers for the soft-shadow search). ε is relative to the scene diagonal.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from .gbuffer import GBuffer
from .light_gbuffer import Light, intensity

EPSILON = 1e-4  # ray offset, × scene diagonal


@dataclass
class DirectLight:
    """Unshadowed direct radiance ``L``, hard visibility ``hard`` (V_h), occluder distance
    ``occluder_dist`` (d) and light distance ``light_dist`` (D), per pixel."""

    L: mi.Color3f
    hard: mi.Float
    occluder_dist: mi.Float
    light_dist: mi.Float


def shade(scene: mi.Scene, light: Light, p, n, albedo, active, eps, distances: bool = True):
    """Unshadowed ρ/π·I·cos/D², the hard visibility V_h, the occluder distance d and the light
    distance D at points ``p`` with normals ``n`` (for the eye G-buffer and for ray-traced glass,
    :mod:`.composite`). Shadow rays are any-hit tests (``ray_test``, as the thesis's OptiX
    any-hit program); only the blocked rays are cast again for their closest hit, which gives d
    (A20). ``distances=False`` skips that second pass (d is then 0)."""
    to_light = light_point(light) - p
    dist = dr.norm(to_light)
    l = to_light / dr.maximum(dist, 1e-12)
    cos = dr.dot(n, l)
    lit = active & (cos > 0) & (dist > 2 * eps)
    radiance = albedo * dr.inv_pi * intensity(light, -l) * cos / dr.square(dist)
    ray = mi.Ray3f(p + eps * n, l)
    ray.maxt = dr.maximum(dist - 2 * eps, 0.0)
    blocked = scene.ray_test(ray, lit)
    radiance = dr.select(lit, radiance, 0.0)
    hard = dr.select(blocked, 0.0, 1.0)
    light_dist = dr.select(active, dist, 0.0)
    occluder = dr.zeros(mi.Float, dr.width(hard))
    if distances:
        dr.eval(radiance, hard, light_dist, ray, blocked)
        index = dr.compress(blocked)  # the shadowed pixels: one closest-hit ray each
        if dr.width(index):
            sub = dr.gather(mi.Ray3f, ray, index)
            t = scene.ray_intersect_preliminary(sub, True).t
            dr.scatter(occluder, dr.minimum(t, sub.maxt) + eps, index)
    return radiance, hard, occluder, light_dist


def light_point(light: Light) -> mi.Point3f:
    """The light centre x_L as an opaque array (a moved light reuses the compiled kernels)."""
    return mi.Point3f(*(dr.opaque(mi.Float, float(c)) for c in light.position))


def direct_light(scene: mi.Scene, gbuf: GBuffer, light: Light, diagonal: float) -> DirectLight:
    """Spec §2.3 + §2.9 over the eye G-buffer (evaluated)."""
    eps = dr.opaque(mi.Float, EPSILON * diagonal)
    out = DirectLight(
        *shade(scene, light, gbuf.pos, mi.Vector3f(gbuf.nrm), gbuf.albedo, gbuf.valid, eps)
    )
    dr.eval(out.L, out.hard, out.occluder_dist, out.light_dist)
    return out
