"""SPPM eye pass: eye paths through mirrors, glass and media to their visible points
(Hachisuka & Jensen 2009 §4, the ray tracing pass), by the transport core's eye-path loop
(:func:`photonmap.core.eye_trace.trace_eye_paths`).

Rule for glossy surfaces (SPPM leaves it open; pbrt-v4 stores the visible point at the first diffuse
or glossy vertex too): an eye path ends at a vertex whose BSDF has a smooth (diffuse *or* glossy)
lobe, and the visible point is stored there; delta and ``Null`` lobes are followed (a BSDF with both
splits the path by Russian roulette). Glossy reflections are then the photons' density estimate at
the visible point, which the shrinking radius makes consistent.

The pass adds to the pixel's direct term ``L_d``: the light arriving straight from the emitters
at the visible point (emitter sampling and BSDF sampling with MIS,
:func:`~photonmap.core.direct.direct_lighting`) and the emission seen — lights seen directly or
through mirrors and glass — from :data:`LIGHT_SPP` paths of their own.

**Participating media** (Jensen & Christensen 1998; as Mitsuba's ``volpath``): in a scene with
media the eye paths are volumetric path tracing throughout — through the media (direct light
along each piece, free-flight collisions, phase-function samples) and on through smooth surfaces
(next-event estimation and BSDF samples under MIS) — and the only light such paths cannot find,
light that reached a surface or a medium through mirrors and glass, comes from the iteration's
caustic photons read at each vertex (``caustics``, ``surfaces="continue"``). The light is then
carried in the same direction as ``volpath``'s — which a file whose media disagree with its
shapes needs (:func:`~photonmap.core.scene_info.warn_disagreeing_media`) — and the photon pass
is small (none without mirrors and glass).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import to_jit
from ..core.camera import pixel_means, pixel_rays
from ..core.direct import direct_lighting
from ..core.eye_rules import Caustics, EyeRules
from ..core.eye_trace import trace_eye_paths
from ..core.film_filter import splat_means
from ..core.media import broadcast
from ..core.sampling import rng


@dataclass
class VisiblePoints:
    """``spp`` visible points per pixel of one iteration (lanes = pixels × spp, a pixel's points
    adjacent, pixels row-major), and the pixel's direct term."""

    si: mi.SurfaceInteraction3f  # the interaction at x (si.wi: the eye direction, local)
    beta: mi.Spectrum  # path throughput from the pixel to x
    found: mi.Bool  # the path reached a smooth surface
    depth: mi.UInt32  # segments from the camera to x (photons of depth ≤ max_depth − depth count)
    direct: mi.Spectrum  # per pixel: L_d of this iteration (emission seen, media, direct light)
    spp: int
    rays: int = 0  # rays the pass cast: segments and shadow rays

    @property
    def bsdf(self) -> mi.BSDFPtr:
        return self.si.bsdf()


LIGHT_SPP = 8  # eye paths per pixel and iteration at least that estimate the emission seen


