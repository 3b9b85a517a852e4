"""Direct lighting at the non-specular eye-ray hit: emitter sampling and BSDF sampling combined by
multiple importance sampling (power heuristic) — the shadow rays of Steinhurst §7.3.2 ("area light
sources ... accommodated using importance sampling"), written after Mitsuba's ``path`` integrator;
shared by the surface method and SPPM's visible points.

``null``-BSDF shapes (fog boxes) are invisible to the shadow rays and to the BSDF-sampled rays
(:func:`photonmap.core.bsdf.occluded`, :func:`~photonmap.core.bsdf.intersect_visible`), where
Mitsuba's own visibility test would stop at them.

In a scene with participating media (``medium`` given: the medium the eye ray reached ``si`` in),
both rays carry the transmittance to the emitter (:func:`photonmap.core.media.transmittance`)
instead of the binary visibility (Jensen & Christensen 1998: attenuated shadow rays).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .bsdf import intersect_visible, occluded
from .media import channel, enter, transmittance


def _power_heuristic(a, b):
    a2, b2 = dr.square(a), dr.square(b)
    return dr.select(a2 + b2 > 0, a2 / (a2 + b2), 0.0)


def direct_lighting(
    scene: mi.Scene,
    si: mi.SurfaceInteraction3f,
    bsdf: mi.BSDFPtr,
    u_light: mi.Point2f,
    gen: mi.PCG32,
    active: mi.Bool,
    null_shapes: bool,
    medium: mi.MediumPtr | None = None,
) -> mi.Spectrum:
    """Radiance reflected at ``si`` towards ``si.wi`` from light arriving straight from emitters;
    ``u_light`` picks the point on the emitters (stratified over a pixel's samples by the caller),
    ``gen`` draws the BSDF sample; ``null_shapes``: whether the scene has ``null``-BSDF shapes
    (:func:`~photonmap.core.bsdf.has_null_shapes`); ``medium``: see the module docstring."""
    ctx = mi.BSDFContext()
    ch = channel(gen) if medium is not None else None

    # emitter sampling (shadow ray)
    ds, em_weight = scene.sample_emitter_direction(si, u_light, False, active)
    lit = active & (ds.pdf != 0)
    if medium is None:
        lit &= ~occluded(scene, si.spawn_ray_to(ds.p), lit, null_shapes)
    else:
        shadow = si.spawn_ray_to(ds.p)
        em_weight *= transmittance(scene, shadow, enter(si, ds.d, medium, lit), gen, ch, lit)
    bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), lit)
    w_em = dr.select(ds.delta, 1.0, _power_heuristic(ds.pdf, bsdf_pdf))
    L = dr.select(lit, w_em * bsdf_val * em_weight, 0.0)

    # BSDF sampling towards emitters
    bs, bsdf_weight = bsdf.sample(
        ctx, si, gen.next_float32(), mi.Point2f(gen.next_float32(), gen.next_float32()), active
    )
    ray = si.spawn_ray(si.to_world(bs.wo))
    si_e = intersect_visible(scene, ray, active, null_shapes)
    emitter = si_e.emitter(scene)
    hits_light = active & (emitter != None) & (bs.pdf > 0)  # noqa: E711 (Dr.Jit pointer test)
    delta_lobe = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
    ds_e = mi.DirectionSample3f(scene, si_e, si)
    pdf_em = scene.pdf_emitter_direction(si, ds_e, hits_light & ~delta_lobe)
    w_bsdf = dr.select(delta_lobe, 1.0, _power_heuristic(bs.pdf, pdf_em))
    if medium is not None:
        to_light = mi.Ray3f(ray)
        to_light.maxt = si_e.t * (1.0 - mi.math.ShadowEpsilon)
        medium_ray = enter(si, ray.d, medium, hits_light)
        bsdf_weight *= transmittance(scene, to_light, medium_ray, gen, ch, hits_light)
    L += dr.select(hits_light, w_bsdf * bsdf_weight * emitter.eval(si_e, hits_light), 0.0)
    return L
