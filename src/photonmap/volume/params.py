"""Parameters of the volume pipeline and their validation (the authors' defaults of Sun et al.
2008 and Pfeuti 2009): :class:`VolumeParams` (the CLI's ``--set`` keys, the plugin's properties), the
stage lists, the memory check of the box grids (:func:`check_grid`) and the checks of light and
medium edits (:func:`check_light`, :func:`updated_medium`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import drjit as dr
import numpy as np

from ..core import sampling
from ..core.errors import ParameterError
from ..core.grid import voxel_count
from ..core.memory import available_memory, human_bytes
from ..core.params import Renamed, check_choice, check_fields, check_range
from ..core.settings import HIDE_CHOICES
from . import mipmap, pilot
from .scatter import SCATTERING
from .scene import EMITTER_KINDS, LIGHT_KINDS, Light, Medium

FIDELITY = ("physical", "paper")
EMISSION = ("uniform", "adaptive")
PLACEMENTS = ("importance", "uniform")  # emission="adaptive": where the phase-2 photons go
STAGES = (
    "voxelization",
    "materials",
    "gradient",
    "octree",
    "march grids",
    "photon generation",
    "photon tracing",
    "smoothing",
    "view grids",
    "viewing",
)  # in the order render() runs them (S1, S2, S3, S4, S6 input, S5, S6/S7, S8, S9 input, S9)
ADAPTIVE_STAGES = (
    *STAGES[:5],
    "pilot photon generation",
    "pilot photon marching",
    "photon distribution",
    "photon generation",
    "photon tracing",
    "mipmap generation",
    "filtering",
    "view grids",
    "viewing",
)  # emission="adaptive": A1, A2, A3, A4, A5, A6, A7 replace S5–S8 (Pfeuti Tables 4.2–4.4)


@dataclasses.dataclass
class VolumeParams:
    """Pipeline parameters (the CLI's ``--set`` keys). Defaults: the papers' values where they
    give them (cited per key), ours otherwise."""

    RENAMED: ClassVar[dict[str, Renamed]] = {"max_radius": Renamed("radius", float)}

    grid: int = 128  # N: voxels along the longest side of the grid box (Sun §4.1: 128)
    grid_bbox: tuple | None = dataclasses.field(
        default=None, metadata={"type": object, "parse": lambda text: parse_bbox(text)}
    )  # the grid box ((x, y, z) min, (x, y, z) max), world units; None: fitted to the media
    photons: int = 1024**2  # initial photons on the photon plane (Sun Table 2)
    sampler: str = "hammersley"  # photon plane point set (Pfeuti §4.1)
    seed: int = 0
    eps: float = 0.005  # octree tolerance ε (Sun §5.3)
    eps2: float = 0.02  # second tolerance ε' (Sun §5.3); = eps for the basic octree
    ds_min: float = 1.0  # Δs_min, voxels (Sun §4.4)
    ds_max: float = 8.0  # Δs_max where ε ≤ range < ε', voxels (Sun §5.3)
    supersample: int = 4  # voxelization supersampling (Sun §4.1)
    blur_all: bool = False  # also blur σ_s and κ (Pfeuti blurs n only)
    smoothing: bool = True  # 3×3×3 smoothing of C and D (S8; emission="adaptive": C only)
    phase_k: float | None = dataclasses.field(default=None, metadata={"type": float})
    # Schlick k (Pfeuti's phase function; k not given); None: from the fog's Mitsuba phase
    # function (isotropic 0, hg g → k = 1.55 g − 0.55 g³); the built-in scenes set Sun's 0.3
    table: float = 0.0  # ρ_table of the reflective bottom layer; 0 = none (Pfeuti §3.1.6)
    iso_reflect: float = 0.04  # R_iso of the isosurface (Fresnel R₀ at n = 1.5); 0 = none
    iso_ior: float = 0.0  # n_iso; 0 = midway between the fog's and the densest object's n
    ior_noise: float = 0.0  # Perlin amplitude on n inside objects (CUBE scene)
    sigma_s_noise: float = 0.0  # relative Perlin amplitude on σ_s inside objects
    noise_scale: float = 16.0  # Perlin feature size, voxels
    fidelity: str = "physical"  # "paper": the papers' literal behaviour (march.py, view.py)
    spp: int = 1  # camera rays per pixel
    k: int = 50  # photons per radiance estimate on opaque surfaces (Jensen; shading.py)
    radius: float = 0.0  # their gather radius (k-NN searches end there), world units; 0 = 8 voxels
    light_samples: int = 4  # emitter + BSDF samples of each area / environment light per hit
    emission: str = "uniform"  # "adaptive": Pfeuti's pilot + importance photons (§3.2)
    scattering: str = "multiple"  # photons scatter in the fog (scatter.py); "single": Sun's
    pilot_photons: int = 64**2  # adaptive: pilot photons, s² on an s × s grid (Pfeuti §4.3)
    grad_threshold: float = 0.0  # adaptive: pilot gradient threshold in (0, 1]; 0 = automatic
    rad_threshold: float = 0.0  # adaptive: pilot radiance threshold in (0, 1]; 0 = automatic
    background: float = 0.75  # adaptive: share β of the pdf spread uniformly (pilot.py)
    delta_weight: float = 1.0  # adaptive: Δweight of the photon-weight filter at 16 photons per
    # voxel column (Pfeuti §3.2.4; mipmap.weight_step scales it with √budget)
    placement: str = "importance"  # adaptive: photons placed by the pilot pdf (Pfeuti) or
    # "uniform" (the reference's plane points; the filter still reads the pilot pdf's weights)
    mip_block: int = 1  # adaptive: filter level chosen per voxel (1, Pfeuti's) or per 2×2×2 block
    hide_emitters: str = "scene"  # hide emitters seen directly: scene | true | false
    mip_blend: bool = True  # adaptive: fractional photon-weight levels blending two mip levels
    # (False: Pfeuti's integer levels ⌊w/Δweight⌋)

    def validate(self) -> None:
        """Raise :class:`ParameterError` saying what is wrong and which values are allowed: the
        types (floats finite, seed in [0, 2³²)) by :func:`~photonmap.core.params.check_fields`,
        then the ranges of each key."""
        check_fields(self)
        check_grid(self.grid)
        check_bbox(self.grid_bbox)
        check_range(
            "photons",
            self.photons,
            1,
            2**31,
            "the number of photons placed on each light's photon plane (e.g. 1048576 = 1024**2, "
            "Sun Table 2)",
        )
        check_choice("sampler", self.sampler, sampling.SAMPLERS, "the photon-plane point set")
        check_choice("hide_emitters", self.hide_emitters, HIDE_CHOICES,
                     "hide emitters seen directly: the scene's setting, or true/false")  # fmt: skip
        check_choice("fidelity", self.fidelity, FIDELITY, "'paper': the papers' literal choices")
        check_choice(
            "scattering",
            self.scattering,
            SCATTERING,
            "'multiple': photons scatter in the fog (all orders); 'single': Sun's single scattering",
        )
        for key, hint in (
            ("eps", "the octree tolerance ε of n's range (Sun §5.3)"),
            ("ds_min", "the shortest photon march step, in voxels (Sun §4.4)"),
            ("noise_scale", "the Perlin feature size, in voxels"),
        ):
            check_range(key, getattr(self, key), 0, None, hint, lo_open=True)
        check_range(
            "eps2",
            self.eps2,
            self.eps,
            None,
            "the second octree tolerance ε' must be >= eps; set eps2 = eps for the basic octree "
            "(Sun §5.3)",
        )
        check_range(
            "ds_max",
            self.ds_max,
            self.ds_min,
            None,
            "the longest march step must be >= ds_min (both in voxels, Sun §5.3)",
        )
        if self.phase_k is not None:
            check_range(
                "phase_k",
                self.phase_k,
                -1,
                1,
                "Schlick's k is 0 for isotropic scattering, > 0 forward, < 0 backward",
                lo_open=True,
                hi_open=True,
            )
        for key in ("table", "iso_reflect"):
            check_range(key, getattr(self, key), 0, 1, "a reflectance; 0 turns it off")
        for key in ("ior_noise", "sigma_s_noise"):
            check_range(key, getattr(self, key), 0, None, "a Perlin amplitude; 0 = no noise")
        if self.iso_ior != 0:
            check_range(
                "iso_ior",
                self.iso_ior,
                1,
                None,
                "the isosurface's index; 0 = automatic (midway between fog and object)",
            )
        for key in ("spp", "supersample", "light_samples"):
            check_range(key, getattr(self, key), 1, None)
        check_range("k", self.k, 1, 1024, "photons per radiance estimate on surfaces")
        check_range("radius", self.radius, 0, None, "world units; 0 = automatic")
        self._validate_adaptive()

    def _validate_adaptive(self) -> None:
        """The keys of ``emission="adaptive"`` (Pfeuti §3.2)."""
        check_choice("emission", self.emission, EMISSION)
        pilot.pilot_side(self.pilot_photons)
        if self.emission == "adaptive":
            check_range(
                "pilot_photons",
                self.pilot_photons,
                None,
                self.photons,
                f"the pilots are part of photons ({self.photons}), the budget of pilot and "
                "importance photons per light: raise photons or lower pilot_photons (Pfeuti: "
                "4096 pilots for 65536 importance photons)",
                hi_open=True,
            )
        for key in ("grad_threshold", "rad_threshold"):
            check_range(
                key,
                getattr(self, key),
                0,
                1,
                "relative to the pilot maximum; 0 = automatic from the pilot statistics",
            )
        check_range(
            "background",
            self.background,
            0,
            1,
            "the share of the photon-plane pdf spread uniformly; 0 would leave regions unsampled",
            lo_open=True,
            hi_open=True,
        )
        check_choice(
            "placement",
            self.placement,
            PLACEMENTS,
            "where the adaptive pipeline places its photons: by the pilot pdf, or uniformly with "
            "the pilot pdf steering only the reconstruction filter",
        )
        check_choice(
            "mip_block",
            self.mip_block,
            mipmap.BLOCKS,
            "the reconstruction filter picks one mip level per voxel, as Pfeuti does, or per "
            "2×2×2 block",
        )
        check_range(
            "delta_weight",
            self.delta_weight,
            0,
            None,
            "photon weight per mip level; 1 = level 1 at 16 uniform photons per voxel column",
            lo_open=True,
        )


def parse_bbox(text: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``grid_bbox`` from the command line: six numbers ``xmin,ymin,zmin,xmax,ymax,zmax``."""
    try:
        v = [float(t) for t in text.replace(";", ",").split(",")]
    except ValueError:
        v = []
    if len(v) != 6:
        raise ParameterError(
            f"--set grid_bbox: expected six numbers 'xmin,ymin,zmin,xmax,ymax,zmax', got {text!r}"
        )
    return tuple(v[:3]), tuple(v[3:])


def check_bbox(bbox) -> None:
    """``grid_bbox``: None, or two corners (min, max) of 3 finite numbers with min < max."""
    if bbox is None:
        return
    try:
        lo, hi = (np.asarray(c, dtype=np.float64) for c in bbox)
    except (TypeError, ValueError):
        lo = hi = np.zeros(0)
    if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite([lo, hi])):
        raise ParameterError(
            f"grid_bbox must be two corners ((xmin, ymin, zmin), (xmax, ymax, zmax)) of finite "
            f"numbers, got {bbox!r}"
        )
    if not np.all(lo < hi):
        raise ParameterError(f"grid_bbox: every min must be below its max, got {bbox!r}")


