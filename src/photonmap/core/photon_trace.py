"""Photon tracing — the first pass of two-pass photon mapping (Jensen 1996; Steinhurst 2007 §2.6.1,
Algorithm 2.4; spec seed-001 §2.2, A5).

Shared by the ``surface`` and ``screen`` pipelines: photons leave every Mitsuba emitter (area,
point, spot, directional, environment) and bounce through Mitsuba BSDFs; every hit on a surface
whose BSDF has a non-delta (diffuse or glossy) component is recorded. What a pipeline builds from
the records (global map, caustic map, splats) is its own business.

Emission (spec §2.2). The path budget ``N`` is split among the emitters in proportion to their
emitted power ``Φ_e`` (:func:`emitter_powers`, :func:`split_paths`). Emitter ``e`` gets ``N_e``
paths; path ``i`` starts with the ray and weight of ``emitter.sample_ray`` (the weight is an
unbiased estimate of ``Φ_e``) and carries ``Φ_i = weight_i / N_e``, so ``Σ_i Φ_i → Φ_e``.

Tracing. At the ``d``-th surface interaction ``x_d`` a photon of power ``Φ`` travelling along ``ω``
is recorded as ``(x_d, Φ, ω, n_s, d, caustic)`` when the BSDF there has a smooth component, then
the BSDF is sampled in importance (adjoint) transport mode, ``Φ ← Φ · f_s |cos θ_o| / p``. The
records form Jensen's global map (every non-specular hit, first-bounce "direct" photons included)
and, through the ``caustic`` flag, the caustic map: hits that end an ``L S+ D`` path — at least one
delta (specular) bounce and no smooth bounce before the hit (spec A5; Algorithm 2.4 as printed
never records a caustic photon). ``null``-BSDF shapes (fog boxes) are invisible: photons pass
straight through them (:func:`~photonmap.core.bsdf.intersect_visible`), and crossing one is no
interaction. Hits 1 … ``rr_depth`` are reached without Russian roulette; from bounce
``rr_depth`` on a photon survives with probability ``q = min(0.95, max_c Φ_c / Φ_{0,c})`` and its
power is divided by ``q`` (as Mitsuba's path tracers do; no η² factor, since importance transport
through a dielectric conserves power). A path ends after ``max_depth`` interactions.

Mitsuba gives the shape of an area light without a BSDF a black ``diffuse`` BSDF, which is
smooth: photons that reach such a light are recorded there and absorbed.

Bad input raises :class:`~photonmap.core.errors.SceneError`: no emitter or no shape, an emitter
that emits nothing, non-finite values in an emitter's or a BSDF's parameters (textures included),
and non-finite photon power after tracing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .bsdf import has_null_shapes, intersect_visible
from .errors import ParameterError, SceneError
from .media import VolumePhotons, channel, enter, free_flight
from .sampling import rng


@dataclass
class PhotonRecords:
    """Stored photon hits as a struct of Dr.Jit arrays, one entry per record, ordered by depth
    (all first hits, then all second hits, ...) and by path within a depth (by path alone when
    traced with ``caustics_only``)."""

    position: mi.Point3f
    power: mi.Color3f  # Φ_p in W
    direction: mi.Vector3f  # unit travel direction ω_p at the hit (pointing into the surface)
    normal: mi.Vector3f  # shading normal at the hit as Mitsuba gives it (not flipped towards ω_p)
    depth: mi.UInt32  # surface interactions up to this hit, included (1 = first hit)
    caustic: mi.Bool  # the hit ends an L S+ D path (spec A5)
    paths: int  # photon paths emitted
    emitted_power: np.ndarray  # Σ of the initial power of all paths (RGB, W)

    @property
    def count(self) -> int:
        """Number of records."""
        return dr.width(self.depth)

    def select(self, mask: mi.Bool) -> PhotonRecords:
        """The records where ``mask`` holds (e.g. ``records.select(records.caustic)`` is the
        caustic map); ``paths`` and ``emitted_power`` are kept."""
        index = dr.compress(mask)
        fields = (self.position, self.power, self.direction, self.normal, self.depth, self.caustic)
        return PhotonRecords(
            *(dr.gather(type(f), f, index) for f in fields), self.paths, self.emitted_power
        )

    def after_first(self) -> PhotonRecords:
        """The records from the second interaction on — the first hits are the direct light that
        the eye pass computes by emitter sampling; none when no photon hit anything (a light
        shining past the scene: Dr.Jit cannot compare a width-0 array with a literal)."""
        return self.select(self.depth > 1) if self.count else self


def emitter_powers(scene: mi.Scene, samples: int = 2**16, seed: int = 0) -> np.ndarray:
    """The power ``Φ_e`` (RGB, W) of each of ``scene.emitters()``, shape ``(n_emitters, 3)``.

    The mean weight of ``samples`` rays from ``emitter.sample_ray``: exact for emitters whose
    weight is constant (point lights, uniform area lights, directional and constant environment
    lights), a Monte Carlo estimate otherwise (spot fall-off, textured lights, environment maps).
    Directional and environment emitters count the power that crosses the scene's bounding sphere.
    """
    count = len(scene.emitters())
    if count == 0:
        return np.zeros((0, 3))
    emitter = dr.arange(mi.UInt32, count * samples) // samples
    _, weight = _sample_rays(scene, emitter, seed)
    total = dr.block_reduce(dr.ReduceOp.Add, mi.Color3d(weight), samples)
    return np.array(total, dtype=np.float64).T.reshape(count, 3) / samples


def split_paths(powers: np.ndarray, paths: int) -> np.ndarray:
    """Split ``paths`` among emitters in proportion to the mean of their RGB ``powers`` by
    largest-remainder rounding, with at least one path per emitter (spec §2.2)."""
    weight = np.asarray(powers, dtype=np.float64).reshape(len(powers), -1).mean(axis=1)
    if paths < len(weight):
        raise ParameterError(
            f"{paths} photon paths cannot cover the scene's {len(weight)} emitters; "
            f"trace at least {len(weight)} paths"
        )
    ideal = paths * weight / weight.sum()
    counts = np.floor(ideal).astype(np.int64)
    by_remainder = np.argsort(-(ideal - counts), kind="stable")
    counts[by_remainder[: paths - counts.sum()]] += 1
    for starved in np.flatnonzero(counts == 0):
        counts[np.argmax(counts)] -= 1
        counts[starved] = 1
    return counts


def trace_photons(
    scene: mi.Scene,
    paths: int,
    max_depth: int = 8,
    rr_depth: int = 3,
    seed: int = 0,
    caustics_only: bool = False,
) -> PhotonRecords:
    """Trace ``paths`` photon paths from the scene's emitters and return the stored hits.

    All paths run in one symbolic Dr.Jit loop; records go to ``paths · max_depth`` preallocated
    slots (slot = (depth − 1) · paths + path, so neighbouring lanes write neighbouring slots) and
    are compacted at the end, so the result is the same for the same ``seed`` whatever the thread
    schedule.

    ``caustics_only`` traces the caustic map's paths alone: a path ends at its first smooth
    interaction, where it is stored if a specular bounce came before. Most paths then cost one
    ray (those whose first hit is not specular), so many paths are cheap — Jensen's projection
    maps reach the same end by aiming photons at the specular objects. Each path keeps one slot.
    """
    if paths < 1:
        raise ParameterError(f"the number of photon paths must be at least 1, got {paths}")
    if max_depth < 1 or rr_depth < 1:
        raise ParameterError(
            f"max_depth and rr_depth must be at least 1, got max_depth={max_depth}, "
            f"rr_depth={rr_depth}"
        )
    emitter, ray, power, emitted = _emission(scene, paths, seed)
    records = _trace(
        scene,
        ray,
        power,
        rng(paths, seed, stream=1),
        max_depth,
        rr_depth,
        caustics_only,
        has_null_shapes(scene),
    )
    slot = dr.compress(records.pop("stored"))
    fields = {name: dr.gather(type(value), value, slot) for name, value in records.items()}
    dr.eval(fields)
    result = PhotonRecords(**fields, paths=paths, emitted_power=emitted)
    _check_power(result)
    return result


def trace_photons_media(
    scene: mi.Scene,
    paths: int,
    max_depth: int = 8,
    rr_depth: int = 3,
    seed: int = 0,
    caustics_only: bool = False,
) -> tuple[PhotonRecords, VolumePhotons]:
    """:func:`trace_photons` through participating media (Jensen & Christensen 1998; spec
    beyond-seeds §4): the surface records as there, and the volume photons.

    Each photon starts in its emitter's medium (:func:`emitter_media`) and flies by
    :func:`~photonmap.core.media.free_flight` (``medium.sample_interaction`` in a colour channel
    drawn per path, delta tracking in heterogeneous media, media switched at ``null``, dielectric
    and other medium-transition boundaries), so the transmittance on the way is in the sampling.
    At a real scattering event it is stored as a volume photon with the power it scatters,
    ``Φ·σ_s T/p`` (``Φ`` times the albedo for a grey medium), ``direct`` when nothing but ``null``
    boundaries lay between it and its emitter; it then goes on with probability
    ``q = min(1, max_c σ_s T/p)`` (the albedo: Russian roulette) with its power divided by ``q`` —
    a grey medium keeps the photon's power — in a direction sampled from the medium's phase
    function. A medium event counts as an interaction (``depth``, ``max_depth``) and as a smooth
    bounce: photons scattered by the medium are never caustic, and ``caustics_only`` paths end
    at their first medium event unstored."""
    if paths < 1:
        raise ParameterError(f"the number of photon paths must be at least 1, got {paths}")
    if max_depth < 1 or rr_depth < 1:
        raise ParameterError(
            f"max_depth and rr_depth must be at least 1, got max_depth={max_depth}, "
            f"rr_depth={rr_depth}"
        )
    emitter, ray, power, emitted = _emission(scene, paths, seed)
    medium = dr.gather(mi.MediumPtr, mi.MediumPtr(emitter_media(scene)), emitter)
    surface, volume = _trace_media(
        scene, ray, medium, power, rng(paths, seed, stream=1), max_depth, rr_depth, caustics_only
    )
    slot = dr.compress(surface.pop("stored"))
    fields = {name: dr.gather(type(value), value, slot) for name, value in surface.items()}
    slot = dr.compress(volume.pop("stored"))
    vfields = {name: dr.gather(type(value), value, slot) for name, value in volume.items()}
    dr.eval(fields, vfields)
    result = PhotonRecords(**fields, paths=paths, emitted_power=emitted)
    _check_power(result)
    return result, VolumePhotons(**vfields)


def emitter_media(scene: mi.Scene) -> list:
    """The medium each of ``scene.emitters()`` emits into: its own ``medium`` (a point, spot or
    other emitter placed in fog), else for an area light its shape's exterior medium — the side
    its normals face, where it emits (Mitsuba's ``target_medium`` of a direction along the
    normal) — else None (vacuum)."""
    media = []
    for emitter in scene.emitters():
        medium, shape = emitter.get_medium(), emitter.get_shape()
        if medium is None and shape is not None:
            medium = shape.exterior_medium()
        media.append(medium)
    return media


def _emission(scene: mi.Scene, paths: int, seed: int):
    """The emitter index, ray and power ``Φ_i = weight_i / N_e`` of each of ``paths`` photon
    paths, and the total emitted power (RGB) — the emission of spec §2.2."""
    counts = split_paths(_checked_powers(scene, seed), paths)
    emitter = mi.UInt32(np.repeat(np.arange(len(counts), dtype=np.uint32), counts))
    ray, weight = _sample_rays(scene, emitter, seed)
    power = weight / dr.gather(mi.Float, mi.Float(counts.astype(np.float32)), emitter)
    emitted = np.array(dr.sum(mi.Color3d(power), axis=1)).ravel()
    return emitter, ray, power, emitted


def _checked_powers(scene: mi.Scene, seed: int) -> np.ndarray:
    """:func:`emitter_powers`, after checking that the scene has emitters and shapes and that the
    emitters and BSDFs have finite parameters (textures included); raise :class:`SceneError` if not or if an
    emitter emits nothing."""
    emitters = scene.emitters()
    if not emitters:
        raise SceneError(
            "the scene has no emitter, so no photons can be traced; add a light (an 'area' "
            "emitter on a shape, or a 'point', 'spot', 'directional', 'constant' or 'envmap' one)"
        )
    if not scene.shapes():
        raise SceneError("the scene has no shapes for photons to land on; add some geometry")
    for emitter in emitters:
        _check_finite(emitter, _emitter_name(emitter))
    checked = set()
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is not None and bsdf.ptr not in checked:
            checked.add(bsdf.ptr)
            _check_finite(bsdf, f"the BSDF of {_shape_name(shape)}")
    powers = emitter_powers(scene, seed=seed)
    dark = [_emitter_name(e) for e, p in zip(emitters, powers, strict=True) if not np.max(p) > 0]
    if dark:
        raise SceneError(
            f"{', '.join(dark)} emit{'s' if len(dark) == 1 else ''} no power; give "
            "them a positive radiance, intensity or irradiance, or remove them from the scene"
        )
    return powers


def _check_finite(obj, what: str) -> None:
    params = mi.traverse(obj)
    for key in params.keys():
        value = params[key]
        if isinstance(value, float):
            finite = math.isfinite(value)
        elif dr.is_array_v(value) and dr.is_float_v(value):
            finite = bool(dr.all(dr.isfinite(value), axis=None))
        else:
            continue
        if not finite:
            raise SceneError(
                f"{what} has NaN or infinite values in its parameter '{key}'; "
                "give it finite values (check the texture file or the colour values)"
            )


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


def _emitter_name(emitter: mi.Emitter) -> str:
    shape = emitter.get_shape()
    if shape is not None:
        return f"the area light of {_shape_name(shape)}"
    return f"emitter '{emitter.id()}' ({emitter.class_name()})"


def _shape_name(shape: mi.Shape) -> str:
    """``shape 'id'``; Mitsuba's merged meshes have no id."""
    return f"shape '{shape.id()}'" if shape.id().strip(" +") else f"a merged {shape.class_name()}"


