"""The methods the viewer offers: name → adapter class. A new method is one line here; ``sppm``
is offered when the package registers it, refining while idle and restarting on any change."""

from __future__ import annotations

from .. import METHODS
from .adapters import Adapter, progressive
from .mitsuba_adapters import ScreenAdapter, SurfaceAdapter
from .volume_adapter import VolumeAdapter

ADAPTERS: dict[str, type[Adapter]] = {
    "volume": VolumeAdapter,
    "screen": ScreenAdapter,
    "surface": SurfaceAdapter,
}
if "sppm" in METHODS:  # stochastic progressive photon mapping: refine, restart on any change
    ADAPTERS["sppm"] = progressive(SurfaceAdapter, ("photons", "alpha"))
if "vcm" in METHODS:  # vertex connection and merging: the same, with its own parameters
    ADAPTERS["vcm"] = progressive(SurfaceAdapter, ("radius", "alpha"))
