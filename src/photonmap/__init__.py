"""photonmap — photon mapping on Mitsuba 3 + Dr.Jit.

Importing the package finds a usable libLLVM (see :mod:`photonmap.core.llvm`), selects a Mitsuba
variant (``llvm_ad_rgb`` by default; ``PHOTONMAP_DEVICE=cuda`` or :func:`set_device` selects
``cuda_ad_rgb``) and registers the Mitsuba integrator plugins (``volume_photon``,
``photon_mapper``, ``ispm``, ``sppm``).
"""

from __future__ import annotations

import os

from .core import interrupt as _interrupt

_interrupt.guard_command()  # the photonmap command: Ctrl-C during this import is answered too

from .core import llvm  # noqa: E402
from .core.errors import (  # noqa: E402
    BackendError,
    ParameterError,
    PhotonmapError,
    PhotonmapWarning,
    SceneError,
)

llvm.configure()

with _interrupt.held():  # Dr.Jit's worker threads start with SIGINT blocked (interrupt.held)
    import drjit as dr
    import mitsuba as mi

VARIANTS = {"cpu": "llvm_ad_rgb", "cuda": "cuda_ad_rgb"}


def set_device(device: str) -> str:
    """Select the Dr.Jit backend: ``"cpu"`` (LLVM, all cores) or ``"cuda"``. Returns the variant."""
    if device not in VARIANTS:
        raise ParameterError(f"unknown device {device!r}; choose one of {sorted(VARIANTS)}")
    variant = VARIANTS[device]
    if variant not in mi.variants():
        raise BackendError(f"Mitsuba variant {variant!r} is not available in this installation")
    try:
        mi.set_variant(variant)
    except Exception as exc:  # pragma: no cover - depends on the machine
        raise BackendError(f"cannot start the {device} backend: {exc}") from exc
    _register_plugins()
    return variant


def _register_plugins() -> None:
    from .core.diff_dielectric import register as register_diff_dielectric
    from .screen.integrator import register as register_screen
    from .sppm.integrator import register as register_sppm
    from .surface.integrator import register as register_surface
    from .vcm.integrator import register as register_vcm
    from .volume.integrator import register as register_volume

    register_diff_dielectric()
    register_volume()
    register_surface()
    register_screen()
    register_sppm()
    register_vcm()


with _interrupt.held():
    set_device(os.environ.get("PHOTONMAP_DEVICE", "cpu"))
    if dr.thread_count() < 2:  # one core: Mitsuba's OpenEXR writer waits forever on one thread
        dr.set_thread_count(2)
    dr.eval(dr.sum(dr.arange(mi.Float, 1 << 22)))  # a parallel job: every worker thread starts

from typing import NamedTuple  # noqa: E402

from .api import render  # noqa: E402
from .core.image import compare  # noqa: E402
from .core.reference import render_reference  # noqa: E402
from .screen.pipeline import STAGES as SCREEN_STAGES  # noqa: E402
from .screen.pipeline import ScreenParams, ScreenPipeline  # noqa: E402
from .sppm.pipeline import STAGES as SPPM_STAGES  # noqa: E402
from .sppm.pipeline import BlockSums, SPPMParams, SPPMPipeline  # noqa: E402
from .surface.params import STAGES as SURFACE_STAGES  # noqa: E402
from .surface.params import SurfaceParams  # noqa: E402
from .surface.pipeline import SurfacePipeline  # noqa: E402
from .vcm.pipeline import STAGES as VCM_STAGES  # noqa: E402
from .vcm.pipeline import VCMParams, VCMPipeline  # noqa: E402
from .volume.params import STAGES as VOLUME_STAGES  # noqa: E402
from .volume.params import VolumeParams  # noqa: E402
from .volume.pipeline import VolumePipeline  # noqa: E402


class Method(NamedTuple):
    """A rendering method: its pipeline class, parameter dataclass and stage names."""

    pipeline: type
    params: type
    stages: tuple[str, ...]


METHODS = {
    "volume": Method(VolumePipeline, VolumeParams, VOLUME_STAGES),
    "surface": Method(SurfacePipeline, SurfaceParams, SURFACE_STAGES),
    "screen": Method(ScreenPipeline, ScreenParams, SCREEN_STAGES),
    "sppm": Method(SPPMPipeline, SPPMParams, SPPM_STAGES),
    "vcm": Method(VCMPipeline, VCMParams, VCM_STAGES),
}

__all__ = [
    "METHODS",
    "SCREEN_STAGES",
    "SPPM_STAGES",
    "SURFACE_STAGES",
    "VOLUME_STAGES",
    "BackendError",
    "BlockSums",
    "Method",
    "ParameterError",
    "PhotonmapError",
    "PhotonmapWarning",
    "SPPMParams",
    "SPPMPipeline",
    "SceneError",
    "ScreenParams",
    "ScreenPipeline",
    "SurfaceParams",
    "SurfacePipeline",
    "VCM_STAGES",
    "VCMParams",
    "VCMPipeline",
    "VolumeParams",
    "VolumePipeline",
    "compare",
    "render",
    "render_reference",
    "dr",
    "mi",
    "set_device",
]
__version__ = "0.1.0"
