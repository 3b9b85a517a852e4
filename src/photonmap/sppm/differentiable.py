"""Differentiable photon mapping: the memoryless photon-mapping estimate (Knaus & Zwicker 2011)
with a smooth kernel, differentiated by Dr.Jit's automatic differentiation.

One iteration traces ``photons`` light paths and ``spp`` eye paths per pixel and estimates the
light at the eye paths' diffuse vertices from the photons within ``r`` (Jensen 2001, eq. 7.6,
with a kernel)::

    L(x, ω_o) ≈ Σ_p K(‖x − x_p‖) f(x, ω_o, ω_p) Φ_p,    K(d) = 2/(π r²) · (1 − d²/r²)

(the Epanechnikov kernel, normalised on the disk; ``f`` is the BSDF without its cosine, its
glossy lobes included where it also has a diffuse one). Eye paths go on through delta lobes (a
vertex with a diffuse lobe) or by sampling the whole BSDF (glossy and specular vertices); photons
are kept at diffuse vertices. A box
kernel — counting the photons within ``r`` — has zero derivative almost everywhere; ``K`` is
continuous, so the estimate is differentiable in the photon positions ``x_p``, the visible points
``x`` and the weights ``Φ_p``, and reverse- or forward-mode AD through the photon trace, the eye
trace and this sum gives its gradient (the smooth-kernel form of Xing, Li, Luan & Xu 2024,
"Differentiable Photon Mapping using Generalized Path Gradients", without their term for the
moving merging region: here ``r`` is fixed).

What carries derivatives:

- **photon positions and directions**: every intersection is Mitsuba's differentiable
  ``ray_intersect`` (mesh vertex positions and normals, shape transforms move the hit points;
  refraction directions follow the normals and ``eta`` — Mitsuba's ``dielectric`` keeps its
  index as a plain float, so the index's derivative needs the ``diff_dielectric`` BSDF
  (:mod:`photonmap.core.diff_dielectric`), the same interface with a differentiable ``eta``);
- **weights**: emitted power (radiance, and the emitter's pose through its sampled positions),
  BSDF values (albedos, Fresnel), the eye paths' throughput and the emission they see;
- **discrete choices** (a dielectric's reflect-or-refract, Russian roulette) are sampled with
  detached probabilities and weighted by ``f / detach(f)`` where Mitsuba's BSDF does so, so the
  derivative of the choice's probability enters the weight.

What does not: **visibility** — a photon or eye ray that changes which surface it hits (a
silhouette, an occluder's edge, a light moving into shadow) contributes no derivative for that
change (no edge sampling or reparameterisation), and the kernel radius is fixed. Gradients are
therefore those of the interior of each visibility region; caustics through smooth refractors
and the light falling on open receivers are what they are built for.

Participating media are refused (:class:`~photonmap.core.errors.SceneError`) here; see
``docs/methods/differentiable.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import drjit as dr
import mitsuba as mi

from ..core.camera import footprint_radius, pixel_rays
from ..core.errors import ParameterError, SceneError
from ..core.hashgrid import HashGrid
from ..core.knn import COS_NORMAL
from ..core.progressive import iteration_seeds
from ..core.scene_info import SceneTraits, check_gathered_bsdfs
from ..core.settings import UNBOUNDED, PathSettings, check_path_params, overridden

RADIUS_PIXELS = 2.0  # automatic kernel radius, in pixel footprints at the median eye distance
MAX_BOUNCES = 64  # unbounded paths (max_depth −1) are unrolled this far at most
RR_MAX = 0.95  # Russian roulette survives with at most this probability


@dataclass
class Vertices:
    """Photons (light-path vertices) or visible points (eye-path vertices) on diffuse surfaces,
    attached to the scene parameters."""

    si: mi.SurfaceInteraction3f  # the interaction (its ``p``, ``n``, and for eye vertices ``wi``)
    weight: mi.Spectrum  # photon: its power Φ_p; eye vertex: its throughput over spp
    depth: mi.UInt32  # segments from the light (photons) or the camera (eye vertices)
    index: mi.UInt32  # photon: its path; eye vertex: its pixel
    d: mi.Vector3f  # the direction of travel that reached the vertex


def lane_rng(ids: mi.UInt32, seed: int, stream: int) -> mi.PCG32:
    """One PCG32 per lane, keyed by the lane's path id ``ids`` and ``(seed, stream)``: a path's
    random numbers at one bounce do not depend on which other paths are still alive."""
    key = mi.sample_tea_32(mi.UInt32(seed & 0xFFFFFFFF), mi.UInt32(stream), 8)[0][0]
    state, sequence = mi.sample_tea_32(dr.opaque(mi.UInt32, key), mi.UInt32(ids))
    gen = mi.PCG32()  # seeded here: the constructor would add the lane number to both
    gen.seed(mi.UInt64(state), mi.UInt64(sequence))
    return gen


def _take(values, index: mi.UInt32):
    """``values`` (an array or a Mitsuba struct) at ``index``: a differentiable gather."""
    return dr.gather(type(values), values, index)


class DifferentiablePhotonMapper:
    """The differentiable memoryless photon-mapping estimate of ``scene`` seen by ``sensor``
    (module docstring). ``render(seed, iterations)`` returns an image attached to whatever scene
    parameters have gradients enabled.

    ``photons``: photon paths per iteration; ``spp``: eye paths per pixel and iteration;
    ``radius``: the kernel radius in scene units (0: :data:`RADIUS_PIXELS` pixel footprints);
    ``max_depth``, ``rr_depth``, ``hide_emitters``: the scene file's by default, with Mitsuba's
    meaning.
    """

    def __init__(
        self,
        scene: mi.Scene,
        sensor: mi.Sensor | int = 0,
        photons: int = 200_000,
        spp: int = 1,
        radius: float = 0.0,
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
        for name, value, low in (("photons", photons, 1), ("spp", spp, 1)):
            if not (isinstance(value, int) and value >= low):
                raise ParameterError(f"{name} must be an integer >= {low}, got {value!r}")
        if not (isinstance(radius, (int, float)) and math.isfinite(radius) and radius >= 0):
            raise ParameterError(f"radius must be >= 0 (0 = automatic), got {radius!r}")
        if isinstance(hide_emitters, bool):
            hide_emitters = str(hide_emitters).lower()
        check_path_params(SimpleNamespace(
            max_depth=max_depth, rr_depth=rr_depth, hide_emitters=hide_emitters
        ))  # fmt: skip
        if SceneTraits.of(scene).media:
            raise SceneError(
                "differentiable photon mapping does not support participating media yet; "
                "remove the media, or differentiate the volume method (photonmap.volume.gradients)"
            )
        check_gathered_bsdfs(scene, "differentiable sppm")
        if not scene.emitters():
            raise SceneError("the scene has no emitter: nothing to differentiate")
        self.scene, self.sensor = scene, sensor
        self.photons, self.spp = photons, spp
        self.settings = overridden(PathSettings.of(scene), max_depth, rr_depth, hide_emitters)
        self.radius = float(radius) or footprint_radius(scene, sensor, RADIUS_PIXELS)
        self.size = tuple(int(c) for c in sensor.film().crop_size())

    @property
    def bounces(self) -> int:
        """The most segments a light or eye path is traced (``max_depth``, or
        :data:`MAX_BOUNCES` when unbounded)."""
        depth = self.settings.max_depth
        return MAX_BOUNCES if depth == UNBOUNDED else depth

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
        return mi.TensorXf(dr.ravel(image), shape=(h, w, 3))

    def estimate(self, eye_seed: int, photon_seed: int) -> mi.Color3f:
        """One iteration's per-pixel radiance (row-major pixels)."""
        w, h = self.size
        image = dr.zeros(mi.Color3f, w * h)
        points = self.eye_vertices(eye_seed, image)
        photons = self.photon_vertices(photon_seed)
        if dr.width(points.depth) and dr.width(photons.depth):
            self.gather(points, photons, image)
        return image

    # ------------------------------------------------------------------ light paths
    def photon_vertices(self, seed: int) -> Vertices:
        """Trace ``photons`` paths from the emitters (``scene.sample_emitter_ray``) and keep
        their vertices on diffuse surfaces, at most ``max_depth − 1`` segments from the light
        (an eye path needs one more). Each bounce is one wavefront over the paths still alive,
        so that reverse-mode AD sees plain arrays (symbolic loops would need their own
        adjoint)."""
        count = self.photons
        ids = dr.arange(mi.UInt32, count)
        gen = lane_rng(ids, seed, 0)
        ray, power, _ = self.scene.sample_emitter_ray(
            0.0,
            gen.next_float32(),
            mi.Point2f(gen.next_float32(), gen.next_float32()),
            mi.Point2f(gen.next_float32(), gen.next_float32()),
            True,
        )
        power = mi.Spectrum(power) / count
        throughput = dr.ones(mi.Float, count)  # detached max of the BSDF weights' product
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        kept = []
        for depth in range(1, self.bounces):
            si = self.scene.ray_intersect(ray, dr.full(mi.Bool, True, dr.width(ids)))
            bsdf = si.bsdf(ray)
            hit = si.is_valid()
            diffuse = hit & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Diffuse)
            stored = dr.compress(diffuse)
            if dr.width(stored):
                kept.append(Vertices(
                    _take(si, stored), _take(power, stored),
                    dr.full(mi.UInt32, depth, dr.width(stored)), _take(ids, stored),
                    _take(ray.d, stored),
                ))  # fmt: skip
            if depth + 1 >= self.bounces:
                break
            gen = lane_rng(ids, seed, depth)
            bs, value = bsdf.sample(
                ctx, si, gen.next_float32(), mi.Point2f(gen.next_float32(), gen.next_float32()),
                hit,
            )  # fmt: skip
            power = power * value
            throughput = throughput * dr.max(dr.detach(value))
            alive = hit & (bs.pdf > 0) & (throughput > 0)
            if depth >= self.settings.rr_depth:
                q = dr.minimum(throughput, RR_MAX)
                alive &= gen.next_float32() < q
                power = power / dr.select(alive, q, 1.0)
                throughput = throughput / dr.select(alive, q, 1.0)
            live = dr.compress(alive)
            if not dr.width(live):
                break
            ray = _take(si.spawn_ray(si.to_world(bs.wo)), live)
            power, ids, throughput = _take(power, live), _take(ids, live), _take(throughput, live)
        return _joined(kept)

    # ------------------------------------------------------------------ eye paths
    def eye_vertices(self, seed: int, image: mi.Color3f) -> Vertices:
        """Trace ``spp`` jittered eye paths per pixel and keep their vertices on diffuse
        surfaces; a path goes on through a diffuse vertex's delta lobes (a plastic's coating),
        sampled alone, and through the whole BSDF of a vertex without a diffuse lobe (mirrors,
        glass, glossy metals). The emission the paths see is added to ``image`` (emitters seen
        directly too, unless hidden)."""
        w, h = self.size
        count = w * h * self.spp
        ids = dr.arange(mi.UInt32, count)
        gen = lane_rng(ids, seed, 0)
        pixel = ids // self.spp
        ray, weight = pixel_rays(self.sensor, pixel, mi.Point2f(gen.next_float32(),
                                                                gen.next_float32()))
        beta = mi.Spectrum(weight) / self.spp
        radiance = mi.BSDFContext(mi.TransportMode.Radiance)
        delta_only = mi.BSDFContext(mi.TransportMode.Radiance)
        delta_only.type_mask = int(mi.BSDFFlags.Delta)
        kept = []
        for depth in range(1, self.bounces + 1):
            si = self.scene.ray_intersect(ray, dr.full(mi.Bool, True, dr.width(ids)))
            hit = si.is_valid()
            seen = si.emitter(self.scene) != None  # noqa: E711 (Dr.Jit pointer test; the sky too)
            if depth == 1 and self.settings.hide_emitters:
                seen = dr.zeros(mi.Bool, dr.width(ids))
            emitted = beta * si.emitter(self.scene).eval(si, seen)
            dr.scatter_add(image, emitted, pixel, seen)
            if depth == self.bounces:
                break
            bsdf = si.bsdf(ray)
            flags = bsdf.flags()
            diffuse = hit & mi.has_flag(flags, mi.BSDFFlags.Diffuse)
            stored = dr.compress(diffuse)
            if dr.width(stored):
                kept.append(Vertices(
                    _take(si, stored), _take(beta, stored),
                    dr.full(mi.UInt32, depth, dr.width(stored)), _take(pixel, stored),
                    _take(ray.d, stored),
                ))  # fmt: skip
            gen = lane_rng(ids, seed, depth)
            u1, u2 = gen.next_float32(), mi.Point2f(gen.next_float32(), gen.next_float32())
            through_delta = diffuse & mi.has_flag(flags, mi.BSDFFlags.Delta)
            bs, value = bsdf.sample(delta_only, si, u1, u2, through_delta)
            other = hit & ~diffuse
            bs_other, value_other = bsdf.sample(radiance, si, u1, u2, other)
            bs = dr.select(other, bs_other, bs)
            value = dr.select(other, value_other, value)
            beta = beta * value
            alive = (through_delta | other) & (bs.pdf > 0) & (dr.max(dr.detach(beta)) > 0)
            live = dr.compress(alive)
            if not dr.width(live):
                break
            ray = _take(si.spawn_ray(si.to_world(bs.wo)), live)
            beta, ids, pixel = _take(beta, live), _take(ids, live), _take(pixel, live)
        return _joined(kept)

    # ------------------------------------------------------------------ density estimate
    def gather(self, points: Vertices, photons: Vertices, image: mi.Color3f) -> None:
        """Add ``Σ_p K(‖x − x_p‖) f(x, ω_o, ω_p) Φ_p`` at every eye vertex to its pixel of
        ``image``. The pairs within ``r`` are found on detached positions (a hash grid of cell
        ``2r``); the sum over them is plain differentiable arithmetic. A photon counts where its
        normal is within 30° of the vertex's (light on the other side of a thin wall does not
        leak) and the two paths together fit ``max_depth``."""
        r = self.radius
        grid = HashGrid(dr.detach(photons.si.p), cell_size=2 * r)
        query, photon = grid.pairs_within(
            dr.detach(points.si.p), dr.opaque(mi.Float, r * r), mi.Bool(True), span=2
        )
        if not dr.width(query):
            return
        si = _take(points.si, query)
        p = _take(photons.si.p, photon)
        d2 = dr.squared_norm(si.p - p)
        kernel = dr.maximum(1.0 - d2 / (r * r), 0.0) * (2.0 / (math.pi * r * r))
        ok = dr.dot(dr.detach(si.n), dr.detach(_take(photons.si.n, photon))) > COS_NORMAL
        if self.settings.max_depth != UNBOUNDED:
            depth = _take(points.depth, query) + _take(photons.depth, photon)
            ok &= depth <= self.settings.max_depth
        wo = si.to_local(-_take(photons.d, photon))
        f = si.bsdf().eval(mi.BSDFContext(), si, wo, ok) / dr.maximum(
            dr.abs(mi.Frame3f.cos_theta(wo)), 1e-4
        )
        share = _take(points.weight, query) * f * kernel * _take(photons.weight, photon)
        dr.scatter_add(image, share, _take(points.index, query), ok)


def _joined(parts: list[Vertices]) -> Vertices:
    """The vertices of every bounce in one set (empty when there are none)."""
    if not parts:
        return Vertices(
            dr.zeros(mi.SurfaceInteraction3f, 0), dr.zeros(mi.Spectrum, 0),
            dr.zeros(mi.UInt32, 0), dr.zeros(mi.UInt32, 0), dr.zeros(mi.Vector3f, 0),
        )  # fmt: skip
    if len(parts) == 1:
        return parts[0]
    total = sum(dr.width(v.depth) for v in parts)
    joined = Vertices(
        dr.zeros(mi.SurfaceInteraction3f, total), dr.zeros(mi.Spectrum, total),
        dr.zeros(mi.UInt32, total), dr.zeros(mi.UInt32, total), dr.zeros(mi.Vector3f, total),
    )  # fmt: skip
    start = 0
    for v in parts:
        n = dr.width(v.depth)
        at = dr.arange(mi.UInt32, start, start + n)
        for name in ("si", "weight", "depth", "index", "d"):
            dr.scatter(getattr(joined, name), getattr(v, name), at)
        start += n
    return joined
