"""The global and caustic photon maps (Steinhurst 2007 §2.6.1, Alg 2.4; Jensen 1996).

Photons come from the transport core's photon loop
(:func:`photonmap.core.photon_trace.trace_photons`: light paths through Mitsuba's BSDFs and media
with Russian roulette, stored at every smooth hit). Following Jensen's convention (Jensen 1996;
Steinhurst's Alg 2.4 as printed never records a caustic photon, and his text and pseudo-code
disagree on the indirect map): the **global map** holds every stored hit of ``photons`` light paths,
first bounces included (the final gather needs them at its secondary hits); the **caustic map**
holds the hits of a separate ``caustic_photons`` paths that lie on L S+ D paths. Caustics at an
eye-ray hit come only from the caustic map, so nothing is counted twice. In a scene with
participating media a third map, the volume map (Jensen & Christensen 1998), holds the photons
stored at scattering events in the media.

Each map keeps its photons as a struct of arrays (position, power, direction, normal; float32, 52
bytes a photon) in tracing order; its search structure keeps the positions with their indices in its
own order — a hash grid sorted by cell, or a left-balanced kd-tree in heap order (Steinhurst §4.2) —
so the memory layout a gather touches is explicit.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.errors import ParameterError
from ..core.hashgrid import HashGrid
from ..core.photon_trace import PhotonRecords, PhotonRules, trace_photons
from ..core.scene_info import SceneTraits
from ..core.settings import UNBOUNDED, PathSettings
from ..core.volume_map import VolumeMap
from .kdtree import KDTree

STRUCTURES = {"hash": HashGrid, "kdtree": KDTree}


@dataclass
class PhotonMap:
    """Stored photons plus the structure that answers k-nearest and fixed-radius queries."""

    photons: PhotonRecords
    structure: object  # HashGrid | KDTree, built over photons.position

    @property
    def size(self) -> int:
        return self.photons.count

    def knn(self, query: mi.Point3f, normal: mi.Vector3f, k: int, max_radius: float):
        """The ``k`` nearest photons to each query that pass the normal test
        (:mod:`photonmap.core.knn`): arrived from the query's front side and stored on a surface
        facing the same way."""
        return self.structure.knn(
            query,
            k=k,
            max_radius=max_radius,
            query_normal=normal,
            normals=self.photons.normal,
            directions=self.photons.direction,
        )


def photon_map(records: PhotonRecords, structure: str) -> PhotonMap:
    if structure not in STRUCTURES:
        raise ParameterError(f"structure must be one of {', '.join(STRUCTURES)}, got {structure!r}")
    return PhotonMap(records, STRUCTURES[structure](records.position))


def build_photon_maps(
    scene: mi.Scene,
    photons: int,
    caustic_photons: int,
    structure: str = "hash",
    settings: PathSettings | None = None,
    seed: int = 0,
    traits: SceneTraits | None = None,
    media: list | None = None,
) -> tuple[PhotonMap, PhotonMap, VolumeMap | None]:
    """Trace the two photon passes (:func:`~photonmap.core.photon_trace.trace_photons`) and build
    the global and caustic maps and, in a scene with participating media, the volume map.

    The caustic pass aims every area light's paths at the specular shapes and keeps ``L S+ D``
    records only. The volume map holds the global pass's volume photons that did not come
    straight from an emitter: single scattering of direct light is the eye pass's next-event
    estimation, as direct light on surfaces is (Jensen & Christensen 1998); volume caustics (light
    through glass scattered once) stay in the map. ``max_depth`` (Mitsuba's path length): the
    global map is read one bounce away from the eye's first vertex (final gather), so it keeps the
    photons of depth ≤ ``max_depth − 2``; the caustic map, read at that vertex, ``max_depth − 1``
    (the transport core stops there)."""
    if photons < 1 or caustic_photons < 0:
        raise ParameterError(
            f"photons must be >= 1 and caustic_photons >= 0, got {photons} and {caustic_photons}"
        )
    settings = settings or PathSettings()
    traits = traits or SceneTraits.of(scene)
    traced = trace_photons(
        scene, photons, PhotonRules(settings, traits, rough_glass=True), seed, media=media
    )
    global_records = traced.records
    if settings.max_depth != UNBOUNDED and global_records.count:
        global_records = global_records.select(global_records.depth + 2 <= settings.max_depth)
    if caustic_photons:
        caustic_rules = PhotonRules(settings, traits, caustics_only=True, rough_glass=True)
        caustic_records = trace_photons(
            scene, caustic_photons, caustic_rules, seed + 1, 1.0, media=media
        ).records
    else:
        caustic_records = global_records.select(dr.zeros(mi.Bool, global_records.count))
    vmap = None
    if traced.volume is not None:
        vmap = VolumeMap.build(traced.volume.select(~traced.volume.direct))
    return photon_map(global_records, structure), photon_map(caustic_records, structure), vmap
