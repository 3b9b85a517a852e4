"""The screen method's memory estimate, checked before anything is allocated (the pipeline's
``check_memory``: construction, ``set_params``, the first render at a new size; the viewer's
updates and the CLI before the render).

Parts (bytes; rough upper bounds measured on the LLVM backend, peak resident memory of a fresh
process on the Cornell box: 1000 B per light texel at 2 bounces, 1300 B at 6):

- the light G-buffer and the photons: ``light_res² × (TEXEL_BYTES + bounces × PHOTON_BYTES)``
  (per texel its G-buffer entry, random map and path, the ``CHUNK`` record slots of the shared
  photon tracer (:mod:`photonmap.core.photon_trace`); per bounce a photon record and the splats'
  state);
- the eye G-buffer, direct light, soft shadows, upsampling and composite:
  ``width × height ×`` :data:`~photonmap.core.memory.BYTES_PER_SAMPLE`.

The photon arrays, ``light_res² × max(bounces, CHUNK)`` entries, must stay under Dr.Jit's 2³²
entries.
"""

from __future__ import annotations

from ..core.memory import check_memory, image_bytes
from ..core.photon_trace import CHUNK

TEXEL_BYTES = 900  # per light G-buffer texel: G-buffer entry, random map, path, record slots
PHOTON_BYTES = 100  # per texel and bounce: photon record and splatting state
HINT = "lower photons (photons · bounces slots), bounces or the image size"


def estimate(params, width: int, height: int):
    """``(parts, entries)``: bytes by part and the widest arrays' entries (module docstring)."""
    texels = params.light_res**2
    parts = {
        "light G-buffer and photons": texels * (TEXEL_BYTES + params.bounces * PHOTON_BYTES),
        "G-buffers and image": image_bytes("screen", width, height),
    }
    entries = {"light_res² × bounces photon slots": texels * max(params.bounces, CHUNK)}
    return parts, entries


def check(params, width: int, height: int, available=None) -> int:
    """Refuse (one-line :class:`~photonmap.core.errors.ParameterError`) settings whose estimate
    exceeds the available memory; return the estimate in bytes."""
    parts, entries = estimate(params, width, height)
    return check_memory("screen", parts, HINT, entries, available)
