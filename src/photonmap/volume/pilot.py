"""A1–A3 — phase 1 of Pfeuti's adaptive pipeline: pilot photons → a 2D pdf on the photon plane
(Pfeuti 2009 §3.2.2, Listing B.1): stages A1–A3 of the pipeline (:mod:`.pipeline`). Where the thesis
says "slightly" or leaves a value open, the choice is said below.

**A1 pilot generation.** ``s × s`` photons on a square grid of the photon plane, each jittered
within its cell (uniformly, by a seeded generator), listed row by row so that photon ``idx`` comes
from origin cell ``(ox, oy) = (idx mod s, ⌊idx/s⌋)`` (the jitter is ignored for the origin). Energy
as in S5.

**A2 pilot marching.** The S6/S7 marcher at full resolution, depositing into a grid 2^k times
coarser (16³ for 128³) per voxel the energy ``C``, the deposit count ``n`` and the origin sums
``Σox, Σoy, Σox², Σoy²`` — unpacked (Pfeuti's 12/15/15/10/10-bit packing overflows for 64 × 64
origins). A photon deposits once per fine voxel it crosses, so the statistics are per deposit: the
mean and spread of the origins are weighted by the path length through the coarse voxel ("the same
as rasterizing … into a voxel grid of higher resolution and applying a smoothing filter").

**A3 importance distribution.** With the pilot radiance ``Y = R+G+B`` normalised by its maximum and
``g = ‖∇Y‖`` (central differences; the thesis's "color based gradient" is not defined), voxel ``v``
is selected if ``n > 0`` and ``g ≥ grad_threshold`` or ``0 < Y ≤ rad_threshold`` (Listing B.1).
Threshold 0 means automatic: the 90th percentile of ``g`` and the 10th percentile of ``Y`` over the
lit voxels, so a selection adapts to each light (Pfeuti §5 names manual thresholds as the method's
main usability flaw). Each selected voxel adds 1 to the cells of the ``s × s`` origin grid inside a
disc centred at the mean origin ``μ = Σo/n`` with diameter ``max(1, σx + σy)``, ``σ² = Σo²/n − μ²``
(the shader's point size; the radius is at least √2/2 so the disc always holds a cell centre). Then
a background ``β·M/((1−β)·s²)`` is added to every cell (M = the circles' mass, β = ``background``: a
fraction of the final mass rather than the thesis's absolute value), the 5×5 Gaussian of variance 2
is applied (clamped edges) and the grid is normalised to sum 1. If nothing is selected the pdf is
uniform. All of A3 is host work on ≤ 16³ voxels and s² cells (NumPy).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..core import sampling
from ..core.errors import ParameterError
from ..core.grid import GridBox, grid_shape
from .deposit import Int64, Vector4i64, coarse_size
from .emit import Photons, emit_at
from .march import Marching, accumulate
from .scene import Light
from .step import MarchGrids

PILOT_GRID = 16  # cells per axis of the pilot grid for a 128³ volume (Pfeuti §3.2.2)
GRAD_PERCENTILE = 90.0  # automatic grad_threshold: this percentile of g over lit voxels
RAD_PERCENTILE = 10.0  # automatic rad_threshold: this percentile of Y over lit voxels
PDF_BLUR = (0.1117, 0.23648, 0.30364, 0.23648, 0.1117)  # 5 taps, σ² = 2 (Listing B.1)


@dataclass
class PilotGrids:
    """The pilot grid (m_z × m_y × m_x cells, [z, y, x]) and the origin grid side ``s``."""

    C: np.ndarray  # (m_z, m_y, m_x, 3) deposited energy
    count: np.ndarray  # (m_z, m_y, m_x) deposits
    origin_sum: np.ndarray  # (m_z, m_y, m_x, 2) Σox, Σoy
    origin_sq: np.ndarray  # (m_z, m_y, m_x, 2) Σox², Σoy²
    side: int
    entering: int  # pilot photons that entered the grid
    steps: int


def pilot_side(count: int) -> int:
    """The origin grid side ``s`` of ``count = s²`` pilot photons."""
    side = math.isqrt(count)
    if count < 4 or side * side != count:
        raise ParameterError(
            f"pilot_photons must be a square number >= 4 (the pilot photons form an s × s grid on "
            f"the photon plane, Pfeuti §3.2.2), got {count}; e.g. {max(side, 2) ** 2} or "
            f"{(side + 1) ** 2}"
        )
    return side


def pilot_shift(n: int) -> int:
    """``k`` such that the pilot grid is ``2^k`` times coarser than ``n`` voxels along the grid's
    longest side (16³ for 128³)."""
    return max(0, math.ceil(math.log2(n / PILOT_GRID)))


def emit_pilot(
    light: Light, box: GridBox, count: int, seed: int = 0, fidelity: str = "physical"
) -> Photons:
    """A1: ``count = s²`` jittered grid photons in row order (origin = list index)."""
    pilot_side(count)
    u, w = sampling.jittered(count, seed)
    return emit_at(light, box, u, w, fidelity)


def _origin_tally(side: int, count: int):
    """Pilot packets per deposit: (C rgb, 1), (ox, oy, ox², oy²) of the photon's origin cell."""
    idx = dr.arange(Int64, count)
    ox, oy = idx % side, idx // side
    origins = Vector4i64(ox, oy, ox * ox, oy * oy)

    def tally(q, zero):
        return Vector4i64(q[0], q[1], q[2], zero + 1), origins

    return tally


