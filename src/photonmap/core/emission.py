"""Photon emission: where the light paths of every method start (Jensen 1996; Steinhurst 2007
§2.6.1, Algorithm 2.4).

The path budget ``N`` is split among the emitters in proportion to their emitted power ``Φ_e``
(:func:`emitter_powers`, :func:`split_paths`). Emitter ``e`` gets ``N_e`` paths; path ``i``
starts with the ray and weight of ``emitter.sample_ray`` (the weight is an unbiased estimate of
``Φ_e``) and carries ``Φ_i = weight_i / N_e``, so ``Σ_i Φ_i → Φ_e``. Each path starts in its
emitter's medium (:func:`~photonmap.core.media.emitter_media`).

**Aimed emission** (Jensen's projection maps, generalised to area lights: :mod:`.aim`): the
fraction ``aim`` of an area emitter's paths leaves towards the bounding spheres of the specular
shapes. The emitter's paths are then *partitioned*: an aimed path keeps its records only if its
first interaction is on a specular shape, a plain one only if it is not (a smooth surface, a
medium, or nothing), so every light path is counted once — the photon loop applies the rule at
the first interaction (:func:`photonmap.core.photon_trace.trace_light_paths`). Other emitters
(points, spots, environment) keep all their paths unaimed.

Bad input raises :class:`~photonmap.core.errors.SceneError`: no emitter or no shape, an emitter
that emits nothing, non-finite values in an emitter's or a BSDF's parameters (textures included).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .aim import aimable, aimed_emission, specular_spheres
from .arrays import to_jit
from .errors import ParameterError, SceneError
from .media import broadcast, emitter_media
from .sampling import rng
from .scene_info import parameter_values, shape_name


@dataclass
class LightPaths:
    """The start of a wavefront of light paths, one lane a path."""

    ray: mi.Ray3f
    power: mi.Color3f  # Φ_i in W
    medium: mi.MediumPtr  # the medium the path starts in
    aimed: mi.Bool  # left towards the specular shapes (module docstring)
    partitioned: mi.Bool  # its emitter's paths are split into aimed and plain ones
    emitted_power: np.ndarray  # Σ of the initial power of all paths (RGB, W)
    aimed_paths: int

    @property
    def count(self) -> int:
        return dr.width(self.power)


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
    _, weight = sample_rays(scene, emitter, seed)
    total = dr.block_reduce(dr.ReduceOp.Add, mi.Color3d(weight), samples)
    return np.array(total, dtype=np.float64).T.reshape(count, 3) / samples


def split_paths(powers: np.ndarray, paths: int) -> np.ndarray:
    """Split ``paths`` among emitters in proportion to the mean of their RGB ``powers`` by
    largest-remainder rounding, with at least one path per emitter (Steinhurst 2007 §2.6.1:
the budget split in proportion to the emitted flux)."""
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


def sample_rays(scene: mi.Scene, emitter: mi.UInt32, seed: int) -> tuple[mi.Ray3f, mi.Color3f]:
    """``sample_ray`` of emitter ``scene.emitters()[emitter[i]]`` for every lane ``i``."""
    gen = rng(dr.width(emitter), seed, stream=0)
    wavelength = gen.next_float32()
    spatial = mi.Point2f(gen.next_float32(), gen.next_float32())
    directional = mi.Point2f(gen.next_float32(), gen.next_float32())
    emitters = dr.gather(mi.EmitterPtr, scene.emitters_dr(), emitter)
    return emitters.sample_ray(0.0, wavelength, spatial, directional)


def emit(
    scene: mi.Scene,
    paths: int,
    seed: int = 0,
    aim: float = 0.0,
    caustics_only: bool = False,
    media: list | None = None,
    powers: np.ndarray | None = None,
    rough_glass: bool = False,
) -> LightPaths:
    """``paths`` light paths from the scene's emitters (module docstring), the fraction ``aim``
    of the area emitters' paths aimed at the specular shapes (``aim = 1`` with ``caustics_only``:
    all of them, the caller keeping only specular-first paths). ``media``: :func:`emitter_media` of the scene,
    ``powers``: :func:`checked_powers`, if known (a pipeline finds them once). Without specular
    shapes or area emitters, or with ``aim = 0``, nothing is aimed. ``rough_glass``: rough glass
    counts as specular (:func:`~photonmap.core.aim.specular_spheres`)."""
    if paths < 1:
        raise ParameterError(f"the number of photon paths must be at least 1, got {paths}")
    if not 0 <= aim < 1 and not (caustics_only and aim == 1):
        raise ParameterError(f"aim must lie in [0, 1), got {aim!r}: the fraction aimed")
    counts = split_paths(checked_powers(scene, 0) if powers is None else powers, paths)
    spheres = specular_spheres(scene, rough_glass) if aim > 0 else []
    can = aimable(scene) & (counts >= (1 if caustics_only else 2))
    if not spheres:
        can[:] = False
    keep_plain = not (caustics_only and aim == 1)  # every path aimed: the caustic map's L S+ D
    aimed = np.where(can, np.clip(np.round(counts * aim), 1, counts - keep_plain), 0)
    aimed = aimed.astype(np.int64)
    plain = counts - aimed
    index = np.arange(len(counts), dtype=np.uint32)
    emitter = to_jit(mi.UInt32, np.concatenate([np.repeat(index, plain), np.repeat(index, aimed)]))
    n_plain, n_aimed = int(plain.sum()), int(aimed.sum())
    ray, weight = sample_rays(scene, emitter, seed)
    per = dr.gather(mi.Float, to_jit(mi.Float, np.maximum(plain, 1)), emitter)
    power = weight / per
    is_aimed = dr.arange(mi.UInt32, paths) >= n_plain
    if n_aimed:
        a_emitter = to_jit(mi.UInt32, np.repeat(index, aimed))
        a_ray, a_power = aimed_emission(scene, a_emitter, aimed, spheres, seed)
        lanes = dr.arange(mi.UInt32, n_plain, paths)
        dr.scatter(ray.o, a_ray.o, lanes)
        dr.scatter(ray.d, a_ray.d, lanes)
        dr.scatter(ray.maxt, a_ray.maxt, lanes)
        dr.scatter(power, a_power, lanes)
    partitioned = dr.gather(mi.Bool, mi.Bool(can), emitter)
    media = emitter_media(scene) if media is None else media
    medium = dr.gather(mi.MediumPtr, mi.MediumPtr(media), emitter)
    if not any(m is not None for m in media):
        medium = broadcast(None, paths)
    emitted = np.array(dr.sum(mi.Color3d(power), axis=1)).ravel()
    dr.eval(ray, power, is_aimed, partitioned, medium)
    return LightPaths(ray, power, medium, is_aimed, partitioned, emitted, n_aimed)


def checked_powers(scene: mi.Scene, seed: int) -> np.ndarray:
    """:func:`emitter_powers`, after checking that the scene has emitters and shapes and that the
    emitters and BSDFs have finite parameters (textures included); raise :class:`SceneError` if
    not or if an emitter emits nothing."""
    emitters = scene.emitters()
    if not emitters:
        raise SceneError(
            "the scene has no emitter, so no photons can be traced; add a light (an 'area' "
            "emitter on a shape, or a 'point', 'spot', 'directional', 'constant' or 'envmap' one)"
        )
    if not scene.shapes():
        raise SceneError("the scene has no shapes for photons to land on; add some geometry")
    for emitter in emitters:
        check_finite(emitter, emitter_name(emitter))
    checked = set()
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is not None and bsdf.ptr not in checked:
            checked.add(bsdf.ptr)
            check_finite(bsdf, f"the BSDF of {shape_name(shape)}")
    powers = emitter_powers(scene, seed=seed)
    dark = [emitter_name(e) for e, p in zip(emitters, powers, strict=True) if not np.max(p) > 0]
    if dark:
        raise SceneError(
            f"{', '.join(dark)} emit{'s' if len(dark) == 1 else ''} no power; give "
            "them a positive radiance, intensity or irradiance, or remove them from the scene"
        )
    return powers


def check_finite(obj, what: str) -> None:
    for key, value in parameter_values(obj):
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


def emitter_name(emitter: mi.Emitter) -> str:
    shape = emitter.get_shape()
    if shape is not None:
        return f"the area light of {shape_name(shape)}"
    return f"emitter '{emitter.id()}' ({emitter.class_name()})"
