"""Eye-side ray tracing shared by the eye pass and the final gather (Steinhurst 2007 §2.6.2, §7.3.2).

"If the surface is highly specular (mirror/glass), reflect/refract and continue until a non-specular
object is found", multiplying the specular reflectances into the path weight; glossy surfaces count
as non-specular (handled by the photon map and final gather) [Steinhurst §7.3.2; spec seed-001 §2.1].
A surface is *specular* here when its BSDF has no smooth (diffuse or glossy) component
(:func:`photonmap.core.bsdf.is_specular`); a BSDF that mixes a delta lobe with a smooth one (e.g.
Mitsuba's ``plastic``) is treated as non-specular and its delta lobe is not followed — use
``roughplastic`` for a glossy coating.

``null``-BSDF shapes (the boundaries of a fog box) are invisible: rays pass straight through them
(:func:`photonmap.core.bsdf.intersect_visible`) and crossing one is no bounce (issue 10).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.bsdf import has_null_shapes, intersect_visible, is_specular


@dr.syntax
def follow_specular(
    scene: mi.Scene,
    ray: mi.Ray3f,
    throughput: mi.Spectrum,
    active: mi.Bool,
    max_depth: int,
    gen: mi.PCG32,
    count_emission: bool,
    null_shapes: bool | None = None,
):
    """Trace ``ray`` through purely specular surfaces until the first non-specular hit.

    Returns ``(si, throughput, emitted, found, bounces)``: the interaction at the non-specular
    surface, the product of the specular weights on the way, the radiance emitted by emitters met
    on the way (``count_emission``; weighted by the throughput), whether a non-specular surface was
    found within ``max_depth`` bounces, and the number of specular bounces before it.
    ``null_shapes``: whether the scene has ``null``-BSDF shapes to pass through
    (:func:`~photonmap.core.bsdf.has_null_shapes`, computed here when None).
    """
    if null_shapes is None:
        null_shapes = has_null_shapes(scene)
    ctx = mi.BSDFContext()
    ray = mi.Ray3f(ray)
    throughput = mi.Spectrum(throughput)
    emitted = dr.zeros(mi.Spectrum, dr.width(throughput))
    depth = dr.zeros(mi.UInt32, dr.width(throughput))
    found = dr.zeros(mi.Bool, dr.width(throughput))
    searching = mi.Bool(active)
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(throughput))

    while searching:
        si = intersect_visible(scene, ray, searching, null_shapes)
        if count_emission:
            emitted += dr.select(searching, throughput * si.emitter(scene).eval(si, searching), 0.0)
        bsdf = si.bsdf(ray)
        hit = searching & si.is_valid()
        specular = is_specular(bsdf, hit)
        found |= hit & ~specular
        bs, weight = bsdf.sample(
            ctx,
            si,
            gen.next_float32(),
            mi.Point2f(gen.next_float32(), gen.next_float32()),
            specular,
        )
        throughput = dr.select(specular, throughput * weight, throughput)
        ray = dr.select(specular, si.spawn_ray(si.to_world(bs.wo)), ray)
        depth += 1
        searching = specular & (depth < max_depth) & (dr.max(throughput) > 0)
    return si, throughput, emitted, found, dr.maximum(depth, 1) - 1
