"""S6 + S7 — adaptive photon marching along curved rays with exact 3D line rasterisation.

Photon marching (Sun et al. 2008 §4.4 eqs 4–6; Pfeuti 2009 §3.1.5): a photon takes curved-ray
steps (``step.py``) from where it enters the grid. It stops when it leaves the grid (after
depositing the clipped segment), when ``max L̃ < 10⁻³ · max L̃₀`` (the papers' "low threshold",
relative so that relighting by a colour scale stays exact) or after ``max_steps`` steps (total
internal reflection can trap photons).

Deposition (S7, Pfeuti §3.1.5 Fig 3.14, "similar to the Bresenham algorithm"): every step's segment
deposits into the voxels that contain its intersections with the major-axis voxel-centre planes in
the half-open range ``[s_a, e_a)``, adding per voxel (S8's grids)::

    C[v] += w · L̃(u)                 (RGB energy)
    D[v] += w · (L̃_r + L̃_g + L̃_b)(u) · v̂(u)   (Sun §4.4: direction weighted by R+G+B)

By default ``w = 1/|v̂_a|`` (length-weighted deposits) and the energy is interpolated geometrically,
``L̃(u) = L̃_s · exp(−κ ‖Δx‖ u)`` (exact for constant κ; :mod:`.deposit`); ``fidelity="paper"``
deposits ``w = 1`` with linear interpolation, as both papers do. Directions are interpolated
linearly. Accumulation is in 64-bit fixed point (``2³²`` units per ``Φ_max``), so sums are exact and
independent of thread scheduling.

The deposits (S7), the fixed-point accumulator's packets and the tallies are in ``deposit.py``.
Each deposit writes two packets of four 64-bit channels per voxel; a *tally* chooses what goes in
them. :func:`radiance_tally` (C rgb, D xyz, two spare channels) is S6/S7. Pfeuti's phase-2 marcher
(§3.2.3, stage A5) also counts photons and sums their weights per voxel; here those two numbers fill
the spare channels of the same packets (:func:`weight_tally`), so the adaptive march costs no
second atomic per deposit — the cost Pfeuti measured in Fig 4.14. The pilot marcher (§3.2.2,
stage A2) deposits into a grid ``2^shift`` times coarser with its own tally (``pilot.py``).

Multiple scattering (``scattering``, our extension of Sun et al. 2008; ``scatter.py``): each order
is this march (:func:`.scatter.march_order`, which also samples the order's collision); the photons
that scatter are compacted, sorted (:func:`.scatter.coherent_order`) and marched as the next order
(:func:`.scatter.march_multiple`), into the same accumulator, so C and D hold the fluence of all
orders and S8/S9 are unchanged. The first order deposits exactly what single scattering does.
With opaque surfaces the legs of a photon's path are marched by ``surface_march.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.errors import ParameterError, PhotonmapError
from ..core.grid import grid_shape, voxel_count
from .deposit import (
    CHANNELS,
    FIXED_POINT_BITS,
    WEIGHT_BITS,
    Deposits,
    Float64,
    Int64,
    Vector4d,
    Vector4i64,
    coarse_size,
    radiance_tally,
    weight_tally,
)
from .emit import Photons
from .scatter import march_multiple
from .step import MarchGrids, MarchSettings, Scattering, march_steps, sample_medium
from .surface_march import march_with_surfaces


@dataclass
class MarchResult:
    C: mi.TensorXf  # (n_z, n_y, n_x, 3) deposited energy
    D: mi.TensorXf  # (n_z, n_y, n_x, 3) Σ (R+G+B)·direction, unnormalised
    steps: int  # photon marching steps taken (Sun Table 1 "millions of steps")
    final: tuple = ()  # per photon (x, v, L̃) where it stopped (voxel units) [+ its scatterings]
    count: mi.TensorXf | None = None  # (n_z, n_y, n_x) deposits per voxel (weighted march only)
    weight: mi.TensorXf | None = None  # (n_z, n_y, n_x) their average weight Σw / cnt, 0 if none
    scatterings: int = 0  # scattering events of all photons (multiple scattering)
    surface: object | None = None  # SurfacePhotons: photons recorded on opaque surfaces


@dataclass(frozen=True)
class Marching:
    """How the photons step (module docstring): ``ds_min`` the smallest step Δs_min in voxels,
    ``max_steps`` the step cap (default 8 × the grid's side), ``fidelity`` ``"paper"`` for the
    papers' literal deposits (one per voxel, linear energy), ``pfeuti_update`` Pfeuti's direction
    update (:func:`~.step.curved_step`)."""

    ds_min: float = 1.0
    max_steps: int | None = None
    fidelity: str = "physical"
    pfeuti_update: bool = False


def accumulate(
    photons: Photons,
    medium: MarchGrids,
    tally=radiance_tally,
    shift: int = 0,
    marching: Marching = Marching(),
    scattering: Scattering | None = None,
    surfaces=None,
    iso: float = float("inf"),
):
    """March ``photons`` and return ``(first, second, unit, steps, final, on_surfaces)``: the two
    packets each voxel of the deposit grid received (``Vector4d`` raw fixed-point sums; energy
    channels times ``unit`` are watts), the total step count, the per-photon final state
    ``(x, v, L̃)``, with multiple ``scattering`` ``(x, v, L̃, scattering events)``, and with
    opaque ``surfaces`` (:class:`~.surfaces.Surfaces`) the photons recorded on them
    (``surface_march.py``; ``iso``: the index above which a photon counts as refracted), else
    None."""
    n = medium.n
    cells = voxel_count(coarse_size(medium.dims, shift))
    acc = dr.zeros(Int64, cells * CHANNELS)
    phi_max = float(dr.max(dr.max(photons.power))[0]) if photons.count else 0.0
    steps, final, atomic, on_surfaces = 0, (), None, None
    if phi_max > 0:
        scale = dr.opaque(mi.Float, 2.0**FIXED_POINT_BITS / phi_max)
        settings = MarchSettings(
            dr.opaque(mi.Float, marching.ds_min),
            marching.max_steps or 8 * n,
            scale,
            marching.fidelity == "paper",
            marching.pfeuti_update,
        )
        rays = (
            mi.Point3f(photons.origin),
            mi.Vector3f(photons.direction),
            mi.Color3f(photons.power),
        )
        if surfaces is not None:
            atomic = dr.zeros(Int64, cells * CHANNELS)
            steps, final, on_surfaces = march_with_surfaces(
                (acc, atomic), medium, rays, settings, scattering, surfaces, iso, tally
            )
            dr.eval(acc, *final)
        elif scattering is None:
            x, d, L = rays  # single scattering: the steps from v₀ = n(x₀)·d₀
            photon = (x, sample_medium(medium, x)[0] * d, L)
            steps, *final = march_steps(Deposits(acc, tally, shift), medium, photon, settings)
            dr.eval(acc, steps, *final)
            steps = int(dr.sum(Float64(steps))[0])
        else:
            atomic = dr.zeros(Int64, cells * CHANNELS)  # no memory until an order writes to it
            steps, *final = march_multiple(
                (acc, atomic), medium, rays, settings, scattering, tally, shift
            )
            dr.eval(acc, *final)
        final = tuple(final)
    voxel = dr.arange(mi.UInt32, cells) * 2
    first, second = (dr.gather(Vector4i64, acc, voxel + k) for k in (0, 1))
    if atomic is not None:  # the two accumulators summed as integers, in the same kernel
        first += dr.gather(Vector4i64, atomic, voxel)
        second += dr.gather(Vector4i64, atomic, voxel + 1)
    first, second = Vector4d(first), Vector4d(second)
    return first, second, phi_max / 2.0**FIXED_POINT_BITS, steps, final, on_surfaces


def march(
    photons: Photons,
    medium: MarchGrids,
    marching: Marching = Marching(),
    voxel_size: float = 1.0,
    weights: mi.Float | None = None,
    scattering: Scattering | None = None,
    surfaces=None,
    iso: float = float("inf"),
) -> MarchResult:
    """March ``photons`` through ``medium`` by ``marching`` (:class:`Marching`) and return the
    deposited C, D grids (S6/S7).

    ``C`` is returned divided by ``voxel_size²`` (the voxel edge h in world units), i.e. as fluence
    in world units (``C/h²`` estimates ``φ = ∫ L_i dω'``); ``D`` likewise. With
    per-photon ``weights`` (``1/p`` of importance sampling, Pfeuti §3.2.3) the result also holds
    the deposit count and average weight per voxel. With ``scattering`` (needs ``medium.scatter``)
    the photons scatter (module docstring), and C, D hold the fluence of all orders. With opaque
    ``surfaces`` (:class:`~.surfaces.Surfaces`) photons stop at them and, scattering, bounce off
    them (``surface_march.py``); ``result.surface`` holds the photons recorded there.
    """
    shape = grid_shape(medium.dims)
    if scattering is not None and medium.scatter is None:
        raise ParameterError(
            "multiple scattering needs σ_s in the march grids: build them with "
            "MarchGrids.build(..., sigma_s=...)"
        )
    tally = radiance_tally if weights is None else weight_tally(weights)
    first, second, unit, steps, final, on_surfaces = accumulate(
        photons, medium, tally, 0, marching, scattering, surfaces, iso
    )
    unit /= voxel_size**2
    energy, flux = mi.Vector4f(first * unit), mi.Vector4f(second * unit)
    C = mi.TensorXf(dr.ravel(mi.Vector3f(energy.x, energy.y, energy.z)), (*shape, 3))
    D = mi.TensorXf(dr.ravel(mi.Vector3f(energy.w, flux.x, flux.y)), (*shape, 3))
    events = int(dr.sum(Float64(final[3]))[0]) if len(final) > 3 else 0
    result = MarchResult(C, D, steps, final, scatterings=events, surface=on_surfaces)
    if weights is not None:
        count = mi.Float(second.z)
        weight = mi.Float(second.w * 2.0**-WEIGHT_BITS / dr.maximum(second.z, 1.0))
        result.count = mi.TensorXf(count, shape)
        result.weight = mi.TensorXf(weight, shape)
    dr.eval(C, D, result.count, result.weight)  # one kernel reads the accumulator
    if dr.min(C.array)[0] < 0:  # deposits are >= 0: a negative sum is a corrupted accumulator
        raise PhotonmapError(
            "the photon march produced negative energy in the radiance grid (a corrupted "
            "fixed-point accumulator); the image would be wrong, so none is made: render again, "
            "and report the scene and parameters if it repeats"
        )
    return result
