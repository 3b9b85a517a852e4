"""SPPM eye pass: one eye path per pixel through specular chains to its visible point
(Hachisuka & Jensen 2009 §4; spec beyond-seeds §1 step 1).

Rule for glossy surfaces (the spec asks to choose one): an eye path stops at its first vertex
whose BSDF has a smooth (diffuse *or* glossy) lobe, and the visible point is stored there — the
rule of the surface method's eye pass (:func:`photonmap.core.eye_trace.follow_specular`); only
purely specular (delta) BSDFs are followed. Glossy reflections are then the photons' density
estimate at the visible point, which the shrinking radius makes consistent.

At the visible point ``x`` the pass also adds, to the pixel's direct term ``L_d``, the light
arriving straight from the emitters (emitter sampling and BSDF sampling with MIS, the surface
method's :func:`~photonmap.core.direct.direct_lighting`) and the emission met on the way
(lights seen directly or through mirrors and glass, from :data:`LIGHT_SPP` paths of their own).
Photons therefore count from their second interaction on (:mod:`.photons`).

In a scene with participating media (issue 11 item 5; Jensen & Christensen 1998, spec
beyond-seeds §4) the eye path runs through the media exactly as the surface method's eye rays
do (:func:`~photonmap.core.eye_trace.follow_specular_media`): the throughput ``β`` carries the
transmittance to the visible point, each piece of the path inside a medium is ray-marched for
its in-scattered light (:class:`~photonmap.core.media.Inscatter`: single scattering of direct
light by transmittance shadow rays, the rest from the iteration's volume map), which joins
``L_d``; the shadow rays of the direct light at ``x`` and the emission seen carry the
transmittance.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.camera import pixel_means, pixel_rays
from ..core.direct import direct_lighting
from ..core.eye_trace import follow_specular, follow_specular_media
from ..core.media import Inscatter, broadcast
from ..core.sampling import rng


@dataclass
class VisiblePoints:
    """One visible point per pixel of one iteration (lanes = pixels, row-major)."""

    si: mi.SurfaceInteraction3f  # the interaction at x (si.wi: the eye direction, local)
    beta: mi.Spectrum  # path throughput from the pixel to x (camera weight × specular weights)
    found: mi.Bool  # the pixel's path reached a smooth surface within max_depth bounces
    direct: mi.Spectrum  # L_d of this iteration: emission met on the way + direct light at x

    @property
    def bsdf(self) -> mi.BSDFPtr:
        return self.si.bsdf()


LIGHT_SPP = 8  # eye paths per pixel and iteration that estimate the emission seen (L_e)


def eye_pass(
    scene: mi.Scene,
    sensor: mi.Sensor,
    seed: int,
    max_depth: int,
    null_shapes: bool,
    inscatter: Inscatter | None = None,
) -> VisiblePoints:
    """Trace one jittered eye path per pixel of ``sensor``'s film crop (random numbers from
    ``seed``, the iteration's seed) to its visible point; evaluated before returning. The
    emission met on the way is the mean of :data:`LIGHT_SPP` further jittered paths per pixel
    (specular chains only, cheap): the lights' images in mirrors and glass are bright and small,
    and one sample per iteration leaves a pixel that catches one a spike of the light's radiance
    over the iteration count — the noisiest part of the image for hundreds of iterations.
    ``inscatter``: the scene has media, and this is the iteration's in-scattered light (module
    docstring)."""
    w, h = (int(c) for c in sensor.film().crop_size())
    lanes = w * h
    pixel = dr.arange(mi.UInt32, lanes)
    gen = rng(lanes, seed, 0)
    jitter = mi.Point2f(gen.next_float32(), gen.next_float32())
    ray, weight = pixel_rays(sensor, pixel, jitter)
    many = lanes * LIGHT_SPP
    extra = rng(many, seed, 1)
    ray_l, weight_l = pixel_rays(
        sensor,
        dr.arange(mi.UInt32, many) // LIGHT_SPP,
        mi.Point2f(extra.next_float32(), extra.next_float32()),
    )
    medium, medium_light = None, dr.zeros(mi.Spectrum, lanes)
    if inscatter is None:
        si, beta, _, found, _ = follow_specular(
            scene, ray, weight, dr.ones(mi.Bool, lanes), max_depth, gen, False, null_shapes
        )
        _, _, seen, _, _ = follow_specular(
            scene, ray_l, weight_l, dr.ones(mi.Bool, many), max_depth, extra, True, null_shapes
        )
    else:
        start = sensor.get_medium()
        si, beta, _, found, _, medium, medium_light = follow_specular_media(
            scene, ray, weight, broadcast(start, lanes), dr.ones(mi.Bool, lanes), max_depth,
            gen, False, inscatter,
        )  # fmt: skip
        _, _, seen, _, _, _, _ = follow_specular_media(
            scene, ray_l, weight_l, broadcast(start, many), dr.ones(mi.Bool, many), max_depth,
            extra, True, None,
        )  # fmt: skip
    emitted = pixel_means(seen, LIGHT_SPP)
    u_light = mi.Point2f(gen.next_float32(), gen.next_float32())
    direct = emitted + medium_light + beta * direct_lighting(
        scene, si, si.bsdf(), u_light, gen, found, null_shapes, medium
    )
    dr.eval(si, beta, found, direct)
    return VisiblePoints(si, beta, found, direct)