# ------------------------------------------------------------------------------------------------
# Memory

DRJIT_MAX_ENTRIES = 2**32  # Dr.Jit arrays hold at most 2³² entries
VIEW_CHANNELS = 16  # floats per voxel in the packed viewing grid, the widest N³ array
PHOTON_BYTES = 128  # per photon: plane samples, entry point, direction, power, march state


def memory_estimate(grid, objects: int = 1, photons: int = 0, threads: int | None = None):
    """Bytes the pipeline needs for a ``grid``³ volume, or a box grid of ``grid = (n_x, n_y, n_z)``
    voxels (a rough upper estimate), as ``(total, per_voxel)``.

    Per voxel, what stays cached: coverage (4 B per refractive object), material grids n, σ_s, κ
    (28 B), ∇n (12 B), octree level and Δs_max (8 B), march grids (40 B, + 16 B of σ_s for
    multiple scattering), the traced and the smoothed C, D (2 × 24 B), the packed viewing grid
    (64 B); and while photons are traced, the 64-bit fixed-point accumulator of 8 channels (64 B)
    with one more copy per Dr.Jit thread (``ReduceMode.Expand``) and a second one for the
    scattered orders of multiple scattering (64 B). Plus :data:`PHOTON_BYTES` per photon.
    Measured on this machine: ≈ 360 B per voxel at 192³ with 2 threads, single scattering,
    against 396 B estimated then; glass_sphere_fog at 160³ with 2²⁰ photons peaks at 1.59 GiB
    (single) and 1.84 GiB (multiple scattering) against 1.94 GiB estimated.
    """
    threads = dr.thread_count() if threads is None else threads
    cached = 4 * objects + 28 + 12 + 8 + 56 + 2 * 24 + 4 * VIEW_CHANNELS
    accumulator = 8 * 8 * (2 + max(int(threads), 1))
    per_voxel = cached + accumulator
    return per_voxel * voxel_count(grid) + PHOTON_BYTES * int(photons), per_voxel