def eye_pass(
    scene: mi.Scene,
    sensor: mi.Sensor,
    seed: int,
    rules: EyeRules,
    caustics: Caustics | None = None,
    spp: int = 1,
    mirrors: mi.UInt32 | None = None,
) -> VisiblePoints:
    """Trace ``spp`` jittered eye paths per pixel of ``sensor``'s film crop (random numbers from
    ``seed``, the iteration's seed) by ``rules`` (the path settings, the scene's traits, the
    media mode, what to do at smooth surfaces; whether they count the emitters met is decided
    here) to their visible points; evaluated before returning. The
    emission seen is estimated from at least :data:`LIGHT_SPP` paths per pixel: the lights'
    images in mirrors and glass are bright and small, and one sample per iteration leaves a pixel
    that catches one a spike of the light's radiance over the iteration count — with fewer eye
    paths, further paths of their own that only follow mirrors and glass, traced in the pixels
    ``mirrors`` (:func:`mirror_pixels`); in a scene without mirrors and glass (``mirrors`` None)
    the eye paths see the lights themselves.
    ``caustics``: the iteration's caustic photons read along the paths; ``rules.surfaces``
    ``"continue"`` traces the paths on through smooth surfaces (module docstring), which leaves
    no visible points: each path is then a whole estimate of its pixel, and the paths are
    splatted through the film's filter as Mitsuba's film splats them (:func:`splatted`)."""
    settings, traits, surfaces = rules.settings, rules.traits, rules.surfaces
    w, h = (int(c) for c in sensor.film().crop_size())
    lanes = w * h * spp
    gen = rng(lanes, seed, 0)
    splat = surfaces == "continue" and splatted(sensor.film())
    jitter = mi.Point2f(gen.next_float32(), gen.next_float32())
    ray, weight = pixel_rays(sensor, dr.arange(mi.UInt32, lanes) // spp, jitter, not splat)
    start = broadcast(sensor.get_medium(), lanes)
    seen_here = spp >= LIGHT_SPP or mirrors is None
    rules = replace(rules, emission=seen_here)
    eye = trace_eye_paths(scene, (ray, weight, start), gen, rules, caustics=caustics)
    L = eye.radiance
    if surfaces == "stop":
        u_light = mi.Point2f(gen.next_float32(), gen.next_float32())
        lit = eye.found & settings.allows(eye.depth + 1)
        L += eye.beta * direct_lighting(scene, eye.si, u_light, gen, lit, traits, eye.medium)
        eye.rays += mi.UInt32(lit) * 2  # its shadow ray and its BSDF-sampled ray
    dr.eval(L, eye.si, eye.beta, eye.found, eye.depth, eye.rays)  # one kernel: read lazily, the
    # loop would run again
    rays = int(np.asarray(eye.rays, np.int64).sum())
    direct = splat_means(sensor.film(), jitter, L, spp) if splat else pixel_means(L, spp)
    if not seen_here:
        seen, seen_rays = emission_seen(scene, sensor, seed, settings, traits, mirrors, splat)
        direct += seen
        rays += seen_rays
    dr.eval(direct)
    return VisiblePoints(eye.si, eye.beta, eye.found, eye.depth, direct, spp, rays)


def splatted(film: mi.Film) -> bool:
    """Whether whole-path samples are splatted (:func:`~photonmap.core.film_filter.splat_means`)
    rather than placed by filter importance sampling: a filter wider than the pixel, with
    samples inside the crop only (without ``sample_border``, Mitsuba's default)."""
    return not film.rfilter().is_box_filter() and not film.sample_border()


def emission_seen(
    scene, sensor, seed: int, settings, traits, pixels: mi.UInt32, splat: bool = False
) -> tuple[mi.Spectrum, int]:
    """Per pixel, the mean emission of :data:`LIGHT_SPP` jittered paths that only follow
    mirrors, glass and the media's transmittance (``splat``: splatted through the film's
    filter), traced in ``pixels`` alone (:func:`mirror_pixels`: elsewhere such paths meet a
    surface that ends them with no light first). A path's random numbers are those of its lane
    in the whole film's wavefront, so the image is the one tracing every pixel gives. Also
    returns the rays the paths cast."""
    w, h = (int(c) for c in sensor.film().crop_size())
    if not dr.width(pixels):  # no light and no mirror or glass in view
        return dr.zeros(mi.Spectrum, w * h), 0
    many = w * h * LIGHT_SPP
    traced = dr.arange(mi.UInt32, dr.width(pixels) * LIGHT_SPP)
    lanes = dr.gather(mi.UInt32, pixels, traced // LIGHT_SPP) * LIGHT_SPP + traced % LIGHT_SPP
    gen = rng(many, seed, 1, lanes)
    jitter = mi.Point2f(gen.next_float32(), gen.next_float32())
    ray, weight = pixel_rays(sensor, lanes // LIGHT_SPP, jitter, not splat)
    start = broadcast(sensor.get_medium(), dr.width(lanes))
    rules = EyeRules(settings, traits, emission=True, media_mode="transmit")
    seen = trace_eye_paths(scene, (ray, weight, start), gen, rules)
    rays = int(np.asarray(seen.rays, np.int64).sum())
    if splat:  # the splats reach the neighbours: the whole film's samples, zero where untraced
        radiance, positions = dr.zeros(mi.Spectrum, many), dr.zeros(mi.Point2f, many)
        dr.scatter(radiance, seen.radiance, lanes)
        dr.scatter(positions, jitter, lanes)
        return splat_means(sensor.film(), positions, radiance, LIGHT_SPP), rays
    means = dr.zeros(mi.Spectrum, w * h)
    dr.scatter(means, pixel_means(seen.radiance, LIGHT_SPP), pixels)
    return means, rays


SUBPIXELS = 4  # rays per pixel side that find the pixels a light may show in (mirror_pixels)


def mirror_pixels(scene: mi.Scene, sensor: mi.Sensor) -> mi.UInt32:
    """The pixels of ``sensor``'s crop where a path that only follows mirrors, glass and media
    can meet emission: those whose first surface, seen by a ``SUBPIXELS``² grid of rays over
    each pixel, is an emitter, a mirror, glass or a ``null`` boundary (or nothing, under an
    environment light), grown by the film filter's reach and one pixel, so that filter-sampled
    rays, which leave their pixel by up to the filter's radius, stay inside. Anywhere else such
    a path ends at its first surface with no light, and :func:`emission_seen` leaves it out.
    A mirror or an emitter narrower than a quarter pixel over three pixels can be missed."""
    film = sensor.film()
    w, h = (int(c) for c in film.crop_size())
    n = SUBPIXELS * SUBPIXELS
    lane = dr.arange(mi.UInt32, w * h * n)
    sub = lane % n
    jitter = mi.Point2f(
        (mi.Float(sub % SUBPIXELS) + 0.5) / SUBPIXELS,
        (mi.Float(sub // SUBPIXELS) + 0.5) / SUBPIXELS,
    )
    ray, _ = pixel_rays(sensor, lane // n, jitter, filtered=False)
    si = scene.ray_intersect(ray)
    lobes = mi.BSDFFlags.Delta | mi.BSDFFlags.Null
    shows = (si.emitter(scene) != None) | mi.has_flag(si.bsdf().flags(), lobes)  # noqa: E711
    if scene.environment() is not None:
        shows |= ~si.is_valid()
    hit = np.array(dr.block_reduce(dr.ReduceOp.Add, mi.UInt32(shows), n)).reshape(h, w) > 0
    grow = math.ceil(float(film.rfilter().radius())) + 1
    padded = np.pad(hit, grow)
    near = np.zeros_like(hit)
    for dy in range(2 * grow + 1):  # a loop over the window's offsets, not over pixels
        for dx in range(2 * grow + 1):
            near |= padded[dy : dy + h, dx : dx + w]
    return to_jit(mi.UInt32, np.flatnonzero(near))
