"""SPPM photon pass (Hachisuka & Jensen 2009 §4; spec beyond-seeds §1 step 2).

Each iteration traces ``M`` photon paths from the lights with the shared photon tracer
(:func:`photonmap.core.photon_trace.trace_photons`: power split by emitted power, Russian
roulette, every smooth hit recorded). The records from the second interaction on are kept: the
first hits are the direct light the eye pass already computed by emitter sampling
(:mod:`.visible`). The powers carry the ``1/M`` of the iteration, so a density estimate over one
iteration's photons is the iteration's estimate of the reflected indirect radiance.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.photon_trace import trace_photons


@dataclass
class Photons:
    """One iteration's photons that the visible points gather."""

    position: mi.Point3f
    power: mi.Color3f  # Φ_p (W), the 1/M of the iteration included
    direction: mi.Vector3f  # travel direction at the hit (into the surface)
    paths: int  # photon paths traced (M)

    @property
    def count(self) -> int:
        return dr.width(self.position)


def photon_pass(scene: mi.Scene, paths: int, seed: int, max_depth: int) -> Photons:
    """Trace ``paths`` photon paths (random numbers from ``seed``, the iteration's seed) and
    keep the records after the first interaction."""
    records = trace_photons(scene, paths, max_depth=max_depth, seed=seed)
    kept = records.select(records.depth > 1)
    return Photons(kept.position, kept.power, kept.direction, paths)
