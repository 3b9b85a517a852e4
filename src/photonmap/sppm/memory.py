"""The SPPM method's memory estimate, checked before anything is allocated (the pipeline's
``check_memory``: construction, ``set_params``, the first iteration at a new size; the viewer's
updates and the CLI before the run; the driver before distributing).

Memory is one iteration's plus the per-pixel state, whatever the number of iterations
(bytes; rough upper bounds measured on the LLVM backend, peak resident memory of a fresh
process, one iteration on the Cornell box; :func:`~photonmap.core.photon_memory.path_bytes`):

- the photon pass: ``photons × (PATH_BYTES + CHUNK × SLOT_BYTES + n ×
  RECORD_BYTES)``, ``n`` the interactions a path may record (``max_depth − 1``; 16 when
  unbounded) — per path its loop state and aiming, the ``CHUNK`` record slots of a chunk (54 B
  each) with their compaction, per record kept its copy in the hash grid; with media the volume
  slots and records. Measured per path: 732 B at max_depth 3, 1002 B at 9, 1060 B unbounded
  (estimated 770, 1040, 1400 B);
- the eye pass, visible points, per-pixel N, R, τ and the gather: ``width × height × eye paths
  per pixel ×`` :data:`~photonmap.core.memory.BYTES_PER_SAMPLE`.

``photons × CHUNK`` record slots must stay under Dr.Jit's 2³² entries.
"""

from __future__ import annotations

from ..core.memory import check_memory, image_bytes
from ..core.photon_memory import CHUNK, path_bytes

PATH_BYTES = 200  # per photon path: loop state, aiming
SLOT_BYTES = 60  # per path and slot of a chunk: a record slot and its compaction
RECORD_BYTES = 45  # per record kept: the record and the hash grid's keys
MEDIA_BYTES = 60  # per slot and record with media: the volume slot and record
HINT = "lower photons (or max_depth, spp) or the image size"


def estimate(params, width: int, height: int, max_depth: int, eye_spp: int = 1,
             media: bool = False):  # fmt: skip
    """``(parts, entries)``: bytes by part and the widest arrays' entries (module docstring);
    ``max_depth`` the effective one, ``eye_spp`` the eye paths per pixel and iteration."""
    slot = SLOT_BYTES + (MEDIA_BYTES if media else 0)
    record = RECORD_BYTES + (MEDIA_BYTES if media else 0)
    paths = params.photons
    parts = {
        "photon pass": paths * path_bytes(max_depth, PATH_BYTES, slot, record),
        "eye pass and pixel state": image_bytes("sppm", width, height, eye_spp),
    }
    entries = {
        "photons × CHUNK record slots": paths * CHUNK,
        "pixels × eye paths": width * height * eye_spp,
    }
    return parts, entries


def check(params, width: int, height: int, max_depth: int, eye_spp: int = 1,
          media: bool = False, available=None) -> int:  # fmt: skip
    """Refuse (one-line :class:`~photonmap.core.errors.ParameterError`) settings whose estimate
    exceeds the available memory; return the estimate in bytes."""
    parts, entries = estimate(params, width, height, max_depth, eye_spp, media)
    return check_memory("sppm", parts, HINT, entries, available)
