"""S6 + S7 — adaptive photon marching along curved rays with exact 3D line rasterisation.

Photon marching (Sun et al. 2008 §4.4 eqs 4–6; Pfeuti 2009 §3.1.5). With ``v = n dx/ds`` the ray
equation ``d/ds (n dx/ds) = ∇n`` is integrated by forward differences::

    x_{i+1} = x_i + (Δs / n(x_i)) · v_i                     (4)
    v_{i+1} = v_i + Δs · ∇n(x_i)                            (5)
    L̃_{i+1} = L̃_i · exp(−κ(x_i) · ‖x_{i+1} − x_i‖)            (6)

The step is the distance ``t`` to the face of the octree node holding ``x_i`` plus δ = 10⁻³ voxel,
clamped to ``[Δs_min, Δs_max(x_i)]`` (Sun §4.4, §5.3, "a little bit further"); that target
displacement gives ``Δs = t · n(x_i)/‖v_i‖`` and eqs 4–5 apply literally (``v`` is not
renormalised). A photon stops when it leaves the grid (after depositing the clipped segment), when
``max L̃ < 10⁻³ · max L̃₀`` (the papers' "low threshold", relative so that relighting by a colour
scale stays exact) or after ``max_steps`` steps (total internal reflection can trap photons).

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

Multiple scattering (``scattering``, our extension of Sun et al. 2008; sampling in
``scatter.py``): each order is
this march (:func:`_march_order`, which also samples the order's collision); the photons that
scatter are compacted, sorted (:func:`.scatter.coherent_order`) and marched as the next order
(:func:`_march_multiple`), into the same accumulator, so C and D hold the fluence of all orders
and S8/S9 are unchanged. The first order deposits exactly what :func:`_march` deposits.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.errors import ParameterError, PhotonmapError
from ..core.grid import (
    flat_index,
    grid_dims,
    grid_extent,
    grid_shape,
    pack,
    to_tensor,
    trilinear_packed,
    voxel_count,
)
from . import scatter
from .deposit import (
    CHANNELS,
    FIXED_POINT_BITS,
    WEIGHT_BITS,
    Float64,
    Int64,
    Vector4d,
    Vector4i64,
    coarse_size,
    deposit_segment,
    radiance_tally,
    weight_tally,
)
from .emit import Photons
from .scatter import Collision, Wavefront

OVERSHOOT = 1e-3  # δ, voxels: Sun's "a little bit further" past the node's face
KILL_FRACTION = 1e-3  # τ_rel: a photon below τ_rel × its initial power stops


@dataclass
class MarchGrids:
    """What the marcher reads, packed for vector gathers (voxel units, layout [z, y, x, c]):
    ``medium`` = (n, ∂n/∂x, ∂n/∂y, ∂n/∂z, κ_r, κ_g, κ_b, 0) per voxel (trilinear), ``octree`` =
    (level, Δs_max, 0, 0) per voxel (nearest); for multiple scattering ``scatter`` =
    (σ_s,r, σ_s,g, σ_s,b, 0) per voxel (trilinear). ``dims = (n_x, n_y, n_z)``: the grid's
    extent (a box grid)."""

    dims: tuple
    medium: mi.Float
    octree: mi.Float
    scatter: mi.Float | None = None

    @property
    def n(self) -> int:
        """Voxels along the grid's longest side."""
        return max(self.dims)

    @staticmethod
    def build(ior, grad, kappa, level, step_limit, sigma_s=None) -> MarchGrids:
        dims = tuple(int(c) for c in to_tensor(ior).shape[:3])[::-1]
        scattering = None if sigma_s is None else pack([sigma_s], dims)
        return MarchGrids(
            dims, pack([ior, grad, kappa], dims), pack([level, step_limit], dims), scattering
        )


def sample_medium(grids: MarchGrids, p: mi.Point3f):
    """``(n, ∇n, κ)`` at voxel coordinates ``p`` (trilinear)."""
    a, b = trilinear_packed(grids.medium, grids.dims, 2, p)
    return a.x, mi.Vector3f(a.y, a.z, a.w), mi.Color3f(b.x, b.y, b.z)


