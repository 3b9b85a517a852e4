"""Heterogeneous media on the voxel grid (Mitsuba's ``heterogeneous`` medium read as Mitsuba defines
it).

A Mitsuba ``heterogeneous`` medium (``sigma_t`` and ``albedo`` volumes, e.g. ``gridvolume``, times
``scale``) is evaluated by Mitsuba itself: ``Medium.get_scattering_coefficients`` at world points
gives ``σ_t = scale·sigma_t(p)`` and ``σ_s = albedo(p)·σ_t`` exactly as ``volpath`` reads them.
Stage S2 needs one value per voxel: the mean over ``s³`` points of each voxel (``s =``
:data:`SUPERSAMPLE`, at ``(i + (a+½)/s, j + (b+½)/s, k + (c+½)/s)``), i.e. the voxel averages of σ_s
and σ_t (not of the albedo), which the marcher and the viewing pass then read trilinearly from the
voxel centres like every other grid (Pfeuti §3.1.1). The octree splits its nodes where κ varies
(:data:`KAPPA_TOLERANCE`; both papers ignore κ in the octree), since the marcher holds κ constant
over a step (Sun et al. 2008 eq 6).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.errors import SceneError
from ..core.grid import GridBox, voxel_count, voxel_of
from ..core.media import within_extent

SUPERSAMPLE = 2  # points per voxel and axis at which a heterogeneous medium is evaluated
KAPPA_TOLERANCE = 0.01  # octree eps_kappa with a heterogeneous medium: κ range per node,
#                         optical depth per voxel


def coefficients_at(medium, points: mi.Point3f) -> tuple[mi.Color3f, mi.Color3f]:
    """``(σ_s, σ_t)`` of the Mitsuba ``medium`` at world ``points`` (Mitsuba's own evaluation;
    zero outside a grid volume's box, where Mitsuba's medium has no interactions:
    :func:`~photonmap.core.media.within_extent`)."""
    mei = dr.zeros(mi.MediumInteraction3f, dr.width(points))
    mei.p = points
    mei.medium = mi.MediumPtr(medium)
    sigma_s, _, sigma_t = medium.get_scattering_coefficients(mei)
    inside = within_extent(mei)
    return mi.Color3f(dr.select(inside, sigma_s, 0.0)), mi.Color3f(dr.select(inside, sigma_t, 0.0))


def medium_on_grid(
    medium, box: GridBox, what: str, supersample: int = SUPERSAMPLE
) -> tuple[mi.Color3f, mi.Color3f]:
    """Per voxel of ``box`` (flat [z, y, x]), the means of ``σ_s`` and ``σ_t`` of the Mitsuba
    ``medium`` over ``supersample³`` points of the voxel, in world units (1/length). Raises
    :class:`SceneError` naming ``what`` for negative or non-finite coefficients."""
    count = voxel_count(box.dims)
    corner = mi.Point3f(*voxel_of(dr.arange(mi.UInt32, count), box.dims))
    lo, h = mi.Point3f(*(float(c) for c in box.lo)), float(box.h)
    sigma_s, sigma_t = dr.zeros(mi.Color3f, count), dr.zeros(mi.Color3f, count)
    for a in range(supersample**3):  # one pass per sub-sample: bounded memory
        offset = [(c + 0.5) / supersample for c in voxel_of(a, (supersample,) * 3)]
        s, t = coefficients_at(medium, lo + h * (corner + mi.Vector3f(*offset)))
        sigma_s += s
        sigma_t += t
        dr.eval(sigma_s, sigma_t)
    sigma_s, sigma_t = sigma_s / supersample**3, sigma_t / supersample**3
    dr.eval(sigma_s, sigma_t)
    s, t = np.asarray(sigma_s), np.asarray(sigma_t)
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(t))):
        raise SceneError(f"{what} has non-finite coefficients somewhere: fix its volumes")
    if np.min(s, initial=0.0) < 0 or np.any(s > t * (1 + 1e-6) + 1e-12):
        raise SceneError(
            f"{what} has negative coefficients or an albedo above 1 somewhere: its sigma_t volume "
            "and scale must be >= 0 and its albedo in [0, 1]"
        )
    return sigma_s, sigma_t
