"""``SurfacePipeline`` — classic two-pass photon mapping as Steinhurst 2007 uses it as his baseline
(Ch. 2 §2.6, §7.3), after Jensen.

Pass 1 traces ``photons`` light paths into the global map and ``caustic_photons`` into the caustic
map. Pass 2 sends ``spp`` eye rays per pixel; each follows mirrors and glass to the first
non-specular surface x, where

    L(x, ω_o) = L_e + L_direct + L_caustic + L_indirect

- ``L_e``: emitters met on the way (the lights and their images in mirrors and glass), with
  ``emitter_spp`` extra samples in the pixels that show them (:func:`light_images`);
- ``L_direct``: emitter sampling and BSDF sampling with MIS (:mod:`.direct`), ``light_samples``
  emitter samples with a stratified pick of the light (automatic: one per emitter, at most 8);
- ``L_caustic``: direct visualisation of the caustic map, k-NN radiance estimate (Eq 2.6), once per
  pixel where all its samples see one surface directly (:func:`caustic_radiance`);
- ``L_indirect``: final gather of ``fg_rays`` rays (:mod:`.final_gather`; directions by
  ``fg_sampling``: BSDF, cosine, uniform, Jensen's photon pdf or combined importance sampling,
  Steinhurst Ch. 6, :mod:`.cis`), optionally through an irradiance cache (``irradiance_cache``:
  Ward's or Steinhurst's tiled cache with precomputed R_avg, Ch. 5, :mod:`.irradiance_cache`),
  whose secondary hits read
  irradiance precomputed at photon positions (``lookup="irradiance"``, default), or run an exact
  k-NN gather per ray (``lookup="knn"``, the dissertation's naive algorithm); ``lookup="direct"``
  skips the final gather and reads the global map at x (photons after ≥ 1 diffuse bounce).

The photon maps are built once per scene and parameter set and reused for every render (a camera
move re-renders without new photons, Steinhurst §7.2.1).

Participating media (Jensen & Christensen 1998): in a scene with fog
(homogeneous or ``heterogeneous`` Mitsuba media, bounded by ``null``, dielectric or any
medium-transition shapes, around the sensor or the emitters) the photons fly through the media and
a third map holds the volume photons (:func:`~.photon_map.build_photon_maps`). Eye and
final-gather paths sample free flights through the media (the transport core's eye-path loop,
:func:`~photonmap.core.eye_trace.trace_eye_paths`); one that collides in a medium ends there and
reads single scattering of direct light by a transmittance shadow ray plus the volume map's
estimate of the rest (:mod:`.volume`: ``volume_k`` photons within ``volume_radius``). Shadow rays
of the direct light carry the transmittance.

The scene file's ``max_depth``, ``rr_depth`` and ``hide_emitters`` are the defaults
(:class:`~photonmap.core.settings.PathSettings`; Mitsuba's meaning of depth).
"""

from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import to_jit, to_numpy
from ..core.bsdf import diffuse_albedo, has_glossy_shapes
from ..core.camera import pixel_means, pixel_rays, scene_bounds
from ..core.direct import direct_lighting
from ..core.errors import PhotonmapWarning, SceneError
from ..core.eye_rules import EyeRules, EyeVertices
from ..core.eye_trace import trace_eye_paths
from ..core.media import broadcast, emitter_media, isotropic
from ..core.memory import check_once
from ..core.params import updated
from ..core.pipeline import Pipeline
from ..core.sampling import rng, rotated_hammersley
from ..core.scene_info import SceneTraits, warn_disagreeing_media
from ..core.settings import PathSettings, overridden
from ..core.stages import StageCache
from ..core.volume_map import ScatteredDensity, VolumeMap
from . import memory
from .cis import TABLE_SAMPLING, sampling_table
from .eye_terms import caustic_radiance, light_images
from .final_gather import GatherPoints, GatherRays, GatherReading, final_gather
from .gather import radiance_estimate
from .gather_batch import OrderParams, RequestLayout
from .irradiance import lookup_radiance, precompute_irradiance, with_glossy_estimates
from .irradiance_cache import (
    RAVG_RAYS,
    apply_cache,
    cache_order,
    harmonic_mean_distance,
    plan_cache,
    precompute_ravg,
    ravg_limits,
)
from .params import STAGES, SurfaceParams
from .photon_map import build_photon_maps, photon_map
from .volume import MediumLight, march_step