def voxel_index(p: mi.Point3f, n) -> mi.Point3i:
    """The voxel holding ``p``, clamped into the grid of extent ``n`` (:func:`~.grid.grid_dims`)."""
    nx, ny, nz = grid_dims(n)
    return dr.clip(mi.Point3i(dr.floor(p)), 0, mi.Point3i(nx - 1, ny - 1, nz - 1))


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


@dataclass
class MarchSettings:
    """The constants of one march (not frozen: Dr.Jit loops read it; ``exclude``d from their
    state): Δs_min in voxels and the deposits' fixed-point scale (opaque arrays, so a new value
    does not recompile), the step cap, the papers' literal deposits (``paper``: one per voxel,
    linear energy) and Pfeuti's direction update (``pfeuti_update``)."""

    ds_min: mi.Float
    max_steps: int
    scale: mi.Float
    paper: bool
    pfeuti_update: bool


@dataclass(frozen=True)
class Scattering:
    """Multiple scattering's settings (``scatter.py``): Schlick's ``k`` of the phase function and
    the seed of the photons' random streams."""

    phase_k: float = 0.0
    seed: int = 0


@dataclass
class Step:
    """One curved-ray step of a photon (:func:`curved_step`), from ``x`` to :attr:`x`."""

    x: mi.Point3f  # x_{i+1}, eq (4)
    v: mi.Vector3f  # v_{i+1} = n dx/ds there, eq (5)
    L: mi.Color3f  # L̃_{i+1}, eq (6)
    direction: mi.Vector3f  # v̂_i, the unit direction at the start
    new_direction: mi.Vector3f  # v̂_{i+1}
    kappa: mi.Color3f  # κ(x_i), constant over the step
    length: mi.Float  # t = ‖x_{i+1} − x_i‖ in voxels
    leaving: mi.Bool  # the step ends on the grid's exit face
    ior: mi.Float  # n(x_i)


def curved_step(
    medium: MarchGrids, x, v, L, march: MarchSettings, size: mi.Point3f, surface=None
) -> Step:
    """S6: one curved-ray step (eqs 4–6) from ``x`` with ``v = n dx/ds`` and energy ``L``, to the
    face of the octree node holding ``x`` (+δ), clamped to ``[Δs_min, Δs_max]`` and clipped at the
    grid's exit face and at ``surface`` (the distance in voxels to an opaque surface,
    ``surface_march.py``). ``Δs = t · n(x)/‖v‖`` for the target displacement ``t``, and ``v``
    is not renormalised, so eqs (4)–(5) apply literally; ``march.pfeuti_update`` uses Pfeuti's
    ``v += Δs·n·∇n`` (Pfeuti 2009 Listing A.4) for eq (5)."""
    n_x, grad, kappa = sample_medium(medium, x)
    vox = voxel_index(x, medium.dims)
    oct_idx = mi.UInt32(flat_index(vox.x, vox.y, vox.z, medium.dims))
    node_info = dr.gather(mi.Vector4f, medium.octree, oct_idx)
    level, limit = mi.Int32(node_info.x), node_info.y
    node = mi.Float(mi.Int32(1) << level)
    lo = mi.Point3f((vox >> level) << level)
    dir_ = dr.normalize(v)
    t_face = dr.select(dir_ > 0, (lo + node - x) / dir_, (lo - x) / dir_)
    t_face = dr.select(dir_ == 0, dr.inf, t_face)
    t = dr.clip(dr.min(t_face) + OVERSHOOT, march.ds_min, limit)

    # the step leaves the grid: clip it at the exit face and finish after depositing
    t_exit = dr.min(dr.select(dir_ > 0, (size - x) / dir_, dr.select(dir_ < 0, -x / dir_, dr.inf)))
    leaving = t >= t_exit
    t = dr.select(leaving, dr.maximum(t_exit, 0.0), t)
    if surface is not None:
        t = dr.minimum(t, dr.maximum(surface, 0.0))

    ds = t * n_x / dr.norm(v)  # Δs for the target displacement t
    x_new = mi.Point3f(x + (ds / n_x) * v)  # (4)
    v_new = v + dr.select(march.pfeuti_update, ds * n_x, ds) * grad  # (5); Pfeuti's variant
    L_new = L * dr.exp(-kappa * t)  # (6), ‖x_{i+1} − x_i‖ = t
    return Step(x_new, v_new, L_new, dir_, dr.normalize(v_new), kappa, t, leaving, n_x)