def check_grid(
    grid, objects: int = 1, photons: int = 0, available: int | None = None, dims=None
) -> None:
    """Raise :class:`ParameterError` unless ``grid`` is an integer >= 4 whose N³ grids (or, given
    ``dims``, the box grid of ``n_x × n_y × n_z`` voxels) fit in Dr.Jit's array limit and in
    ``available`` bytes (default: :func:`available_memory`)."""
    if isinstance(grid, bool) or not isinstance(grid, int | np.integer) or grid < 4:
        raise ParameterError(
            f"grid must be an integer >= 4 (voxels along the grid's longest side; the papers "
            "use 128), "
            f"got {grid!r}"
        )
    dims = (grid,) * 3 if dims is None else tuple(int(c) for c in dims)
    voxels = voxel_count(dims)
    need, per_voxel = memory_estimate(dims, objects, photons)
    available = available_memory() if available is None else available
    # the largest grid that fits: N scales every side of the box (fraction of the N³ cube)
    fraction = voxels / grid**3
    if available is not None and need > available:
        fits = int((max(available - PHOTON_BYTES * photons, 0) / per_voxel / fraction) ** (1 / 3))
        size = "×".join(str(c) for c in dims) if len(set(dims)) > 1 else f"{grid}³"
        parts = (
            f"{size} voxels × {per_voxel} bytes for the material, octree, photon and view grids"
        )
        if photons:
            parts += f" + {photons:,} photons × {PHOTON_BYTES} bytes"
        raise ParameterError(
            f"grid={grid} needs about {human_bytes(need)} of memory ({parts}), but only "
            f"{human_bytes(available)} is available: use a smaller grid (grid <= {fits} fits)"
            + (" or fewer photons" if photons else "")
        )
    if VIEW_CHANNELS * voxels > DRJIT_MAX_ENTRIES:
        largest = int((DRJIT_MAX_ENTRIES / VIEW_CHANNELS / fraction) ** (1 / 3))
        raise ParameterError(
            f"grid={grid} needs arrays of {VIEW_CHANNELS}·{voxels:,} = {VIEW_CHANNELS * voxels:,} "
            f"entries, more than Dr.Jit's limit of 2³² entries per array: use grid <= {largest}"
        )


