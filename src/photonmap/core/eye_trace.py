"""Eye-side ray tracing shared by the surface method's eye pass and final gather and by SPPM's eye
pass (Steinhurst 2007 §2.6.2, §7.3.2; Hachisuka & Jensen 2009 §4).

"If the surface is highly specular (mirror/glass), reflect/refract and continue until a non-specular
object is found", multiplying the specular reflectances into the path weight; glossy surfaces count
as non-specular (handled by the photon map and final gather) [Steinhurst §7.3.2; spec seed-001 §2.1].
A surface is *specular* here when its BSDF has no smooth (diffuse or glossy) component
(:func:`photonmap.core.bsdf.is_specular`); a BSDF that mixes a delta lobe with a smooth one (e.g.
Mitsuba's ``plastic``) is treated as non-specular and its delta lobe is not followed — use
``roughplastic`` for a glossy coating.

``null``-BSDF shapes (the boundaries of a fog box) are invisible: rays pass straight through them
(:func:`photonmap.core.bsdf.intersect_visible`) and crossing one is no bounce (issue 10). In a
scene with participating media :func:`follow_specular_media` does the same through the media
(Jensen & Christensen 1998): transmittance, in-scattered light, and the medium at the end.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .bsdf import MAX_NULL_CROSSINGS, has_null_shapes, intersect_visible, is_null, is_specular
from .media import (
    Inscatter,
    Segments,
    channel,
    enter,
    escape_length,
    free_flight,
    segment_transmittance,
)


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


MAX_SEGMENTS = 4  # medium segments of an eye path that are marched (later ones: transmittance)
MEDIA_STREAM = 1 << 24  # RNG streams of the in-scattering estimates start here


def follow_specular_media(
    scene: mi.Scene,
    ray: mi.Ray3f,
    throughput: mi.Spectrum,
    medium: mi.MediumPtr,
    active: mi.Bool,
    max_depth: int,
    gen: mi.PCG32,
    count_emission: bool,
    inscatter: Inscatter | None,
    march: bool = True,
    stream: int = MEDIA_STREAM,
):
    """:func:`follow_specular` through participating media (Jensen & Christensen 1998; spec
    beyond-seeds §4). The ray starts in ``medium`` and switches media at medium transitions
    (:mod:`photonmap.core.media`); ``null`` boundaries switch the medium and are no bounce.

    With ``march`` (the eye rays) each piece of the path inside a medium multiplies the throughput
    by its transmittance and is ray-marched afterwards, all pieces in one batch
    (:meth:`~photonmap.core.media.Inscatter.march`; the first :data:`MAX_SEGMENTS` of a path):
    its in-scattered radiance, weighted by the throughput at its start, is ``L_medium``. Without
    ``march`` (final-gather rays) each piece samples a free flight
    (:func:`~photonmap.core.media.free_flight`): where it scatters the path ends, with
    ``L_medium = throughput · (σ_s T/p) · L_s / σ_s`` read at the collision; elsewhere the
    throughput takes the flight's ``T/p``. ``inscatter=None``: transmittance only. ``stream``:
    the random streams of the in-scattering estimates.

    Returns ``(si, throughput, emitted, found, bounces, medium, L_medium)``: as
    :func:`follow_specular`, plus the medium the ray is in at ``si`` and the in-scattered light."""
    n = max(dr.width(ray.o), dr.width(ray.d), dr.width(throughput), dr.width(active))
    throughput = mi.Spectrum(throughput) * dr.ones(mi.Float, n)  # every loop variable full width
    marching = march and inscatter is not None
    slots = n * MAX_SEGMENTS if marching else 1
    buffers = Segments(  # slot = segment number · n + lane (44 bytes a slot, lane implicit)
        dr.zeros(mi.Point3f, slots),
        dr.zeros(mi.Vector3f, slots),
        dr.zeros(mi.Float, slots),
        dr.zeros(mi.MediumPtr, slots),
        dr.zeros(mi.Spectrum, slots),
        None,
    )
    stored = dr.zeros(mi.Bool, slots)
    si, throughput, emitted, found, depth, medium, mei, weight, scattered = _follow(
        scene,
        ray,
        throughput,
        medium,
        active,
        max_depth,
        gen,
        count_emission,
        march or inscatter is None,
        buffers if marching else None,
        stored,
    )
    L_medium = dr.zeros(mi.Spectrum, n)
    if marching:
        index = dr.compress(stored)
        fields = [dr.gather(type(f), f, index) for f in vars(buffers).values() if f is not None]
        segments = Segments(*fields, index % n)
        L_medium = inscatter.march(segments, n, stream)
    elif inscatter is not None and dr.any(scattered, axis=None):
        index = dr.compress(scattered)
        at = dr.gather(mi.MediumInteraction3f, mei, index)
        L_s = inscatter.at(at, True, stream)
        sigma_s = at.sigma_s
        per_sigma = dr.select(sigma_s > 0, L_s / dr.maximum(sigma_s, 1e-30), 0.0)
        dr.scatter(L_medium, dr.gather(mi.Spectrum, weight, index) * per_sigma, index)
    return si, throughput, emitted, found, depth, medium, L_medium


@dr.syntax
def _follow(
    scene,
    ray,
    throughput,
    medium,
    active,
    max_depth,
    gen,
    count_emission,
    transmit,
    buffers,
    stored,
):
    """The bounce loop of :func:`follow_specular_media`: ``transmit`` multiplies the throughput
    by each segment's transmittance (and records the segment into ``buffers`` if given), else
    each segment samples a free flight, which may end the path in the medium (``mei``, with
    ``weight`` = throughput × the flight's weight, ``scattered``)."""
    n = dr.width(throughput)
    ray = mi.Ray3f(ray)
    throughput = mi.Spectrum(throughput)
    medium = mi.MediumPtr(medium)
    emitted = dr.zeros(mi.Spectrum, n)
    depth = dr.zeros(mi.UInt32, n)
    crossings = dr.zeros(mi.UInt32, n)
    segments = dr.zeros(mi.UInt32, n)
    found = dr.zeros(mi.Bool, n)
    searching = mi.Bool(active)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    mei = dr.zeros(mi.MediumInteraction3f, n)
    weight = dr.zeros(mi.Spectrum, n)
    scattered = dr.zeros(mi.Bool, n)
    lane = dr.arange(mi.UInt32, n)
    ch = channel(gen)
    ctx = mi.BSDFContext()

    while searching & (crossings < MAX_NULL_CROSSINGS):
        if dr.hint(transmit, mode="scalar"):
            si = scene.ray_intersect(ray, searching)
            in_medium = searching & (medium != None)  # noqa: E711
            escaping = in_medium & ~si.is_valid()  # leaving the scene inside a medium
            length = dr.select(escaping, escape_length(scene, ray, medium, escaping), si.t)
            if dr.hint(buffers is not None, mode="scalar"):
                record = in_medium & (segments < MAX_SEGMENTS)
                slot = segments * n + lane
                dr.scatter(buffers.origin, ray.o, slot, record)
                dr.scatter(buffers.direction, ray.d, slot, record)
                dr.scatter(buffers.length, length, slot, record)
                dr.scatter(buffers.medium, medium, slot, record)
                dr.scatter(buffers.weight, throughput, slot, record)
                dr.scatter(stored, True, slot, record)
                segments[record] += 1
            throughput[in_medium] *= segment_transmittance(ray, length, medium, gen, ch, in_medium)
            bsdf = si.bsdf(ray)
            hit = searching & si.is_valid()
            cross = is_null(bsdf, hit) & (si.emitter(scene) == None)  # noqa: E711
        else:
            flight = free_flight(scene, ray, medium, gen, ch, searching)
            now = searching & flight.scattered
            mei[now] = flight.mei
            weight[now] = throughput * flight.weight
            scattered |= now
            throughput[searching] *= flight.weight
            searching &= ~now
            si = flight.si
            medium = dr.select(searching, flight.medium, medium)
            bsdf = si.bsdf(ray)
            hit = searching & si.is_valid()
            cross = dr.zeros(mi.Bool, n)
        if dr.hint(count_emission, mode="scalar"):
            emitted += dr.select(searching, throughput * si.emitter(scene).eval(si, searching), 0.0)
        visible = hit & ~cross
        specular = is_specular(bsdf, visible)
        found |= visible & ~specular
        bs, bsdf_weight = bsdf.sample(
            ctx,
            si,
            gen.next_float32(),
            mi.Point2f(gen.next_float32(), gen.next_float32()),
            specular,
        )
        d = dr.select(specular, si.to_world(bs.wo), ray.d)
        throughput = dr.select(specular, throughput * bsdf_weight, throughput)
        medium = enter(si, d, medium, specular | cross)
        ray = dr.select(specular | cross, si.spawn_ray(d), ray)
        depth[specular] += 1
        crossings[cross] += 1
        searching = (specular & (depth < max_depth) | cross) & (dr.max(throughput) > 0)
    return si, throughput, emitted, found, depth, medium, mei, weight, scattered