def deposit_step(acc, n, x, step: Step, L, march: MarchSettings, tally, shift=0, expand=True):
    """S7: rasterise the segment ``x → step.x`` of a photon that carried ``L`` at ``x``
    (:func:`.deposit.deposit_segment`)."""
    deposit_segment(
        acc,
        n,
        x,
        step.x,
        L,
        step.kappa * step.length,
        step.direction,
        step.new_direction,
        march.scale,
        march.paper,
        tally=tally,
        shift=shift,
        expand=expand,
    )


@dr.syntax
def _march(
    acc: Int64,
    medium: MarchGrids,
    x: mi.Point3f,
    d: mi.Vector3f,
    L: mi.Color3f,
    march: MarchSettings,
    tally=radiance_tally,
    shift: int = 0,
):
    n = medium.dims
    count = dr.width(L)
    L_kill = dr.max(L) * KILL_FRACTION
    ior = sample_medium(medium, x)[0]
    v = ior * d  # v₀ = n(x₀)·d₀
    steps = dr.zeros(mi.UInt32, count)
    active = dr.max(L) > 0  # photons that miss the grid carry no power
    size = grid_extent(n)

    while dr.hint(active, exclude=[march]):
        step = curved_step(medium, x, v, L, march, size)
        deposit_step(acc, n, x, step, L, march, tally, shift)
        x, v, L = step.x, step.v, step.L
        steps += 1
        active = ~step.leaving & (dr.max(L) >= L_kill) & (steps < march.max_steps)
    return steps, x, v, L


@dr.syntax
def _march_order(
    acc: Int64,
    medium: MarchGrids,
    x: mi.Point3f,
    v: mi.Vector3f,
    L: mi.Color3f,
    march: MarchSettings,
    target: mi.Float,
    channel: mi.UInt32,
    tally=radiance_tally,
    shift: int = 0,
    expand: bool = True,
):
    """One scattering order of every photon (module docstring): :func:`_march`'s loop from
    ``(x, v = n dx/ds, L)``, which also finds the :class:`Collision` where the optical depth of
    colour ``channel`` reaches ``target``. Returns the steps, the final ``(x, v, L̃)`` and the
    collision."""
    n = medium.dims
    count = dr.width(L)
    size = grid_extent(n)
    L_kill = dr.max(L) * KILL_FRACTION
    steps = dr.zeros(mi.UInt32, count)
    active = dr.max(L) > 0
    collision = Collision.none(count)

    while dr.hint(active, exclude=[march]):
        step = curved_step(medium, x, v, L, march, size)
        collision.search(x, step, target, channel)
        deposit_step(acc, n, x, step, L, march, tally, shift, expand)
        x, v, L = step.x, step.v, step.L
        steps += 1
        active = ~step.leaving & (dr.max(L) >= L_kill) & (steps < march.max_steps)
    return steps, x, v, L, collision