LIGHT_VECTORS = ("position", "direction", "intensity")


def light_vector(name: str, value) -> np.ndarray:
    """A light vector as float64 RGB/xyz; a scalar intensity is grey."""
    try:
        a = np.asarray(value, dtype=np.float64)
        if name == "intensity" and a.ndim == 0:
            a = np.repeat(a, 3)
        if a.shape != (3,):
            raise ValueError
    except (TypeError, ValueError):
        raise ParameterError(
            f"light {name} must be 3 numbers (x, y, z{'' if name != 'intensity' else ' or RGB'}), "
            f"got {value!r}"
        ) from None
    return a


def check_light(light: Light) -> None:
    if light.kind in EMITTER_KINDS:
        if light.emitter is None or light.position is not None or light.direction is not None:
            raise ParameterError(
                f"an {light.kind} light is the scene's own Mitsuba emitter: set_light changes only "
                "its intensity (an RGB factor on its radiance); edit the emitter itself through "
                "mi.traverse and call reload()"
            )
    elif light.kind not in LIGHT_KINDS:
        raise ParameterError(f"light kind must be point, spot or directional, got {light.kind!r}")
    for name in ("intensity", "position", "direction"):
        value = getattr(light, name)
        if value is not None and not np.all(np.isfinite(value)):
            raise ParameterError(
                f"light {name} must be finite, got {np.asarray(value).tolist()}: pass finite numbers"
            )
    if np.any(np.asarray(light.intensity) < 0):
        raise ParameterError(
            f"light intensity must be >= 0 in every channel, got {np.asarray(light.intensity).tolist()}"
        )
    for name in ("cos_inner", "cos_outer"):
        value = getattr(light, name)
        if not (math.isfinite(value) and -1 <= value <= 1):
            raise ParameterError(f"{name} must be a cosine in [-1, 1], got {value!r}")
    if light.kind == "directional" and (
        light.direction is None or np.linalg.norm(light.direction) == 0
    ):
        raise ParameterError("a directional light needs a non-zero direction (where light travels)")
    if light.kind in ("point", "spot") and light.position is None:
        raise ParameterError(f"a {light.kind} light needs a position (world units)")
    if light.kind == "spot" and (light.direction is None or np.linalg.norm(light.direction) == 0):
        raise ParameterError("a spot light needs a non-zero direction (its axis)")