def _sample_rays(scene: mi.Scene, emitter: mi.UInt32, seed: int) -> tuple[mi.Ray3f, mi.Color3f]:
    """``sample_ray`` of emitter ``scene.emitters()[emitter[i]]`` for every lane ``i``."""
    gen = rng(dr.width(emitter), seed, stream=0)
    wavelength = gen.next_float32()
    spatial = mi.Point2f(gen.next_float32(), gen.next_float32())
    directional = mi.Point2f(gen.next_float32(), gen.next_float32())
    emitters = dr.gather(mi.EmitterPtr, scene.emitters_dr(), emitter)
    return emitters.sample_ray(0.0, wavelength, spatial, directional)


def _store(records: dict, slot, store, position, power, direction, normal, depth, caustic):
    """Write one surface photon record per lane where ``store`` (slot ``slot``)."""
    dr.scatter(records["position"], position, slot, store)
    dr.scatter(records["power"], power, slot, store)
    dr.scatter(records["direction"], direction, slot, store)
    dr.scatter(records["normal"], mi.Vector3f(normal), slot, store)
    dr.scatter(records["depth"], depth, slot, store)
    dr.scatter(records["caustic"], caustic, slot, store)
    dr.scatter(records["stored"], True, slot, store)


@dr.syntax
def _trace(
    scene: mi.Scene,
    ray: mi.Ray3f,
    power: mi.Color3f,
    rng: mi.PCG32,
    max_depth: int,
    rr_depth: int,
    caustics_only: bool,
    null_shapes: bool,
) -> dict:
    """The bounce loop; returns the record slots and the ``stored`` mask over them."""
    n = dr.width(power)
    slots = n if caustics_only else n * max_depth
    records = {
        "position": dr.zeros(mi.Point3f, slots),
        "power": dr.zeros(mi.Color3f, slots),
        "direction": dr.zeros(mi.Vector3f, slots),
        "normal": dr.zeros(mi.Vector3f, slots),
        "depth": dr.zeros(mi.UInt32, slots),
        "caustic": dr.zeros(mi.Bool, slots),
        "stored": dr.zeros(mi.Bool, slots),
    }
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    path = dr.arange(mi.UInt32, n)
    depth = dr.zeros(mi.UInt32, n)
    throughput = dr.full(mi.Color3f, 1.0, n)  # Φ / Φ₀ per channel
    specular_bounce = dr.zeros(mi.Bool, n)  # a delta lobe was sampled on the way here
    smooth_bounce = dr.zeros(mi.Bool, n)  # a diffuse or glossy lobe was sampled on the way here
    active = dr.max(power) > 0

    # Every iteration either ends a path or adds one interaction, so depth < max_depth caps it.
    while active:
        si = intersect_visible(scene, ray, active, null_shapes)
        active &= si.is_valid()
        depth[active] += 1
        bsdf = si.bsdf(ray)

        store = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        caustic = specular_bounce & ~smooth_bounce
        if caustics_only:
            store &= caustic
            slot = mi.UInt32(path)
        else:
            slot = (depth - 1) * n + path
        _store(records, slot, store, si.p, power * throughput, ray.d, si.sh_frame.n, depth, caustic)

        sample, weight = bsdf.sample(
            ctx,
            si,
            rng.next_float32(),
            mi.Point2f(rng.next_float32(), rng.next_float32()),
            active,
        )
        throughput *= weight
        lobe = sample.sampled_type
        null = mi.has_flag(lobe, mi.BSDFFlags.Null)  # a null-BSDF emitter's shape is no bounce
        specular_bounce |= active & mi.has_flag(lobe, mi.BSDFFlags.Delta) & ~null
        smooth_bounce |= active & mi.has_flag(lobe, mi.BSDFFlags.Smooth)
        ray = si.spawn_ray(si.to_world(sample.wo))
        if caustics_only:
            active &= ~smooth_bounce

        # Russian roulette (Mitsuba's path tracers): survive with q, power divided by q.
        survival = dr.minimum(dr.max(throughput), 0.95)
        roulette = active & (depth >= rr_depth)
        throughput[roulette] /= survival
        active &= ~roulette | (rng.next_float32() < survival)
        active &= (dr.max(throughput) > 0) & (depth < max_depth)

    return records


