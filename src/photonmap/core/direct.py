"""Direct light at an eye path's vertex: emitter sampling and BSDF sampling combined by multiple
importance sampling (power heuristic) — the shadow rays of Steinhurst §7.3.2 ("area light
sources ... accommodated using importance sampling"), written after Mitsuba's ``volpath``.

At a surface vertex only the BSDF's smooth lobes take part (the eye-path loop follows its delta
and ``Null`` lobes itself, :mod:`photonmap.core.eye_trace`): Mitsuba's ``eval`` and ``pdf`` of a
delta or Null lobe are zero, and a BSDF sample that picks one counts nothing. Both rays carry
the transmittance to the emitter (:func:`photonmap.core.media.transmittance`): through media,
``null`` boundaries and the ``Null`` lobes of ``mask`` and ``thindielectric`` surfaces, blocked by
anything else — vacuum is the case without media, where an any-hit shadow ray suffices unless
some BSDF lets light through (Jensen & Christensen 1998: attenuated shadow rays).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from .media import (
    channel,
    enter,
    interaction,
    segment_transmittance,
    transmittance,
    walk,
    within_extent,
)
from .scene_info import SceneTraits

CONTEXT = mi.BSDFContext()
GOLDEN = 0.6180339887  # shifts u_light.y between the emitter samples of one vertex


def power_heuristic(a, b):
    """Veach's power heuristic ``a² / (a² + b²)`` as ``1 / (1 + (b/a)²)``: a squared density
    overflows float32 (the emitter density of a point in the light's own plane is ~1e19 per
    steradian) and the quotient form then gives NaN; 0 where ``a`` is 0."""
    return dr.select(a > 0, dr.rcp(1.0 + dr.square(b / a)), 0.0)


def shadow_transmittance(scene, ray, medium, gen, active, traits: SceneTraits) -> mi.Spectrum:
    """Transmittance along the finite shadow ``ray`` starting in ``medium`` (module docstring)."""
    if not traits.media and not traits.null_lobes:
        return dr.select(active & ~scene.ray_test(ray, active), 1.0, 0.0) * mi.Spectrum(1.0)
    return transmittance(scene, ray, medium, gen, channel(gen), active)


def direct_lighting(
    scene: mi.Scene,
    si: mi.SurfaceInteraction3f,
    u_light: mi.Point2f,
    gen: mi.PCG32,
    active: mi.Bool,
    traits: SceneTraits,
    medium: mi.MediumPtr | None = None,
    samples: int = 1,
) -> mi.Spectrum:
    """Radiance the smooth lobes at ``si`` reflect towards ``si.wi`` from light arriving straight
    from emitters; ``u_light`` picks the point on the emitters (stratified by the caller),
    ``gen`` draws the BSDF sample; ``medium``: the medium the eye path reached ``si`` in.
    ``samples`` emitter samples (one BSDF sample) stratify the emitter pick: sample ``i`` takes
    ``u_light.x`` into ``[i, i + 1) / samples``, so that with as many samples as lights of equal
    weight each light is sampled once, and a pixel's direct light carries no noise of which
    light was picked (Veach 1997 §9.2: multi-sample MIS, the emitter density counted
    ``samples`` times in the power heuristic)."""
    bsdf = si.bsdf()
    lanes = dr.width(si.p)
    medium = dr.zeros(mi.MediumPtr, lanes) if medium is None else medium
    L = dr.zeros(mi.Spectrum, lanes)
    for i in range(samples):  # a loop over the samples, not over lanes
        u = u_light
        if samples > 1:
            y = u_light.y + i * GOLDEN
            u = mi.Point2f((i + u_light.x) / samples, y - dr.floor(y))
        L += emitter_sampled(scene, si, u, gen, active, traits, medium, samples)
    L /= samples

    # BSDF sampling towards emitters: a sample of a delta or Null lobe counts nothing here (the
    # eye path follows those lobes), which leaves an unbiased estimate of the smooth lobes'
    # share (a BSDFContext restricted to the smooth lobes is not honoured by every BSDF: a
    # mask's then samples its Null lobe)
    bs, bsdf_weight = bsdf.sample(
        CONTEXT, si, gen.next_float32(), mi.Point2f(gen.next_float32(), gen.next_float32()), active
    )
    sampled = active & (bs.pdf > 0) & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Smooth)
    ray = si.spawn_ray(si.to_world(bs.wo))
    si_e, T = emitter_along(scene, ray, enter(si, ray.d, medium, sampled), gen, sampled, traits)
    emitter = si_e.emitter(scene, sampled)
    hits_light = sampled & (emitter != None)  # noqa: E711 (Dr.Jit pointer test)
    ds_e = mi.DirectionSample3f(scene, si_e, si)
    pdf_em = scene.pdf_emitter_direction(si, ds_e, hits_light)
    w_bsdf = power_heuristic(bsdf.pdf(CONTEXT, si, bs.wo, hits_light), samples * pdf_em)
    L += dr.select(hits_light, w_bsdf * bsdf_weight * T * emitter.eval(si_e, hits_light), 0.0)
    return L


def emitter_sampled(
    scene, si, u_light, gen, active, traits: SceneTraits, medium, samples: int = 1
) -> mi.Spectrum:
    """The emitter-sampling half of :func:`direct_lighting` (a shadow ray with transmittance),
    MIS-weighted against sampling ``si``'s BSDF (power heuristic; the emitter density counted
    ``samples`` times where that many emitter samples are taken) — also the next-event
    estimation of a path that goes on by sampling the BSDF (its emitter hits take the other
    weight)."""
    light = light_sample(scene, si, u_light, gen, active, traits, medium)
    wo = si.to_local(light.ds.d)
    bsdf_val, bsdf_pdf = si.bsdf().eval_pdf(CONTEXT, si, wo, light.lit)  # smooth lobes only
    return nee_weighted(light, bsdf_val, bsdf_pdf, samples)


@dataclass
class LightSample:
    """An emitter sample of next-event estimation (:func:`light_sample`): its direction sample,
    the emitter's weight ``L_e / p`` times the shadow ray's transmittance, and the lanes it
    lights."""

    ds: mi.DirectionSample3f
    weight: mi.Spectrum
    lit: mi.Bool


def light_sample(scene, si, u_light, gen, active, traits: SceneTraits, medium) -> LightSample:
    """Sample an emitter from ``si`` (``u_light``) and trace the shadow ray (with transmittance,
    :func:`shadow_transmittance`) towards it."""
    ds, em_weight = scene.sample_emitter_direction(si, u_light, False, active)
    lit = active & (ds.pdf != 0)
    shadow = si.spawn_ray_to(ds.p)
    em_weight *= shadow_transmittance(scene, shadow, enter(si, ds.d, medium, lit), gen, lit, traits)
    return LightSample(ds, em_weight, lit)


def nee_weighted(light: LightSample, bsdf_val, bsdf_pdf, samples: int = 1) -> mi.Spectrum:
    """``light``'s contribution ``w f L_e T / p`` through the BSDF value ``bsdf_val`` (cosine
    included) of its direction, weighted against BSDF sampling (density ``bsdf_pdf``) by the
    power heuristic; a delta emitter takes weight 1."""
    ds = light.ds
    w_em = dr.select(ds.delta, 1.0, power_heuristic(samples * ds.pdf, bsdf_pdf))
    return dr.select(light.lit, w_em * bsdf_val * light.weight, 0.0)


def emitter_along(scene, ray, medium, gen, active, traits: SceneTraits):
    """The first emitter surface on ``ray`` (an invalid interaction where it escapes: the
    environment) and the transmittance to it, through the surfaces that let light through in
    part (``eval_null_transmission``) and the media — the BSDF-sampled half of
    :func:`direct_lighting`, consistent with its shadow rays."""
    if not traits.media and not traits.null_lobes:
        si = scene.ray_intersect(ray, active)
        return si, dr.select(active, 1.0, 0.0) * mi.Spectrum(1.0)
    return walk(scene, ray, medium, gen, channel(gen), active, True)


def inscattered_direct(
    scene: mi.Scene,
    mei: mi.MediumInteraction3f,
    u: mi.Point2f,
    gen: mi.PCG32,
    ch: mi.UInt32,
    active: mi.Bool,
) -> mi.Spectrum:
    """Single scattering of direct light at ``mei`` towards ``mei.wi`` per unit length,
    ``σ_s f_p L_e T / p``: one emitter sample (``u``) and a transmittance shadow ray (Jensen &
    Christensen 1998)."""
    it = mi.Interaction3f(mei)
    ds, em_weight = scene.sample_emitter_direction(it, u, False, active)
    lit = active & (ds.pdf != 0)
    T = transmittance(scene, it.spawn_ray_to(ds.p), mei.medium, gen, ch, lit)
    sigma_s, _, _ = mei.medium.get_scattering_coefficients(mei, lit)
    f, _ = mei.medium.phase_function().eval_pdf(mi.PhaseFunctionContext(None), mei, ds.d, lit)
    return dr.select(lit, sigma_s * f * em_weight * T, 0.0)


def equiangular(ray: mi.Ray3f, length, centre: mi.Point3f, u) -> tuple[mi.Float, mi.Float]:
    """A distance ``t`` on ``[0, length]`` of ``ray`` drawn in proportion to ``1/r²`` about
    ``centre`` (Kulla & Fajardo 2012, equiangular sampling: ``t = Δ + D tan θ`` with ``θ``
    uniform between the angles of the ends), and its pdf ``D / ((θ_b − θ_a)(D² + (t − Δ)²))``;
    ``u`` may be stratified."""
    delta = dr.dot(centre - ray.o, ray.d)
    D = dr.maximum(dr.norm(centre - ray.o - delta * ray.d), 1e-6 * dr.maximum(length, 1e-6))
    theta_a = dr.atan2(-delta, D)
    theta_b = dr.atan2(length - delta, D)
    t = dr.clip(delta + D * dr.tan(theta_a + u * (theta_b - theta_a)), 0.0, length)
    pdf = D / ((theta_b - theta_a) * (dr.square(D) + dr.square(t - delta)))
    return t, pdf


def piece_direct(scene, ray, length, medium, gen, ch, active) -> mi.Spectrum:
    """``∫₀^ℓ T(t) L_s,direct(t) dt`` along a piece of ``ray`` inside one ``medium`` (no surface
    on it): one equiangular point about a point on the emitters sampled from the piece's middle
    (the ``1/r²`` peak of a point or spot light near the ray is sampled in proportion, where
    free-flight collisions would rarely land), ``T`` from the piece's start."""
    middle = dr.zeros(mi.Interaction3f, dr.width(length))
    middle.p = ray(0.5 * length)
    u = mi.Point2f(gen.next_float32(), gen.next_float32())
    centre = scene.sample_emitter_direction(middle, u, False, active)[0].p
    t, pdf = equiangular(ray, length, centre, gen.next_float32())
    mei = interaction(ray(t), ray.d, t, medium)
    ok = active & (pdf > 0) & within_extent(mei)
    T = segment_transmittance(ray, t, medium, gen, ch, ok)
    u = mi.Point2f(gen.next_float32(), gen.next_float32())
    L = inscattered_direct(scene, mei, u, gen, ch, ok)
    return dr.select(ok, T * L / dr.maximum(pdf, 1e-30), 0.0)
