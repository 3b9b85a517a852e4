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

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.camera import pixel_means, pixel_rays
from ..core.direct import direct_lighting
from ..core.eye_trace import Caustics, trace_eye_paths
from ..core.film_filter import splat_means
from ..core.media import broadcast
from ..core.sampling import rng
from ..core.scene_info import SceneTraits
from ..core.settings import PathSettings


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

    @property
    def bsdf(self) -> mi.BSDFPtr:
        return self.si.bsdf()


LIGHT_SPP = 8  # eye paths per pixel and iteration at least that estimate the emission seen


def eye_pass(
    scene: mi.Scene,
    sensor: mi.Sensor,
    seed: int,
    settings: PathSettings,
    traits: SceneTraits,
    caustics: Caustics | None = None,
    spp: int = 1,
    surfaces: str = "stop",
    mirrors: bool = True,
) -> VisiblePoints:
    """Trace ``spp`` jittered eye paths per pixel of ``sensor``'s film crop (random numbers from
    ``seed``, the iteration's seed) to their visible points; evaluated before returning. The
    emission seen is estimated from at least :data:`LIGHT_SPP` paths per pixel: the lights'
    images in mirrors and glass are bright and small, and one sample per iteration leaves a pixel
    that catches one a spike of the light's radiance over the iteration count — with fewer eye
    paths, further paths of their own that only follow mirrors and glass (cheap); in a scene
    without them (``mirrors`` False) the eye paths see the lights themselves.
    ``caustics``: the iteration's caustic photons read along the paths; ``surfaces``:
    ``"continue"`` traces the paths on through smooth surfaces (module docstring), which leaves
    no visible points: each path is then a whole estimate of its pixel, and the paths are
    splatted through the film's filter as Mitsuba's film splats them (:func:`splatted`)."""
    w, h = (int(c) for c in sensor.film().crop_size())
    lanes = w * h * spp
    gen = rng(lanes, seed, 0)
    splat = surfaces == "continue" and splatted(sensor.film())
    jitter = mi.Point2f(gen.next_float32(), gen.next_float32())
    ray, weight = pixel_rays(sensor, dr.arange(mi.UInt32, lanes) // spp, jitter, not splat)
    start = broadcast(sensor.get_medium(), lanes)
    seen_here = spp >= LIGHT_SPP or not mirrors
    eye = trace_eye_paths(
        scene, ray, weight, start, gen, settings, traits, emission=seen_here,
        media_mode="continue", surfaces=surfaces, caustics=caustics,
    )  # fmt: skip
    L = eye.radiance
    if surfaces == "stop":
        u_light = mi.Point2f(gen.next_float32(), gen.next_float32())
        lit = eye.found & settings.allows(eye.depth + 1)
        L += eye.beta * direct_lighting(scene, eye.si, u_light, gen, lit, traits, eye.medium)
    dr.eval(L, eye.si, eye.beta, eye.found, eye.depth)  # one kernel: read lazily, the loop reran
    direct = splat_means(sensor.film(), jitter, L, spp) if splat else pixel_means(L, spp)
    if not seen_here:
        direct += emission_seen(scene, sensor, seed, settings, traits, w * h, splat)
    dr.eval(direct)
    return VisiblePoints(eye.si, eye.beta, eye.found, eye.depth, direct, spp)


def splatted(film: mi.Film) -> bool:
    """Whether whole-path samples are splatted (:func:`~photonmap.core.film_filter.splat_means`)
    rather than placed by filter importance sampling: a filter wider than the pixel, with
    samples inside the crop only (without ``sample_border``, Mitsuba's default)."""
    return not film.rfilter().is_box_filter() and not film.sample_border()


def emission_seen(
    scene, sensor, seed: int, settings, traits, pixels: int, splat: bool = False
) -> mi.Spectrum:
    """Per pixel, the mean emission of :data:`LIGHT_SPP` jittered paths that only follow
    mirrors, glass and the media's transmittance (``splat``: splatted through the film's
    filter)."""
    many = pixels * LIGHT_SPP
    gen = rng(many, seed, 1)
    jitter = mi.Point2f(gen.next_float32(), gen.next_float32())
    ray, weight = pixel_rays(sensor, dr.arange(mi.UInt32, many) // LIGHT_SPP, jitter, not splat)
    seen = trace_eye_paths(
        scene, ray, weight, broadcast(sensor.get_medium(), many), gen, settings, traits,
        emission=True, media_mode="transmit",
    )  # fmt: skip
    if splat:
        return splat_means(sensor.film(), jitter, seen.radiance, LIGHT_SPP)
    return pixel_means(seen.radiance, LIGHT_SPP)
