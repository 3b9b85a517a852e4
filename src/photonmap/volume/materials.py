"""Stages S2 and S3: material grids from coverage, Gaussian smoothing, and the gradient of n.

Sun et al. 2008 §4.1 (convert coverage to refractive index and smooth it), Pfeuti 2009 §3.1.2
("the refraction index voxel grid is then filtered", "we build the gradient array from the
refraction indices"). Where the papers leave a rule open (which grids are blurred, the
boundary, the coverage map, the gradient scheme), the choice is said below.

**Mapping (S2).** Linear in coverage, from the surrounding medium's values to each object's,
objects applied in turn: ``q(v) ← q(v) + cov(v)·(q_obj(v) − q(v))`` for ``q ∈ {n, σ_s, κ}`` (RGB
for σ_s and κ). Bounded fog (the interior of a ``null``/``thindielectric`` shape)
is applied the same way before the objects, to σ_s and κ only (index-matched: n unchanged), so
that outside its shape σ is the surrounding medium's (vacuum: 0) and on its border the coverage
fraction of it. A heterogeneous medium's values are per voxel (``medium_grid.py``: Mitsuba's own
evaluation, averaged over 2³ points per voxel). Coefficients are stored in **voxel units**:
``σ_vox = σ_world · h``.

**Perturbation** (the cube scene of Pfeuti 2009 Fig 4.9): inside objects, at voxel centres
``v``, ``n_obj(v) = n_obj + a_n·perlin(v/s)`` and
``σ_s,obj(v) = σ_s,obj·max(0, 1 + a_σ·perlin'(v/s))`` with ``κ_obj = σ_s,obj + σ_a,obj``;
``perlin`` is seeded with ``seed``, ``perlin'`` with ``seed + 1`` (:class:`Perturbation`:
``a_n``, ``a_σ``, ``s``, ``seed``).

**Blur (S2).** Separable 9-tap Gaussian, σ = 9/6 = 1.5 voxels, normalised, clamp-to-edge
(:data:`BLUR_TAPS`), applied to n (Pfeuti blurs "the refraction index voxel grid"); ``blur_all=True``
also blurs σ_s and κ.

**Gradient (S3).** Central differences in voxel units,
``∂n/∂x (i,j,k) = (n[i+1,j,k] − n[i−1,j,k]) / 2``, one-sided at the grid faces.

Simulation or painted data bypass S1 and S2 through :func:`from_arrays`.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import to_jit
from ..core.errors import ParameterError
from ..core.grid import GridBox, filter_separable, gaussian_taps, grid_shape, voxel_count, voxel_of
from ..core.noise import perlin3
from .medium import Medium
from .medium_grid import medium_on_grid

BLUR_TAPS = gaussian_taps(4, 1.5)
"""The 9 taps of the S2 blur: [0.00761, 0.03607, 0.10959, 0.21344, 0.26656, 0.21344, ...]."""


@dataclass(frozen=True)
class Perturbation:
    """The Perlin perturbation inside objects (module docstring): amplitudes ``ior`` (a_n) and
    ``sigma_s`` (a_σ), feature size ``scale`` (s, voxels) and ``seed``; none by default."""

    ior: float = 0.0
    sigma_s: float = 0.0
    scale: float = 16.0
    seed: int = 0


@dataclass
class MaterialGrids:
    """Grids indexed [z, y, x]: ``ior`` (n_z, n_y, n_x, 1); ``sigma_s`` and ``kappa``
    (n_z, n_y, n_x, 3), in voxel units (per voxel edge)."""

    ior: mi.TensorXf
    sigma_s: mi.TensorXf
    kappa: mi.TensorXf


def _check_material(ior, sigma_s, kappa, where: str) -> None:
    """Raise :class:`ParameterError` unless n ≥ 1, 0 ≤ σ_s ≤ κ and all are finite."""
    for name, values in (("n", ior), ("sigma_s", sigma_s), ("kappa", kappa)):
        if not np.all(np.isfinite(values)):
            raise ParameterError(f"{name} of {where} has NaN or infinite values")
    if np.any(ior < 1.0):
        raise ParameterError(f"n of {where} must be >= 1 (min {np.min(ior):g})")
    if np.any(sigma_s < 0.0) or np.any(kappa < 0.0):
        raise ParameterError(f"sigma_s and kappa of {where} must be >= 0")
    if np.any(kappa < sigma_s - 1e-6 * np.abs(sigma_s)):
        raise ParameterError(
            f"kappa of {where} is smaller than sigma_s somewhere: extinction kappa = sigma_s + "
            "sigma_a cannot be below scattering sigma_s"
        )


def _check_coverage(coverage: mi.TensorXf, dims, what: str) -> None:
    if tuple(coverage.shape[:3]) != grid_shape(dims) or dr.width(coverage.array) != voxel_count(
        dims
    ):
        raise ParameterError(f"{what} has shape {coverage.shape}, expected {grid_shape(dims)}")


def voxel_centres(dims) -> mi.Point3f:
    """The centres of every voxel of a grid of extent ``dims``, in flat [z, y, x] order."""
    return mi.Point3f(*voxel_of(dr.arange(mi.UInt32, voxel_count(dims)), dims)) + 0.5


def _grid(values: mi.Color3f, dims) -> mi.TensorXf:
    return mi.TensorXf(dr.ravel(values), grid_shape(dims, 3))


def material_grids(
    coverages: list[tuple[mi.TensorXf, Medium]],
    fog: Medium,
    box: GridBox,
    blur_all: bool = False,
    noise: Perturbation = Perturbation(),
    media: list[tuple[mi.TensorXf, Medium]] = (),
) -> MaterialGrids:
    """Map coverages (n_z, n_y, n_x) to n, σ_s and κ, then blur n: ``fog`` everywhere, then each
    fog volume of ``media`` (σ_s and κ only), then each object of ``coverages`` (perturbed by
    ``noise``)."""
    dims, h, count = box.dims, box.h, box.voxels
    _check_material(fog.ior, fog.sigma_s, fog.kappa, "the fog")
    if not (np.isfinite(noise.scale) and noise.scale > 0):
        raise ParameterError(f"noise_scale must be positive, got {noise.scale!r}")

    def opaque_color(c):
        return dr.opaque(mi.Color3f(*(float(x) * h for x in np.broadcast_to(c, 3))))

    def values(medium: Medium, what: str):
        """(σ_s, κ, σ_a) in voxel units: constants, or per voxel for a heterogeneous medium."""
        if medium.field is None:
            return tuple(opaque_color(c) for c in (medium.sigma_s, medium.kappa, medium.sigma_a))
        s, t = medium_on_grid(medium.field, box, what)
        return s * h, t * h, (t - s) * h

    ior = dr.opaque(mi.Float, fog.ior, count)
    fog_s, fog_kappa, _ = values(fog, "the fog")
    sigma_s = fog_s * dr.ones(mi.Float, count)
    kappa = fog_kappa * dr.ones(mi.Float, count)
    p = voxel_centres(dims) / dr.opaque(mi.Float, noise.scale)
    noise_n = noise_s = 0.0
    if noise.ior:
        noise_n = dr.opaque(mi.Float, noise.ior) * perlin3(p, noise.seed)
    if noise.sigma_s:
        noise_s = dr.opaque(mi.Float, noise.sigma_s) * perlin3(p, noise.seed + 1)
    for i, (coverage, medium) in enumerate(media):
        _check_coverage(coverage, dims, f"fog volume {i}")
        _check_material(1.0, medium.sigma_s, medium.kappa, f"fog volume {i}")
        medium_s, medium_kappa, _ = values(medium, f"fog volume {i}")
        cov = coverage.array
        sigma_s = dr.lerp(sigma_s, medium_s, cov)
        kappa = dr.lerp(kappa, medium_kappa, cov)
    for i, (coverage, medium) in enumerate(coverages):
        _check_coverage(coverage, dims, f"coverage {i}")
        _check_material(medium.ior, medium.sigma_s, medium.kappa, f"object {i}")
        ior_obj = dr.opaque(mi.Float, medium.ior) + noise_n
        medium_s, _, medium_a = values(medium, f"object {i}")
        sigma_s_obj = medium_s * dr.maximum(1.0 + noise_s, 0.0)
        kappa_obj = sigma_s_obj + medium_a
        cov = coverage.array
        ior = dr.lerp(ior, ior_obj, cov)
        sigma_s = dr.lerp(sigma_s, sigma_s_obj, cov)
        kappa = dr.lerp(kappa, kappa_obj, cov)

    grids = MaterialGrids(
        mi.TensorXf(ior, grid_shape(dims, 1)), _grid(sigma_s, dims), _grid(kappa, dims)
    )
    grids.ior = filter_separable(grids.ior, BLUR_TAPS)
    if blur_all:
        grids.sigma_s = filter_separable(grids.sigma_s, BLUR_TAPS)
        grids.kappa = filter_separable(grids.kappa, BLUR_TAPS)
    dr.eval(grids.ior, grids.sigma_s, grids.kappa)
    return grids


def from_arrays(grids: dict, box: GridBox) -> MaterialGrids:
    """Material grids from NumPy data in world units (the bypass of S1/S2, Sun et al. 2008 §3):
    ``{"n": (n_z, n_y, n_x), "sigma_s": (n_z, n_y, n_x) or (n_z, n_y, n_x, 3), "kappa": same}``,
    indexed [z, y, x] (the box's :attr:`~.GridBox.shape`)."""
    keys = {"n", "sigma_s", "kappa"}
    if set(grids) != keys:
        raise ParameterError(
            f"volume grids need exactly the keys {sorted(keys)}, got {sorted(grids)}"
        )
    shape = box.shape
    ior = np.asarray(grids["n"], dtype=np.float64)
    if ior.shape != shape:
        raise ParameterError(f"grid 'n' has shape {ior.shape}, expected {shape}")
    rgb = {}
    for name in ("sigma_s", "kappa"):
        values = np.asarray(grids[name], dtype=np.float64)
        if values.shape == shape:
            values = np.repeat(values[..., None], 3, axis=-1)
        if values.shape != (*shape, 3):
            raise ParameterError(
                f"grid {name!r} has shape {values.shape}, expected {shape} or {(*shape, 3)}"
            )
        rgb[name] = values
    _check_material(ior, rgb["sigma_s"], rgb["kappa"], "the volume grids")
    return MaterialGrids(
        to_jit(mi.TensorXf, ior[..., None]),
        to_jit(mi.TensorXf, (rgb["sigma_s"] * box.h)),
        to_jit(mi.TensorXf, (rgb["kappa"] * box.h)),
    )


def gradient(ior: mi.TensorXf) -> mi.TensorXf:
    """∇n of a grid (nz, ny, nx[, 1]) in voxel units: a tensor (nz, ny, nx, 3) of (∂x, ∂y, ∂z)."""
    extent = tuple(ior.shape[:3])
    if len(ior.shape) not in (3, 4) or min(extent) < 2 or dr.width(ior.array) != np.prod(extent):
        raise ParameterError(f"gradient needs a scalar grid of at least 2³ voxels, got {ior.shape}")
    nz, ny, nx = extent
    index = dr.arange(mi.UInt32, 3 * nz * ny * nx)
    voxel, axis = index // 3, index % 3
    stride = dr.select(axis == 0, 1, dr.select(axis == 1, nx, nx * ny))
    size = dr.select(axis == 0, nx, dr.select(axis == 1, ny, nz))
    coord = (voxel // stride) % size
    base = voxel - coord * stride
    below = dr.select(coord > 0, coord - 1, coord)
    above = dr.select(coord < size - 1, coord + 1, coord)
    difference = dr.gather(mi.Float, ior.array, base + above * stride) - dr.gather(
        mi.Float, ior.array, base + below * stride
    )
    return mi.TensorXf(difference / mi.Float(above - below), (nz, ny, nx, 3))
