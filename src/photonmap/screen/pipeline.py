"""``ScreenPipeline`` — Yao 2011's real-time global illumination: image-space photon mapping
(McGuire & Luebke 2009) with image-space soft shadows (Robison & Shirley 2009).

::

    camera ─► eye G-buffer ─┬─► direct light + shadow rays (V_h, d, D) ─► soft shadows (V_s) ─┐
    light ─► light G-buffer ┴─► photon tracing (PRM) ─► splat at 1/s ─► upsample ─────────────┼─► composite
                                                                   glass eye rays ─────────────┘

Each stage's result is cached (:class:`~photonmap.core.stages.StageCache`) under a key of exactly
the inputs it depends on: a camera move reruns the eye G-buffer and everything image-space, but
keeps the light G-buffer and the photons; a light change reruns everything but the random map; a
change of ``radius``, ``splat`` or ``subsample`` reruns only splatting, upsampling and compositing;
a change of ``light_size`` or ``isg_samples`` only the soft shadows and compositing (``shadows`` to
or from ``"sampled"`` also the direct light). ``recomputed`` lists the stages the last
:meth:`render` ran, ``timer`` their milliseconds, :meth:`invalidate` forgets stages.

The splat ``radius`` is in scene units, as every method's gather radius; its default (0) is
:data:`RADIUS` × the scene's bounding-box diagonal (``null``-BSDF shapes do not count): the
thesis's radii 4.5 / 8.5 / 10.5 have no unit, and 0.045 × diagonal (about 30 photons per kernel
disk at 10k photons in a Cornell box) is the regime its Cornell box figure shows (Fig 3.9).
``light_size`` is a fraction of that diagonal.

**Area lights** are lit by samples on the light (:mod:`.direct`), seen by the eye and
in mirrors, and their soft shadows have the light's own size (:func:`.light_gbuffer.light_radius`;
``light_size`` is the virtual size of spot and point lights only). Their penumbrae come either
from image space gathering (``shadows="soft"``, the default: the thesis's method, applied to the
hard shadow toward the light's centre) or from the 16 light samples' own shadow rays
(``"sampled"``). Measured on ``mi.cornell_box()``: at 256², direct light only, the 4 × 4-block
relative RMSE against Mitsuba ``path`` (max_depth 2, 256 spp) away from the light is 0.037 hard,
0.031 soft, 0.018 sampled; at 1024 × 768 the direct light and shadow stages take ≈ 300 ms either
way (ISG 80–97 + 211–224 ms, sampled 263–276 ms; 2 shared cores). ``"soft"`` stays the default, as
the method under study and the one the stage graph is built around (a ``light_size`` or
``isg_samples`` change reruns only the gather), and both stay within the tests' bounds against
``path`` (:mod:`tests.screen.test_vs_mitsuba`); ``"sampled"`` gives exact penumbrae at the same
cost where they matter.

The G-buffers hold one sample per pixel centre, so the film's reconstruction filter (Mitsuba's
default is a gaussian) is applied to the composited image as a discrete separable kernel
(:func:`photonmap.core.film_filter.filter_image`), except to the emission seen directly, whose
silhouette pixels importance-sample the filter (:mod:`.gbuffer`); a box filter leaves the image
as it is.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.errors import ParameterError, SceneError
from ..core.film_filter import filter_image
from ..core.memory import check_once
from ..core.params import Renamed, check_choice, check_fields, check_range, updated
from ..core.pipeline import Pipeline
from ..core.scene_info import refuse_media
from ..core.settings import HIDE_CHOICES, UNBOUNDED, PathSettings, overridden
from ..core.stages import StageCache
from . import memory
from .composite import chain_indirect, composite, glass_eye
from .direct import direct_light
from .gbuffer import GBuffer, eye_gbuffer
from .light_gbuffer import check_light_outside, find_light, light_gbuffer
from .light_photons import GLOSSY_MODES, ScreenPhotons, random_map, trace_photons
from .scene_checks import (
    check_dielectrics,
    check_shading,
    visible_diagonal,
    warn_sharp_caustics,
)
from .soft_shadow import MODES, soft_visibility

SPLATS = ("quad", "icosahedron")
SHADOWS = (*MODES, "sampled")
"""Shadow modes: those of :mod:`.soft_shadow` and ``"sampled"`` (area lights: each light sample's
own shadow ray, :mod:`.direct`; spot and point lights: the hard shadow)."""
RADIUS = 0.045  # the automatic splat radius, × the scene diagonal
SHARP_DENSITY = 4.0  # path density from which photons splat at full resolution (_indirect_stages)
MAX_BOUNCES = 8  # recorded bounces at most (a file's unbounded max_depth gets these)
STAGES = (
    "eye G-buffer",
    "light G-buffer",
    "photon tracing",
    "direct + shadow rays",
    "soft shadows",
    "subsample",
    "splatting",
    "upsampling",
    "glass",
    "glass indirect",
    "composite",
)


@dataclasses.dataclass
class ScreenParams:
    """Parameters of the screen pipeline (the ``ispm`` plugin and the CLI's ``--set`` keys).
    Defaults: the thesis's values where it gives them (Tables 1–2), ours otherwise."""

    RENAMED: ClassVar[dict[str, Renamed]] = {
        "light_res": Renamed("photons", int, lambda side: side * side)
    }

    light: int = 0  # the light: its index among the scene's spot, point and area lights
    bounces: int = 0  # B: recorded indirect bounces per path (Tab 1: 1, 2, 3); 0 = the file's
    max_depth: int = 0  # longest path in segments (Mitsuba's); 0 = the scene's, -1 = unbounded
    hide_emitters: str = "scene"  # hide emitters seen directly: scene | true | false
    photons: int = 100**2  # light paths, one per light G-buffer texel: W_L = H_L = √photons
    radius: float = 0.0  # splat radius r, scene units; 0 = RADIUS × the scene diagonal
    splat: str = "quad"  # quad | icosahedron (Tab 2)
    compression: float = 1.0  # icosahedron normal compression c (1 = Yao's uncompressed)
    subsample: int = 4  # s: indirect light at (W/s)×(H/s) (Tab 1: 8, 4, 2)
    # soft (ISG, Eqs 2–5) | hard | fixed_radius (penumbra = light_size) | sampled (area lights)
    shadows: str = "soft"
    isg_samples: str = "4+5"  # ISG radial sample steps, pass 1 + pass 2 (Tab 1: 4+5, 4+7)
    # virtual light radius L of spot / point lights, × scene diagonal (0 = hard shadow); area
    # lights use their own size (ScreenPipeline.shadow_radius)
    light_size: float = 0.02
    glossy: str = "yao_average"  # glossy photon bounce: yao_average (Yao's) | bsdf
    seed: int = 0  # seed of the fixed random map (PRM)

    @property
    def light_res(self) -> int:
        """W_L = H_L: the side of the light G-buffer, √photons rounded."""
        return max(1, round(math.sqrt(self.photons)))

    def validate(self) -> None:
        """Types (:func:`~photonmap.core.params.check_fields`: integers, finite numbers, the
        seed in [0, 2³²)), then ranges and choices."""
        check_fields(self)
        check_range("light", self.light, 0, None, "the index of the light among the scene's "
                    "spot, point and area lights")  # fmt: skip
        check_range(
            "bounces", self.bounces, 0, MAX_BOUNCES,
            "recorded indirect bounces (the thesis: 1–3); 0 = the scene's max_depth − 2",
        )  # fmt: skip
        check_range(
            "max_depth",
            self.max_depth,
            -1,
            None,
            "path segments at most as Mitsuba counts them; 0 = the scene's, -1 = unbounded",
        )
        check_choice("hide_emitters", self.hide_emitters, HIDE_CHOICES,
                     "hide emitters seen directly: the scene's setting, or true/false")  # fmt: skip
        check_range(
            "photons", self.photons, 1, None,
            "light paths, one per texel of the square light G-buffer (√photons rounded per side)",
        )  # fmt: skip
        check_range("subsample", self.subsample, 1, None, "indirect light at 1/subsample (2, 4, 8)")
        check_range("radius", self.radius, 0, None, "scene units; 0 = automatic")
        check_range("compression", self.compression, 0, 1, "icosahedron normals", lo_open=True)
        check_range("light_size", self.light_size, 0, None, "× scene diagonal; 0 = hard shadows")
        check_choice("splat", self.splat, SPLATS)
        check_choice("shadows", self.shadows, SHADOWS)
        check_choice("glossy", self.glossy, GLOSSY_MODES)
        self.isg_pair()

    def isg_pair(self) -> tuple[int, int]:
        """``isg_samples`` "a+b" as the integer pair (a, b)."""
        parts = str(self.isg_samples).split("+")
        try:
            pair = tuple(int(p) for p in parts)
        except ValueError:
            pair = ()
        if len(pair) != 2 or min(pair) < 1:
            raise ParameterError(
                f"isg_samples must be two positive integers 'a+b' (the thesis: '4+5', '4+7'), "
                f"got {self.isg_samples!r}"
            )
        return pair


def _film_image(out: mi.Color3f, emission: mi.Color3f | None, film) -> mi.TensorXf:
    """The composited pixels as the film's image: one sample per pixel centre, so the film's
    reconstruction filter is applied to the image (:func:`filter_image`), except to the emission
    seen, whose silhouette pixels already importance-sample the filter (:mod:`.gbuffer`)."""
    w, h = (int(c) for c in film.crop_size())
    shape = (h, w, 3)
    if film.rfilter().is_box_filter():
        return mi.TensorXf(dr.ravel(out), shape)
    emission = emission if emission is not None else dr.zeros(mi.Color3f, dr.width(out))
    rest = filter_image(mi.TensorXf(dr.ravel(out - emission), shape), film)
    return mi.TensorXf(rest.array + dr.ravel(emission), shape)


def _sensor_key(sensor) -> tuple:
    """The camera's cache key: pose, field of view, the film's size, crop window and filter."""
    m = np.array(sensor.world_transform().matrix, dtype=np.float64).ravel()
    fov = np.array(mi.traverse(sensor)["x_fov"]).ravel()
    film = sensor.film()
    size = tuple(int(c) for c in film.crop_size())
    crop = (tuple(int(c) for c in film.crop_offset()), str(film.rfilter()), film.sample_border())
    return (tuple(m.round(9)), tuple(fov), size, tuple(int(c) for c in film.size()), crop)


class ScreenPipeline(Pipeline):
    """Image-space photon mapping of a Mitsuba scene (name, XML path, dict or ``mi.Scene``) with
    a spot, point or area light (rectangle, disk, sphere, mesh).

    The scene is lit by one light (``light``: its index among the spot, point and area lights); a
    :class:`~photonmap.core.errors.PhotonmapWarning` names every other emitter, whose light is
    left out, and every participating medium (the method renders as in vacuum; ``null``-BSDF
    shapes such as fog boxes are invisible to it). A dielectric with a non-finite ``eta`` is
    refused (:func:`check_dielectrics`).

    >>> pipe = ScreenPipeline("cornell_ispm", bounces=2, subsample=8)
    >>> image = pipe.render()                  # mi.TensorXf (height, width, 3), linear radiance
    >>> pipe.set_camera(origin=(0.3, 0.3, -0.6))
    >>> image = pipe.render()                  # photons kept
    """

    method, params_type, stages = "screen", ScreenParams, STAGES
    edits = frozenset({"camera", "params", "light"})

    def __init__(self, scene, **params):
        from ..scenes import load_with_sensor

        self.scene, self.sensor, own = load_with_sensor(scene, ScreenParams, params)
        self.params = updated(ScreenParams(), own, "screen")  # named before the scene is judged
        self.file_settings = PathSettings.of(self.scene, scene)
        refuse_media(self.scene, "screen")
        check_dielectrics(self.scene)
        check_shading(self.scene)
        self.check_memory()
        self.light = find_light(self.scene, self.params.light, warn=True)
        check_light_outside(self.scene, self.light)
        self._light_version = 0
        self.cache = StageCache()
        self._prm: tuple = ((None,), None)  # (key, random map): made once, not a frame stage
        self.stats: dict[str, float] = {}
        self.outputs: dict[str, object] = {}
        self.diagonal = visible_diagonal(self.scene)
        if not self.diagonal > 0:
            raise SceneError("the scene has no geometry (empty bounding box)")
        warn_sharp_caustics(self.scene, self.light.radius, self.splat_radius)

    # ------------------------------------------------------------------------------- changes
    def set_params(self, **params) -> None:
        """Change :class:`ScreenParams` fields; the next render reruns only what they affect.
        Settings that would not fit in memory are refused (:meth:`check_memory`)."""
        new = updated(self.params, params, "screen")
        self.check_memory(new)
        if new.light != self.params.light:
            light = find_light(self.scene, new.light, warn=True)
            check_light_outside(self.scene, light)
            self.light, self._light_version = light, self._light_version + 1
        self.params = new

    def check_memory(self, params: ScreenParams | None = None, size=None) -> int:
        """Raise a :class:`ParameterError` when ``params`` (default: the pipeline's) at ``size``
        (width, height; default: the camera's) would need more memory than is available
        (:mod:`.memory`); return the estimate in bytes."""
        w, h = size or self.size
        return memory.check(params or self.params, w, h)

    def set_light(self, position=None, target=None, intensity=None, cutoff=None, index=None):
        """Move or re-aim the spot / point light (``target``: a point the spot aims at), scale its
        colour (``intensity``: RGB or scalar, W/sr) or change the spot's cut-off (degrees).
        Everything but the random map reruns."""
        if index is not None:
            self.set_params(light=index)
        light = find_light(self.scene, self.params.light)
        params = mi.traverse(light.emitter)
        if light.kind == "area" and any(v is not None for v in (position, target, cutoff)):
            raise ParameterError(
                "an area light is moved with its shape; set_light can change only its intensity"
            )
        if position is not None or target is not None:
            pos = np.asarray(position if position is not None else light.position, float)
            if target is None:
                target = pos + light.axis
            target = np.asarray(target, float)
            if not np.all(np.isfinite(pos)) or np.allclose(target, pos):
                raise ParameterError("set_light: position must be finite and differ from target")
            axis = (target - pos) / np.linalg.norm(target - pos)
            up = [0, 1, 0] if abs(axis[1]) < 0.99 else [0, 0, 1]
            if light.kind == "point":
                params["position"] = mi.Point3f(*pos.tolist())
            else:
                params["to_world"] = mi.ScalarTransform4f().look_at(
                    origin=pos.tolist(), target=target.tolist(), up=up
                )
        if intensity is not None:
            key = "intensity.value" if light.kind != "area" else "radiance.value"
            value = np.broadcast_to(np.asarray(intensity, float), 3)
            if not (np.all(np.isfinite(value)) and np.all(value >= 0)):
                raise ParameterError(
                    f"set_light: intensity must be finite and >= 0, got {intensity}"
                )
            params[key] = mi.Color3f(*value.tolist())
        if cutoff is not None:
            if light.kind != "spot" or not 0 < cutoff <= 90:
                raise ParameterError(
                    "set_light: cutoff (degrees, in (0, 90]) applies to spots only"
                )
            params["cutoff_angle"] = float(cutoff)
            params["beam_width"] = min(float(np.array(params["beam_width"]).ravel()[0]), cutoff)
        params.update()
        self.light = find_light(self.scene, self.params.light)
        check_light_outside(self.scene, self.light)
        self._light_version += 1

    @property
    def settings(self) -> PathSettings:
        """The file's ``max_depth`` and ``hide_emitters`` with this pipeline's parameters applied
        (no Russian roulette, as in the thesis: every path records its bounces)."""
        p = self.params
        return overridden(self.file_settings, p.max_depth, 0, p.hide_emitters)

    def recorded_bounces(self) -> int:
        """B: ``bounces``, or where it is 0 the file's ``max_depth`` − 2 (a photon recorded after
        B bounces ends a path of B + 2 segments: light, B bounces, the eye), at most
        :data:`MAX_BOUNCES`; 0 for direct light only."""
        if self.params.bounces:
            return self.params.bounces
        depth = self.settings.max_depth
        return MAX_BOUNCES if depth == UNBOUNDED else min(max(depth - 2, 0), MAX_BOUNCES)

    @property
    def splat_radius(self) -> float:
        """The splat radius r in scene units: ``radius``, or :data:`RADIUS` × the diagonal."""
        return self.params.radius if self.params.radius > 0 else RADIUS * self.diagonal

    def shadow_radius(self) -> float:
        """The world-space radius of the soft shadows: an area light's own virtual radius
        (:func:`.light_gbuffer.light_radius`) with ``shadows="soft"``, else ``light_size`` ×
        the scene diagonal (the spot or point light's virtual size, or the ``fixed_radius``
        blur)."""
        if self.light.kind == "area" and self.params.shadows == "soft":
            return self.light.radius
        return self.params.light_size * self.diagonal

    # ------------------------------------------------------------------------------- stages
    def render(self, progress=None) -> mi.TensorXf:
        """Render from the current camera: ``(height, width, 3)`` linear radiance. Every
        intermediate is in :attr:`outputs`, for inspection and tests."""
        p = self.params
        check_once(self, p, self.size, self.check_memory)
        self.cache.new_frame(progress)
        cam_key = _sensor_key(self.sensor)
        light_key = (p.light, self._light_version)
        gbuf, specular = self.cache.stage(
            "eye G-buffer", cam_key, lambda: eye_gbuffer(self.scene, self.sensor)
        )
        lgb, photons, photon_key = self._photon_stages(light_key)
        direct, visibility, shadow_key = self._direct_stages(gbuf, (cam_key, light_key))
        low, L_low, E_low, indirect, splat_key = self._indirect_stages(
            gbuf, cam_key, photons, photon_key
        )
        glass = self._glass_stages(gbuf, specular, photons, (cam_key, light_key), splat_key)
        hide = self.settings.hide_emitters  # Mitsuba hides the emitters seen directly only
        emission = None if hide else gbuf.emission
        sampled = p.shadows == "sampled"
        out = self.cache.stage(
            "composite",
            (shadow_key, splat_key, cam_key, light_key, self.settings.max_depth, hide),
            lambda: composite(
                direct.L_sampled if sampled else direct.L,
                None if sampled else visibility,
                indirect,
                glass,
                emission,
            ),
        )
        self.outputs = {
            "gbuffer": gbuf, "specular": specular, "light_gbuffer": lgb, "photons": photons,
            "direct": direct, "visibility": visibility, "low_gbuffer": low,
            "indirect_low": L_low, "irradiance_low": E_low, "indirect": indirect,
            "glass": glass, "image": out,
        }  # fmt: skip
        self.stats.update(
            photons=int(dr.count(photons.valid)[0]) if photons is not None else 0,
            photon_slots=p.light_res**2 * self.recorded_bounces(),
            width=gbuf.width,
            height=gbuf.height,
        )
        self.cache.progress = None
        image = _film_image(out, emission, self.sensor.film())
        if not dr.all(dr.isfinite(dr.sum(out, axis=None))):
            raise SceneError(
                "the render produced NaN or infinite values; check the scene's textures, BSDF "
                "parameters and light intensity for NaN"
            )
        return image

    def _photon_stages(self, light_key):
        """The light G-buffer and the photons traced from it (with the fixed random map, made
        once per size and seed, §2.4: not a stage); the photons' stage key."""
        p = self.params
        lgb_key = (light_key, p.light_res, p.seed)
        lgb = self.cache.stage("light G-buffer", lgb_key, lambda: light_gbuffer(
            self.scene, self.light, p.light_res, p.light_res, p.seed))  # fmt: skip
        if self._prm[0] != (p.light_res, p.seed):
            self._prm = ((p.light_res, p.seed), random_map(p.light_res, p.light_res, p.seed))
        prm, bounces = self._prm[1], self.recorded_bounces()
        photon_key = (lgb_key, bounces, p.glossy)
        photons = self.cache.stage("photon tracing", photon_key, lambda: (
            trace_photons(self.scene, lgb, prm, bounces, p.glossy) if bounces else None))  # fmt: skip
        return lgb, photons, photon_key

    def _direct_stages(self, gbuf: GBuffer, direct_key):
        """Direct light with its shadow rays, then the soft shadows' visibility V_s (Yao §3.4);
        the visibility's stage key."""
        p, diag = self.params, self.diagonal
        sampled = p.shadows == "sampled"
        direct = self.cache.stage("direct + shadow rays", (direct_key, sampled), lambda: (
            direct_light(self.scene, gbuf, self.light, diag, samples=sampled)))  # fmt: skip
        radius = self.shadow_radius()
        shadow_key = (direct_key, sampled, p.shadows, radius, p.isg_pair())
        visibility = self.cache.stage("soft shadows", shadow_key, lambda: soft_visibility(
            gbuf, (direct.hard, direct.occluder_dist, direct.light_dist), radius, diag,
            samples=p.isg_pair(), mode="hard" if sampled else p.shadows,
        ))  # fmt: skip
        return direct, visibility, shadow_key

    def _indirect_stages(self, gbuf: GBuffer, cam_key, photons, photon_key):
        """The subsampled G-buffer, the photons splatted on it (L_ind, E_ind) and L_ind
        upsampled to every pixel (Yao §3.3, Eq 1); the splats' stage key. With ``subsample``
        > 1 the *sharp* photons — path density ρ ≥ :data:`SHARP_DENSITY`, splats of at most
        r/2 (a mirror or glass bounce on the way: caustics) — are splatted at full resolution
        instead and added after upsampling: one low sample per s × s block point-samples a
        caustic narrower than the block, and the upsampler moves what it catches to the
        neighbours of like geometry (a glass ball's caustic came out missing where it lies
        and as a block of light beside it: 4 × 4-block error 0.29, against 0.07 at s = 1)."""
        from .upsample import subsample, upsample

        p = self.params
        low_key = (cam_key, p.subsample)
        low = self.cache.stage("subsample", low_key, lambda: subsample(gbuf, p.subsample))
        splat_key = (low_key, photon_key, p.splat, p.radius, p.compression)
        smooth, sharp = photons, None
        if photons is not None and p.subsample > 1:
            is_sharp = photons.valid & (photons.density >= SHARP_DENSITY)
            if dr.any(is_sharp):
                smooth = dataclasses.replace(photons, valid=photons.valid & ~is_sharp)
                sharp = dataclasses.replace(photons, valid=is_sharp)
        L_low, E_low = self.cache.stage("splatting", splat_key, lambda: self._splat(smooth, low))

        def upsampled():
            L = upsample(L_low, low, gbuf, p.subsample)
            return L if sharp is None else L + self._splat(sharp, gbuf)[0]

        indirect = self.cache.stage("upsampling", splat_key, upsampled)
        return low, L_low, E_low, indirect, splat_key

    def _splat(self, photons: ScreenPhotons | None, points: GBuffer, cull: bool = True):
        """L_ind and E_ind at ``points`` from the photons' quads or icosahedra (0 without)."""
        from .splat import splat_icosahedra, splat_quads

        p = self.params
        if photons is None:  # direct light only
            zero = dr.zeros(mi.Color3f, points.width * points.height)
            return zero, zero
        if p.splat == "quad":
            return splat_quads(points, photons, self.splat_radius, cull)
        return splat_icosahedra(points, photons, self.splat_radius, p.compression, cull)

    def _glass_stages(self, gbuf, specular, photons, direct_key, splat_key):
        """The mirror and glass pixels: their chains' direct light and emission, plus the
        photons' indirect light at the chains' ends within ``max_depth`` (:mod:`.composite`)."""
        depth, bounces = self.settings.max_depth, self.recorded_bounces()
        chains = self.cache.stage("glass", (direct_key, depth), lambda: glass_eye(
            self.scene, gbuf, specular, self.light, self.diagonal, depth))  # fmt: skip

        def chain_bounces(level: int) -> int:  # m + k + 2 segments at most
            return bounces if depth == UNBOUNDED else min(bounces, depth - 2 - level)

        def splat_ends(points: GBuffer, k: int):
            texels = self.params.light_res**2  # bounce k fills slots [(k - 1) texels, k texels)
            kept = photons.valid & (dr.arange(mi.UInt32, dr.width(photons.valid)) < k * texels)
            return self._splat(dataclasses.replace(photons, valid=kept), points, cull=False)

        indirect = self.cache.stage("glass indirect", (direct_key, splat_key, depth), lambda: (
            None if chains is None or photons is None
            else chain_indirect(chains[1], splat_ends, chain_bounces, gbuf.width * gbuf.height)
        ))  # fmt: skip
        if chains is None:
            return None
        return chains[0] if indirect is None else chains[0] + indirect