def _march_multiple(
    acc: Int64,
    medium: MarchGrids,
    x: mi.Point3f,
    d: mi.Vector3f,
    L: mi.Color3f,
    march: MarchSettings,
    scattering: Scattering,
    tally=radiance_tally,
    shift: int = 0,
    atomic: Int64 | None = None,
):
    """:func:`_march` with multiple scattering (``scatter.py``), one order at a
    time over the photons still alive (a :class:`Wavefront`). The collision of each order starts
    the next there, in a Schlick-sampled direction, with weight ``W ⊙ σ_s ⊙ T/p̄`` and Russian
    roulette (:func:`.scatter.roulette`). The first order deposits into ``acc`` as
    :func:`_march` does; the scattered orders deposit with atomics into ``atomic`` (same layout,
    summed with ``acc`` by the caller): one reduction mode per array, one ``Expand`` launch (see
    :func:`reduce_mode`). Returns the total steps and, per photon, the final ``(x, v, L̃)`` and
    its scattering events.
    """
    k = dr.opaque(mi.Float, scattering.phase_k)
    v = sample_medium(medium, x)[0] * d  # v₀ = n(x₀)·d₀
    photons = Wavefront.emitted(x, v, L, scattering.seed, tally)
    rng = photons.rng
    for order in range(scatter.MAX_ORDERS + 1):
        target, channel = scatter.free_flight(rng)
        into = acc if order == 0 else atomic
        n_steps, x, v, L_end, collision = _march_order(
            into,
            medium,
            x,
            v,
            L,
            march,
            target,
            channel,
            photons.tally,
            shift,
            order == 0,
        )
        dr.eval(into, n_steps, x, v, L_end, collision)  # one launch per order
        photons.record(order, n_steps, x, v, L_end)
        if order == scatter.MAX_ORDERS:
            break
        # the next order starts at the collisions
        W = L * collision.sigma_s(medium) * collision.ratio
        survives, W = scatter.roulette(W, photons.start, order, rng.next_float32())
        omega = scatter.schlick_direction(
            k, collision.direction, mi.Point2f(rng.next_float32(), rng.next_float32())
        )
        going = collision.found & survives & (dr.max(W) > 0)  # not absorbed
        dr.eval(going, W, omega, rng)  # one kernel: the compaction gathers them per channel
        alive = dr.compress(going)
        if dr.width(alive) == 0:
            break
        x, omega, L = photons.compact(alive, collision.x, omega, W, medium.n)
        v = sample_medium(medium, x)[0] * omega
    return photons.steps, *photons.final


def accumulate(
    photons: Photons,
    medium: MarchGrids,
    tally=radiance_tally,
    shift: int = 0,
    ds_min: float = 1.0,
    max_steps: int | None = None,
    fidelity: str = "physical",
    pfeuti_update: bool = False,
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
            dr.opaque(mi.Float, ds_min),
            max_steps or 8 * n,
            scale,
            fidelity == "paper",
            pfeuti_update,
        )
        rays = (
            mi.Point3f(photons.origin),
            mi.Vector3f(photons.direction),
            mi.Color3f(photons.power),
        )
        if surfaces is not None:
            from .surface_march import march_with_surfaces  # it builds on this module

            atomic = dr.zeros(Int64, cells * CHANNELS)
            steps, final, on_surfaces = march_with_surfaces(
                acc, atomic, medium, *rays, settings, scattering, surfaces, iso, tally
            )
            dr.eval(acc, *final)
        elif scattering is None:
            steps, *final = _march(acc, medium, *rays, settings, tally, shift)
            dr.eval(acc, steps, *final)
            steps = int(dr.sum(Float64(steps))[0])
        else:
            atomic = dr.zeros(Int64, cells * CHANNELS)  # no memory until an order writes to it
            steps, *final = _march_multiple(
                acc, medium, *rays, settings, scattering, tally, shift, atomic
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
    ds_min: float = 1.0,
    max_steps: int | None = None,
    fidelity: str = "physical",
    pfeuti_update: bool = False,
    voxel_size: float = 1.0,
    weights: mi.Float | None = None,
    scattering: Scattering | None = None,
    surfaces=None,
    iso: float = float("inf"),
) -> MarchResult:
    """March ``photons`` through ``medium`` and return the deposited C, D grids (S6/S7).

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
        photons,
        medium,
        tally,
        0,
        ds_min,
        max_steps,
        fidelity,
        pfeuti_update,
        scattering,
        surfaces,
        iso,
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
