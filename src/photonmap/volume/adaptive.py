"""A4–A5 — phase 2 of Pfeuti's adaptive pipeline: importance-distributed photons (Pfeuti 2009
§3.2.3 after Pharr & Humphreys). Stages A4–A5 of the pipeline (:mod:`.pipeline`).

The pdf ``P[j, i]`` of phase 1 (``pilot.py``) is piecewise constant on a ``W × H`` grid over the
photon plane ``[0,1]²``. Marginal/conditional sampling, continuous
piecewise-constant (Pharr & Humphreys' ``Distribution2D``; the weight uses the continuous density)::

    m[j]   = Σ_i P[j, i]                 Cy[j]   = Σ_{j'<j} m[j']          (rows: the plane's w)
    q[i|j] = P[j, i] / m[j]              Cx[i|j] = Σ_{i'<i} q[i'|j]        (columns: u)
    j = the row with Cy[j] ≤ u₂ < Cy[j+1]       y = (j + (u₂ − Cy[j]) / m[j]) / H
    i = the column with Cx[i|j] ≤ u₁ < Cx[i+1|j] x = (i + (u₁ − Cx[i|j]) / q[i|j]) / W
    p(x, y) = P[j, i] · W · H

with ``(u₁, u₂)`` Hammersley points and binary searches on the CDFs ("we do not build the inverse
explicitly"); rows and cells of zero mass are never chosen. A photon's power is the S5 power for
``N`` plane samples times its weight ``w = 1/p(x, y)`` (relative to the uniform pdf, so Δweight is
dimensionless; Pfeuti's weight ``1/(p·A·N)`` holds the factor ``A·N`` too; = 1 for the uniform pdf,
so ``Φ = I·(A/N)·cos³θ/(d²·p)``, Pfeuti's ``light_power/(p_x·p_y·square_area·photon_count)``). The
phase-2 march (A5) is S6/S7 with the count and weight sums in the spare accumulator channels
(:func:`photonmap.volume.deposit.weight_tally`).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core import sampling
from ..core.arrays import to_jit
from ..core.errors import ParameterError
from ..core.grid import GridBox
from .emit import Photons, emit_at
from .pilot import PilotGrids, importance_pdf
from .scene import Light


@dataclass
class PlaneSampler:
    """Marginal/conditional CDFs of a ``(H, W)`` pdf [row j = w, column i = u] (module
    docstring)."""

    pdf: np.ndarray  # (H, W) cell probabilities, sum 1
    row_cdf: mi.Float  # Cy, H + 1 entries
    col_cdf: mi.Float  # Cx, H rows of W + 1 entries
    filter_pdf: np.ndarray | None = None  # (H, W) the pdf whose weights the A7 filter reads

    @staticmethod
    def build(pdf, filter_pdf=None) -> PlaneSampler:
        """Normalise ``pdf`` and build the CDFs; a negative, non-finite or all-zero pdf raises a
        :class:`ParameterError`. ``filter_pdf`` (default ``pdf``): the photon weights reported to
        the photon-weight filter are ``1/p`` of this pdf (``placement="uniform"`` samples the plane
        uniformly but filters by the importance pdf)."""
        if filter_pdf is not None:
            f = PlaneSampler.build(filter_pdf).pdf
            if f.shape != np.shape(pdf) or np.any((f > 0) != (np.asarray(pdf) > 0)):
                raise ParameterError(
                    "filter_pdf must have the shape and the zero cells of the sampled pdf"
                )
            sampler = PlaneSampler.build(pdf)
            sampler.filter_pdf = f
            return sampler
        p = np.asarray(pdf, dtype=np.float64)
        if p.ndim != 2 or min(p.shape) < 1:
            raise ParameterError(f"the photon-plane pdf must be a 2D array, got shape {p.shape}")
        if not np.all(np.isfinite(p)) or np.any(p < 0):
            raise ParameterError(
                "the photon-plane pdf must be finite and >= 0 in every cell; check the pilot "
                "photons' energies and the background probability"
            )
        if p.sum() <= 0:
            raise ParameterError(
                "the photon-plane pdf is zero everywhere, so no photon can be placed: give a "
                "background probability > 0 or a pdf with positive mass"
            )
        p = p / p.sum()
        rows = p.sum(1)
        row_cdf = np.concatenate([[0.0], np.cumsum(rows)])
        cond = np.divide(p, rows[:, None], out=np.zeros_like(p), where=rows[:, None] > 0)
        col_cdf = np.concatenate([np.zeros((p.shape[0], 1)), np.cumsum(cond, 1)], 1)
        # exactly 1 from the last cell of positive mass on: u < 1 never selects a later cell
        row_cdf[np.flatnonzero(rows)[-1] + 1 :] = 1.0
        last = p.shape[1] - 1 - np.argmax(cond[:, ::-1] > 0, axis=1)
        col_cdf[:, 1:][np.arange(p.shape[1]) >= last[:, None]] = 1.0
        return PlaneSampler(p, mi.Float(row_cdf.ravel()), mi.Float(col_cdf.ravel()))

    def sample(
        self, u1: mi.Float, u2: mi.Float, filtered: bool = False
    ) -> tuple[mi.Float, mi.Float, mi.Float] | tuple[mi.Float, mi.Float, mi.Float, mi.Float]:
        """Warp unit-square points to ``(x, y, p(x, y))`` distributed by the pdf; ``filtered``
        appends the density of ``filter_pdf`` (that of the pdf if none) at ``(x, y)``."""
        h, w = self.pdf.shape
        j = dr.binary_search(0, h - 1, lambda k: dr.gather(mi.Float, self.row_cdf, k + 1) <= u2)
        row = j * (w + 1)
        i = dr.binary_search(
            0, w - 1, lambda k: dr.gather(mi.Float, self.col_cdf, row + k + 1) <= u1
        )
        cy0 = dr.gather(mi.Float, self.row_cdf, j)
        cy1 = dr.gather(mi.Float, self.row_cdf, j + 1)
        cx0 = dr.gather(mi.Float, self.col_cdf, row + i)
        cx1 = dr.gather(mi.Float, self.col_cdf, row + i + 1)
        fy = dr.clip((u2 - cy0) / dr.maximum(cy1 - cy0, 1e-30), 0.0, 1.0 - 1e-6)
        fx = dr.clip((u1 - cx0) / dr.maximum(cx1 - cx0, 1e-30), 0.0, 1.0 - 1e-6)
        cell = to_jit(mi.Float, self.pdf.ravel())
        density = dr.gather(mi.Float, cell, j * w + i) * (w * h)
        x, y = (mi.Float(i) + fx) / w, (mi.Float(j) + fy) / h
        if not filtered:
            return x, y, density
        if self.filter_pdf is None:
            return x, y, density, density
        other = to_jit(mi.Float, self.filter_pdf.ravel())
        return x, y, density, dr.gather(mi.Float, other, j * w + i) * (w * h)


def emit_importance(
    light: Light,
    box: GridBox,
    sampler: PlaneSampler,
    count: int,
    points: str = "hammersley",
    seed: int = 0,
    fidelity: str = "physical",
) -> tuple[Photons, mi.Float]:
    """A4: ``count`` photons placed by ``sampler`` and weighted by ``1/p``; returns the photons
    and the weights the photon-weight filter reads (``1/p`` of ``sampler.filter_pdf`` if set;
    0 for photons that miss the grid)."""
    u1, u2 = sampling.coherent_points(points, count, seed)
    x, y, density, filter_density = sampler.sample(u1, u2, filtered=True)
    dr.eval(x, y, density, filter_density)  # one CDF inversion, read by both kernels below
    photons = emit_at(light, box, x, y, fidelity, dr.rcp(density))
    weight = dr.select(dr.max(photons.power) > 0, dr.rcp(filter_density), 0.0)
    dr.eval(weight)
    return photons, weight


def plane_sampler(
    pilot_grids: PilotGrids,
    grad_threshold: float,
    rad_threshold: float,
    background: float,
    placement: str,
) -> PlaneSampler:
    """A3–A4: the photon-plane sampler of one light from its pilot grids (thresholds and
    ``background`` as in :func:`~.pilot.importance_pdf`). ``placement="uniform"`` samples the plane
    uniformly (the reference's points, weight 1) and reports the importance pdf's weights ``1/p``
    to the photon-weight filter, so the pilots steer the reconstruction only."""
    pdf = importance_pdf(pilot_grids, grad_threshold, rad_threshold, background)
    if placement == "importance":
        return PlaneSampler.build(pdf)
    return PlaneSampler.build(np.ones_like(pdf), filter_pdf=pdf)
