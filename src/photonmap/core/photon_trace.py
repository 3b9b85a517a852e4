"""The photon-path loop of the transport core: light paths through Mitsuba's BSDFs and media (Jensen
1996; Jensen & Christensen 1998; Steinhurst 2007 §2.6.1, Algorithm 2.4). Every method that traces
photons uses it: the surface method's maps, SPPM's photon passes and the screen method's photon
bounces.

A photon of power ``Φ`` leaves its emitter in its emitter's medium (:mod:`.emission`) and flies:
through media by free-flight sampling (:func:`~photonmap.core.media.free_flight`; the
transmittance is in the sampling, ``null`` boundaries only switch the medium), through vacuum to
the next surface that is not a ``null`` boundary. Medium is optional state — vacuum is the case
without one, as in Mitsuba's ``volpath``:

- at a **surface** with a smooth (diffuse or glossy) lobe the photon is recorded as
  ``(x, Φ, ω, n_s, depth, caustic)``; then the BSDF is sampled in importance (adjoint) mode,
  ``Φ ← Φ · f_s |cos θ_o| / p`` — any Mitsuba BSDF through its own ``sample``: delta lobes are
  followed, a ``Null`` lobe (``mask``, ``thindielectric`` transmission) passes the photon
  straight on without counting an interaction, a dielectric boundary switches the medium;
- at a **medium** collision it is recorded as a volume photon with the power it scatters
  (``Φ σ_s T / p``, :class:`~photonmap.core.volume_map.VolumePhotons`) and survives with the
  albedo's probability (Jensen & Christensen 1998), its power divided by it, in a direction
  sampled from the phase function.

``depth`` counts the path's segments from the light up to the record (a medium event and a
surface interaction each add one; ``null`` crossings none), as Mitsuba's ``max_depth`` counts
segments: a record of depth ``d`` can end a path of at least ``d + 1`` segments, so only records
with ``d ≤ max_depth − 1`` are kept and paths stop there. ``caustic``: the history is a pure
specular chain — at least one delta bounce, no smooth bounce and no medium event (the L S+ D
paths of Jensen's caustic map, Jensen 1996; the volume caustics); where rough glass is followed
(:func:`~photonmap.core.bsdf.is_rough_glass`, the surface method) its bounces count as delta
ones and nothing is recorded on it. From ``rr_depth`` on a photon survives a surface
interaction with probability ``q = min(0.95, max_c Φ_c / Φ_{0,c})`` and its power is divided
by ``q`` (Mitsuba's Russian roulette, :func:`~photonmap.core.settings.survival`).

**Wavefront in chunks.** All paths run in one symbolic Dr.Jit loop for up to :data:`CHUNK`
interactions each; records go to preallocated slots (slot = step · paths + path) and are
compacted; the paths still alive continue in the next chunk. Memory is bounded per chunk while
``max_depth`` may be unbounded (−1: ended by Russian roulette), and the records come out in the
same order for the same seed whatever the thread schedule.

Mitsuba gives the shape of an area light without a BSDF a black ``diffuse`` BSDF, which is
smooth: photons that reach such a light are recorded there and absorbed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import drjit as dr
import mitsuba as mi
import numpy as np

from .arrays import concat
from .bsdf import intersect_visible, is_rough_glass, is_specular
from .emission import LightPaths, emit
from .errors import SceneError
from .media import channel, enter, free_flight
from .rows import Rows
from .sampling import rng
from .scene_info import SceneTraits
from .settings import UNBOUNDED, PathSettings, survival
from .volume_map import VolumePhotons

CHUNK = 8  # interactions per path in one symbolic loop (record slots: paths × CHUNK)
MAX_STEPS = 4096  # interactions of one path at most, Null-lobe passes included


@dataclass
class PhotonRecords:
    """Stored photon hits on surfaces, one entry per record (module docstring), in tracing
    order: by chunk, by step within it, by path within a step."""

    position: mi.Point3f
    power: mi.Color3f  # Φ_p in W
    direction: mi.Vector3f  # unit travel direction ω_p at the hit (pointing into the surface)
    normal: mi.Vector3f  # shading normal at the hit as Mitsuba gives it (not flipped towards ω_p)
    depth: mi.UInt32  # path segments from the light to this hit, included (1 = first hit)
    caustic: mi.Bool  # the hit ends an L S+ D path (Jensen's caustic map)
    path: mi.UInt32  # the light path (lane of the traced wavefront)
    delta: mi.UInt32  # delta (specular) bounces before the hit
    glossy: mi.UInt32  # glossy bounces before the hit
    paths: int  # photon paths emitted
    emitted_power: np.ndarray  # Σ of the initial power of all paths (RGB, W)
    rays: int = 0  # rays the paths cast (one per segment)

    @property
    def count(self) -> int:
        """Number of records."""
        return dr.width(self.depth)

    def select(self, mask: mi.Bool) -> PhotonRecords:
        """The records where ``mask`` holds (e.g. ``records.select(records.caustic)`` is the
        caustic map); ``paths``, ``emitted_power`` and ``rays`` are kept."""
        index = dr.compress(mi.Bool(mask))
        return PhotonRecords(
            *(dr.gather(type(f), f, index) for f in self._arrays()),
            self.paths,
            self.emitted_power,
            self.rays,
        )

    def after_first(self) -> PhotonRecords:
        """The records from the second interaction on — the first hits are the direct light that
        eye paths compute by emitter sampling; none when no photon hit anything (a light shining
        past the scene: Dr.Jit cannot compare a width-0 array with a literal)."""
        return self.select(self.depth > 1) if self.count else self

    def _arrays(self) -> list:
        return [getattr(self, f.name) for f in fields(self)][:-3]


@dataclass
class Traced:
    """What :func:`trace_photons` traced: the surface records, the volume photons (None without
    media), and the emission (its aimed share)."""

    records: PhotonRecords
    volume: VolumePhotons | None
    light: LightPaths

    @property
    def caustic_fraction(self) -> float:
        """Of the aimed paths, the share whose first interaction was on a specular shape (their
        records' paths)."""
        if self.light.aimed_paths == 0 or self.records.count == 0:
            return 0.0
        first = dr.zeros(mi.Bool, self.light.count)
        dr.scatter(first, True, self.records.path)
        return dr.count(first & self.light.aimed)[0] / self.light.aimed_paths


@dataclass(frozen=True)
class PhotonRules:
    """How :func:`trace_light_paths` treats every path: its path ``settings`` and the scene's
    ``traits``; ``caustics_only``: a path ends at its first smooth interaction (surface or
    medium), stored only if caustic; ``roulette``: Russian roulette from ``settings.rr_depth``
    on; ``redirect(si, bs, gen)``: a direction to go on in instead of the BSDF sample's (the
    screen method's glossy rule); ``rough_glass``: see :func:`trace_photons`; ``null_counts``:
    a ``Null`` event (a ``null`` shape, a mask's or a thin dielectric's pass) is an interaction
    like a delta bounce, counted in ``depth``, as the VCM subpaths need it (their MIS treats it
    as a delta vertex: SmallVCM's rule, and their camera subpaths'), where a photon otherwise
    passes it uncounted."""

    settings: PathSettings
    traits: SceneTraits
    caustics_only: bool = False
    roulette: bool = True
    redirect: Callable | None = None
    rough_glass: bool = False
    null_counts: bool = False

    @staticmethod
    def of(scene: mi.Scene, settings: PathSettings | None = None, **options) -> PhotonRules:
        """The rules for ``scene`` (its traits found here) under ``settings`` (default
        Mitsuba's) and ``options`` (the other fields)."""
        return PhotonRules(settings or PathSettings(), SceneTraits.of(scene), **options)

    @property
    def limit(self) -> int:
        """The deepest record kept (``max_depth − 1`` segments; paths stop there)."""
        unbounded = self.settings.max_depth == UNBOUNDED
        return np.iinfo(np.int32).max if unbounded else self.settings.max_depth - 1


def trace_photons(
    scene: mi.Scene,
    paths: int,
    rules: PhotonRules | None = None,
    seed: int = 0,
    aim: float = 0.0,
    media: list | None = None,
    powers: np.ndarray | None = None,
) -> Traced:
    """Emit ``paths`` light paths (:func:`~photonmap.core.emission.emit`, the fraction ``aim``
    aimed at specular shapes) and trace them by ``rules`` (:func:`trace_light_paths`; default
    :meth:`PhotonRules.of` the scene): the one way every method makes photons. With
    ``rules.caustics_only`` only the caustic records are kept (``aim = 1``: every area light's
    paths aimed — the caustics of surfaces that also have smooth lobes, a plastic's coating, are
    then left out); with ``rules.rough_glass`` rough glass is followed as glass is
    (:func:`~photonmap.core.bsdf.is_rough_glass`: aimed at, no records on it, its bounces
    specular). ``media``: the emitters' media and ``powers`` their checked powers, if known
    (:func:`~photonmap.core.media.emitter_media`, :func:`~photonmap.core.emission.checked_powers`:
    a pipeline finds them once)."""
    rules = rules or PhotonRules.of(scene)
    light = emit(scene, paths, seed, aim, rules.caustics_only, media, powers, rules.rough_glass)
    records, volume = trace_light_paths(scene, light, rng(paths, seed, stream=1), rules)
    return Traced(records, volume, light)


def trace_light_paths(
    scene: mi.Scene, light: LightPaths, gen, rules: PhotonRules, first_depth: int = 0,
    vertices: VertexRule | None = None,
) -> tuple:
    """Trace the light paths ``light`` by ``rules`` (module docstring) and return what
    ``vertices`` made of their surface vertices (default :class:`PhotonMapVertices`: the photon
    records) and, in a scene with media, their volume photons. ``gen``: one random generator per
    path (an ``mi.PCG32`` or any Dr.Jit struct with ``next_float32()``, e.g. a fixed random
    map); ``first_depth``: interactions the paths have already had (records then count from
    it)."""
    vertices = vertices or PhotonMapVertices()
    if rules.traits.media and not vertices.media:
        raise ValueError(f"{type(vertices).__name__} handles surface vertices only; the scene "
                         "has participating media")  # fmt: skip
    state = _PathState.start(light, gen, first_depth, vertices.extra())
    surface, volume = [], []
    steps = rays = 0
    while state.count and steps < MAX_STEPS:
        rec, vrec, state, cast = _chunk(scene, state, rules, vertices)
        surface.append(rec)
        volume.append(vrec)
        steps += CHUNK
        rays += cast
    made = vertices.result(dict(zip(vertices.fields, _concat(surface, len(vertices.fields)),
                                    strict=True)), light, rays)  # fmt: skip
    if not rules.traits.media:
        return made, None
    return made, VolumePhotons(*_concat(volume, 5))


class VertexRule:
    """What a method does at the surface vertices of the core's light paths (the per-vertex
    hook): its records' ``fields`` (name → Dr.Jit type), its per-path state (:meth:`extra`,
    carried in ``state.extra`` through the chunks), and the steps :func:`_loop` calls — on
    arrival at a vertex (:meth:`arrive`), the record's values where one is stored
    (:meth:`record`; they are stored after it returns, so a value it updates in place, as a
    masked ``x[mask] += 1`` does, goes out as a copy) and after the BSDF sample
    (:meth:`bounced`). :meth:`result` makes the method's output of the records (each field
    concatenated over the chunks). ``media``: whether the rule's state stays right through
    medium collisions (where the loop scatters without calling it); a rule that does not is
    refused in a scene with media."""

    fields: dict
    media = False

    def extra(self):
        return None

    def arrive(self, state, si: mi.SurfaceInteraction3f, on_surface: mi.Bool) -> None:
        pass

    def record(self, state, si, bsdf, store: mi.Bool, caustic: mi.Bool) -> tuple:
        raise NotImplementedError

    def bounced(self, state, si, bsdf, sample, bounced: mi.Bool) -> None:
        pass

    def result(self, records: dict, light: LightPaths, rays: int):
        raise NotImplementedError


class PhotonMapVertices(VertexRule):
    """The photon map's vertices (module docstring): a :class:`PhotonRecords` entry at each
    surface with a smooth lobe."""

    media = True  # the volume photons are the loop's own
    fields = {
        "position": mi.Point3f, "power": mi.Color3f, "direction": mi.Vector3f,
        "normal": mi.Vector3f, "depth": mi.UInt32, "caustic": mi.Bool, "path": mi.UInt32,
        "delta": mi.UInt32, "glossy": mi.UInt32,
    }  # fmt: skip

    def record(self, state, si, bsdf, store, caustic) -> tuple:
        return (si.p, state.power, state.ray.d, mi.Vector3f(si.sh_frame.n), state.depth + 1,
                caustic, state.path, state.delta, state.glossy)  # fmt: skip

    def result(self, records: dict, light: LightPaths, rays: int) -> PhotonRecords:
        out = PhotonRecords(*records.values(), light.count, light.emitted_power, rays)
        _check_power(out)
        return out


@dataclass
class _PathState:
    """The paths alive between chunks (their lane in the original wavefront: ``path``)."""

    ray: mi.Ray3f
    power: mi.Color3f  # Φ (W), the throughput applied
    power0: mi.Color3f  # Φ₀, for Russian roulette
    medium: mi.MediumPtr
    depth: mi.UInt32
    specular: mi.Bool  # a delta bounce on the way
    smooth: mi.Bool  # a smooth bounce or a medium event on the way
    fresh: mi.Bool  # no interaction yet (the partition applies at the first)
    aimed: mi.Bool
    partitioned: mi.Bool
    delta: mi.UInt32
    glossy: mi.UInt32
    path: mi.UInt32
    gen: object
    extra: object  # the vertex rule's per-path state, or None

    @classmethod
    def start(cls, light: LightPaths, gen, first_depth: int, extra) -> _PathState:
        n = light.count
        return cls(
            mi.Ray3f(light.ray), mi.Color3f(light.power), mi.Color3f(light.power),
            mi.MediumPtr(light.medium), dr.full(mi.UInt32, first_depth, n), dr.zeros(mi.Bool, n),
            dr.zeros(mi.Bool, n), dr.full(mi.Bool, first_depth == 0, n), mi.Bool(light.aimed),
            mi.Bool(light.partitioned), dr.zeros(mi.UInt32, n), dr.zeros(mi.UInt32, n),
            dr.arange(mi.UInt32, n), gen, extra,
        )  # fmt: skip

    @property
    def count(self) -> int:
        return dr.width(self.path)

    def kept(self, alive: mi.Bool) -> _PathState:
        index = dr.compress(alive)
        values = [v if v is None else dr.gather(type(v), v, index) for v in vars(self).values()]
        state = _PathState(*values)
        dr.eval(*vars(state).values())
        return state


def _concat(chunks: list, width: int) -> list:
    """The chunks' fields one after the other (``width`` fields each)."""
    return [concat([c[i] for c in chunks]) for i in range(width)]


VOLUME_ROWS = Rows.of(VolumePhotons)


def _chunk(scene, state, rules: PhotonRules, vertices: VertexRule):
    """One chunk of the loop: the records it stored (compacted, as field lists), the state of
    the paths still alive and the rays the chunk cast."""
    lanes = state.count
    slots = lanes * CHUNK
    rows = Rows(vertices.fields)
    # record slots, read where stored only: not cleared (clearing them was a quarter of the pass)
    rec, vrec = rows.empty(slots), VOLUME_ROWS.empty(slots if rules.traits.media else 1)
    stored = dr.zeros(mi.Bool, slots)
    vstored = dr.zeros(mi.Bool, slots if rules.traits.media else 1)
    alive, steps = _loop(scene, state, (rows, rec, vrec, stored, vstored), rules, vertices)
    dr.eval(rec, vrec, stored, vstored, alive, steps, *vars(state).values())
    out = [layout.read(storage, dr.compress(mask))
           for layout, storage, mask in ((rows, rec, stored), (VOLUME_ROWS, vrec, vstored))]
    return out[0], out[1], state.kept(alive), int(np.asarray(steps, np.int64).sum())


@dr.syntax
def _loop(scene, state, slots, rules: PhotonRules, vertices: VertexRule):
    """The symbolic loop of one chunk; updates ``state`` in place, fills the record ``slots``
    (surface and volume records and where they were stored) and returns which paths are still
    alive. One iteration flies to the next interaction
    (:func:`_fly`), applies the partition of aimed emission (:mod:`.emission`) at the first one,
    stores a volume photon or the ``vertices`` rule's record at a surface, samples the BSDF or
    the phase function (:func:`_scatter`) and plays Russian roulette (:func:`_survival`). Also
    returns each path's steps in the chunk: one ray cast each."""
    rows, rec, vrec, stored, vstored = slots
    # frozen dataclasses stay out of loops: their values as locals
    media, null_counts = rules.traits.media, rules.null_counts
    null_shapes = False if null_counts else rules.traits.null_shapes  # null shapes: vertices
    roulette, redirect = rules.roulette, rules.redirect
    # a value, not code: the global and the caustic map's passes run one kernel
    all_records = ~dr.opaque(mi.Bool, rules.caustics_only)
    rough_glass = rules.rough_glass
    lanes = state.count
    limit = dr.opaque(mi.UInt32, rules.limit)
    rr_depth = dr.opaque(mi.UInt32, rules.settings.rr_depth)
    lane = dr.arange(mi.UInt32, lanes)
    stride = dr.opaque(mi.UInt32, lanes)  # not a literal: the survivors' count varies
    ch = channel(state.gen)
    step = dr.zeros(mi.UInt32, lanes)
    active = dr.max(state.power) > 0
    while active & (step < CHUNK):
        si, mei, in_medium, on_surface, albedo = _fly(scene, state, ch, active, media, null_shapes)
        bsdf = si.bsdf(state.ray)
        # the partition of aimed emission (core.emission), at the first interaction
        first_specular = on_surface & is_specular(bsdf, on_surface, rough_glass)
        keep = ~state.fresh | ~state.partitioned | (state.aimed == first_specular)
        in_medium &= keep
        on_surface &= keep
        state.fresh &= ~(in_medium | on_surface)
        caustic = state.specular & ~state.smooth
        vertices.arrive(state, si, on_surface)
        slot = step * stride + lane

        # ---- a medium collision: a volume photon
        state.depth[in_medium] += 1
        if dr.hint(media, mode="scalar"):
            vstore = in_medium & (state.depth <= limit) & (caustic | all_records)
            values = (mei.p, state.ray.d, state.power, state.depth, caustic)
            VOLUME_ROWS.write(vrec, values, slot, vstore)
            dr.scatter(vstored, True, slot, vstore)

        # ---- a surface: a record where the BSDF has a smooth lobe
        followed = dr.zeros(mi.Bool, lanes)  # rough glass followed whatever lobe it samples
        if dr.hint(rough_glass, mode="scalar"):
            followed = is_rough_glass(bsdf, on_surface)
        store = on_surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & ~followed
        store &= (state.depth + 1 <= limit) & (caustic | all_records)
        rows.write(rec, vertices.record(state, si, bsdf, store, caustic), slot, store)
        dr.scatter(stored, True, slot, store)

        where = (on_surface, in_medium, followed)
        bs, bounced = _scatter(state, (si, bsdf, mei), where, (redirect, null_counts), media)
        vertices.bounced(state, si, bsdf, bs, bounced)
        active = (in_medium | on_surface) & (~state.smooth | all_records)
        if dr.hint(roulette, mode="scalar"):
            survival = _survival(state, in_medium, albedo, media)
            rolled = in_medium | (bounced & (state.depth >= rr_depth))
            state.power[rolled] /= dr.maximum(survival, 1e-30)
            active &= ~rolled | (state.gen.next_float32() < survival)
        active &= (dr.max(state.power) > 0) & (state.depth < limit)
        step += 1
    return active, step


def _fly(scene, state: _PathState, ch, active, media: bool, null_shapes):
    """To the next interaction: a medium collision (free flight, whose weight the power takes)
    or a surface that is not a ``null`` boundary. Returns ``(si, mei, in_medium, on_surface,
    albedo)``; ``albedo`` is ``σ_s/σ_t`` where the photon scattered (``mei`` and ``albedo``
    are None in vacuum)."""
    if not media:
        si = intersect_visible(scene, state.ray, active, null_shapes)
        return si, None, dr.zeros(mi.Bool, state.count), active & si.is_valid(), None
    flight = free_flight(scene, state.ray, state.medium, state.gen, ch, active)
    si = flight.si
    in_medium = active & flight.scattered
    on_surface = active & ~flight.scattered & si.is_valid()
    state.power[active] *= flight.weight
    albedo = dr.minimum(dr.max(flight.weight), 1.0)  # σ_s/σ_t where it scattered
    state.medium = dr.select(active, flight.medium, state.medium)
    return si, flight.mei, in_medium, on_surface, albedo


def _scatter(state: _PathState, interaction, where, surface_rules, media):
    """Go on from the ``interaction`` ``(si, bsdf, mei)``: ``where = (on_surface, in_medium,
    followed)``, at a surface by the BSDF in importance mode (``surface_rules = (redirect,
    null_counts)``: the direction instead of the sample's, and whether a ``Null`` event counts
    as a bounce; ``followed``: rough glass followed as glass), in a medium by the phase
    function; the path's history (specular, smooth, bounce counts) follows. Returns the BSDF
    sample and where a surface bounce (not an uncounted ``Null`` pass) happened."""
    (si, bsdf, mei), (on_surface, in_medium, followed) = interaction, where
    redirect, null_counts = surface_rules
    gen = state.gen
    bs, weight = bsdf.sample(
        mi.BSDFContext(mi.TransportMode.Importance), si, gen.next_float32(),
        mi.Point2f(gen.next_float32(), gen.next_float32()), on_surface,
    )  # fmt: skip
    lobe = bs.sampled_type
    passed = on_surface & mi.has_flag(lobe, mi.BSDFFlags.Null)  # straight on, no interaction
    if null_counts:
        passed = dr.zeros(mi.Bool, dr.width(on_surface))
    bounced = on_surface & ~passed
    state.depth[bounced] += 1
    state.power[on_surface] *= weight
    is_delta = bounced & (mi.has_flag(lobe, mi.BSDFFlags.Delta) | followed)
    state.specular |= is_delta
    smooth_bounce = bounced & ~followed & mi.has_flag(lobe, mi.BSDFFlags.Smooth)
    state.smooth |= in_medium | smooth_bounce
    state.delta[is_delta] += 1
    state.glossy[bounced & mi.has_flag(lobe, mi.BSDFFlags.Glossy)] += 1
    wo_surface = bs.wo if redirect is None else redirect(si, bs, gen)
    d_surface = si.to_world(wo_surface)
    state.ray[on_surface] = si.spawn_ray(d_surface)
    if media:
        state.medium = enter(si, d_surface, state.medium, on_surface)
        wo, phase_weight, _ = mei.medium.phase_function().sample(
            mi.PhaseFunctionContext(None, mi.TransportMode.Importance), mei, gen.next_float32(),
            mi.Point2f(gen.next_float32(), gen.next_float32()), in_medium,
        )  # fmt: skip
        state.power[in_medium] *= phase_weight
        state.ray[in_medium] = mei.spawn_ray(wo)
    return bs, bounced


def _survival(state: _PathState, in_medium, albedo, media: bool) -> mi.Float:
    """Russian roulette's survival probability: a medium event survives with the albedo (Jensen
    & Christensen 1998), a surface interaction by :func:`~.settings.survival`."""
    q = survival(state.power, state.power0)
    if media:
        q = dr.select(in_medium, albedo, q)
    return q


def _check_power(records: PhotonRecords) -> None:
    if records.count == 0:
        return
    bad = dr.compress(~dr.all(dr.isfinite(records.power)))
    if dr.width(bad):
        where = np.array(dr.gather(mi.Point3f, records.position, bad[0])).ravel()
        raise SceneError(
            f"{dr.width(bad)} photon records have NaN or infinite power (the first at "
            f"{where.round(4).tolist()}); a BSDF or texture of the surface there evaluates to "
            "NaN or infinity"
        )