CAUSTIC_RADIUS = 0.05  # automatic caustic gather radius, × scene diagonal (radii(): ours)
GLOBAL_RADIUS = 0.1  # automatic global gather radius, × scene diagonal (radii(): ours)
VOLUME_RADIUS = 0.1  # automatic volume gather radius, × scene diagonal
LIGHT_SAMPLES = 8  # automatic emitter samples of the direct light: one per emitter, at most


class SurfacePipeline(Pipeline):
    """Two-pass photon mapping of a Mitsuba scene (name, XML path, dict or ``mi.Scene``).

    >>> pipe = SurfacePipeline("cornell_steinhurst", photons=200_000, fg_rays=32)
    >>> image = pipe.render()           # mi.TensorXf (height, width, 3)
    """

    method, params_type, stages = "surface", SurfaceParams, STAGES

    def __init__(self, scene, **params):
        from ..scenes import load_with_sensor

        self.cache = StageCache()
        self.scene, self.sensor, own = load_with_sensor(scene, SurfaceParams, params)
        self.traits = SceneTraits.of(self.scene)
        if self.traits.media:
            warn_disagreeing_media(self.scene, "surface")
        self.file_settings = PathSettings.of(self.scene, scene)
        self.emitter_media = emitter_media(self.scene)
        self.glossy_shapes = has_glossy_shapes(self.scene)  # final gathers need k-NN there
        self.params = SurfaceParams()
        self.set_params(**own)
        self.stats: dict[str, float] = {}
        self.kept_requests: list | None = None  # a list: keep the k-NN final-gather batches
        self.requests_only = False  # with kept_requests: keep them without gathering
        self._warned_spp = False  # the warning about one eye ray per pixel in fog, given once

    def set_params(self, **params) -> None:
        """Change pipeline parameters (:class:`SurfaceParams` fields); settings that would not
        fit in memory are refused (:meth:`check_memory`)."""
        new = updated(self.params, params, "surface")
        self.check_memory(new)
        self.params = new

    def check_memory(self, params: SurfaceParams | None = None, size=None) -> int:
        """Raise a :class:`ParameterError` when ``params`` (default: the pipeline's) at ``size``
        (width, height; default: the camera's) would need more memory than is available
        (:mod:`.memory`); return the estimate in bytes."""
        p = params or self.params
        w, h = size or self.size
        depth = overridden(self.file_settings, p.max_depth, p.rr_depth, p.hide_emitters).max_depth
        return memory.check(p, w, h, depth, self.traits.media)

    @property
    def settings(self) -> PathSettings:
        """The path-length settings: the file's, with this pipeline's parameters applied."""
        p = self.params
        return overridden(self.file_settings, p.max_depth, p.rr_depth, p.hide_emitters)

    @property
    def diagonal(self) -> float:
        return scene_bounds(self.scene)[1]

    def radii(self) -> tuple[float, float]:
        """Maximum gather radius for the caustic and the global map (Steinhurst gives none): 5% of
        the scene diagonal for caustics; for the global map 10% rather than an unbounded search
        (k-limited), which visits the whole grid wherever fewer than k photons pass the normal
        test."""
        if self.params.radius > 0:
            return self.params.radius, self.params.radius
        return CAUSTIC_RADIUS * self.diagonal, GLOBAL_RADIUS * self.diagonal

    @property
    def _maps_key(self) -> tuple:
        """What the photon maps depend on."""
        p = self.params
        return (p.photons, p.caustic_photons, p.structure, self.settings, p.seed)

    def _traced_maps(self) -> tuple[object, object, VolumeMap | None]:
        """Stage "photon maps": the global map, the caustic map and the volume map (scenes
        with media), traced again only when a parameter of the tracing changes."""

        def trace():
            p = self.params
            global_map, caustic_map, volume = build_photon_maps(
                self.scene, p.photons, p.caustic_photons, p.structure, self.settings,
                p.seed, self.traits, self.emitter_media,
            )  # fmt: skip
            if volume is not None:
                self.stats.update(volume_photons=volume.size)
            self.stats.update(global_photons=global_map.size, caustic_photons=caustic_map.size)
            return global_map, caustic_map, volume

        return self.cache.stage("photon maps", self._maps_key, trace)

    def photon_maps(self):
        """Global map, caustic map and the lookup's own data — for ``lookup="irradiance"`` the
        precomputed irradiance, for ``"direct"`` the indirect photons' map — each kept while
        its inputs are unchanged: the maps are traced again only when a parameter of the
        tracing changes, the derived data when a lookup parameter or the maps change."""
        p = self.params
        global_map, caustic_map, _ = self._traced_maps()
        extra = None
        if p.lookup == "irradiance":
            key = (self._maps_key, p.k, p.irradiance_every, p.radius)
            extra = self.cache.stage("irradiance", key, lambda: precompute_irradiance(
                global_map, p.irradiance_every, p.k, self.radii()[1]))  # fmt: skip
        elif p.lookup == "direct":  # direct visualisation: only photons after a diffuse bounce
            extra = self.indirect_photons()
        return global_map, caustic_map, extra

    def indirect_photons(self):
        """The global map's photons that came from another surface after a diffuse bounce —
        neither straight from a light nor through mirrors and glass (direct light and caustics
        at x are computed separately): the light a final-gather ray can find, as its own map
        (the direct visualisation, and the photon tables of Jensen's and Steinhurst's
        importance sampling, whose k nearest photons should all be of that light)."""
        global_map = self._traced_maps()[0]

        def select():
            later = global_map.photons.after_first()
            return photon_map(later.select(~later.caustic), self.params.structure)

        return self.cache.stage("indirect photons", self._maps_key, select, timed=False)

    def medium_light(self) -> MediumLight:
        """The in-scattered light of the current volume map (:mod:`.volume`): the automatic
        gather radius is :data:`VOLUME_RADIUS` × the scene diagonal, the automatic march step half
        the median distance of the ``volume_k``-th nearest photon (the step follows the photon
        density, as the radius of the estimate does); in isotropic media the density precomputed
        at every ``irradiance_every``-th volume photon."""
        p = self.params
        radius = p.volume_radius if p.volume_radius > 0 else VOLUME_RADIUS * self.diagonal
        volume = self._traced_maps()[2]

        def density():
            built = None
            if isotropic(self.scene) and volume.size:
                built = ScatteredDensity.build(volume, p.irradiance_every, p.volume_k, radius)
            return march_step(volume, p.volume_k, radius), built

        key = (self._maps_key, p.volume_k, radius, p.irradiance_every)
        auto_step, built = self.cache.stage("scattered density", key, density, timed=False)
        step = p.march_step if p.march_step > 0 else auto_step
        return MediumLight(self.scene, volume, p.volume_k, radius, built, p.seed, step)

    def request_layout(
        self, w: int, h: int, bounces: mi.UInt32, lanes=None
    ) -> RequestLayout | None:
        """How the final gather emits and orders its k-NN requests (``lookup="knn"``);
        ``lanes``: the query point of each gathering lane when only some gather (the irradiance
        cache's plan)."""
        p = self.params
        if p.lookup != "knn":
            return None
        bbox = self.scene.bbox()
        return RequestLayout(
            w,
            h,
            p.spp,
            bounces.numpy() > 0,
            (np.array(bbox.min), np.array(bbox.max)),
            p.gather_order,
            OrderParams(tile=p.tile),
            keep=self.kept_requests is not None,
            batches=self.kept_requests,
            lanes=lanes,
            record_only=self.requests_only,
        )

    def indirect(self, eye: EyeVertices, lookup, size, medium_light=None) -> mi.Spectrum:
        """``L_indirect`` at the eye paths' smooth vertices ``eye``: the final gather, sampled by
        ``fg_sampling``, at every vertex or — with an irradiance cache — at the vertices its plan
        gathers (:func:`~.irradiance_cache.plan_cache`), the others interpolating; ``lookup``:
        what a gather ray reads where it lands, ``size`` the image's."""
        p = self.params
        si, bsdf, found, depth, medium = eye.si, eye.bsdf, eye.found, eye.depth, eye.medium
        plan, irradiance, at, ok = None, None, si, found
        if p.irradiance_cache != "none":
            plan = self.cache_plan(si, bsdf, found, size)
            lanes = to_jit(mi.UInt32, plan.gather)
            at, ok = dr.gather(type(si), si, lanes), dr.gather(mi.Bool, found, lanes)
            depth = dr.gather(mi.UInt32, depth, lanes)
            medium = None if medium is None else dr.gather(mi.MediumPtr, medium, lanes)
            irradiance = mi.Bool(plan.record)
        table = None
        if p.fg_sampling in TABLE_SAMPLING:
            pmap = self.indirect_photons()
            table = sampling_table(p.fg_sampling, pmap, at, ok, p.k, self.radii()[1])
        L = dr.zeros(mi.Spectrum, 0)
        if dr.width(ok):
            layout = self.request_layout(*size, eye.bounces, None if plan is None else plan.gather)
            L = final_gather(
                self.scene,
                GatherPoints(at, ok, depth, medium, irradiance),
                GatherRays(p.fg_rays, p.seed, self.settings, self.traits, p.fg_sampling, table),
                GatherReading(lookup, p.lookup == "irradiance", layout, medium_light),
            )
        if plan is None:
            return L
        rho = diffuse_albedo(bsdf, si, found)
        return apply_cache(plan, L, rho, dr.width(found))

    def cache_plan(self, si, bsdf, found, size):
        """The irradiance cache's decisions (:func:`~.irradiance_cache.plan_cache`) for the
        eye-ray hits: R_avg cast at each hit (``ward``) or read at the nearest photon where it
        was precomputed (``tiled``); only purely Lambertian hits take part."""
        p = self.params
        limits = ravg_limits(self.scene)
        normal = si.sh_frame.n
        if p.irradiance_cache == "ward":
            R = harmonic_mean_distance(
                self.scene, si.p, normal, RAVG_RAYS, p.seed, limits, self.traits.null_shapes
            )
        else:
            global_map = self._traced_maps()[0]
            points = self.cache.stage("R_avg", self._maps_key, lambda: precompute_ravg(
                self.scene, global_map, p.seed, self.traits.null_shapes), timed=False)  # fmt: skip
            R = points.lookup(si, found, self.radii()[1], limits[0])
        flags = mi.UInt32(bsdf.flags())
        other = mi.BSDFFlags.Glossy | mi.BSDFFlags.Delta | mi.BSDFFlags.DiffuseTransmission
        lambertian = ((flags & int(other)) == 0) & (
            (flags & int(mi.BSDFFlags.DiffuseReflection)) > 0
        )
        order, cache = cache_order(p.irradiance_cache, *size, p.spp)
        plan = plan_cache(
            to_numpy(si.p).T.astype(np.float64),
            to_numpy(normal).T.astype(np.float64),
            R.numpy().astype(np.float64),
            lambertian.numpy(),
            found.numpy(),
            order,
            cache,
            p.ic_error,
        )
        self.stats.update(
            ic_final_gathers=len(plan.gather),
            ic_records=int(plan.record.sum()),
            ic_interpolated=len(plan.interpolate),
            ic_hit_rate=plan.hit_rate,
        )
        return plan

    def render(self, progress=None) -> mi.TensorXf:
        """Render from the current camera: ``(height, width, 3)`` linear radiance. The photon
        maps and what derives from them are kept while their inputs are unchanged; the eye
        pass, direct lighting, caustics, final gather and light images run every frame."""
        p = self.params
        check_once(self, p, self.size, self.check_memory)
        if self.traits.media and p.spp == 1 and not self._warned_spp:
            self._warned_spp = True
            warnings.warn(
                "one eye ray per pixel leaves the light the fog scatters noisy (each ray "
                "marches the fog once): raise --set spp (or --spp), e.g. to 4",
                PhotonmapWarning,
                stacklevel=2,
            )
        self.cache.new_frame(progress)
        global_map, caustic_map, extra = self.photon_maps()
        volume = self._traced_maps()[2]
        r_caustic, r_global = self.radii()
        w, h = self.size
        lanes = w * h * p.spp  # all samples of all pixels in one wavefront; a pixel's are adjacent
        pixel = dr.arange(mi.UInt32, lanes) // p.spp
        gen = rng(lanes, p.seed, 0)
        # a pixel's samples: stratified positions in the pixel and stratified light samples
        shifts = rng(w * h, p.seed, 2)
        sample = dr.arange(mi.UInt32, lanes) % p.spp

        def stratified() -> mi.Point2f:
            shift = mi.Point2f(shifts.next_float32(), shifts.next_float32())
            return rotated_hammersley(p.spp, sample, dr.gather(mi.Point2f, shift, pixel))

        jitter, u_light = stratified(), stratified()
        run = self.cache.run
        medium_light = self.medium_light() if volume is not None else None
        eye, L = run("eye pass", lambda: self._eye_pass(pixel, jitter, gen, medium_light))
        si, beta, found, bounces = eye.si, eye.beta, eye.found, eye.bounces
        bsdf = si.bsdf()
        L = run("direct lighting", lambda: _added(L, lambda: beta * direct_lighting(
            self.scene, si, u_light, gen, found, self.traits, eye.medium,
            self.light_samples())))  # fmt: skip
        L = run("caustics", lambda: _added(L, lambda: beta * caustic_radiance(
            caustic_map, si, found, bounces, p.spp, p.k, r_caustic)))  # fmt: skip

        def final_gather_pass():
            if p.lookup == "direct":
                return radiance_estimate(extra, si, bsdf, p.k, r_global, found)
            lookup = self._lookup(global_map, extra, r_global)
            return self.indirect(eye, lookup, (w, h), medium_light)

        L = run("final gather", lambda: _added(L, lambda: beta * final_gather_pass()))
        image = pixel_means(L, p.spp)
        image += run("light images", lambda: light_images(
            self.scene, self.sensor, eye.radiance, bounces > 0, (w, h), p, self.settings,
            self.traits,
        ))  # fmt: skip
        image = mi.TensorXf(dr.ravel(image), (h, w, 3))
        if not np.all(np.isfinite(np.asarray(image))):
            raise SceneError(
                "the render produced NaN or infinite values; check the scene's "
                "textures and emitters for NaN"
            )
        return image

    def light_samples(self) -> int:
        """Emitter samples of the direct light at each eye-path end: ``light_samples``, or
        automatically one per emitter up to :data:`LIGHT_SAMPLES` — the final gather smooths
        the indirect light, and at one sample per pixel the pick of one light among several
        would leave the direct light noisy (a few samples cost little beside ``fg_rays``)."""
        if self.params.light_samples > 0:
            return self.params.light_samples
        return max(1, min(len(self.scene.emitters()), LIGHT_SAMPLES))

    def _lookup(self, global_map, extra, r_global):
        """The radiance a final-gather ray finds at its hit ``(si_y, bsdf_y, active)``: the
        precomputed irradiance (``lookup="irradiance"``; k-NN estimates on glossy shapes), else
        the k-NN radiance estimate of the global map."""
        p = self.params
        if p.lookup == "irradiance":

            def lookup(si_y, bsdf_y, active):
                L = lookup_radiance(extra, si_y, bsdf_y, active)
                if not self.glossy_shapes:
                    return L
                return with_glossy_estimates(L, global_map, si_y, bsdf_y, p.k, r_global, active)

            return lookup
        return lambda si_y, bsdf_y, active: radiance_estimate(
            global_map, si_y, bsdf_y, p.k, r_global, active
        )

    def _eye_pass(self, pixel, jitter, gen, medium_light):
        """Eye paths from the pixels to their first smooth surfaces (the light met on the way
        in ``radiance``); the light scattered in the media along them (``medium_light``)."""
        lanes = dr.width(pixel)
        ray, ray_weight = pixel_rays(self.sensor, pixel, jitter)
        rules = EyeRules(self.settings, self.traits, emission=True, media_mode="march",
                         rough_glass=True)  # fmt: skip
        start = broadcast(self.sensor.get_medium(), lanes)
        eye = trace_eye_paths(self.scene, (ray, ray_weight, start), gen, rules)
        eye.found &= self.settings.allows(eye.depth + 1)  # light can still arrive
        L = dr.zeros(mi.Spectrum, lanes)  # light at the eye-path ends and in the media
        if medium_light is not None:
            L += medium_light.march(eye.segments, lanes, 1 << 24)
        dr.eval(eye.si, eye.beta, eye.found, eye.bounces, eye.medium, eye.radiance, eye.depth, L)
        return eye, L

def _added(L: mi.Spectrum, term) -> mi.Spectrum:
    """``L + term()``, evaluated: a stage's kernels run inside its own time."""
    out = L + term()
    dr.eval(out)
    return out
