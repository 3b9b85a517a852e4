"""Two terms the surface method adds at the eye: the emitted radiance seen directly or through
mirrors and glass, resampled where it is bright and small (:func:`light_images`), and the
caustic map's radiance at the eye-path ends (:func:`caustic_radiance`: Jensen 1996's caustic
map, read directly at the eye).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import to_jit
from ..core.camera import pixel_means, pixel_rays
from ..core.eye_rules import EyeRules
from ..core.eye_trace import trace_eye_paths
from ..core.media import broadcast
from ..core.sampling import rng, rotated_hammersley
from .gather import radiance_estimate


def light_images(
    scene, sensor, emitted: mi.Spectrum, specular: mi.Bool, size: tuple, p, settings, traits
) -> mi.Spectrum:
    """Per pixel of the ``size = (w, h)`` image, the emitted radiance seen directly or through
    mirrors and glass: the mean of the eye samples' ``emitted``, except in the pixels where a
    sample saw a light or followed a mirror or glass (``specular``), and their neighbours: there
    it is the mean of ``p.emitter_spp`` new samples of this term alone (a selection by the
    samples themselves, as in adaptive sampling: a slight bias at a light's edge, within the
    noise it removes). Those
    pixels hold the lights and their specular images — bright, small, and the one place where
    the eye samples alone leave visible noise. Flagging every pixel that sees glass, not only
    those whose sample happened to meet a light, keeps the glints of a glass stack (one of
    many reflections at one of many interfaces: few eye samples find them). The extra samples
    only follow mirrors, glass and the media's transmittance, so they are cheap."""
    w, h = size
    image = pixel_means(emitted, p.spp)
    if p.emitter_spp == 0:
        return image
    specular = dr.block_reduce(dr.ReduceOp.Max, mi.UInt32(specular), p.spp) > 0
    seen = np.array((dr.max(image) > 0) | specular)
    seen = np.pad(seen.reshape(h, w), 1)
    grown = np.zeros((h, w), bool)
    for dy in range(3):
        for dx in range(3):
            grown |= seen[dy : dy + h, dx : dx + w]
    flagged = to_jit(mi.UInt32, np.flatnonzero(grown))
    count = dr.width(flagged)
    if count == 0:
        return image
    lanes = count * p.emitter_spp
    which = dr.arange(mi.UInt32, lanes) // p.emitter_spp
    pixel = dr.gather(mi.UInt32, flagged, which)
    shifts = rng(count, p.seed, 3)
    shift = mi.Point2f(shifts.next_float32(), shifts.next_float32())
    sample = dr.arange(mi.UInt32, lanes) % p.emitter_spp
    jitter = rotated_hammersley(p.emitter_spp, sample, dr.gather(mi.Point2f, shift, which))
    ray, weight = pixel_rays(sensor, pixel, jitter)
    rules = EyeRules(settings, traits, emission=True, media_mode="transmit", rough_glass=True)
    start = broadcast(sensor.get_medium(), lanes)
    extra = trace_eye_paths(scene, (ray, weight, start), rng(lanes, p.seed, 4), rules).radiance
    dr.scatter(image, pixel_means(extra, p.emitter_spp), flagged)
    return image


def caustic_radiance(
    caustic_map, si: mi.SurfaceInteraction3f, found, bounces, spp: int, k: int, radius: float
) -> mi.Spectrum:
    """The caustic map's radiance estimate (Eq 2.6) at every sample of a pixel — except where
    all of a pixel's ``spp`` samples see the same surface directly: there the estimate at the
    first sample serves them all. The k-NN kernel spans many pixels, so the estimate barely
    changes within one, and its gathers are the costliest per-sample work; pixels on edges or
    seen through mirrors and glass, where samples land far apart, keep one estimate each."""
    lanes = dr.width(found)
    lane = dr.arange(mi.UInt32, lanes)
    first = lane // spp * spp
    same = found & (bounces == 0) & (si.shape == dr.gather(mi.ShapePtr, si.shape, first))
    plain = dr.gather(
        mi.Bool, dr.block_reduce(dr.ReduceOp.Min, mi.UInt32(same), spp) > 0, lane // spp
    )
    needed = dr.compress(found & (~plain | (lane == first)))
    at = dr.gather(mi.SurfaceInteraction3f, si, needed)
    estimate = dr.zeros(mi.Spectrum, lanes)
    dr.scatter(estimate, radiance_estimate(caustic_map, at, at.bsdf(), k, radius, True), needed)
    return dr.gather(mi.Spectrum, estimate, dr.select(plain, first, lane))