def march_pilot(
    photons: Photons, medium: MarchGrids, ds_min: float = 1.0, fidelity: str = "physical"
) -> PilotGrids:
    """A2: march the pilot photons, depositing into the coarse pilot grid with origin sums."""
    side = math.isqrt(photons.generated)
    shift = pilot_shift(medium.n)
    m = grid_shape(coarse_size(medium.dims, shift), 4)
    marching = Marching(ds_min, fidelity=fidelity)
    first, second, unit, steps, *_ = accumulate(
        photons, medium, _origin_tally(side, photons.generated), shift, marching
    )
    first = np.asarray(first, dtype=np.float64).T.reshape(m)
    second = np.asarray(second, dtype=np.float64).T.reshape(m)
    return PilotGrids(
        C=first[..., :3] * unit,
        count=first[..., 3],
        origin_sum=second[..., :2],
        origin_sq=second[..., 2:],
        side=side,
        entering=photons.count,
        steps=steps,
    )


def thresholds(pilot: PilotGrids, grad_threshold: float = 0.0, rad_threshold: float = 0.0):
    """``(Y, g, grad_threshold, rad_threshold)``: normalised pilot radiance, its gradient norm, and
    the thresholds (a 0 argument is replaced by its automatic percentile over lit voxels)."""
    Y = pilot.C.sum(-1)
    peak = Y.max()
    Y = Y / peak if peak > 0 else Y
    g = np.linalg.norm(np.stack(np.gradient(Y)), axis=0)
    lit = (pilot.count > 0) & (Y > 0)
    if lit.any():
        grad_threshold = grad_threshold or float(np.percentile(g[lit], GRAD_PERCENTILE))
        rad_threshold = rad_threshold or float(np.percentile(Y[lit], RAD_PERCENTILE))
    return Y, g, grad_threshold, rad_threshold


def selected_voxels(
    pilot: PilotGrids, grad_threshold: float = 0.0, rad_threshold: float = 0.0
) -> np.ndarray:
    """A3 voxel selection (Listing B.1): a boolean grid of the pilot grid's shape."""
    Y, g, gt, rt = thresholds(pilot, grad_threshold, rad_threshold)
    hit = pilot.count > 0
    return hit & ((g >= gt) & (g > 0) | ((Y > 0) & (Y <= rt)))


def circle_mass(pilot: PilotGrids, selected: np.ndarray) -> np.ndarray:
    """A3 circles: ``(s, s)`` grid [oy, ox], +1 per selected voxel in each cell whose centre lies
    in the voxel's disc (centre = mean origin, diameter ``max(1, σx + σy)``)."""
    n = pilot.count[selected][:, None]
    mean = pilot.origin_sum[selected] / n
    spread = np.sqrt(np.maximum(pilot.origin_sq[selected] / n - mean**2, 0.0))
    radius = np.maximum(0.5 * np.maximum(spread.sum(-1), 1.0), math.sqrt(0.5))
    side = pilot.side
    rows = np.arange(side, dtype=np.float64)
    dy = (rows[None, :] - mean[:, 1, None]) ** 2  # (discs, rows)
    r2 = (radius**2)[:, None]
    mx = mean[:, 0, None]

    def inside(c):
        return (c - mx) ** 2 + dy <= r2

    # per disc and row the run of cells [lo, hi] inside it (the exact test fixes sqrt's rounding)
    half = np.sqrt(np.maximum(r2 - dy, 0.0))
    lo, hi = np.ceil(mx - half), np.floor(mx + half)
    lo = np.where(inside(lo - 1), lo - 1, np.where(inside(lo), lo, lo + 1))
    hi = np.where(inside(hi + 1), hi + 1, np.where(inside(hi), hi, hi - 1))
    lo, hi = np.maximum(lo, 0), np.minimum(hi, side - 1)
    run = (hi >= lo) & (r2 >= dy)
    row = np.broadcast_to(np.arange(side), run.shape)[run]
    runs = np.zeros((side, side + 1))
    np.add.at(runs, (row, lo[run].astype(int)), 1.0)
    np.add.at(runs, (row, hi[run].astype(int) + 1), -1.0)
    return np.cumsum(runs, axis=1)[:, :side]


def blur_pdf(grid: np.ndarray) -> np.ndarray:
    """The separable 5×5 Gaussian of variance 2 with clamped edges (Pfeuti §3.2.2)."""
    taps = np.asarray(PDF_BLUR)
    for axis in (0, 1):
        padded = np.pad(grid, [(2, 2) if a == axis else (0, 0) for a in (0, 1)], mode="edge")
        size = grid.shape[axis]
        grid = sum(
            w * np.take(padded, np.arange(k, k + size), axis=axis) for k, w in enumerate(taps)
        )
    return grid


def importance_pdf(
    pilot: PilotGrids,
    grad_threshold: float = 0.0,
    rad_threshold: float = 0.0,
    background: float = 0.75,
) -> np.ndarray:
    """A3: the ``(s, s)`` pdf [oy, ox] over the origin cells, summing to 1."""
    circles = circle_mass(pilot, selected_voxels(pilot, grad_threshold, rad_threshold))
    mass = circles.sum()
    if mass == 0:
        return np.full(circles.shape, 1.0 / circles.size)
    pdf = blur_pdf(circles + background * mass / ((1.0 - background) * circles.size))
    return pdf / pdf.sum()
