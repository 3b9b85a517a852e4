"""S6/S7 in a scene with opaque surfaces: photons stop where they meet one (ours, after Sun et al.
2008 Fig. 1, whose glass stands on a table the photons light; Pfeuti 2009 §3.1.6 keeps that
table as the grid's bottom voxel layer).

A photon's path is a chain of **legs**. A leg starts anywhere — at a light outside the grid, at a
scattering event, on a surface it bounced off — and runs straight to the grid (slab test), curved
through it (Sun §4.4 eqs 4–6, the octree steps and S7 deposits of ``step.py``), and straight on
after it, until the first opaque surface (:class:`~.surfaces.Surfaces`) or away. Mitsuba casts
the straight stretches: one cast per leg while ∇n = 0, and again only once the direction has
turned by more than :data:`~.surfaces.RECAST_TURN` (in and around refractive objects); every
step is clipped at the surface's distance, so nothing is deposited behind it. Outside the grid
the volume method's medium is vacuum (nothing is deposited there; S9 adds no fog there either).

What a leg leaves behind (:func:`march_with_surfaces`):

- **records**: a photon that reaches a surface after an event — a refraction (it passed where
  n ≥ ``iso``, inside a refractive object: its shadow ray would stop at the object), a scattering
  in the fog, a bounce — is recorded there with its power ``L̃ = W·T`` (the expected arrival, as
  the deposits are). Light that arrives straight from an emitter is not: the viewing pass
  computes it with shadow rays (``shading.py``);
- with multiple scattering, the **next leg** (``scatter.py``): a free-flight
  collision sampled before the surface restarts in a phase-sampled direction with weight
  ``W σ_s T/p̄``; a photon that got to the surface (probability ``P = ⅓ Σ_c T_c``, the spectral
  free-flight sampling's survival) bounces off it with the BSDF's importance sample
  (``TransportMode.Importance``), weight ``W T/P · f cos/pdf``. Russian roulette as for
  scattering. This carries the light surfaces reflect into the fog and onto other surfaces.
  With ``scattering="single"`` (Sun's model) photons neither scatter nor bounce: a leg is a
  photon's whole path.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.grid import grid_extent
from . import scatter
from .deposit import Deposits, Int64, radiance_tally
from .emit import box_entry
from .scatter import Collision, Wavefront
from .step import (
    KILL_FRACTION,
    MarchGrids,
    MarchSettings,
    Scattering,
    curved_step,
    deposit_step,
    sample_medium,
)
from .surfaces import RECAST_TURN, SurfacePhotons, Surfaces, record

IMPORTANCE = mi.BSDFContext(mi.TransportMode.Importance)
SMOOTH = int(mi.BSDFFlags.Smooth)


@dataclass
class Leg:
    """Where one leg of each photon ended (:func:`_leg`)."""

    steps: mi.UInt32  # marching steps in the grid
    x: mi.Point3f  # the final position (voxel coordinates)
    v: mi.Vector3f  # the final v = n dx/ds
    L: mi.Color3f  # the final L̃
    collision: Collision  # the free-flight collision on the way, if found
    surface: mi.Bool  # the leg ended on a surface
    cast_x: mi.Point3f  # the ray cast that found it: origin (voxel coordinates) ...
    cast_d: mi.Vector3f  # ... and direction
    bent: mi.Bool  # it passed where n ≥ iso (through a refractive object)


@dr.syntax
def _leg(
    into: Deposits,
    medium: MarchGrids,
    surfaces: Surfaces,
    photon: tuple,
    march: MarchSettings,
    flight: tuple[mi.Float, mi.UInt32],
    iso: mi.Float,
):
    """One leg of every ``photon = (x, d, L)`` from ``x`` (voxel coordinates, inside the grid or
    not) along unit ``d`` with energy ``L`` (module docstring), depositing ``into``, which also
    finds its :class:`~.scatter.Collision` (``flight = (target, channel)``) as
    :func:`.scatter.march_order` does."""
    x, d, L = photon
    n = medium.dims
    count = dr.width(L)
    size = grid_extent(n)
    L_kill = dr.max(L) * KILL_FRACTION
    live = dr.max(L) > 0
    # before the grid: straight to its face, or to a surface first
    enters, t_near, _ = box_entry(x, d, n)
    t_surf = surfaces.distance(x, d, live)
    cast_x, cast_d = mi.Point3f(x), mi.Vector3f(d)
    reach = live & enters & (t_surf > t_near)
    x = dr.select(reach, x + t_near * d, x)
    t_surf = dr.select(reach, t_surf - t_near, t_surf)
    surface = live & ~reach & dr.isfinite(t_surf)
    v = sample_medium(medium, x)[0] * d  # v₀ = n(x₀)·d₀
    steps = dr.zeros(mi.UInt32, count)
    active = mi.Bool(reach)
    exited = dr.zeros(mi.Bool, count)
    recast = dr.zeros(mi.Bool, count)
    bent = dr.zeros(mi.Bool, count)
    collision = Collision.none(count, *flight)

    while dr.hint(active, exclude=[march, into]):
        cast = active & recast  # the direction has turned since the last cast
        t_new = surfaces.distance(x, dr.normalize(v), cast)
        t_surf = dr.select(cast, t_new, t_surf)
        cast_x = dr.select(cast, x, cast_x)
        cast_d = dr.select(cast, dr.normalize(v), cast_d)
        step = curved_step(medium, x, v, L, march, size, surface=t_surf)
        hits = t_surf <= step.length
        bent |= step.ior >= iso
        collision.search(x, step)
        deposit_step(into, n, x, step, L, march)
        x, v, L = step.x, step.v, step.L
        t_surf -= step.length
        steps += 1
        recast = dr.norm(step.new_direction - cast_d) > RECAST_TURN
        surface |= hits
        exited = step.leaving & ~hits
        active = ~step.leaving & ~hits & (dr.max(L) >= L_kill) & (steps < march.max_steps)

    # after the grid: straight on to a surface, or away
    again = exited & recast
    t_new = surfaces.distance(x, dr.normalize(v), again)
    t_surf = dr.select(again, t_new, t_surf)
    cast_x = dr.select(again, x, cast_x)
    cast_d = dr.select(again, dr.normalize(v), cast_d)
    surface |= exited & dr.isfinite(t_surf)
    return Leg(steps, x, v, L, collision, surface, cast_x, cast_d, bent)


def march_with_surfaces(
    accumulators: tuple[Int64, Int64],
    medium: MarchGrids,
    rays: tuple,
    march: MarchSettings,
    scattering: Scattering | None,
    surfaces: Surfaces,
    iso: float,
    tally=radiance_tally,
):
    """March the photons ``rays = (x, d, L)`` leg by leg (module docstring) into ``acc`` (the
    first leg) and ``atomic`` (the later legs; ``accumulators = (acc, atomic)``, summed by the
    caller, as :func:`.scatter.march_multiple` does). Returns the total steps, the per-photon
    final ``(x, v, L̃, events)`` and the :class:`~.surfaces.SurfacePhotons`. Photon ``i`` draws
    from PCG32 stream ``i`` of the scattering seed."""
    acc, atomic = accumulators
    x, d, L = rays
    seed = scattering.seed if scattering is not None else 0
    k = dr.opaque(mi.Float, scattering.phase_k if scattering is not None else 0.0)
    iso = dr.opaque(mi.Float, iso)
    photons = Wavefront.emitted(x, d, L, seed, tally)
    rng = photons.rng
    records = []
    last = scatter.MAX_ORDERS if scattering is not None else 0
    for order in range(last + 1):
        if scattering is not None:
            target, channel = scatter.free_flight(rng)
        else:  # single scattering: no collision
            target, channel = dr.full(mi.Float, dr.inf, dr.width(L)), dr.zeros(mi.UInt32, 1)
        into = Deposits(acc if order == 0 else atomic, photons.tally, 0, order == 0)
        leg = _leg(into, medium, surfaces, (x, d, L), march, (target, channel), iso)
        dr.eval(into.acc, leg)  # one launch per leg
        photons.record(order, leg.steps, leg.x, leg.v, leg.L)
        si = surfaces.hit(leg.cast_x, leg.cast_d, leg.surface)
        surface = leg.surface & si.is_valid()
        scattered = dr.opaque(mi.Bool, order > 0)  # opaque: every order's kernel is one
        keep = surface & (leg.bent | scattered) & (dr.max(leg.L) > 0)  # after an event
        keep &= (mi.UInt32(si.bsdf().flags()) & SMOOTH) != 0  # a mirror shows none (view.py)
        position, normal = mi.Point3f(si.p), mi.Vector3f(si.sh_frame.n)
        if order == last:
            dr.eval(keep, position, normal)
            records.append(record(position, leg.cast_d, leg.L, normal, keep))
            break
        # the next leg: from the collisions, or off the surfaces the others reached
        collision = leg.collision
        sigma_s = collision.sigma_s(medium)
        omega = scatter.schlick_direction(
            k, collision.direction, mi.Point2f(rng.next_float32(), rng.next_float32())
        )
        bounce = surface & ~collision.found
        W_scatter = L * sigma_s * collision.ratio
        W, x_next, omega = _bounce(surfaces, si, leg, bounce, rng, W_scatter, omega)
        survives, W = scatter.roulette(W, photons.start, order, rng.next_float32())
        next_leg = (collision.found | bounce) & survives & (dr.max(W) > 0)
        dr.eval(keep, position, normal, next_leg, W, x_next, omega, rng)  # one kernel
        records.append(record(position, leg.cast_d, leg.L, normal, keep))
        alive = dr.compress(next_leg)
        if dr.width(alive) == 0:
            break
        x, d, L = photons.compact(alive, x_next, omega, W, medium.n)
    return photons.steps, photons.final, SurfacePhotons.concat(records)


def _bounce(surfaces, si, leg: Leg, bounce, rng, W_scatter, omega):
    """The next leg's weight, start (voxel coordinates) and direction: the medium collisions'
    as given (``W_scatter``, ``omega``), and for the photons that reached a surface
    (``bounce``) its BSDF's importance sample, ``W = L̃ / P · f cos/pdf`` with
    ``P = ⅓ Σ_c T_c``."""
    T = dr.exp(-leg.collision.depth)
    survival = (T.x + T.y + T.z) / 3.0
    bs, f = si.bsdf().sample(
        IMPORTANCE, si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()),
        bounce,
    )  # fmt: skip
    wo = si.to_world(bs.wo)
    W_bounce = leg.L / dr.maximum(survival, 1e-30) * mi.Color3f(f)
    W_bounce = dr.select(bounce & (bs.pdf > 0), W_bounce, 0.0)
    start = surfaces.voxel(si.spawn_ray(wo).o)
    found = leg.collision.found
    W = dr.select(found, W_scatter, W_bounce)
    return W, dr.select(found, leg.collision.x, start), dr.select(found, omega, wo)
