"""Photon splatting: quads and icosahedra (Yao 2011 §3.3, Eq 1, Ch. 5; the icosahedra of McGuire &
Luebke 2009). The thesis's falloff texture, "surface material colour" and path density are not
defined there; the choices are those below.

Every covered pixel with G-buffer point s, normal n and albedo ρ gathers Eq (1),

    L(s) += f(s) · max(0, n_p·n) · Φ_p · κ(s − s_p),   f = ρ/π,   E(s) = L(s) without f,

with the normalized Jensen cone κ(ρ) = 3/(π r_p²) · max(0, 1 − ρ/r_p) (normalized, so splats
conserve power) and the per-photon radius r_p = clamp(r/√ρ_path, r/8, r). Photons that are invalid
or face away from the eye, (e − s_p)·n_p ≤ 0, are culled (with the eye position e). Where κ is
evaluated:

- quad (at the G-buffer point, with a depth tolerance): Δ = s − s_p, h = Δ·n_p,
  ρ = ‖Δ − h n_p‖, and the pixel is covered only if |h| ≤ τ r_p (τ = :data:`TAU`). The kernel is
  radial, so the quad's tangent frame does not change the result;
- icosahedron (circumradius 1.25841 r_p) with normal compression c = 1: the 3D distance
  ρ = ‖Δ‖ (Yao's uncompressed volume); c < 1: the in-plane ρ with |h| ≤ c r_p (ISPM style).

**Scatter as a gather** (no rasterizer: each splat is evaluated over its screen bounds): each pixel
sums over the photons whose support contains its G-buffer point. The kept photons are sorted into a
uniform grid of cells of edge half the reach R = max r_p, times √(1 + τ²) (or √(1 + c²)) for the
in-plane kernels, whose support reaches ‖Δ‖ < r_p √(1 + τ²). A pixel visits the cells overlapping
the box s ± R as x-runs of consecutive cells, i.e. contiguous ranges of the sorted photons (outer
loop over runs, inner loop over a run's photons).
"""

from __future__ import annotations

import math
import numbers

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import to_jit, to_numpy
from ..core.errors import ParameterError
from .gbuffer import GBuffer
from .light_photons import ScreenPhotons

MAX_CELLS = 1 << 21
"""Cells of the photon grid at most (the cell edge grows to fit)."""
TAU = 0.25
"""Plane tolerance τ of the quads, in units of r_p."""


def splat_quads(
    gbuf: GBuffer, photons: ScreenPhotons, radius: float, cull: bool = True
) -> tuple[mi.Color3f, mi.Color3f]:
    """Indirect radiance L_ind and irradiance E_ind per pixel of ``gbuf`` from photon quads.

    ``radius``: the splat radius r in world units (module docstring). Invalid pixels get 0.
    ``cull``: leave out the photons facing away from the eye; False for points seen
    in mirrors and through glass, which face other ways.
    """
    return _splat(gbuf, photons, radius, TAU, "gbuffer", cull)


def splat_icosahedra(
    gbuf: GBuffer,
    photons: ScreenPhotons,
    radius: float,
    compression: float = 1.0,
    cull: bool = True,
) -> tuple[mi.Color3f, mi.Color3f]:
    """L_ind and E_ind from icosahedron photon volumes with normal compression c ∈ (0, 1]
    (``cull`` as in :func:`splat_quads`)."""
    if not 0 < compression <= 1:
        raise ParameterError(
            f"compression must lie in (0, 1] (1 = Yao's uncompressed volume, 0.25 = ISPM-like), "
            f"got {compression!r}"
        )
    if compression == 1:
        return _splat(gbuf, photons, radius, 1.0, "sphere", cull)
    return _splat(gbuf, photons, radius, compression, "gbuffer", cull)


def _check_positive(name: str, value: float):
    if not (isinstance(value, numbers.Real) and math.isfinite(value) and value > 0):
        raise ParameterError(f"{name} must be a positive finite number, got {value!r}")


