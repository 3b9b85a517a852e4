"""SPPM eye pass: one eye path per pixel through specular chains to its visible point
(Hachisuka & Jensen 2009 §4; spec beyond-seeds §1 step 1).

Rule for glossy surfaces (the spec asks to choose one): an eye path stops at its first vertex
whose BSDF has a smooth (diffuse *or* glossy) lobe, and the visible point is stored there — the
rule of the surface method's eye pass (:func:`photonmap.surface.trace.follow_specular`); only
purely specular (delta) BSDFs are followed. Glossy reflections are then the photons' density
estimate at the visible point, which the shrinking radius makes consistent.

At the visible point ``x`` the pass also adds, to the pixel's direct term ``L_d``, the light
arriving straight from the emitters (emitter sampling and BSDF sampling with MIS, the surface
method's :func:`~photonmap.surface.direct.direct_lighting`) and the emission met on the way
(lights seen directly or through mirrors and glass). Photons therefore count from their second
interaction on (:mod:`.photons`).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.camera import pixel_rays
from ..core.sampling import rng
from ..surface.direct import direct_lighting
from ..surface.trace import follow_specular


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


def eye_pass(
    scene: mi.Scene, sensor: mi.Sensor, seed: int, max_depth: int, null_shapes: bool
) -> VisiblePoints:
    """Trace one jittered eye path per pixel of ``sensor``'s film crop (random numbers from
    ``seed``, the iteration's seed) to its visible point; evaluated before returning."""
    w, h = (int(c) for c in sensor.film().crop_size())
    lanes = w * h
    pixel = dr.arange(mi.UInt32, lanes)
    gen = rng(lanes, seed, 0)
    jitter = mi.Point2f(gen.next_float32(), gen.next_float32())
    ray, weight = pixel_rays(sensor, pixel, jitter)
    si, beta, emitted, found, _ = follow_specular(
        scene, ray, weight, dr.ones(mi.Bool, lanes), max_depth, gen, True, null_shapes
    )
    u_light = mi.Point2f(gen.next_float32(), gen.next_float32())
    direct = emitted + beta * direct_lighting(
        scene, si, si.bsdf(), u_light, gen, found, null_shapes
    )
    dr.eval(si, beta, found, direct)
    return VisiblePoints(si, beta, found, direct)
