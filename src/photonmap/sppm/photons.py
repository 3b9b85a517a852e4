"""SPPM photon pass (Hachisuka & Jensen 2009 §4, the photon tracing pass).

Each iteration traces ``M`` photon paths from the lights with the transport core's photon loop
(:func:`photonmap.core.photon_trace.trace_photons`: power split by emitted power, Russian
roulette, every smooth hit recorded, through the media), a fraction of them aimed at the specular
shapes (:mod:`photonmap.core.aim`). The records from the second interaction on are kept: the
first hits are the direct light the eye pass computes by emitter sampling (:mod:`.visible`). The
powers carry the ``1/M`` of the iteration, so a density estimate over one iteration's photons is
the iteration's estimate of the reflected indirect radiance.

In a scene with participating media the eye paths find the light themselves (volumetric path
tracing, :mod:`.visible`), except the light that reached a surface or a medium only through
mirrors and glass: the photon pass then traces those *caustic* photons alone (a pure specular
history; Jensen & Christensen 1998's volume caustics among them).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.photon_trace import PhotonRules, trace_photons
from ..core.volume_map import VolumePhotons


@dataclass
class Photons:
    """One iteration's photons that the visible points gather."""

    position: mi.Point3f
    power: mi.Color3f  # Φ_p (W), the 1/M of the iteration included
    direction: mi.Vector3f  # travel direction at the hit (into the surface)
    depth: mi.UInt32  # path segments from the light to the hit
    paths: int  # photon paths traced (M)
    aimed: int  # of them, aimed at specular shapes (core.aim)
    caustic_fraction: float  # of the aimed paths, those that met a specular shape first
    volume: VolumePhotons | None = None  # scenes with media: the iteration's caustic volume photons
    rays: int = 0  # rays the photon paths cast

    @property
    def count(self) -> int:
        return dr.width(self.position)


def photon_pass(
    scene: mi.Scene,
    paths: int,
    seed: int,
    aim: float,
    rules: PhotonRules,
    media: list | None = None,
    powers=None,
) -> Photons:
    """Trace ``paths`` photon paths by ``rules`` (random numbers from ``seed``, the iteration's
    seed), the fraction ``aim`` of the area lights' paths aimed at the specular shapes, and keep
    the records after the first interaction; in a scene with media also the caustic volume
    photons (module docstring). ``media``, ``powers``: the emitters' media and checked powers, if
    known. With ``rules.caustics_only`` only the photons that reached a surface or a medium
    through mirrors and glass (every area light's paths aimed at them)."""
    aim = 1.0 if rules.caustics_only else aim
    traced = trace_photons(scene, paths, rules, seed, aim, media, powers)
    kept = traced.records.after_first()
    volume = None
    if traced.volume is not None:
        volume = traced.volume.select(traced.volume.caustic) if traced.volume.count else None
    return Photons(
        kept.position, kept.power, kept.direction, kept.depth, paths, traced.light.aimed_paths,
        traced.caustic_fraction, volume if volume is not None and volume.count else None,
        traced.records.rays,
    )  # fmt: skip
