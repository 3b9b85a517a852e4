"""The global and caustic photon maps (Steinhurst 2007 §2.6.1, Alg 2.4; Jensen 1996).

Photons come from :func:`photonmap.core.photon_trace.trace_photons` (light paths through Mitsuba's
BSDFs with Russian roulette, stored at every non-specular hit). Following Jensen's convention
(spec seed-001 A5): the **global map** holds every stored hit of ``photons`` light paths, first
bounces included (the final gather needs them at its secondary hits); the **caustic map** holds the
hits of a separate ``caustic_photons`` paths that lie on L S+ D paths. Caustics at an eye-ray hit
come only from the caustic map, so nothing is counted twice. In a scene with participating media
(:func:`build_media_maps`) a third map, the volume map (Jensen & Christensen 1998), holds the
photons stored at scattering events in the media.

Each map keeps its photons as a struct of arrays (position, power, direction, normal; float32,
52 bytes a photon) in tracing order; its search structure keeps the positions with their indices in
its own order — a hash grid sorted by cell, or a left-balanced kd-tree in heap order (spec §2.3) —
so the memory layout a gather touches is explicit.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.aim import trace_aimed_photons
from ..core.errors import ParameterError
from ..core.hashgrid import HashGrid
from ..core.media import VolumeMap
from ..core.photon_trace import PhotonRecords, trace_photons, trace_photons_media
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
        """The ``k`` nearest photons to each query that pass the normal test (spec §2.4, A13):
        arrived from the query's front side and stored on a surface facing the same way."""
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
    max_depth: int = 8,
    seed: int = 0,
) -> tuple[PhotonMap, PhotonMap]:
    """Trace the two photon passes and build the global and caustic maps."""
    if photons < 1 or caustic_photons < 0:
        raise ParameterError(
            f"photons must be >= 1 and caustic_photons >= 0, got {photons} and {caustic_photons}"
        )
    global_records = trace_photons(scene, photons, max_depth=max_depth, seed=seed)
    if caustic_photons:
        caustic_records = trace_aimed_photons(  # aimed at the specular shapes (issue 12)
            scene, caustic_photons, 1.0, max_depth=max_depth, seed=seed + 1, caustics_only=True
        ).records
    else:
        caustic_records = global_records.select(dr.zeros(mi.Bool, global_records.count))
    return photon_map(global_records, structure), photon_map(caustic_records, structure)


def build_media_maps(
    scene: mi.Scene,
    photons: int,
    caustic_photons: int,
    structure: str = "hash",
    max_depth: int = 8,
    seed: int = 0,
) -> tuple[PhotonMap, PhotonMap, VolumeMap]:
    """:func:`build_photon_maps` for a scene with participating media (Jensen & Christensen 1998;
    spec beyond-seeds §4): the photons fly through the media
    (:func:`~photonmap.core.photon_trace.trace_photons_media`), and the volume photons of the
    global pass that did not come straight from an emitter form the volume map — single
    scattering of direct light is computed by the eye pass with shadow rays instead, as direct
    light on surfaces is. Volume caustics (light through glass scattered once) stay in the map."""
    if photons < 1 or caustic_photons < 0:
        raise ParameterError(
            f"photons must be >= 1 and caustic_photons >= 0, got {photons} and {caustic_photons}"
        )
    global_records, volume = trace_photons_media(scene, photons, max_depth=max_depth, seed=seed)
    if caustic_photons:
        caustic_records, _ = trace_photons_media(
            scene, caustic_photons, max_depth=max_depth, seed=seed + 1, caustics_only=True
        )
    else:
        caustic_records = global_records.select(dr.zeros(mi.Bool, global_records.count))
    vmap = VolumeMap.build(volume.select(~volume.direct))
    return photon_map(global_records, structure), photon_map(caustic_records, structure), vmap