@dr.syntax
def _trace_media(
    scene: mi.Scene,
    ray: mi.Ray3f,
    medium: mi.MediumPtr,
    power: mi.Color3f,
    rng: mi.PCG32,
    max_depth: int,
    rr_depth: int,
    caustics_only: bool,
) -> tuple[dict, dict]:
    """The bounce loop of :func:`trace_photons_media`: surface and volume record slots, each with
    its ``stored`` mask."""
    n = dr.width(power)
    slots = n if caustics_only else n * max_depth
    records = {
        "position": dr.zeros(mi.Point3f, slots),
        "power": dr.zeros(mi.Color3f, slots),
        "direction": dr.zeros(mi.Vector3f, slots),
        "normal": dr.zeros(mi.Vector3f, slots),
        "depth": dr.zeros(mi.UInt32, slots),
        "caustic": dr.zeros(mi.Bool, slots),
        "stored": dr.zeros(mi.Bool, slots),
    }
    vslots = 1 if caustics_only else n * max_depth
    volume = {
        "position": dr.zeros(mi.Point3f, vslots),
        "direction": dr.zeros(mi.Vector3f, vslots),
        "power": dr.zeros(mi.Color3f, vslots),
        "direct": dr.zeros(mi.Bool, vslots),
        "stored": dr.zeros(mi.Bool, vslots),
    }
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    phase_ctx = mi.PhaseFunctionContext(None, mi.TransportMode.Importance)
    path = dr.arange(mi.UInt32, n)
    depth = dr.zeros(mi.UInt32, n)
    throughput = dr.full(mi.Color3f, 1.0, n)  # Φ / Φ₀ per channel
    medium = mi.MediumPtr(medium)
    ch = channel(rng)
    specular_bounce = dr.zeros(mi.Bool, n)
    smooth_bounce = dr.zeros(mi.Bool, n)  # a diffuse, glossy or medium scattering on the way
    active = dr.max(power) > 0

    # Every iteration either ends a path or adds one interaction, so depth < max_depth caps it.
    while active:
        flight = free_flight(scene, ray, medium, rng, ch, active)
        si, mei = flight.si, flight.mei
        in_medium = active & flight.scattered
        on_surface = active & ~flight.scattered & si.is_valid()
        active = in_medium | on_surface
        depth[active] += 1
        throughput[active] *= flight.weight
        direct = ~specular_bounce & ~smooth_bounce

        if not caustics_only:
            vslot = (depth - 1) * n + path
            dr.scatter(volume["position"], mei.p, vslot, in_medium)
            dr.scatter(volume["direction"], ray.d, vslot, in_medium)
            dr.scatter(volume["power"], power * throughput, vslot, in_medium)
            dr.scatter(volume["direct"], direct, vslot, in_medium)
            dr.scatter(volume["stored"], True, vslot, in_medium)

        bsdf = si.bsdf(ray)
        store = on_surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        caustic = specular_bounce & ~smooth_bounce
        if caustics_only:
            store &= caustic
            slot = mi.UInt32(path)
        else:
            slot = (depth - 1) * n + path
        _store(records, slot, store, si.p, power * throughput, ray.d, si.sh_frame.n, depth, caustic)

        sample, weight = bsdf.sample(
            ctx,
            si,
            rng.next_float32(),
            mi.Point2f(rng.next_float32(), rng.next_float32()),
            on_surface,
        )
        wo, phase_weight, _ = mei.medium.phase_function().sample(
            phase_ctx,
            mei,
            rng.next_float32(),
            mi.Point2f(rng.next_float32(), rng.next_float32()),
            in_medium,
        )
        throughput[on_surface] *= weight
        throughput[in_medium] *= phase_weight
        lobe = sample.sampled_type
        null = mi.has_flag(lobe, mi.BSDFFlags.Null)
        specular_bounce |= on_surface & mi.has_flag(lobe, mi.BSDFFlags.Delta) & ~null
        smooth_bounce |= in_medium | (on_surface & mi.has_flag(lobe, mi.BSDFFlags.Smooth))
        d_surface = si.to_world(sample.wo)
        medium = dr.select(in_medium, mei.medium, enter(si, d_surface, flight.medium, on_surface))
        ray = dr.select(in_medium, mei.spawn_ray(wo), si.spawn_ray(d_surface))
        if caustics_only:
            active &= ~smooth_bounce

        # Russian roulette: at a medium event survive with the albedo q (Jensen & Christensen),
        # at a surface from rr_depth on with q = min(0.95, max Φ/Φ₀); the power is divided by q.
        survival = dr.select(
            in_medium,
            dr.minimum(dr.max(flight.weight), 1.0),
            dr.minimum(dr.max(throughput), 0.95),
        )
        roulette = in_medium | (on_surface & (depth >= rr_depth))
        throughput[roulette] /= dr.maximum(survival, 1e-30)
        active &= ~roulette | (rng.next_float32() < survival)
        active &= (dr.max(throughput) > 0) & (depth < max_depth)

    return records, volume
