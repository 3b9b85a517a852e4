"""The media of the volume pipeline: :class:`Medium` (coefficients in world units) and how Mitsuba's
``homogeneous`` and ``heterogeneous`` media are read into it (:func:`read_medium`, through Mitsuba's
own ``get_scattering_coefficients``; :mod:`.medium_grid` evaluates a heterogeneous one per voxel)."""

from __future__ import annotations

from dataclasses import dataclass, field

import mitsuba as mi
import numpy as np

from ..core.arrays import columns
from ..core.errors import SceneError
from .medium_grid import coefficients_at
from .surfaces import digest


@dataclass
class Medium:
    """A medium in world units: scattering and absorption coefficients (RGB, 1/length).

    For a refractive object ``ior`` is its index relative to the fog (whose ``ior`` is 1). A
    heterogeneous medium keeps the Mitsuba medium itself in ``field`` (evaluated per voxel by S2,
    ``medium_grid.py``) and a digest of its parameters in ``fingerprint``; ``sigma_s``, ``sigma_a``
    are then its means over its shape's bounding box.
    """

    sigma_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sigma_a: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ior: float = 1.0
    phase_k: float | None = 0.0  # Schlick k of its phase function (isotropic 0; None: other)
    field: object | None = None  # mi.Medium of a heterogeneous medium
    fingerprint: str = ""

    @property
    def kappa(self) -> np.ndarray:
        """Extinction κ = σ_s + σ_a."""
        return np.asarray(self.sigma_s) + np.asarray(self.sigma_a)

    @property
    def extinction_key(self) -> tuple:
        """What κ depends on: the cache key of the photon stages (a heterogeneous medium's field
        and its parameters too)."""
        return tuple(self.kappa), id(self.field), self.fingerprint


class MediaReader:
    """One :class:`Medium` per Mitsuba medium, so that the fog volumes, the outside and
    :attr:`.scene.VolumeScene.fog` sharing a Mitsuba medium share the object ``set_material``
    replaces."""

    def __init__(self, bbox):
        self.bbox = bbox  # the scene's: where a medium bounded by no shape is averaged
        self._read: list[tuple[object, Medium]] = []

    def read(self, medium, what: str, bbox=None) -> Medium:
        """The :class:`Medium` of Mitsuba ``medium`` (:func:`read_medium`; ``what`` names it in
        errors), the same object for the same Mitsuba medium."""
        if medium is None:
            return Medium()
        for known, ours in self._read:
            if known is medium:
                return ours
        ours = read_medium(medium, what, self.bbox if bbox is None else bbox)
        self._read.append((medium, ours))
        return ours


def read_medium(medium, what: str, bbox) -> Medium:
    """Coefficients of a Mitsuba medium (None → vacuum), checked: Mitsuba's own
    ``get_scattering_coefficients`` (``σ_t·scale`` and ``albedo·σ_t·scale``, RGB), at the centre
    of ``bbox`` for a homogeneous medium; a heterogeneous one is kept (``field``) with its means
    over ``bbox`` (8³ points)."""
    if medium is None:
        return Medium()
    heterogeneous = not medium.is_homogeneous()
    lo, hi = (np.asarray(c, dtype=np.float64).reshape(-1)[:3] for c in (bbox.min, bbox.max))
    side = 8 if heterogeneous else 1
    u = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5
    points = lo + (hi - lo) * u / side
    sigma_s, sigma_t = coefficients_at(medium, mi.Point3f(*columns(mi.Float, points)))
    sigma_s = np.asarray(sigma_s, dtype=np.float64).reshape(-1, 3).mean(0)
    sigma_t = np.asarray(sigma_t, dtype=np.float64).reshape(-1, 3).mean(0)
    if not (np.all(np.isfinite(sigma_t)) and np.all(np.isfinite(sigma_s))):
        raise SceneError(f"{what} has non-finite coefficients (σ_t = {sigma_t}): use finite values")
    sigma_a = sigma_t - sigma_s
    if np.any(sigma_s < 0) or np.any(sigma_a < -1e-7 * np.abs(sigma_t)):
        raise SceneError(
            f"{what} has negative coefficients (σ_s = {sigma_s}, σ_a = {sigma_a}): sigma_t and "
            "scale must be >= 0 and albedo in [0, 1]"
        )
    if not heterogeneous:
        return Medium(sigma_s, np.maximum(sigma_a, 0.0), phase_k=schlick_k(medium))
    return Medium(
        sigma_s,
        np.maximum(sigma_a, 0.0),
        phase_k=schlick_k(medium),
        field=medium,
        fingerprint=digest(medium),
    )


def schlick_k(medium) -> float | None:
    """Schlick's k matching a Mitsuba phase function: isotropic → 0; Henyey–Greenstein g →
    k = 1.55 g − 0.55 g³ (Blasi, Le Saëc & Schlick 1993, the fit the volume pipeline's Schlick
    phase function is made for)."""
    phase = medium.phase_function()
    name = phase.class_name()
    if name == "IsotropicPhaseFunction":
        return 0.0
    if name == "HGPhaseFunction":
        g = float(np.asarray(mi.traverse(phase)["g"]).ravel()[0])
        return float(np.clip(1.55 * g - 0.55 * g**3, -0.999, 0.999))
    return None  # another phase function: the pipeline asks for an explicit phase_k
