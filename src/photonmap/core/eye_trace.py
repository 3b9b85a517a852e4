"""The eye-path loop of the transport core: camera (or final-gather) rays followed through
mirrors, glass and media to the vertex where a method's estimate takes over (Steinhurst 2007
§2.6.2, §7.3.2; Hachisuka & Jensen 2009 §4; Jensen & Christensen 1998; Mitsuba's ``volpath``).

"If the surface is highly specular (mirror/glass), reflect/refract and continue until a
non-specular object is found" [Steinhurst §7.3.2]. Every BSDF is handled through Mitsuba's own
interface, split into the lobes the path *follows* — delta lobes and ``Null`` lobes (``mask``,
``thindielectric`` transmission) — and the smooth (diffuse, glossy) lobes where it *ends*, as a
visible point that photons and direct light then shade (their BSDF queries see only the smooth
lobes: a delta lobe evaluates to zero):

- only followed lobes (mirror, glass, thin glass): sample them, go on;
- only smooth lobes: end here;
- both (``plastic``, ``mask``, ``blendbsdf`` of glass and diffuse): sample the BSDF; the weight
  ``w`` of a sample that picked a followed lobe (0 otherwise) is an unbiased estimate of their
  share; go on with probability ``q = clamp(max w, 0.2, 0.8)`` (0 where ``w = 0``) carrying
  ``w / q``, else end here carrying ``1 / (1 − q)`` — an unbiased split of one path into the two
  parts. (A ``BSDFContext`` restricted to some lobes is not honoured by every BSDF: a ``mask``
  asked for its smooth lobes samples its Null lobe.)

With ``rough_glass`` (the surface method) rough glass is followed as glass is, whatever lobe its
sample picks (:func:`~photonmap.core.bsdf.is_rough_glass`: a visible point there would need a
photon density estimate of its near-specular transmission, which blurs what lies behind it).
Unlike glass, rough glass scatters light from every direction towards the path: with
``emission`` each rough-glass vertex adds next-event estimation of its glossy lobes, weighted
against the BSDF sample's later emitter hits by MIS, as at a smooth vertex of ``"continue"`` —
without it a point, spot or directional light seen through rough glass, or its highlight on it,
is never found (BSDF sampling cannot hit a delta light).

A ``Null`` lobe passes the ray straight on and is no interaction (``volpath``: it adds no depth).
Medium is optional state (vacuum is the case without one). In a medium the flight is one of:

- ``"transmit"``: the throughput takes the transmittance of every piece (nothing scatters; the
  paths that only look for emitters);
- ``"march"``: as ``"transmit"``, and each piece inside a medium is recorded
  (:class:`~photonmap.core.media.Segments`, the first ``segments`` of a path) for the caller to
  ray-march its in-scattered light (Jensen & Christensen 1998);
- ``"end"``: a free flight (:func:`~photonmap.core.media.free_flight`) that may end the path at a
  medium collision, returned as a medium vertex (the surface method's volume photon map reads
  the in-scattered light there, Jensen & Christensen 1998);
- ``"continue"``: volumetric path tracing — each piece of the path inside a medium adds its
  single scattering of direct light, ``∫ T(t) σ_s f_p L_e T_e / p dt``, from one equiangular
  point (Kulla & Fajardo 2012: distances drawn ∝ ``1/r²`` about a point on the emitters, where a
  point or spot light's peak would rarely be found by collisions) with a transmittance shadow ray;
  a free-flight collision in the piece (delta tracking) then carries the rest: ``medium_light``
  there (the light no eye path can find: volume caustics from photons) and a phase-function
  sample that continues the path. Unbiased as ``volpath``, with direct light from the pieces.

At a smooth surface vertex the path ends (``surfaces="stop"``: the visible point of a photon
method) or goes on as in Mitsuba's ``path`` (``surfaces="continue"``): next-event estimation of
the smooth lobes (:func:`~photonmap.core.direct.emitter_sampled`) and a BSDF sample that goes on,
the two combined by multiple importance sampling.

Emitters met on the way add ``β L_e``: after the camera or a chain of followed lobes from it
(when ``emission``; hidden on the first segment with ``hide_emitters``, as Mitsuba hides area
emitters and the environment seen directly); right after a medium collision never (the pieces'
direct light holds it); right after a smooth surface vertex with the MIS weight of BSDF
sampling; after a collision or a smooth vertex and then a delta chain not when ``caustics`` are
given: photons carry that light (:class:`Caustics`, read at each medium collision and smooth
surface vertex). Depth counts segments as Mitsuba's
``max_depth`` does; Russian roulette from ``rr_depth`` on, ``q = min(0.95, max β · η²)``.

A method with a vertex rule of its own (``EyeRules.vertex``, an :class:`EyeVertexRule`: VCM's
camera subpaths) does the work at every surface itself — the emission met and its own
techniques at a smooth vertex, its per-path state around the BSDF sample the loop takes — and
the loop goes on from every surface by that sample (a ``Null`` event counts as a vertex, and
``null`` shapes are hit).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from .bsdf import intersect_visible, is_rough_glass
from .direct import emitter_sampled, light_sample, nee_weighted, piece_direct, power_heuristic
from .eye_rules import Caustics, EyeRules, EyeVertexRule, EyeVertices
from .media import (
    Segments,
    channel,
    collide,
    enter,
    escape_length,
    free_flight,
    segment_transmittance,
)
from .rows import Rows
from .scene_info import SceneTraits
from .settings import UNBOUNDED, PathSettings, survival

MAX_EVENTS = 1024  # loop iterations of one eye path at most (Null-lobe passes included)
FOLLOWED = mi.BSDFFlags.Delta | mi.BSDFFlags.Null
SEGMENT_ROWS = Rows.of(Segments)
SPLIT_MIN, SPLIT_MAX = 0.2, 0.8  # the clamp of q at a BSDF with followed and smooth lobes

# where the path's last scattering was, which decides whether an emitter hit counts
FROM_CAMERA, FROM_MEDIUM, THROUGH_DELTA, FROM_SURFACE = 0, 1, 2, 3


def trace_eye_paths(
    scene: mi.Scene,
    rays: tuple,
    gen: mi.PCG32,
    rules: EyeRules,
    *,
    caustics: Caustics | None = None,
    start_depth: int | mi.UInt32 = 0,
    active: mi.Bool | None = None,
) -> EyeVertices:
    """Follow ``rays = (ray, weight, medium)`` (unit directions, their throughput, the medium
    where they start) to their vertices by ``rules`` (module docstring). ``caustics``: photon
    estimates read along the paths (:class:`Caustics`); ``start_depth``: segments before these
    rays (per lane for a final gather; rays from the camera start at 0). The result is
    evaluated."""
    ray, weight, medium = rays
    settings, traits, segments = rules.settings, rules.traits, rules.segments
    n = max(dr.width(ray.o), dr.width(ray.d), dr.width(weight), dr.width(medium))
    active = dr.full(mi.Bool, True, n) if active is None else mi.Bool(active)
    zero = dr.zeros(mi.Float, n)
    ray = mi.Ray3f(ray.o + zero, ray.d + zero, ray.maxt + zero, ray.time + zero, ray.wavelengths)
    if dr.width(medium) != n:
        medium = dr.gather(mi.MediumPtr, mi.MediumPtr(medium), dr.zeros(mi.UInt32, n))
    marching = rules.media_mode == "march" and traits.media
    slots = n * segments if marching else 1
    buffers = SEGMENT_ROWS.empty(slots)  # slot = piece · n + lane; read where stored only
    stored = dr.zeros(mi.Bool, slots)
    walk = _Walk.start(
        ray, mi.Spectrum(weight) * dr.ones(mi.Float, n), mi.MediumPtr(medium), start_depth,
        active & dr.full(mi.Bool, True, n), rules.vertex.extra() if rules.vertex else None,
    )  # fmt: skip
    if rules.vertex is not None:  # in memory: the literals a rule's loop changes (a changed
        dr.make_opaque(walk.radiance, walk.eta, walk.depth, walk.extra)  # literal is refused)
    vertex_rules = _Rules(
        media=traits.media,
        media_mode=rules.media_mode if traits.media else "transmit",  # vacuum: no collisions
        continuing=rules.surfaces == "continue",
        emission=rules.emission,
        hide=settings.hide_emitters and isinstance(start_depth, int) and start_depth == 0,
        photons_carry=caustics is not None,
        rough_glass=rules.rough_glass,
        rough_nee=rules.rough_glass and rules.emission and rules.surfaces == "stop"
        and traits.rough_glass,
        max_pieces=segments,
        settings=settings,
        traits=traits,
        vertex=rules.vertex,
    )  # fmt: skip
    vertices = _follow(scene, walk, gen, vertex_rules, caustics or Caustics(), (buffers, stored))
    # every output at once: evaluating one output of a symbolic loop runs the whole loop again
    dr.eval(*(v for v in vars(vertices).values() if v is not None), buffers, stored)
    if marching:
        vertices.segments = Segments(*SEGMENT_ROWS.read(buffers, dr.compress(stored)))
    return vertices


@dataclass
class _Walk:
    """The loop state of the eye paths (one lane a path) and the vertices where they ended."""

    ray: mi.Ray3f
    beta: mi.Spectrum  # throughput so far
    medium: mi.MediumPtr  # the medium the ray travels in
    depth: mi.UInt32  # segments so far
    radiance: mi.Spectrum  # light collected so far
    eta: mi.Float  # product of the relative IORs crossed (Russian roulette's η²)
    bounces: mi.UInt32  # followed (delta) bounces
    origin: mi.UInt32  # where the last scattering was: FROM_CAMERA, FROM_MEDIUM, ...
    prev_it: mi.Interaction3f  # the last smooth surface vertex, for MIS
    prev_pdf: mi.Float  # its BSDF sample's pdf
    pieces: mi.UInt32  # pieces recorded in media ("march" mode)
    active: mi.Bool
    events: mi.UInt32  # loop iterations so far
    rays: mi.UInt32  # rays cast so far: segments and shadow rays
    # ---- where the paths ended
    si_end: mi.SurfaceInteraction3f
    mei_end: mi.MediumInteraction3f
    beta_end: mi.Spectrum
    medium_end: mi.MediumPtr
    found: mi.Bool  # on a smooth surface
    in_medium: mi.Bool  # at a medium collision ("end" mode)
    extra: object = None  # the vertex rule's per-path state

    @staticmethod
    def start(ray, beta, medium, start_depth, active, extra=None) -> _Walk:
        """Paths at the start of ``ray``, none ended yet (every variable at full width)."""
        n = dr.width(beta)
        return _Walk(
            ray, beta, medium,
            mi.UInt32(start_depth) + dr.zeros(mi.UInt32, n), dr.zeros(mi.Spectrum, n),
            dr.ones(mi.Float, n), dr.zeros(mi.UInt32, n), dr.full(mi.UInt32, FROM_CAMERA, n),
            dr.zeros(mi.Interaction3f, n), dr.zeros(mi.Float, n), dr.zeros(mi.UInt32, n),
            active, dr.zeros(mi.UInt32, n), dr.zeros(mi.UInt32, n),
            dr.zeros(mi.SurfaceInteraction3f, n), dr.zeros(mi.MediumInteraction3f, n),
            dr.zeros(mi.Spectrum, n), dr.zeros(mi.MediumPtr, n), dr.zeros(mi.Bool, n),
            dr.zeros(mi.Bool, n), extra,
        )  # fmt: skip

    def vertices(self) -> EyeVertices:
        return EyeVertices(
            self.si_end, self.mei_end, self.beta_end, self.radiance, self.found, self.in_medium,
            self.depth, self.medium_end, self.bounces, self.rays,
        )  # fmt: skip


@dataclass(frozen=True)
class _Rules:
    """What :func:`_follow` does at each kind of vertex (see :func:`trace_eye_paths`); Python
    values only, read while the loop is traced."""

    media: bool  # the scene has media (else the flight is through vacuum)
    media_mode: str
    continuing: bool  # surfaces="continue"
    emission: bool
    hide: bool  # hide emitters on the first segment
    photons_carry: bool  # caustics are given: photons carry the light after a delta chain
    rough_glass: bool
    rough_nee: bool  # next-event estimation at rough-glass vertices (rough_glass and emission)
    max_pieces: int
    settings: PathSettings
    traits: SceneTraits
    vertex: EyeVertexRule | None


@dr.syntax
def _follow(scene, walk: _Walk, gen, rules: _Rules, caustics: Caustics, pieces):
    """The loop of :func:`trace_eye_paths` (module docstring) from ``walk``'s start: one
    iteration flies to the next vertex (:func:`_fly`), adds the emission met there
    (:func:`_emission_met`), handles a medium collision (:func:`_medium_vertex`) or a surface
    (:func:`_surface_vertex`) and plays Russian roulette. ``pieces``: the slots of the pieces in
    media and where they were stored ("march" mode). Returns the :class:`EyeVertices` (lazy)."""
    buffers, stored = pieces
    n = dr.width(walk.beta)
    settings = rules.settings
    max_depth = settings.max_depth if settings.max_depth != UNBOUNDED else 2**31 - 1
    max_depth = dr.opaque(mi.UInt32, max_depth)
    rr_depth = dr.opaque(mi.UInt32, settings.rr_depth)
    medium_light, surface_light = caustics.medium, caustics.surface
    null_shapes = False if rules.vertex else rules.traits.null_shapes  # a rule's: vertices
    ch = channel(gen)
    lane = dr.arange(mi.UInt32, n)
    stride = dr.opaque(mi.UInt32, n)  # not a literal: one kernel for every size
    record = (buffers, stored, lane, stride)
    while dr.hint(walk.active & (walk.events < MAX_EVENTS), exclude=[rules]):
        si, mei, scattered = _fly(scene, walk, gen, ch, max_depth, rules, null_shapes, record)
        surface = walk.active & ~scattered & si.is_valid()
        escaped = walk.active & ~scattered & ~si.is_valid()
        arrived = walk.depth + 1  # segments to this vertex
        emitter = _emission_met(scene, walk, si, scattered, arrived, rules)
        walk.active &= ~escaped
        _medium_vertex(walk, mei, scattered, arrived, max_depth, gen, rules, medium_light)
        bounced = _surface_vertex(
            scene, walk, (si, surface, emitter, arrived), max_depth, gen, rules, surface_light
        )
        # ---- Russian roulette (Mitsuba's path tracers)
        rolled = walk.active & (bounced | scattered) & (walk.depth >= rr_depth)
        survive = survival(walk.beta, eta=walk.eta)
        walk.beta[rolled] /= survive
        walk.active &= ~rolled | (gen.next_float32() < survive)
        walk.active &= dr.any(walk.beta != 0.0)
        walk.events += 1
        walk.rays += 1  # the segment's ray (shadow rays are counted where they are cast)
    return walk.vertices()


def _fly(scene, walk: _Walk, gen, ch, max_depth, rules: _Rules, null_shapes, record):
    """To the next vertex: a medium collision or the next surface. In media one piece at a time
    (``null`` boundaries are passed as surfaces) in ``"march"`` mode, recorded for the caller,
    and in ``"continue"`` mode, whose pieces add their direct in-scattering by an equiangular
    point before a collision in them is sampled; a free flight otherwise. Returns ``(si, mei,
    scattered)`` (``mei`` None where no collision can happen)."""
    ray, medium, active = walk.ray, walk.medium, walk.active
    scattered = dr.zeros(mi.Bool, dr.width(active))
    mei = None
    if not rules.media:
        si = intersect_visible(scene, ray, active, null_shapes)
    elif rules.media_mode == "march":
        buffers, stored, lane, stride = record
        si = scene.ray_intersect(ray, active)
        in_medium = active & (medium != None)  # noqa: E711
        length = dr.select(si.is_valid(), si.t, escape_length(scene, ray, medium, in_medium))
        recorded = in_medium & (walk.pieces < rules.max_pieces)
        slot = walk.pieces * stride + lane
        SEGMENT_ROWS.write(buffers, (ray.o, ray.d, length, medium, walk.beta, lane), slot, recorded)
        dr.scatter(stored, True, slot, recorded)
        walk.pieces[recorded] += 1
        walk.beta[in_medium] *= segment_transmittance(ray, length, medium, gen, ch, in_medium)
    elif rules.media_mode == "continue":
        si = scene.ray_intersect(ray, active)
        in_medium = active & (medium != None)  # noqa: E711
        length = dr.select(si.is_valid(), si.t, escape_length(scene, ray, medium, in_medium))
        lit = in_medium & (walk.depth + 2 <= max_depth)
        walk.radiance[lit] += walk.beta * piece_direct(scene, ray, length, medium, gen, ch, lit)
        walk.rays[lit] += 1
        scattered, mei, weight = collide(ray, length, medium, gen, in_medium)
        walk.beta[in_medium] *= weight
    else:
        flight = free_flight(scene, ray, medium, gen, ch, active, rules.media_mode == "end")
        si, mei = flight.si, flight.mei
        walk.beta[active] *= flight.weight
        scattered = active & flight.scattered
        walk.medium = dr.select(active, flight.medium, medium)
    return si, mei, scattered


def _emission_met(scene, walk: _Walk, si, scattered, arrived, rules: _Rules):
    """Add ``β L_e`` of an emitter's surface or the environment met where it counts (module
    docstring); returns the emitter met. A vertex rule adds what it counts itself."""
    active = walk.active & ~scattered
    if rules.vertex is not None:
        rules.vertex.arrive(walk, si, arrived, active & si.is_valid())
        return None
    emitter = si.emitter(scene, active)
    shown = active & (emitter != None)  # noqa: E711 (Dr.Jit pointer test)
    if rules.hide:
        shown &= arrived > 1
    if not rules.emission:
        shown &= walk.origin != FROM_CAMERA
    shown &= walk.origin != FROM_MEDIUM  # the pieces' direct in-scattering holds that light
    if rules.photons_carry:
        shown &= walk.origin != THROUGH_DELTA
    w_em = dr.ones(mi.Float, dr.width(active))
    if rules.continuing or rules.rough_nee:
        after = shown & (walk.origin == FROM_SURFACE)
        ds = mi.DirectionSample3f(scene, si, walk.prev_it)
        pdf_em = scene.pdf_emitter_direction(walk.prev_it, ds, after)
        w_em[after] = power_heuristic(walk.prev_pdf, pdf_em)
    walk.radiance[shown] += walk.beta * w_em * emitter.eval(si, shown)
    return emitter


def _medium_vertex(walk: _Walk, mei, scattered, arrived, max_depth, gen, rules, medium_light):
    """A medium collision: the path ends there (``"end"``) or, in ``"continue"`` mode, adds the
    photons' in-scattered light (``medium_light``: volume caustics) and goes on in a direction
    sampled from the phase function."""
    if rules.media_mode == "end":
        walk.mei_end[scattered] = mei
        walk.beta_end[scattered] = walk.beta
        walk.medium_end[scattered] = walk.medium
        walk.in_medium |= scattered
        walk.depth[scattered] = arrived
        walk.active &= ~scattered
    elif rules.media_mode == "continue":
        walk.depth[scattered] = arrived
        room = scattered & (arrived < max_depth)  # a next segment fits
        if medium_light is not None:
            sigma_s = mi.Spectrum(mei.sigma_s)
            L_s = medium_light(mei, max_depth - arrived, room)
            walk.radiance[room] += walk.beta * dr.select(sigma_s > 0, L_s / sigma_s, 0.0)
        wo, phase_weight, phase_pdf = mei.medium.phase_function().sample(
            mi.PhaseFunctionContext(None), mei, gen.next_float32(),
            mi.Point2f(gen.next_float32(), gen.next_float32()), room,
        )  # fmt: skip
        walk.beta[scattered] *= phase_weight
        walk.origin[scattered] = FROM_MEDIUM
        walk.ray[scattered] = mei.spawn_ray(wo)
        walk.active &= ~scattered | (room & (phase_pdf > 0))


def _surface_vertex(scene, walk: _Walk, vertex, max_depth, gen, rules: _Rules, surface_light):
    """A surface ``vertex = (si, surface, emitter, arrived)`` (the hit, the lanes on a surface,
    the emitter there, the segments to it): end on its smooth lobes or follow its delta /
    ``Null`` lobes (``surfaces="stop"``, :func:`_end_or_follow`), or shade the smooth lobes and
    go on with the BSDF sample (``"continue"``, :func:`_shade_and_go_on`). Returns where a bounce
    (not a ``Null`` pass) continued the path."""
    if rules.vertex is not None:
        return _rule_vertex(walk, vertex, max_depth, gen, rules.vertex)
    si, surface, emitter, arrived = vertex
    n = dr.width(surface)
    bsdf = si.bsdf(walk.ray)
    skip = dr.zeros(mi.Bool, n)  # hidden area emitters seen directly are passed
    if rules.hide:
        skip = surface & (emitter != None) & (arrived == 1)  # noqa: E711
    u = gen.next_float32(), mi.Point2f(gen.next_float32(), gen.next_float32())
    if rules.continuing:
        bs, w_follow, go_on, q, whole = _shade_and_go_on(
            scene, walk, (si, bsdf, surface & ~skip, arrived), u, max_depth, gen, rules,
            surface_light,
        )  # fmt: skip
        go_on |= skip
    else:
        bs, w_follow, go_on, q, whole = _end_or_follow(
            scene, walk, (si, bsdf, surface, arrived), skip, u, max_depth, gen, rules
        )
    followed = (mi.has_flag(bs.sampled_type, FOLLOWED) | whole) & (bs.pdf > 0)
    passed = skip | (go_on & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null))
    bounced = go_on & ~passed
    d = dr.select(skip, walk.ray.d, si.to_world(bs.wo))
    walk.beta[go_on & ~skip] *= w_follow / q
    walk.eta[bounced] *= bs.eta
    delta = bounced & followed
    walk.bounces[delta] += 1
    walk.depth[bounced] = arrived
    walk.origin[delta & (walk.origin != FROM_CAMERA)] = THROUGH_DELTA
    if rules.rough_nee:  # its emitter hits take BSDF sampling's MIS weight
        glossy = bounced & whole
        walk.prev_it[glossy] = mi.Interaction3f(si)
        walk.prev_pdf[glossy] = bsdf.pdf(mi.BSDFContext(), si, bs.wo, glossy)
        walk.origin[glossy] = FROM_SURFACE
    walk.medium = enter(si, d, walk.medium, go_on)
    walk.ray[go_on] = si.spawn_ray(d)
    walk.active &= ~surface | (go_on & ((arrived < max_depth) | passed))
    return bounced


def _shade_and_go_on(scene, walk: _Walk, vertex, u, max_depth, gen, rules, surface_light):
    """``surfaces="continue"`` at ``vertex = (si, bsdf, active, arrived)``: next-event
    estimation of the smooth lobes and the photons' light there (``surface_light``), and a
    sample of the whole BSDF (``u``) to go on with — one BSDF call for both, as Mitsuba's
    ``path`` (``eval_pdf_sample``); the sample's own density is what a later emitter hit weighs
    against. Returns ``(bs, weight, go_on, q = 1, whole = False)``."""
    si, bsdf, active, arrived = vertex
    n = dr.width(active)
    smooth = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
    here = active & smooth & (arrived < max_depth)
    u_light = mi.Point2f(gen.next_float32(), gen.next_float32())
    light = light_sample(scene, si, u_light, gen, here, rules.traits, walk.medium)
    f_light, pdf_light, bs, weight = bsdf.eval_pdf_sample(
        mi.BSDFContext(), si, si.to_local(light.ds.d), u[0], u[1], active
    )
    walk.radiance[here] += walk.beta * nee_weighted(light, f_light, pdf_light)
    walk.rays[here] += 1
    if surface_light is not None:
        walk.radiance[here] += walk.beta * surface_light(si, max_depth - arrived, here)
    go_on = active & (bs.pdf > 0)
    picked_smooth = go_on & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Smooth)
    walk.prev_it[picked_smooth] = mi.Interaction3f(si)
    walk.prev_pdf[picked_smooth] = bs.pdf
    walk.origin[picked_smooth] = FROM_SURFACE
    return bs, weight, go_on, dr.ones(mi.Float, n), dr.zeros(mi.Bool, n)


def _end_or_follow(scene, walk: _Walk, vertex, skip, u, max_depth, gen, rules):
    """``surfaces="stop"`` at ``vertex = (si, bsdf, surface, arrived)``: end on the smooth lobes
    or follow a delta / ``Null`` lobe of the BSDF sample ``u`` (module docstring; rough glass
    followed whole with ``rules.rough_glass``, its glossy lobes lit by next-event estimation
    with ``rules.rough_nee``). Returns ``(bs, weight, go_on, q, whole)``: ``q`` the probability
    of going on, ``whole`` the rough glass followed."""
    si, bsdf, surface, arrived = vertex
    n = dr.width(surface)
    smooth = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
    bs, w_follow = bsdf.sample(mi.BSDFContext(), si, u[0], u[1], surface & ~skip)
    whole = dr.zeros(mi.Bool, n)  # rough glass, followed whatever lobe it samples
    if rules.rough_glass:
        whole = is_rough_glass(bsdf, surface)
        smooth &= ~whole
    if rules.rough_nee:
        lit = whole & ~skip & (arrived < max_depth)
        u_light = mi.Point2f(gen.next_float32(), gen.next_float32())
        walk.radiance[lit] += walk.beta * emitter_sampled(
            scene, si, u_light, gen, lit, rules.traits, walk.medium
        )
        walk.rays[lit] += 1
    followed = (mi.has_flag(bs.sampled_type, FOLLOWED) | whole) & (bs.pdf > 0)
    w_follow = dr.select(followed, w_follow, 0.0)  # the followed lobes' share
    w_max = dr.max(w_follow)
    q = dr.select(smooth, dr.select(w_max > 0, dr.clip(w_max, SPLIT_MIN, SPLIT_MAX), 0.0), 1.0)
    go_on = skip | (surface & (gen.next_float32() < q) & followed)
    stop = surface & ~go_on & smooth
    walk.si_end[stop] = si
    walk.beta_end[stop] = walk.beta / (1.0 - q)
    walk.medium_end[stop] = walk.medium
    walk.depth[stop] = arrived
    walk.found |= stop
    return bs, w_follow, go_on, q, whole


def _rule_vertex(walk: _Walk, vertex, max_depth, gen, rule: EyeVertexRule):
    """A surface ``vertex`` under a method's vertex rule (module docstring): the rule's
    techniques at a smooth vertex, then the BSDF sample from every vertex within ``max_depth``,
    the rule deciding where it goes on. Returns where it did."""
    si, surface, _, arrived = vertex
    bsdf = si.bsdf(walk.ray)
    here = surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & (arrived < max_depth)
    walk.radiance[here] += walk.beta * rule.at_vertex(walk, si, bsdf, gen, arrived, here)
    go_on = surface & (arrived < max_depth)
    bs, weight = bsdf.sample(
        mi.BSDFContext(), si, gen.next_float32(),
        mi.Point2f(gen.next_float32(), gen.next_float32()), go_on,
    )  # fmt: skip
    go_on &= (bs.pdf > 0) & dr.any(weight != 0.0)
    go_on = rule.bounced(walk, si, bsdf, bs, go_on)
    walk.beta[go_on] *= weight
    walk.eta[go_on] *= bs.eta
    walk.ray[go_on] = si.spawn_ray(si.to_world(bs.wo))
    walk.depth[go_on] = arrived
    walk.active &= ~surface | go_on
    return go_on
