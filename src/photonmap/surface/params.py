"""The surface method's parameters (:class:`SurfaceParams`: the ``photon_mapper`` plugin's
properties and the ``--set`` keys of ``--method surface``), their ranges and choices, and the
pipeline's stages."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from ..core.params import Renamed, check_choice, check_fields, check_range
from ..core.settings import check_path_params
from .cis import TABLE_SAMPLING
from .gather_batch import ORDERS
from .irradiance_cache import MODES
from .photon_map import STRUCTURES

LOOKUPS = ("irradiance", "knn", "direct")
FG_SAMPLING = ("bsdf", "cosine", "uniform") + TABLE_SAMPLING
STAGES = (
    "photon maps",
    "irradiance",
    "eye pass",
    "direct lighting",
    "caustics",
    "final gather",
    "light images",
)


@dataclasses.dataclass
class SurfaceParams:
    """Parameters of the surface pipeline (the ``photon_mapper`` plugin and ``--set`` keys)."""

    RENAMED: ClassVar[dict[str, Renamed]] = {"max_radius": Renamed("radius", float)}

    photons: int = 200_000  # light paths into the global map
    caustic_photons: int = 1_000_000  # light paths for the caustic map (most cost one ray)
    k: int = 100  # photons per gather (Steinhurst Table 7.1)
    radius: float = 0.0  # gather radius, scene units: k-NN searches end there; 0 = automatic
    fg_rays: int = 32  # final-gather rays per eye-ray hit (N_FG)
    structure: str = "hash"  # "hash" (hash grid) | "kdtree" (left-balanced, heap order)
    max_depth: int = 0  # longest path in segments (Mitsuba's); 0 = the scene's, -1 = unbounded
    rr_depth: int = 0  # depth where Russian roulette starts; 0 = the scene's
    hide_emitters: str = "scene"  # hide emitters seen directly: scene | true | false
    seed: int = 0
    lookup: str = "irradiance"  # final-gather secondary lookup: irradiance | knn | direct
    fg_sampling: str = "bsdf"  # final-gather directions: bsdf | cosine | uniform | jensen | cis
    irradiance_cache: str = "none"  # none | ward (one sequential cache) | tiled (Steinhurst Ch. 5)
    ic_error: float = 0.05  # the irradiance cache's ε_max
    irradiance_every: int = 4  # precompute irradiance at every m-th photon (Christensen 1999)
    spp: int = 1  # eye rays per pixel
    emitter_spp: int = 256  # extra samples of the lights' direct and specular images (0 = none)
    light_samples: int = 0  # emitter samples of the direct light per eye-path end; 0 = automatic
    volume_k: int = 50  # volume photons per in-scattering estimate (scenes with media)
    volume_radius: float = 0.0  # maximum volume gather radius; 0 = automatic
    march_step: float = 0.0  # ray-marching step in media; 0 = half the median k-NN radius
    gather_order: str = "hilbert"  # order of the k-NN final gathers (Steinhurst Ch. 3): the
    # fastest on the CPU (benchmarks/steinhurst_tables.py), the image is the same in every order
    tile: int = 16  # screen tile edge for the tiled gather orders

    def validate(self) -> None:
        """Types (:func:`~photonmap.core.params.check_fields`: integers, finite numbers, the seed
        in [0, 2³²)), then ranges and choices; a :class:`ParameterError` names what is wrong."""
        check_fields(self)
        for key, hint in (
            ("photons", "light paths into the global map"),
            ("k", "photons per gather (Steinhurst: 100)"),
            ("fg_rays", "final-gather rays per eye-ray hit"),
            ("irradiance_every", "irradiance precomputed at every m-th photon"),
            ("spp", "eye rays per pixel"),
            ("volume_k", "volume photons per in-scattering estimate"),
            ("tile", "screen tile edge in pixels for the tiled gather orders"),
        ):
            check_range(key, getattr(self, key), 1, None, hint)
        check_range("caustic_photons", self.caustic_photons, 0, None, "0 = no caustic map")
        check_range("emitter_spp", self.emitter_spp, 0, None, "0 = no extra light samples")
        check_range("light_samples", self.light_samples, 0, None, "0 = automatic")
        check_range("radius", self.radius, 0, None, "the gather radius, scene units; 0 = automatic")
        check_range("volume_radius", self.volume_radius, 0, None, "0 = automatic")
        check_range("march_step", self.march_step, 0, None, "0 = automatic")
        check_path_params(self)
        check_choice("structure", self.structure, tuple(STRUCTURES), "the photon search structure")
        check_choice("lookup", self.lookup, LOOKUPS, "the final gather's secondary lookup")
        check_choice("fg_sampling", self.fg_sampling, FG_SAMPLING, "final-gather directions")
        check_choice("gather_order", self.gather_order, ORDERS, "the final gathers' order")
        check_choice("irradiance_cache", self.irradiance_cache, MODES, "the irradiance cache")
        check_range("ic_error", self.ic_error, 1e-6, None, "the irradiance cache's ε_max")
