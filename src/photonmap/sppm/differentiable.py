"""Differentiable photon mapping: the memoryless photon-mapping estimate (Knaus & Zwicker 2011)
with a smooth kernel, differentiated by Dr.Jit's automatic differentiation.

One iteration traces ``photons`` light paths and ``spp`` eye paths per pixel and estimates the
light at the eye paths' smooth vertices from the photons within ``r`` (Jensen 2001, eq. 7.6,
with a kernel)::

    L(x, ω_o) ≈ Σ_p K(‖x − x_p‖) f(x, ω_o, ω_p) Φ_p,    K(d) = 2/(π r²) · (1 − d²/r²)

(the Epanechnikov kernel, normalised on the disk; ``f`` is the BSDF without its cosine).
The rules are ``sppm``'s (photons kept, and eye paths ended, at smooth lobes:
``mi.BSDFFlags.Smooth``; the file's path settings); the kernel, the fixed radius, a smooth vertex's
delta lobes (followed as well as read) and media (all light from photons) differ on purpose
(docs/methods/differentiable.md). A box kernel — counting the photons within ``r`` — has zero
derivative almost everywhere; ``K`` is continuous, so the estimate is differentiable in the photon
positions ``x_p``, the visible points ``x`` and the weights ``Φ_p``, and reverse- or forward-mode
AD through the photon trace, the eye trace and this sum gives its gradient (the smooth-kernel
form of Xing, Li, Luan & Xu 2024, "Differentiable Photon Mapping using Generalized Path
Gradients", without their term for the moving merging region: here ``r`` is fixed).

What carries derivatives:

- **photon positions and directions**: every intersection is Mitsuba's differentiable
  ``ray_intersect`` (mesh vertex positions and normals, shape transforms move the hit points;
  refraction directions follow the normals and ``eta`` — Mitsuba's ``dielectric`` keeps its
  index as a plain float, so the index's derivative needs the ``diff_dielectric`` BSDF
  (:mod:`photonmap.core.diff_dielectric`), the same interface with a differentiable ``eta``);
- **weights**: emitted power (radiance, and the emitter's pose through its sampled positions),
  BSDF values (albedos, Fresnel), the eye paths' throughput and the emission they see;
- **discrete choices** (reflect or refract, Russian roulette): detached probabilities, weights
  ``f / detach(f)`` where Mitsuba's BSDF does so (the choice's derivative enters the weight).

What does not: **visibility** — a ray that changes which surface it hits (a silhouette, a
shadow's edge) gives no derivative for that change (no edge sampling or reparameterisation):
gradients of the interior of each visibility region, as caustics through smooth refractors need.

**Homogeneous participating media** (volumetric photon mapping, Jensen & Christensen 1998):
photons and eye rays sample free-flight distances with detached coefficients (one colour
channel, the spectral mean as pdf, as ``volpath``) and carry attached weights,
``σ_s e^{−σ_t t} / p(t)`` at a collision (the eye's without ``σ_s``: the photons hold it) and
``e^{−σ_t d} / P(d)`` across a segment of length ``d``, so the derivatives with respect to σ_s and
σ_t are those of the weights (Zeltner et al. 2021's attached weights on detached samples). An
eye ray's collision is a volume query that ends its path::

    L_s(x, ω_o) ≈ Σ_p K₃(‖x − x_p‖) f_p(ω_o, ω_p) Φ_p,   K₃(d) = 15/(8π ρ³) · (1 − d²/ρ²)

over the volume photons (collisions) within ``ρ``. Heterogeneous media are refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from types import SimpleNamespace

import drjit as dr
import mitsuba as mi

from ..core.arrays import channel_mean, concat
from ..core.bsdf import is_null
from ..core.camera import footprint_radius, pixel_rays
from ..core.emission import check_finite, checked_powers
from ..core.errors import ParameterError, SceneError
from ..core.hashgrid import HashGrid
from ..core.knn import COS_NORMAL
from ..core.media import broadcast, channel, emitter_media, enter, pick, scene_media
from ..core.progressive import iteration_seeds
from ..core.scene_info import SceneTraits, check_gathered_bsdfs
from ..core.settings import RR_MAX, UNBOUNDED, PathSettings, check_path_params, overridden

RADIUS_PIXELS = 2.0  # automatic radius in pixel footprints: sppm starts at 4 but shrinks; not this
VOLUME_RADIUS = 1.0  # automatic volume kernel radius ρ, in surface radii (larger: boundary bias)
MAX_BOUNCES = 64  # unbounded paths (max_depth −1) are unrolled this far at most
NULL_CROSSINGS = 16  # extra wavefronts for the null boundaries of media (they add no depth)
FAR = 1e30  # a free flight's length where it meets nothing (finite: no NaN in derivatives)


@dataclass
class Photons:
    """Light-path vertices on smooth surfaces or at medium collisions, attached to the scene
    parameters."""

    p: mi.Point3f  # position
    n: mi.Normal3f  # the surface's geometric normal (zero in a medium), for the normal test
    d: mi.Vector3f  # direction of travel that reached it
    power: mi.Spectrum  # Φ_p (σ_s included at a collision)
    depth: mi.UInt32  # segments from the light


@dataclass
class SurfacePoints:
    """Eye-path vertices on smooth surfaces: where the photons are read."""

    si: mi.SurfaceInteraction3f  # the interaction (``wi`` towards the camera)
    beta: mi.Spectrum  # throughput from the pixel, over spp
    pixel: mi.UInt32
    depth: mi.UInt32  # segments from the camera


@dataclass
class MediumPoints:
    """Eye-path collisions in media: where the volume photons are read."""

    mei: mi.MediumInteraction3f
    beta: mi.Spectrum
    pixel: mi.UInt32
    depth: mi.UInt32


@dataclass
class Segment:
    """Where one segment of a wavefront of paths ends: a surface or a medium collision."""

    si: mi.SurfaceInteraction3f
    bsdf: mi.BSDFPtr
    mei: mi.MediumInteraction3f
    scattered: mi.Bool  # a collision in a medium before the surface
    on_surface: mi.Bool
    crossing: mi.Bool  # a ``null`` boundary (no depth)
    depth: mi.UInt32  # the paths' depth after the segment
    weight: mi.Spectrum  # the free flight's weight (:meth:`DifferentiablePhotonMapper.flight`)
    gen: mi.PCG32  # the segment's random numbers (two already drawn by the free flight)


def lane_rng(ids: mi.UInt32, seed: int, stream: int) -> mi.PCG32:
    """One PCG32 per lane, keyed by the lane's path id ``ids`` and ``(seed, stream)``: a path's
    random numbers at one bounce do not depend on which other paths are still alive."""
    key = mi.sample_tea_32(mi.UInt32(seed & 0xFFFFFFFF), mi.UInt32(stream), 8)[0][0]
    state, sequence = mi.sample_tea_32(dr.opaque(mi.UInt32, key), mi.UInt32(ids))
    gen = mi.PCG32()  # seeded here: the constructor would add the lane number to both
    gen.seed(mi.UInt64(state), mi.UInt64(sequence))
    return gen


def _take(values, index: mi.UInt32):
    """``values`` (an array or a Mitsuba struct) at ``index``: a differentiable gather. Its
    reverse-mode derivative is a scatter-add into an array as wide as ``values`` (a photon
    count, a wavefront); reduced locally, not in Dr.Jit's default expanded mode on the CPU,
    whose kernel holds that width as a literal and is compiled anew for every width."""
    return dr.gather(type(values), values, index, mode=dr.ReduceMode.Local)


def _keep(parts: list, cls, mask: mi.Bool, **values) -> None:
    """Append the lanes of ``mask`` of ``values`` as a ``cls`` to ``parts``."""
    index = dr.compress(mask)
    if dr.width(index):
        parts.append(cls(**{name: _take(v, index) for name, v in values.items()}))


def _joined(parts: list, cls):
    """The records of every wavefront in one ``cls`` (None when there are none)."""
    if not parts:
        return None
    names = [f.name for f in fields(cls)]
    return cls(**{name: concat([getattr(part, name) for part in parts]) for name in names})


def _epanechnikov(d2: mi.Float, r2: float, norm: float) -> mi.Float:
    """``norm · max(1 − d²/r², 0)``, with ``r²`` and ``norm`` as opaque values: one compiled
    kernel serves every radius."""
    return dr.maximum(1.0 - d2 / dr.opaque(mi.Float, r2), 0.0) * dr.opaque(mi.Float, norm)


class DifferentiablePhotonMapper:
    """The differentiable memoryless photon-mapping estimate of ``scene`` seen by ``sensor``
    (module docstring). ``render(seed, iterations)`` returns an image attached to whatever scene
    parameters have gradients enabled.

    ``photons``: photon paths per iteration; ``spp``: eye paths per pixel and iteration;
    ``radius``: the surface kernel's radius in scene units (0: :data:`RADIUS_PIXELS` pixel
    footprints); ``volume_radius``: the volume kernel's (0: :data:`VOLUME_RADIUS` surface radii);
    ``max_depth``, ``rr_depth``, ``hide_emitters``: the scene file's by default, with Mitsuba's
    meaning (``null`` boundaries of media add no depth).
    """

    def __init__(
        self,
        scene: mi.Scene,
        sensor: mi.Sensor | int = 0,
        photons: int = 200_000,
        spp: int = 1,
        radius: float = 0.0,
        volume_radius: float = 0.0,
        max_depth: int = 0,
        rr_depth: int = 0,
        hide_emitters: str = "scene",
    ):
        if not isinstance(scene, mi.Scene):
            raise ParameterError(f"scene must be a mi.Scene, got {type(scene).__name__}")
        if isinstance(sensor, int):
            if not 0 <= sensor < len(scene.sensors()):
                raise ParameterError(
                    f"sensor index {sensor} is out of range: the scene has "
                    f"{len(scene.sensors())} sensor(s)"
                )
            sensor = scene.sensors()[sensor]
        for name, value in (("photons", photons), ("spp", spp)):
            if not (isinstance(value, int) and value >= 1):
                raise ParameterError(f"{name} must be an integer >= 1, got {value!r}")
        for name, value in (("radius", radius), ("volume_radius", volume_radius)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ParameterError(f"{name} must be >= 0 (0 = automatic), got {value!r}")
        if isinstance(hide_emitters, bool):
            hide_emitters = str(hide_emitters).lower()
        check_path_params(SimpleNamespace(
            max_depth=max_depth, rr_depth=rr_depth, hide_emitters=hide_emitters
        ))  # fmt: skip
        heterogeneous = [m for m in scene_media(scene) if not m.is_homogeneous()]
        if heterogeneous:
            raise SceneError(
                "differentiable photon mapping supports homogeneous media only; the scene has "
                f"{len(heterogeneous)} heterogeneous medium/media"
            )
        check_gathered_bsdfs(scene, "differentiable sppm")
        with dr.suspend_grad():
            checked_powers(scene, 0)  # emitters and shapes present, finite, emitting
            for medium in scene_media(scene):
                check_finite(medium, f"the medium '{medium.id()}'")
        self.scene, self.sensor = scene, sensor
        self.photons, self.spp = photons, spp
        self.traits = SceneTraits.of(scene)
        self.emitter_media = emitter_media(scene)
        self.settings = overridden(PathSettings.of(scene), max_depth, rr_depth, hide_emitters)
        self.radius = float(radius) or footprint_radius(scene, sensor, RADIUS_PIXELS)
        self.volume_radius = float(volume_radius) or VOLUME_RADIUS * self.radius
        self.size = tuple(int(c) for c in sensor.film().crop_size())

    @property
    def bounces(self) -> int:
        """The most segments a path may have (``max_depth``, or :data:`MAX_BOUNCES` when
        unbounded)."""
        depth = self.settings.max_depth
        return MAX_BOUNCES if depth == UNBOUNDED else depth

    @property
    def wavefronts(self) -> int:
        """The most wavefronts a path is traced: one per segment, and more for ``null``
        boundaries."""
        return self.bounces + (NULL_CROSSINGS if self.traits.null_shapes else 0)

    def render(self, seed: int = 0, iterations: int = 1) -> mi.TensorXf:
        """The mean of ``iterations`` estimates (random numbers from ``(seed, i)``), an image
        ``(height, width, 3)`` attached to the scene parameters that have gradients enabled."""
        if not (isinstance(iterations, int) and iterations >= 1):
            raise ParameterError(f"iterations must be an integer >= 1, got {iterations!r}")
        w, h = self.size
        total = dr.zeros(mi.Color3f, w * h)
        # Dr.Jit 1.5 loses derivatives through Mitsuba's shape calls (a moving mesh's hits) when
        # calls are optimised while recording them, after the same calls ran without AD
        with dr.scoped_set_flag(dr.JitFlag.OptimizeCalls, False):
            for i in range(1, iterations + 1):
                eye_seed, photon_seed = iteration_seeds(seed, i)
                total += self.estimate(eye_seed, photon_seed)
        image = total / iterations
        dr.eval(image)
        if not dr.all(dr.isfinite(dr.ravel(image)), axis=None):
            raise ParameterError(
                "the differentiable estimate holds NaN or infinite values: a scene parameter is "
                "NaN or infinite (check the values set through mi.traverse)"
            )
        return mi.TensorXf(dr.ravel(image), shape=(h, w, 3))

    def estimate(self, eye_seed: int, photon_seed: int) -> mi.Color3f:
        """One iteration's per-pixel radiance (row-major pixels)."""
        w, h = self.size
        image = dr.zeros(mi.Color3f, w * h)
        surface_points, medium_points = self.eye_vertices(eye_seed, image)
        surface_photons, medium_photons = self.photon_vertices(photon_seed)
        if surface_points is not None and surface_photons is not None:
            self.gather_surfaces(surface_points, surface_photons, image)
        if medium_points is not None and medium_photons is not None:
            self.gather_media(medium_points, medium_photons, image)
        return image

    # ------------------------------------------------------------------ transport
    def segment(self, ray, medium, ids, depth, seed: int, step: int, albedo: bool) -> Segment:
        """Trace wavefront ``step`` of the paths ``ids`` one segment (random numbers from
        ``(seed, step)`` and each path's id), evaluated once: its surface, or its collision in
        the medium the path travels in (:meth:`flight`)."""
        gen = lane_rng(ids, seed, step)
        si = self.scene.ray_intersect(ray, dr.full(mi.Bool, True, dr.width(ids)))
        scattered, mei, weight = self.flight(ray, si, medium, gen, albedo)
        on_surface = si.is_valid() & ~scattered
        bsdf = si.bsdf(ray)
        crossing = is_null(bsdf, on_surface)
        depth = depth + dr.select(crossing, 0, 1)
        dr.eval(si, scattered, mei, weight, depth, crossing)  # once, not once per gather
        return Segment(si, bsdf, mei, scattered, on_surface, crossing, depth, weight, gen)

    def flight(self, ray, si, medium, gen, albedo: bool):
        """Free flight of ``ray`` in ``medium`` up to the surface ``si``: ``(scattered, mei,
        weight)`` (module docstring: detached sampling, attached weights; ``albedo``: the
        collision's weight holds σ_s, as a photon's does)."""
        n = dr.width(ray.d)
        inside = medium != None  # noqa: E711 (Dr.Jit pointer test)
        mei = dr.zeros(mi.MediumInteraction3f, n)
        mei.p, mei.wi, mei.time = ray.o, -ray.d, ray.time
        mei.sh_frame = mi.Frame3f(mei.wi)
        mei.medium = medium
        sigma_s, _, sigma_t = medium.get_scattering_coefficients(mei, inside)
        fixed = dr.detach(sigma_t)
        ch = channel(gen)
        rate = pick(fixed, ch)
        t = dr.select(rate > 0, dr.minimum(-dr.log(1.0 - gen.next_float32()) / rate, FAR), FAR)
        length = dr.select(si.is_valid(), si.t, FAR)
        scattered = inside & (t < length)
        pdf_t = channel_mean(fixed * dr.exp(-fixed * t))
        at_collision = dr.exp(-sigma_t * t) / dr.maximum(pdf_t, 1e-30)
        if albedo:
            at_collision = at_collision * sigma_s
        p_length = channel_mean(dr.exp(-fixed * length))
        across = dr.select(p_length > 0, dr.exp(-sigma_t * length) / p_length, 0.0)
        weight = dr.select(scattered, at_collision, dr.select(inside, across, 1.0))
        mei.t = dr.select(scattered, t, dr.inf)
        mei.p = ray(dr.select(scattered, t, 0.0))
        return scattered, mei, mi.Spectrum(weight)

    def photon_vertices(self, seed: int) -> tuple[Photons | None, Photons | None]:
        """Trace ``photons`` paths from the emitters (``scene.sample_emitter_ray``); keep
        their vertices on smooth surfaces and their collisions in media, at most
        ``max_depth − 1`` segments from the light (an eye path needs one more). Each segment
        is one wavefront over the paths still alive, so that reverse-mode AD sees plain arrays
        (symbolic loops would need their own adjoint)."""
        count = self.photons
        ids = dr.arange(mi.UInt32, count)
        gen = lane_rng(ids, seed, 0)
        ray, power, emitter = self.scene.sample_emitter_ray(
            0.0,
            gen.next_float32(),
            mi.Point2f(gen.next_float32(), gen.next_float32()),
            mi.Point2f(gen.next_float32(), gen.next_float32()),
            True,
        )
        power = mi.Spectrum(power) / count
        medium = self.emitter_medium(emitter)
        depth = dr.zeros(mi.UInt32, count)
        throughput = dr.ones(mi.Float, count)  # detached max of the weights' product
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        phase_ctx = mi.PhaseFunctionContext(None, mi.TransportMode.Importance)
        limit = self.bounces - 1
        surface, volume = [], []
        for step in range(1, self.wavefronts + 1):
            seg = self.segment(ray, medium, ids, depth, seed, step, albedo=True)
            si, bsdf, mei, scattered, depth = seg.si, seg.bsdf, seg.mei, seg.scattered, seg.depth
            on_surface, crossing, gen = seg.on_surface, seg.crossing, seg.gen
            power = power * seg.weight
            smooth = on_surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            _keep(surface, Photons, smooth & (depth <= limit), p=si.p, n=si.n, d=ray.d,
                  power=power, depth=depth)  # fmt: skip
            _keep(volume, Photons, scattered & (depth <= limit), p=mei.p,
                  n=dr.zeros(mi.Normal3f, dr.width(ids)), d=ray.d, power=power, depth=depth)
            u1, u2 = gen.next_float32(), mi.Point2f(gen.next_float32(), gen.next_float32())
            bs, value = bsdf.sample(ctx, si, u1, u2, on_surface)
            wo = si.to_world(bs.wo)
            next_ray = si.spawn_ray(wo)
            going = on_surface & (bs.pdf > 0)
            if self.traits.media:
                phase = mei.medium.phase_function()
                wo_m, value_m, _ = phase.sample(phase_ctx, mei, u1, u2, scattered)
                value = dr.select(scattered, value_m, value)
                next_ray = dr.select(scattered, mei.spawn_ray(wo_m), next_ray)
                medium = enter(si, wo, medium, on_surface)
                going |= scattered
            power = power * value
            throughput = throughput * dr.max(dr.detach(value))
            alive = going & (throughput > 0) & dr.select(crossing, depth <= limit, depth < limit)
            if self.settings.rr_depth <= limit:
                roulette = alive & ~crossing & (depth >= self.settings.rr_depth)
                q = dr.select(roulette, dr.minimum(throughput, RR_MAX), 1.0)
                alive &= gen.next_float32() < q
                power, throughput = power / q, throughput / q
            dr.eval(next_ray, power, throughput, medium, alive)
            live = dr.compress(alive)
            if not dr.width(live):
                break
            ray, power, ids = _take(next_ray, live), _take(power, live), _take(ids, live)
            medium, depth = _take(medium, live), _take(depth, live)
            throughput = _take(throughput, live)
        return _joined(surface, Photons), _joined(volume, Photons)

    def emitter_medium(self, emitter: mi.EmitterPtr) -> mi.MediumPtr:
        """The medium each sampled emitter emits into
        (:func:`~photonmap.core.media.emitter_media`)."""
        medium = dr.zeros(mi.MediumPtr, dr.width(emitter))
        for candidate, surrounding in zip(self.scene.emitters(), self.emitter_media, strict=True):
            if surrounding is not None:
                here = emitter == mi.EmitterPtr(candidate)
                medium = dr.select(here, mi.MediumPtr(surrounding), medium)
        return medium

    def eye_vertices(self, seed: int, image: mi.Color3f):
        """Trace ``spp`` jittered eye paths per pixel; keep their vertices on smooth surfaces
        and their collisions in media (which end them). A path goes on through a smooth
        vertex's delta lobes (a plastic's coating), sampled alone, and through the whole BSDF of
        a vertex without a smooth lobe (mirrors, glass). The emission the paths
        meet is added to ``image`` (emitters seen directly too, unless hidden)."""
        w, h = self.size
        count = w * h * self.spp
        ids = dr.arange(mi.UInt32, count)
        gen = lane_rng(ids, seed, 0)
        pixel = ids // self.spp
        jitter = mi.Point2f(gen.next_float32(), gen.next_float32())
        ray, weight = pixel_rays(self.sensor, pixel, jitter)
        beta = mi.Spectrum(weight) / self.spp
        medium = broadcast(self.sensor.get_medium(), count)
        depth = dr.zeros(mi.UInt32, count)
        radiance = mi.BSDFContext(mi.TransportMode.Radiance)
        delta_only = mi.BSDFContext(mi.TransportMode.Radiance)
        delta_only.type_mask = int(mi.BSDFFlags.Delta)
        surface, volume = [], []
        for step in range(1, self.wavefronts + 1):
            seg = self.segment(ray, medium, ids, depth, seed, step, albedo=False)
            si, bsdf, mei, scattered, depth = seg.si, seg.bsdf, seg.mei, seg.scattered, seg.depth
            on_surface, crossing, gen = seg.on_surface, seg.crossing, seg.gen
            beta = beta * seg.weight
            seen = ~scattered & (si.emitter(self.scene) != None)  # noqa: E711 (the sky too)
            if self.settings.hide_emitters:
                seen &= depth > 1
            seen &= self.settings.allows(depth)
            dr.scatter_add(image, beta * si.emitter(self.scene).eval(si, seen), pixel, seen)
            _keep(volume, MediumPoints, scattered & (depth < self.bounces), mei=mei, beta=beta,
                  pixel=pixel, depth=depth)  # fmt: skip
            flags = bsdf.flags()
            smooth = on_surface & mi.has_flag(flags, mi.BSDFFlags.Smooth)
            _keep(surface, SurfacePoints, smooth & (depth < self.bounces), si=si, beta=beta,
                  pixel=pixel, depth=depth)  # fmt: skip
            u1, u2 = gen.next_float32(), mi.Point2f(gen.next_float32(), gen.next_float32())
            through_delta = smooth & mi.has_flag(flags, mi.BSDFFlags.Delta)
            bs, value = bsdf.sample(delta_only, si, u1, u2, through_delta)
            other = on_surface & ~smooth
            bs_other, value_other = bsdf.sample(radiance, si, u1, u2, other)
            bs = dr.select(other, bs_other, bs)
            beta = beta * dr.select(other, value_other, value)
            wo = si.to_world(bs.wo)
            medium = enter(si, wo, medium, on_surface)
            alive = (through_delta | other) & (bs.pdf > 0) & (dr.max(dr.detach(beta)) > 0)
            alive &= dr.select(crossing, depth <= self.bounces, depth < self.bounces)
            next_ray = si.spawn_ray(wo)
            dr.eval(next_ray, beta, medium, alive)
            live = dr.compress(alive)
            if not dr.width(live):
                break
            ray = _take(next_ray, live)
            beta, ids, pixel = _take(beta, live), _take(ids, live), _take(pixel, live)
            medium, depth = _take(medium, live), _take(depth, live)
        return _joined(surface, SurfacePoints), _joined(volume, MediumPoints)

    # ------------------------------------------------------------------ density estimates
    def _pairs(self, query: mi.Point3f, photons: mi.Point3f, radius: float):
        """The (query, photon) pairs within ``radius``, found on detached positions: a hash grid
        (cell ``2 radius``) over the queries, searched from each photon, so that a photon's
        pairs are adjacent and the backward pass's scatter-adds into the photons reduce within
        a SIMD packet."""
        grid = HashGrid(dr.detach(query), cell_size=2 * radius)
        photon, query_index = grid.pairs_within(
            dr.detach(photons), dr.opaque(mi.Float, radius * radius), mi.Bool(True), span=2
        )
        return query_index, photon

    def _depth_ok(self, eye_depth: mi.UInt32, photon_depth: mi.UInt32) -> mi.Bool:
        """The two paths together fit ``max_depth``."""
        if self.settings.max_depth == UNBOUNDED:
            return dr.full(mi.Bool, True, dr.width(eye_depth))
        return eye_depth + photon_depth <= self.settings.max_depth

    def gather_surfaces(self, points: SurfacePoints, photons: Photons, image) -> None:
        """Add ``Σ_p K(‖x − x_p‖) f(x, ω_o, ω_p) Φ_p`` at every surface point to its pixel. The
        sum over the pairs within ``r`` is plain differentiable arithmetic. A photon counts
        where its normal is within 30° of the point's (light on the other side of a thin wall
        does not leak) and the two paths together fit ``max_depth``."""
        r = self.radius
        query, photon = self._pairs(points.si.p, photons.p, r)
        if not dr.width(query):
            return
        si = _take(points.si, query)
        d2 = dr.squared_norm(si.p - _take(photons.p, photon))
        kernel = _epanechnikov(d2, r * r, 2.0 / (math.pi * r * r))
        ok = dr.dot(dr.detach(si.n), dr.detach(_take(photons.n, photon))) > COS_NORMAL
        ok &= self._depth_ok(_take(points.depth, query), _take(photons.depth, photon))
        wo = si.to_local(-_take(photons.d, photon))
        f = si.bsdf().eval(mi.BSDFContext(), si, wo, ok) / dr.maximum(
            dr.abs(mi.Frame3f.cos_theta(wo)), 1e-4
        )
        share = _take(points.beta, query) * f * kernel * _take(photons.power, photon)
        dr.scatter_add(image, share, _take(points.pixel, query), ok)

    def gather_media(self, points: MediumPoints, photons: Photons, image) -> None:
        """Add ``Σ_p K₃(‖x − x_p‖) f_p(ω_o, ω_p) Φ_p`` at every medium point to its pixel."""
        rho = self.volume_radius
        query, photon = self._pairs(points.mei.p, photons.p, rho)
        if not dr.width(query):
            return
        mei = _take(points.mei, query)
        d2 = dr.squared_norm(mei.p - _take(photons.p, photon))
        kernel = _epanechnikov(d2, rho * rho, 15.0 / (8.0 * math.pi * rho**3))
        ok = self._depth_ok(_take(points.depth, query), _take(photons.depth, photon))
        wo = -_take(photons.d, photon)
        f, _ = mei.medium.phase_function().eval_pdf(mi.PhaseFunctionContext(None), mei, wo, ok)
        share = _take(points.beta, query) * f * kernel * _take(photons.power, photon)
        dr.scatter_add(image, share, _take(points.pixel, query), ok)
