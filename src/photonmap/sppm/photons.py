"""SPPM photon pass (Hachisuka & Jensen 2009 §4; spec beyond-seeds §1 step 2).

Each iteration traces ``M`` photon paths from the lights with the shared photon tracer
(:mod:`photonmap.core.photon_trace`: power split by emitted power, Russian roulette, every smooth
hit recorded), a fraction of them aimed at the specular shapes (:mod:`photonmap.core.aim`).
The records from the second interaction on are kept: the first hits are the direct light the
eye pass already computed by emitter sampling (:mod:`.visible`). The powers carry the ``1/M`` of
the iteration, so a density estimate over one iteration's photons is the iteration's estimate of
the reflected indirect radiance.

In a scene with participating media (issue 11 item 5) the photons fly through the media with the
surface method's tracer (:func:`~photonmap.core.photon_trace.trace_photons_media`; no aiming) and
the iteration's volume photons that did not come straight from an emitter form its volume map
(Jensen & Christensen 1998), as :func:`photonmap.surface.photon_map.build_media_maps` does: the
eye pass computes single scattering of direct light with shadow rays.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.aim import trace_aimed_photons
from ..core.media import VolumeMap
from ..core.photon_trace import trace_photons_media


@dataclass
class Photons:
    """One iteration's photons that the visible points gather."""

    position: mi.Point3f
    power: mi.Color3f  # Φ_p (W), the 1/M of the iteration included
    direction: mi.Vector3f  # travel direction at the hit (into the surface)
    paths: int  # photon paths traced (M)
    aimed: int  # of them, aimed at specular shapes (core.aim)
    caustic_fraction: float  # of the aimed paths, those that met a specular shape first
    volume: VolumeMap | None = None  # scenes with media: the iteration's volume map

    @property
    def count(self) -> int:
        return dr.width(self.position)


def photon_pass(
    scene: mi.Scene, paths: int, seed: int, max_depth: int, aim: float, media: bool = False
) -> Photons:
    """Trace ``paths`` photon paths (random numbers from ``seed``, the iteration's seed), the
    fraction ``aim`` of the area lights' paths aimed at the specular shapes
    (:func:`~photonmap.core.aim.trace_aimed_photons`), and keep the records after the first
    interaction. ``media``: through participating media, with a volume map (module docstring)."""
    if media:
        records, volume = trace_photons_media(scene, paths, max_depth=max_depth, seed=seed)
        kept = records.after_first()
        vmap = VolumeMap.build(volume.select(~volume.direct))
        return Photons(kept.position, kept.power, kept.direction, paths, 0, 0.0, vmap)
    traced = trace_aimed_photons(scene, paths, aim, max_depth=max_depth, seed=seed)
    kept = traced.records.after_first()
    return Photons(
        kept.position, kept.power, kept.direction, paths, traced.aimed_paths, traced.caustic_fraction
    )

