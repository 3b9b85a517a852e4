"""S6 — one photon step along a curved ray, and the grids it reads.

Photon marching (Sun et al. 2008 §4.4 eqs 4–6; Pfeuti 2009 §3.1.5). With ``v = n dx/ds`` the ray
equation ``d/ds (n dx/ds) = ∇n`` is integrated by forward differences::

    x_{i+1} = x_i + (Δs / n(x_i)) · v_i                     (4)
    v_{i+1} = v_i + Δs · ∇n(x_i)                            (5)
    L̃_{i+1} = L̃_i · exp(−κ(x_i) · ‖x_{i+1} − x_i‖)            (6)

The step is the distance ``t`` to the face of the octree node holding ``x_i`` plus δ = 10⁻³ voxel,
clamped to ``[Δs_min, Δs_max(x_i)]`` (Sun §4.4, §5.3, "a little bit further"); that target
displacement gives ``Δs = t · n(x_i)/‖v_i‖`` and eqs 4–5 apply literally (``v`` is not
renormalised). Each step's segment is deposited (S7) by :func:`deposit_step`;
:func:`march_steps` chains the steps of every photon (``march.py`` runs it for single
scattering, ``scatter.py`` once per scattering order; ``surface_march.py`` has its own loop,
which also casts rays to the opaque surfaces).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.grid import flat_index, grid_dims, grid_extent, pack, to_tensor, trilinear_packed
from .deposit import Deposits, deposit_segment

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


def deposit_step(into: Deposits, n, x, step: Step, L, march: MarchSettings):
    """S7: rasterise the segment ``x → step.x`` of a photon that carried ``L`` at ``x``
    (:func:`.deposit.deposit_segment`)."""
    deposit_segment(
        into, n, (x, step.x), L, step.kappa * step.length, (step.direction, step.new_direction),
        (march.scale, march.paper),
    )  # fmt: skip


@dr.syntax
def march_steps(into: Deposits, medium: MarchGrids, photon, march: MarchSettings, collision=None):
    """S6/S7: march every ``photon = (x, v = n dx/ds, L̃)`` by :func:`curved_step`, depositing
    each step (:func:`deposit_step`), until it leaves the grid, falls below
    :data:`KILL_FRACTION` of its starting power or reaches ``march.max_steps``. With a
    ``collision`` (:class:`.scatter.Collision`) the loop also finds each photon's free-flight
    collision. Returns the steps and the final ``(x, v, L̃)``."""
    x, v, L = photon
    n = medium.dims
    count = dr.width(L)
    size = grid_extent(n)
    L_kill = dr.max(L) * KILL_FRACTION
    steps = dr.zeros(mi.UInt32, count)
    active = dr.max(L) > 0  # photons that miss the grid carry no power

    while dr.hint(active, exclude=[march, into]):
        step = curved_step(medium, x, v, L, march, size)
        if collision is not None:  # a Python condition: decided when the loop is traced
            collision.search(x, step)
        deposit_step(into, n, x, step, L, march)
        x, v, L = step.x, step.v, step.L
        steps += 1
        active = ~step.leaving & (dr.max(L) >= L_kill) & (steps < march.max_steps)
    return steps, x, v, L