def updated_medium(medium: Medium, ior, sigma_s, sigma_a, where: str) -> Medium:
    def rgb(name, value):
        try:
            return np.broadcast_to(np.asarray(value, dtype=np.float64), 3).copy()
        except (TypeError, ValueError):
            raise ParameterError(
                f"{name} of {where} must be a number or 3 numbers (RGB, 1/world unit), "
                f"got {value!r}"
            ) from None

    try:
        n = float(medium.ior if ior is None else ior)
    except (TypeError, ValueError):
        raise ParameterError(f"n (ior) of {where} must be a number, got {ior!r}") from None
    keep = sigma_s is None and sigma_a is None  # a heterogeneous medium stays one
    new = Medium(
        sigma_s=rgb("sigma_s", medium.sigma_s if sigma_s is None else sigma_s),
        sigma_a=rgb("sigma_a", medium.sigma_a if sigma_a is None else sigma_a),
        ior=n,
        phase_k=medium.phase_k,
        field=medium.field if keep else None,
        fingerprint=medium.fingerprint if keep else "",
    )
    for name, value in (("sigma_s", new.sigma_s), ("sigma_a", new.sigma_a), ("ior", new.ior)):
        if not np.all(np.isfinite(value)):
            raise ParameterError(
                f"{name} of {where} must be finite, got {np.asarray(value).tolist()}: "
                "pass finite coefficients (world units)"
            )
    for name, value in (("sigma_s", new.sigma_s), ("sigma_a", new.sigma_a)):
        if np.any(value < 0):
            raise ParameterError(
                f"{name} of {where} must be >= 0, got {value.tolist()}: coefficients are "
                "non-negative (kappa = sigma_s + sigma_a)"
            )
    if new.ior < 1:
        raise ParameterError(
            f"n (ior) of {where} must be >= 1, got {new.ior}: the volume pipeline needs objects "
            "optically denser than the fog (n is relative to the fog)"
        )
    return new
