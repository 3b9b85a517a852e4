"""S8 — radiance storage smoothing (Sun et al. 2008 §4.4; Pfeuti 2009 §3.1.5).

"In each voxel, we approximate the incoming radiance distribution by storing only a weighted average
of the direction of arriving photons and a single radiance value for the red, green, and blue
wavelengths" (Sun §4.4). The deposited sums are smoothed "using a 3×3×3 approximation of a Gaussian
kernel to reduce noise": the binomial ``[1, 2, 1]/4`` separably with clamped edges (the papers give
no weights), applied to ``C`` and to the unnormalised ``D``; then ``D̂ = D/‖D‖`` (0 where ``D = 0``;
Pfeuti's listing treats the stored direction as a unit vector).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.grid import filter_separable

BINOMIAL = (0.25, 0.5, 0.25)


def smooth(C: mi.TensorXf, D: mi.TensorXf, enabled: bool = True) -> tuple[mi.TensorXf, mi.TensorXf]:
    """Return the smoothed radiance grid ``C`` and the unit mean-direction grid ``D̂``."""
    if enabled:
        C = filter_separable(C, BINOMIAL)
        D = filter_separable(D, BINOMIAL)
    shape = tuple(D.shape)
    d = dr.unravel(mi.Vector3f, D.array)
    length = dr.norm(d)
    d_hat = dr.select(length > 0, d / dr.maximum(length, 1e-30), 0.0)
    D_hat = mi.TensorXf(dr.ravel(d_hat), shape)
    dr.eval(C, D_hat)
    return C, D_hat
