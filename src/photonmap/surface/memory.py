"""The surface method's memory estimate, checked before anything is allocated (the pipeline's
``check_memory``: construction, ``set_params``, the first render at a new size; the viewer's
updates and the CLI before the render).

Parts (bytes; rough upper bounds measured on the LLVM backend at 64×48 and 128×96, Cornell box,
peak resident memory of a fresh process):

- photon tracing and maps: ``photons × (PATH_BYTES + max_depth × SLOT_BYTES)`` — per light
  path its loop state, its share of the stored records, the map's sort keys and the precomputed
  irradiance, and per bounce one record slot (position, power, direction, normal, depth, flags:
  54 B) and its compressed copy (measured 975 B per path at max_depth 8 and 540 B at 3 with
  ``lookup=knn``, 1095 B at 8 with ``lookup=irradiance``); with media each slot also has a volume
  slot (:data:`VOLUME_SLOT_BYTES`);
- the caustic map: ``caustic_photons × (PATH_BYTES + SLOT_BYTES)`` (one slot per path);
- the eye pass, direct light, caustics and final-gather batches: ``width × height × spp ×``
  :data:`~photonmap.core.memory.BYTES_PER_SAMPLE` (measured 210–350 B per sample).

The widest arrays, ``photons × max_depth`` record slots, must stay under Dr.Jit's 2³² entries.
A chunked tracer that keeps ``chunk`` bounces of slots at a time replaces ``max_depth`` by
``chunk`` in the slot term and keeps the stored records in ``PATH_BYTES``.
"""

from __future__ import annotations

from ..core.memory import check_memory, image_bytes

PATH_BYTES = 320  # per light path: loop state, stored records' share, map keys, irradiance
SLOT_BYTES = 100  # per path and bounce: a record slot (54 B) and its compressed copy
VOLUME_SLOT_BYTES = 80  # per path and bounce with media: a volume record slot and its copy
HINT = "lower photons (or caustic_photons, max_depth), the image size or spp"


def estimate(params, width: int, height: int, media: bool = False):
    """``(parts, entries)``: bytes by part and the widest arrays' entries (module docstring)."""
    slot = SLOT_BYTES + (VOLUME_SLOT_BYTES if media else 0)
    parts = {
        "photon tracing and maps": params.photons * (PATH_BYTES + params.max_depth * slot),
        "caustic map": params.caustic_photons * (PATH_BYTES + slot),
        "eye pass and final gather": image_bytes("surface", width, height, params.spp),
    }
    entries = {
        "photons × max_depth record slots": params.photons * params.max_depth,
        "pixels × spp eye samples": width * height * params.spp,
    }
    return parts, entries


def check(params, width: int, height: int, media: bool = False, available=None) -> int:
    """Refuse (one-line :class:`~photonmap.core.errors.ParameterError`) settings whose estimate
    exceeds the available memory; return the estimate in bytes."""
    parts, entries = estimate(params, width, height, media)
    return check_memory("surface", parts, HINT, entries, available)
