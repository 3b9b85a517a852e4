"""The SPPM method's memory estimate, checked before anything is allocated (the pipeline's
``check_memory``: construction, ``set_params``, the first iteration at a new size; the viewer's
updates and the CLI before the run; the driver before distributing).

Memory is one iteration's plus the per-pixel state, whatever the number of iterations
(bytes; rough upper bounds measured on the LLVM backend, peak resident memory of a fresh
process, one iteration at 64×48):

- the photon pass: ``photons_per_iteration × (PATH_BYTES + max_depth × SLOT_BYTES)`` — per path
  its loop state and aiming, per bounce a record slot (54 B), its compressed copy and the hash
  grid's keys (measured 700 B per path at max_depth 8 on the Cornell box, 560 B with glass);
  with media each slot also has a volume slot;
- the eye pass, visible points, per-pixel N, R, τ and the gather:
  ``width × height ×`` :data:`~photonmap.core.memory.BYTES_PER_SAMPLE`.

``photons_per_iteration × max_depth`` record slots must stay under Dr.Jit's 2³² entries.
"""

from __future__ import annotations

from ..core.memory import check_memory, image_bytes

PATH_BYTES = 200  # per photon path: loop state, aiming, stored records' share
SLOT_BYTES = 64  # per path and bounce: record slot, compressed copy, hash-grid keys
VOLUME_SLOT_BYTES = 80  # per path and bounce with media: a volume record slot and its copy
HINT = "lower photons_per_iteration (or max_depth) or the image size"


def estimate(params, width: int, height: int, media: bool = False):
    """``(parts, entries)``: bytes by part and the widest arrays' entries (module docstring)."""
    slot = SLOT_BYTES + (VOLUME_SLOT_BYTES if media else 0)
    paths = params.photons_per_iteration
    parts = {
        "photon pass": paths * (PATH_BYTES + params.max_depth * slot),
        "eye pass and pixel state": image_bytes("sppm", width, height),
    }
    entries = {"photons_per_iteration × max_depth record slots": paths * params.max_depth}
    return parts, entries


def check(params, width: int, height: int, media: bool = False, available=None) -> int:
    """Refuse (one-line :class:`~photonmap.core.errors.ParameterError`) settings whose estimate
    exceeds the available memory; return the estimate in bytes."""
    parts, entries = estimate(params, width, height, media)
    return check_memory("sppm", parts, HINT, entries, available)
