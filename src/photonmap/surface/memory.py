"""The surface method's memory estimate, checked before anything is allocated (the pipeline's
``check_memory``: construction, ``set_params``, the first render at a new size; the viewer's
updates and the CLI before the render).

Parts (bytes; rough upper bounds measured on the LLVM backend, peak resident memory of a fresh
process on the Cornell box; :func:`~photonmap.core.photon_memory.path_bytes`):

- photon tracing and maps: ``photons × (PATH_BYTES + CHUNK × SLOT_BYTES + n × RECORD_BYTES)``,
  ``n`` the interactions a path may record (``max_depth − 1``; 16 when unbounded) — per light
  path its loop state, the ``CHUNK`` record slots of a chunk (position, power, direction,
  normal, depth, flags: 54 B each) with their compaction, per record kept the map with its sort
  keys and the precomputed irradiance; with media each slot and record also has a volume one.
  Measured per path: 955 B at max_depth 4 and 1265 B at 9 with ``lookup=knn``, 1515 B at 9 and
  1570 B unbounded with the default ``lookup=irradiance`` (estimated 1060, 1540, 2300 B);
- the caustic map: ``caustic_photons × (PATH_BYTES + CHUNK × SLOT_BYTES + RECORD_BYTES)``
  (one record per path at most; measured 610 B per path);
- the eye pass, direct light, caustics and final-gather batches: ``width × height × spp ×``
  :data:`~photonmap.core.memory.BYTES_PER_SAMPLE` (measured 210–350 B per sample).

The widest arrays, ``photons × CHUNK`` record slots, must stay under Dr.Jit's 2³² entries.
"""

from __future__ import annotations

from ..core.memory import check_memory, image_bytes
from ..core.photon_memory import CHUNK, path_bytes

PATH_BYTES = 300  # per light path: loop state, emission, the chunk's path state
SLOT_BYTES = 60  # per path and slot of a chunk: a record slot and its compaction
RECORD_BYTES = 95  # per record kept: the map, its sort keys, the precomputed irradiance
MEDIA_BYTES = 60  # per slot and record with media: the volume slot and record
HINT = "lower photons (or caustic_photons, max_depth), the image size or spp"


def estimate(params, width: int, height: int, max_depth: int, media: bool = False):
    """``(parts, entries)``: bytes by part and the widest arrays' entries (module docstring);
    ``max_depth``: the effective one (the scene file's unless the parameters override it)."""
    slot = SLOT_BYTES + (MEDIA_BYTES if media else 0)
    record = RECORD_BYTES + (MEDIA_BYTES if media else 0)
    parts = {
        "photon tracing and maps": params.photons * path_bytes(max_depth, PATH_BYTES, slot, record),
        "caustic map": params.caustic_photons * (PATH_BYTES + CHUNK * slot + record),
        "eye pass and final gather": image_bytes("surface", width, height, params.spp),
    }
    entries = {
        "photons × CHUNK record slots": max(params.photons, params.caustic_photons) * CHUNK,
        "pixels × spp eye samples": width * height * params.spp,
    }
    return parts, entries


def check(params, width: int, height: int, max_depth: int, media: bool = False,
          available=None) -> int:  # fmt: skip
    """Refuse (one-line :class:`~photonmap.core.errors.ParameterError`) settings whose estimate
    exceeds the available memory; return the estimate in bytes."""
    parts, entries = estimate(params, width, height, max_depth, media)
    return check_memory("surface", parts, HINT, entries, available)