def _splat(gbuf: GBuffer, photons: ScreenPhotons, radius: float, tau: float, mode: str,
           cull: bool):  # fmt: skip
    _check_positive("radius", radius)
    radius, tau = float(radius), float(tau)
    pixels = gbuf.width * gbuf.height
    if dr.width(gbuf.pos) != pixels:
        raise ParameterError(
            f"the G-buffer holds {dr.width(gbuf.pos)} pixels, not width·height = {pixels}"
        )
    # ---- keep the photons that can contribute: valid, facing the eye, some power
    eye = mi.Point3f(gbuf.eye)
    r_p = dr.clip(radius / dr.sqrt(dr.maximum(photons.density, 1e-30)), radius / 8, radius)
    keep = photons.valid & (dr.max(photons.power) > 0)
    if cull:
        keep &= dr.dot(eye - photons.pos, photons.nrm) > 0
    keep_idx = dr.compress(keep)
    zero = dr.zeros(mi.Color3f, pixels)
    if dr.width(keep_idx) == 0:
        return zero, zero
    pos, nrm, power = (
        to_numpy(dr.gather(type(a), a, keep_idx)).T
        for a in (mi.Point3f(photons.pos), mi.Vector3f(photons.nrm), mi.Color3f(photons.power))
    )
    r_p = dr.gather(mi.Float, r_p, keep_idx).numpy()
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(power)) and np.all(np.isfinite(r_p))):
        raise ParameterError(
            "photon positions, powers and path densities must be finite (check the photon map)"
        )

    # ---- the grid over the kept photons, cell edge >= the farthest reach from a pixel's point
    reach = float(r_p.max())
    if mode == "gbuffer":  # ρ < r_p and |h| ≤ τ r_p: ‖Δ‖ < r_p √(1 + τ²)
        reach *= math.sqrt(1 + tau * tau)
    lo = pos.min(axis=0)
    span = pos.max(axis=0) - lo
    cell = max(reach / 2, float(np.cbrt(np.prod(span + reach) / MAX_CELLS)))
    dims = np.floor(span / cell).astype(np.int64) + 1
    c = np.minimum(np.floor((pos - lo) / cell).astype(np.int64), dims - 1)
    number = (c[:, 2] * dims[1] + c[:, 1]) * dims[0] + c[:, 0]
    order = np.argsort(number, kind="stable")
    counts = np.bincount(number, minlength=int(np.prod(dims)))
    cell_start = to_jit(mi.UInt32, np.concatenate([[0], np.cumsum(counts)]))
    rec = np.zeros((len(order), 12), np.float32)  # (pos, r_p), (nrm, 0), (power, 0)
    rec[:, 0:3], rec[:, 3] = pos[order], r_p[order]
    rec[:, 4:7], rec[:, 8:11] = nrm[order], power[order]

    grid = (
        cell_start,
        dr.opaque(mi.Point3f, [float(v) for v in lo]),
        dr.opaque(mi.Float, 1.0 / cell),
        dr.opaque(mi.Point3i, [int(v) for v in dims]),
    )
    E = _gather(
        gbuf, mi.Float(rec.ravel()), grid, dr.opaque(mi.Float, reach), dr.opaque(mi.Float, tau),
        mode,
    )  # fmt: skip
    L = E * gbuf.albedo * dr.inv_pi
    dr.eval(L, E)
    return L, E


@dr.syntax
def _gather(gbuf, rec, grid, reach, tau, mode):
    """Σ over photons of max(0, n_p·n) Φ_p κ per pixel (E_ind); see the module docstring.
    ``grid = (cell_start, origin, inv_cell, dims)``: the photons' uniform grid."""
    cell_start, origin, inv_cell, dims = grid
    pixels = dr.width(gbuf.pos)
    s, n = mi.Point3f(gbuf.pos), mi.Vector3f(gbuf.nrm)
    # the cells overlapping the box s ± reach, clipped to the grid
    top = mi.Point3f(dims - 1)
    lo = dr.floor((s - reach - origin) * inv_cell)
    hi = dr.floor((s + reach - origin) * inv_cell)
    overlaps = gbuf.valid & dr.all((hi >= 0) & (lo <= top))
    lo, hi = mi.Point3i(dr.clip(lo, 0, top)), mi.Point3i(dr.clip(hi, 0, top))
    ny, nz = hi.y - lo.y + 1, hi.z - lo.z + 1
    runs = dr.select(overlaps, mi.UInt32(ny * nz), 0)
    E = dr.zeros(mi.Color3f, pixels)
    run = dr.zeros(mi.UInt32, pixels)  # the x-run of cells lo.x .. hi.x at (cy, cz)
    while run < runs:
        cy = lo.y + mi.Int32(run) % ny
        cz = lo.z + mi.Int32(run) // ny
        first = mi.UInt32((cz * dims.y + cy) * dims.x + lo.x)
        j = dr.gather(mi.UInt32, cell_start, first)
        j_end = dr.gather(mi.UInt32, cell_start, first + mi.UInt32(hi.x - lo.x + 1))
        while j < j_end:
            a = dr.gather(mi.Vector4f, rec, 3 * j)
            s_p, r = mi.Point3f(a.x, a.y, a.z), a.w
            b = dr.gather(mi.Vector4f, rec, 3 * j + 1)
            n_p = mi.Vector3f(b.x, b.y, b.z)
            delta = s - s_p
            h = dr.dot(delta, n_p)
            if dr.hint(mode == "sphere", mode="scalar"):
                rho = dr.norm(delta)
                covered = rho < r
            else:
                rho = dr.norm(delta - h * n_p)
                covered = (rho < r) & (dr.abs(h) <= tau * r)
            weight = dr.maximum(dr.dot(n_p, n), 0) * (3 * dr.inv_pi) / (r * r) * (1 - rho / r)
            c = dr.gather(mi.Vector4f, rec, 3 * j + 2)  # unmasked: faster than a branch here
            E += dr.select(covered, weight, 0) * mi.Color3f(c.x, c.y, c.z)
            j += 1
        run += 1
    return E
