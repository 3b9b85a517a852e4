"""Participating media through Mitsuba's own ``Medium`` and ``PhaseFunction`` API — the medium
kit of the transport core (Jensen & Christensen 1998; Mitsuba's ``volpath``), shared by the photon
and eye paths of every method.

**Which medium a ray is in** follows Mitsuba's ``volpath``: a sensor ray starts in
``sensor.get_medium()``; at a surface that is a medium transition (a shape with an ``interior`` or
``exterior`` medium) the ray continues in ``si.target_medium(d)`` for its new direction ``d``, and
at any other surface it keeps its medium. ``null``-BSDF surfaces (fog boxes) only switch the
medium: the ray goes on unchanged. A photon starts in its emitter's medium: the ``medium`` the
file gives the emitter, else the medium found around it (:func:`emitter_media`) — ``volpath``'s
image never depends on an emitter's medium, so a file may leave it out.

**Free flight** (:func:`free_flight`): distances sampled by ``medium.sample_interaction`` in a
colour channel drawn afresh for each sample, weighted by ``T / p̄`` with ``p̄`` the mean of the
channels' pdfs from ``medium.transmittance_eval_pdf`` — one-sample MIS over the channels with the
balance heuristic (spectral MIS, Miller, Georgiev & Jarosz 2019; Mitsuba's ``volpathmis``), so
that the weight stays below 3 where ``volpath``'s ``T / p_c`` of one channel grows as
``exp((σ_c − σ_k) t)`` in the other channels of a coloured medium. Heterogeneous media sample
against their (grey) majorant and reject null collisions with probability ``σ_n / σ̄`` (delta
tracking), so homogeneous and ``heterogeneous`` grid media take the same path. At a real
collision the weight holds ``σ_s / p̄``: the scattering albedo ``σ_s / σ_t`` for a grey medium.

**Transmittance of a shadow ray** (:func:`transmittance`): the product of the media's
transmittances between the surfaces on the ray (``exp(−σ_t d)`` in closed form in homogeneous
media, ratio tracking ``T ← T σ_n / σ̄`` in heterogeneous ones) and of each surface's
``eval_null_transmission`` — 1 for a ``null`` boundary, ``1 − opacity`` for a ``mask``, ``1 − R``
for a ``thindielectric``, 0 for an opaque or refracting surface — as ``volpath``'s next-event
estimation computes it.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from .arrays import channel_mean
from .bsdf import beyond, is_null
from .sampling import rng

MAX_EVENTS = 256  # null collisions + boundary crossings in one free flight or transmittance ray


def scene_media(scene: mi.Scene) -> list:
    """The distinct ``mi.Medium`` objects of ``scene`` (shape interiors and exteriors, sensors,
    emitters)."""
    found = {}
    candidates = []
    for shape in scene.shapes():
        candidates += [shape.interior_medium(), shape.exterior_medium()]
    candidates += [s.get_medium() for s in scene.sensors()]
    candidates += [e.get_medium() for e in scene.emitters()]
    for medium in candidates:
        if medium is not None:
            found.setdefault(medium.ptr, medium)
    return list(found.values())


def channel(gen: mi.PCG32) -> mi.UInt32:
    """A colour channel drawn uniformly per lane: the one that samples a distance (``volpath``)."""
    n = dr.size_v(mi.Spectrum)
    return dr.minimum(mi.UInt32(gen.next_float32() * n), n - 1)


def pick(spectrum: mi.Spectrum, ch: mi.UInt32) -> mi.Float:
    """Component ``ch`` of ``spectrum`` per lane."""
    return dr.select(ch == 0, spectrum[0], dr.select(ch == 1, spectrum[1], spectrum[2]))


def enter(
    si: mi.SurfaceInteraction3f, d: mi.Vector3f, medium: mi.MediumPtr, active
) -> mi.MediumPtr:
    """The medium a ray leaving ``si`` along ``d`` travels in: ``si.target_medium(d)`` at a medium
    transition, else ``medium`` (``volpath``)."""
    change = active & si.is_valid() & si.is_medium_transition()
    return dr.select(change, si.target_medium(d), medium)


def broadcast(medium: mi.Medium | None, n: int) -> mi.MediumPtr:
    """``medium`` (a scene's medium or None) in every one of ``n`` lanes."""
    return dr.gather(mi.MediumPtr, mi.MediumPtr(medium), dr.zeros(mi.UInt32, n))


def full_width(ray: mi.Ray3f, n: int) -> mi.Ray3f:
    """A copy of ``ray`` with every field ``n`` lanes wide (loop variables must be full width)."""
    zero = dr.zeros(mi.Float, n)
    return mi.Ray3f(ray.o + zero, ray.d + zero, ray.maxt + zero, ray.time + zero, ray.wavelengths)


def interaction(
    p: mi.Point3f, d: mi.Vector3f, t: mi.Float, medium: mi.MediumPtr
) -> mi.MediumInteraction3f:
    """A medium interaction at ``p`` on a ray travelling along ``d`` (``wi = −d``, as
    ``sample_interaction`` sets it), for phase-function and coefficient queries."""
    mei = dr.zeros(mi.MediumInteraction3f, dr.width(p))
    mei.p = mi.Point3f(p)
    mei.wi = -mi.Vector3f(d)
    mei.sh_frame = mi.Frame3f(mei.wi)
    mei.t = mi.Float(t)
    mei.medium = mi.MediumPtr(medium)
    return mei


ESCAPE_FREE_PATHS = 10.0  # an escaping ray is marched this many mean free paths beyond the scene


def escape_length(
    scene: mi.Scene, ray: mi.Ray3f, medium: mi.MediumPtr, active: mi.Bool
) -> mi.Float:
    """How far to march ``ray`` when it leaves the scene inside ``medium`` (e.g. the sensor's
    medium around everything): to the exit of the medium's bounding box where it has one
    (a grid volume), else to the exit of the scene's bounding box and then
    :data:`ESCAPE_FREE_PATHS` mean free paths (σ_t at the ray's origin) further, beyond which
    less than e⁻¹⁰ of the light remains."""
    _, _, medium_exit = medium.intersect_aabb(ray)
    box = scene.bbox()
    lo, hi = mi.Point3f(box.min), mi.Point3f(box.max)
    inv = dr.rcp(ray.d)
    far = dr.maximum((lo - ray.o) * inv, (hi - ray.o) * inv)
    scene_exit = dr.maximum(dr.min(far), 0.0)
    _, _, sigma_t = medium.get_scattering_coefficients(
        interaction(ray.o, ray.d, 0.0, medium), active
    )
    further = ESCAPE_FREE_PATHS / dr.maximum(channel_mean(sigma_t), 1e-6)
    return dr.select(dr.isfinite(medium_exit), medium_exit, scene_exit + further)


@dataclass
class Segments:
    """Pieces of eye paths inside media, recorded for ray marching: origin, unit direction,
    length, medium, the path throughput at the origin and the lane (eye path) that owns it."""

    origin: mi.Point3f
    direction: mi.Vector3f
    length: mi.Float
    medium: mi.MediumPtr
    weight: mi.Spectrum
    lane: mi.UInt32

    @property
    def count(self) -> int:
        return dr.width(self.lane)


INFER_RAYS = 64  # rays that find the medium around an emitter without one (emitter_media)


def emitter_media(scene: mi.Scene) -> list:
    """The medium each of ``scene.emitters()`` emits into: the ``medium`` the file gives it, else
    for an area light its shape's exterior medium (the side its normals face, where it emits),
    else the medium around it — found, as ``volpath`` would see it, from :data:`INFER_RAYS`
    rays in spread directions from the emitter's position (an area light's: points on its shape,
    just off the side it emits from): the first medium transition each ray meets says on which of
    its sides the ray started (``si.target_medium(−d)``), and the medium most of them agree on is
    the emitter's (None: vacuum). Directional and environment emitters are outside everything."""
    media = []
    if not scene_media(scene):
        return [None] * len(scene.emitters())
    for emitter in scene.emitters():
        medium, shape = emitter.get_medium(), emitter.get_shape()
        if medium is None and shape is not None:
            medium = shape.exterior_medium() or _surrounding_medium(scene, emitter, shape)
        elif medium is None and not _is_infinite(emitter):
            medium = _surrounding_medium(scene, emitter, None)
        media.append(medium)
    return media


def _is_infinite(emitter: mi.Emitter) -> bool:
    return mi.has_flag(emitter.flags(), mi.EmitterFlags.Infinite) or mi.has_flag(
        emitter.flags(), mi.EmitterFlags.DeltaDirection
    )


def _surrounding_medium(scene: mi.Scene, emitter: mi.Emitter, shape) -> mi.Medium | None:
    """The medium most of :data:`INFER_RAYS` rays from ``emitter`` find themselves in."""
    gen = rng(INFER_RAYS, 0x6D656469, 0)
    u = mi.Point2f(gen.next_float32(), gen.next_float32())
    d = mi.warp.square_to_uniform_sphere(mi.Point2f(gen.next_float32(), gen.next_float32()))
    if shape is not None:
        ps = shape.sample_position(0.0, u)
        d = dr.mulsign(d, dr.dot(d, ps.n))  # leave on the side the light is emitted to
        zero = dr.zeros(mi.Float, INFER_RAYS)
        ray = mi.Interaction3f(zero, zero, dr.zeros(mi.Color0f), ps.p, ps.n).spawn_ray(d)
    else:
        ray = emitter.sample_ray(0.0, 0.5, u, mi.Point2f(gen.next_float32(), gen.next_float32()))[0]
        ray = mi.Ray3f(ray.o, d)
    medium, met = first_transition_medium(scene, ray)
    best, most = None, 0
    for candidate in [None, *scene_media(scene)]:
        votes = dr.count(met & (medium == mi.MediumPtr(candidate)))[0]
        if votes > most:
            best, most = candidate, votes
    return best


def first_transition_medium(scene: mi.Scene, ray: mi.Ray3f) -> tuple[mi.MediumPtr, mi.Bool]:
    """Per ray: the medium on the side facing the ray's origin of the first medium transition it
    meets (the medium around the origin, as the shapes say), and whether it met one; surfaces
    that are not transitions are passed."""
    n = dr.width(ray.d)
    ray = full_width(ray, n)
    medium = dr.zeros(mi.MediumPtr, n)
    met = dr.zeros(mi.Bool, n)
    going = dr.full(mi.Bool, True, n)
    for _ in range(MAX_EVENTS // 16):
        si = scene.ray_intersect(ray, going)
        hit = going & si.is_valid()
        transition = hit & si.is_medium_transition()
        medium = dr.select(transition, si.target_medium(-ray.d), medium)
        met |= transition
        going = hit & ~transition
        ray = dr.select(going, si.spawn_ray(ray.d), ray)
        if not dr.any(going, axis=None):
            break
    return medium, met


@dataclass
class Flight:
    """Result of :func:`free_flight` per lane: ``scattered`` — a real collision at ``mei``;
    otherwise the ray ended at ``si`` (a surface that is not ``null``, or an invalid hit: it
    escaped). ``weight``: ``T/p`` along the flight (``σ_s T / p`` where it scattered);
    ``medium``: the medium at the end (where ``si`` is hit)."""

    si: mi.SurfaceInteraction3f
    mei: mi.MediumInteraction3f
    weight: mi.Spectrum
    scattered: mi.Bool
    medium: mi.MediumPtr


@dr.syntax
def collide(
    ray: mi.Ray3f,
    length: mi.Float,
    medium: mi.MediumPtr,
    gen: mi.PCG32,
    active: mi.Bool,
) -> tuple[mi.Bool, mi.MediumInteraction3f, mi.Spectrum]:
    """Sample a real collision of ``ray`` (unit direction) in ``medium`` within ``[0, length]``
    (no surface on the way): ``(scattered, mei, weight)``, ``weight`` = ``T/p̄`` to the end of
    the piece or ``σ_s T / p̄`` at the collision (module docstring: delta tracking against the
    majorant, each distance in a fresh channel, ``p̄`` the channels' mean pdf); nothing happens
    in vacuum (``medium`` None)."""
    n = dr.width(active)
    ray = full_width(ray, n)
    ray.maxt = mi.Float(length) + dr.zeros(mi.Float, n)
    weight = dr.full(mi.Spectrum, 1.0, n)
    mei = dr.zeros(mi.MediumInteraction3f, n)
    scattered = dr.zeros(mi.Bool, n)
    going = active & (medium != None)  # noqa: E711 (Dr.Jit pointer test)
    events = dr.zeros(mi.UInt32, n)
    while going & (events < MAX_EVENTS):
        m = medium.sample_interaction(ray, gen.next_float32(), channel(gen), going)
        hit = going & m.is_valid() & (m.t < ray.maxt)
        m.t = dr.select(hit, m.t, dr.inf)
        end = dr.zeros(mi.SurfaceInteraction3f, n)
        end.t = ray.maxt
        tr, pdf = medium.transmittance_eval_pdf(m, end, going)
        p_mean = channel_mean(pdf)
        weight[going] *= dr.select(p_mean > 0, tr / p_mean, 0.0)
        real_p = dr.select(hit, channel_mean(m.sigma_t / dr.maximum(m.combined_extinction, 1e-30)), 1.0)
        real = hit & (gen.next_float32() < real_p)
        null_hit = hit & ~real
        weight[null_hit] *= m.sigma_n / dr.maximum(1.0 - real_p, 1e-30)
        weight[real] *= m.sigma_s / real_p
        scattered |= real
        mei[real] = m
        ray.o[null_hit] = m.p
        ray.maxt[null_hit] = ray.maxt - m.t
        going = null_hit & dr.any(weight != 0.0)
        events += 1
    return scattered, mei, weight


@dr.syntax
def free_flight(
    scene: mi.Scene,
    ray: mi.Ray3f,
    medium: mi.MediumPtr,
    gen: mi.PCG32,
    ch: mi.UInt32,
    active: mi.Bool,
    collisions: bool = True,
) -> Flight:
    """Sample where ``ray`` (unit direction) next interacts: a real collision in a medium
    (:func:`collide`, piece by piece) or the next non-``null`` surface (module docstring).
    ``ch``: the sampling channel per lane (:func:`channel`). Without ``collisions`` the ray goes
    to the next non-``null`` surface (or out of the scene) and its weight is the transmittance
    of the media on the way (:func:`segment_transmittance`)."""
    n = dr.width(active)
    ray = full_width(ray, n)
    medium = mi.MediumPtr(medium)
    weight = dr.full(mi.Spectrum, 1.0, n)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    mei = dr.zeros(mi.MediumInteraction3f, n)
    scattered = dr.zeros(mi.Bool, n)
    going = mi.Bool(active)
    crossings = dr.zeros(mi.UInt32, n)
    while going & (crossings < MAX_EVENTS):
        si_next = scene.ray_intersect(ray, going)
        si[going] = si_next
        length = dr.minimum(ray.maxt, si.t)
        if dr.hint(collisions, mode="scalar"):
            real, m, w = collide(ray, length, medium, gen, going)
            weight[going] *= w
            scattered |= real
            mei[real] = m
        else:
            real = dr.zeros(mi.Bool, n)
            weight[going] *= segment_transmittance(ray, length, medium, gen, ch, going)
        # the surface at the end of the piece: a null boundary switches the medium only
        surface = going & ~real & si.is_valid()
        cross = surface & is_null(si.bsdf(ray), surface) & (si.emitter(scene) == None)  # noqa: E711
        medium = enter(si, ray.d, medium, cross)
        ray[cross] = beyond(si, ray)
        going = cross & dr.any(weight != 0.0)
        crossings += 1
    return Flight(si, mei, weight, scattered, medium)


@dr.syntax
def segment_transmittance(
    ray: mi.Ray3f,
    length: mi.Float,
    medium: mi.MediumPtr,
    gen: mi.PCG32,
    ch: mi.UInt32,
    active: mi.Bool,
) -> mi.Spectrum:
    """Transmittance of ``medium`` over ``[0, length]`` of ``ray`` (unit direction; no surface on
    the way): ``exp(−σ_t length)`` in a homogeneous medium, ratio tracking (``T ← T σ_n / σ̄`` at
    each tentative collision against the majorant σ̄, in channel ``ch``) in a heterogeneous one;
    1 in vacuum (``medium`` None)."""
    n = dr.width(active)
    ray = full_width(ray, n)
    ray.maxt = dr.select(active, length, 0.0)
    in_medium = active & (medium != None)  # noqa: E711
    homogeneous = in_medium & medium.is_homogeneous()
    _, _, sigma_t = medium.get_scattering_coefficients(
        interaction(ray.o, ray.d, 0.0, medium), homogeneous
    )
    T = dr.full(mi.Spectrum, 1.0, n)
    T[homogeneous] = dr.exp(-sigma_t * length)
    tracking = in_medium & ~homogeneous
    events = dr.zeros(mi.UInt32, n)
    while tracking & (events < MAX_EVENTS):
        m = medium.sample_interaction(ray, gen.next_float32(), ch, tracking)
        collide = tracking & m.is_valid() & (m.t < ray.maxt)
        dist = dr.select(collide, m.t, ray.maxt) - m.mint
        tr = dr.exp(-dist * m.combined_extinction)
        pdf = pick(dr.select(collide, tr * m.combined_extinction, tr), ch)
        T[tracking] *= dr.select(pdf > 0, tr / pdf, 0.0)
        T[collide] *= m.sigma_n
        ray.o[collide] = m.p
        ray.maxt[collide] = ray.maxt - m.t
        tracking = collide & dr.any(T != 0.0)
        events += 1
    return T


def transmittance(
    scene: mi.Scene,
    ray: mi.Ray3f,
    medium: mi.MediumPtr,
    gen: mi.PCG32,
    ch: mi.UInt32,
    active: mi.Bool,
) -> mi.Spectrum:
    """Transmittance along the finite ``ray`` (unit direction, length ``ray.maxt``) starting in
    ``medium``: the media's transmittances between the surfaces on it times each surface's
    ``eval_null_transmission`` (module docstring); zero behind an opaque surface."""
    return walk(scene, ray, medium, gen, ch, active, False)[1]


@dr.syntax
def walk(scene, ray, medium, gen, ch, active, to_emitter: bool):
    """``ray``'s walk through the surfaces that let light pass (module docstring): ``(si, T)``,
    the surface it stopped at — with ``to_emitter`` the first emitter's (invalid where the ray
    escaped: the environment) — and the transmittance up to there."""
    n = dr.width(active)
    ray = full_width(ray, n)
    medium = mi.MediumPtr(medium)
    T = dr.full(mi.Spectrum, 1.0, n)
    T[~active] = 0.0
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    going = mi.Bool(active)
    crossings = dr.zeros(mi.UInt32, n)
    while going & (crossings < MAX_EVENTS):
        si_next = scene.ray_intersect(ray, going)
        si[going] = si_next
        T[going] *= segment_transmittance(ray, dr.minimum(si.t, ray.maxt), medium, gen, ch, going)
        through = going & si.is_valid()
        if dr.hint(to_emitter, mode="scalar"):
            through &= si.emitter(scene) == None  # noqa: E711
        T[through] *= mi.Spectrum(si.bsdf(ray).eval_null_transmission(si, through))
        medium = enter(si, ray.d, medium, through)
        ray[through] = beyond(si, ray)
        going = through & dr.any(T != 0.0)
        crossings += 1
    return si, T


def isotropic(scene: mi.Scene) -> bool:
    """Whether every medium of ``scene`` has an isotropic phase function."""
    return all(
        mi.has_flag(m.phase_function().flags(), mi.PhaseFunctionFlags.Isotropic)
        for m in scene_media(scene)
    )


def within_extent(mei: mi.MediumInteraction3f) -> mi.Bool:
    """Whether ``mei.p`` lies where ``mei.medium`` exists: inside a grid volume's bounding box
    (Mitsuba's heterogeneous medium has interactions only there, while its grid lookups clamp
    to the border values outside it), everywhere for a homogeneous medium."""
    hit, mint, maxt = mei.medium.intersect_aabb(mi.Ray3f(mei.p, mi.Vector3f(0, 0, 1)))
    return hit & (mint <= 0) & (maxt >= 0)


