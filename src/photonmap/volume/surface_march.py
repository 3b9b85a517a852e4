"""S6/S7 in a scene with opaque surfaces: photons stop where they meet one (ours, after Sun et al.
2008 Fig. 1, whose glass stands on a table the photons light; Pfeuti 2009 §3.1.6 keeps that
table as the grid's bottom voxel layer).

A photon's path is a chain of **legs**. A leg starts anywhere — at a light outside the grid, at a
scattering event, on a surface it bounced off — and runs straight to the grid (slab test), curved
through it (Sun §4.4 eqs 4–6, the octree steps and S7 deposits of ``march.py``), and straight on
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
- with multiple scattering, the **next leg** (beyond-seeds §5, ``scatter.py``): a free-flight
  collision sampled before the surface restarts in a phase-sampled direction with weight
  ``W σ_s T/p̄``; a photon that got to the surface (probability ``P = ⅓ Σ_c T_c``, the spectral
  free-flight sampling's survival) bounces off it with the BSDF's importance sample
  (``TransportMode.Importance``), weight ``W T/P · f cos/pdf``. Russian roulette as for
  scattering. This carries the light surfaces reflect into the fog and onto other surfaces.
  With ``scattering="single"`` (Sun's model) photons neither scatter nor bounce: a leg is a
  photon's whole path.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.grid import grid_extent, trilinear_packed
from . import scatter
from .deposit import Float64, Int64, deposit_segment, radiance_tally, weight_tally
from .emit import box_entry
from .march import KILL_FRACTION, MarchGrids, Scattering, _advance, sample_medium
from .surfaces import RECAST_TURN, SurfacePhotons, Surfaces, record

IMPORTANCE = mi.BSDFContext(mi.TransportMode.Importance)
SMOOTH = int(mi.BSDFFlags.Smooth)


@dr.syntax
def _leg(
    acc: Int64,
    medium: MarchGrids,
    surfaces: Surfaces,
    x: mi.Point3f,
    d: mi.Vector3f,
    L: mi.Color3f,
    ds_min: mi.Float,
    max_steps: int,
    scale: mi.Float,
    paper: bool,
    pfeuti_update: bool,
    target: mi.Float,
    channel: mi.UInt32,
    iso: mi.Float,
    tally=radiance_tally,
    shift: int = 0,
    expand: bool = True,
):
    """One leg of every photon from ``x`` (voxel coordinates, inside the grid or not) along unit
    ``d`` with energy ``L`` (module docstring); the collision as in ``march._march_order``.
    Returns the steps; the final ``x``, ``v``, ``L̃``; the collision (found, point, direction,
    ``T/p̄``, the start of its step); whether the leg ended on a surface, the cast that found it
    (voxel origin and direction); whether it passed n ≥ ``iso``; its optical depth."""
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
    depth = dr.zeros(mi.Color3f, count)
    found = dr.zeros(mi.Bool, count)
    x_c, x_s = dr.zeros(mi.Point3f, count), dr.zeros(mi.Point3f, count)
    d_c, ratio = dr.zeros(mi.Vector3f, count), dr.zeros(mi.Color3f, count)

    while active:
        cast = active & recast  # the direction has turned since the last cast
        t_new = surfaces.distance(x, dr.normalize(v), cast)
        t_surf = dr.select(cast, t_new, t_surf)
        cast_x = dr.select(cast, x, cast_x)
        cast_d = dr.select(cast, dr.normalize(v), cast_d)
        x_new, v_new, L_new, dir_, dir_new, kappa, t, leaving, n_x = _advance(
            medium, x, v, L, ds_min, size, pfeuti_update, surface=t_surf
        )
        hits = t_surf <= t
        bent |= n_x >= iso
        depth_new = depth + kappa * t
        before, after = scatter.channel_of(depth, channel), scatter.channel_of(depth_new, channel)
        hit = ~found & (after >= target) & (after > before)
        f = (target - before) / dr.maximum(after - before, 1e-30)  # where in the step
        x_c = dr.select(hit, dr.lerp(x, x_new, f), x_c)
        x_s = dr.select(hit, x, x_s)
        d_c = dr.select(hit, dr.normalize(dr.lerp(dir_, dir_new, f)), d_c)
        ratio = dr.select(hit, scatter.collision_weight(1.0, kappa, depth + kappa * (f * t)), ratio)
        found |= hit
        deposit_segment(
            acc,
            n,
            x,
            x_new,
            L,
            kappa * t,
            dir_,
            dir_new,
            scale,
            paper,
            tally=tally,
            shift=shift,
            expand=expand,
        )
        x, v, L, depth = x_new, v_new, L_new, depth_new
        t_surf -= t
        steps += 1
        recast = dr.norm(dir_new - cast_d) > RECAST_TURN
        surface |= hits
        exited = leaving & ~hits
        active = ~leaving & ~hits & (dr.max(L) >= L_kill) & (steps < max_steps)

    # after the grid: straight on to a surface, or away
    again = exited & recast
    t_new = surfaces.distance(x, dr.normalize(v), again)
    t_surf = dr.select(again, t_new, t_surf)
    cast_x = dr.select(again, x, cast_x)
    cast_d = dr.select(again, dr.normalize(v), cast_d)
    surface |= exited & dr.isfinite(t_surf)
    return steps, x, v, L, found, x_c, d_c, ratio, x_s, surface, cast_x, cast_d, bent, depth


def march_with_surfaces(
    acc: Int64,
    atomic: Int64,
    medium: MarchGrids,
    x: mi.Point3f,
    d: mi.Vector3f,
    L: mi.Color3f,
    ds_min: mi.Float,
    max_steps: int,
    scale: mi.Float,
    paper: bool,
    pfeuti_update: bool,
    scattering: Scattering | None,
    surfaces: Surfaces,
    iso: float,
    tally=radiance_tally,
):
    """March photons leg by leg (module docstring) into ``acc`` (the first leg) and ``atomic``
    (the later legs; summed by the caller, as ``march._march_multiple`` does). Returns the total
    steps, the per-photon final ``(x, v, L̃, events)`` and the :class:`~.surfaces.SurfacePhotons`.
    Photon ``i`` draws from PCG32 stream ``i`` of the scattering seed."""
    count = dr.width(L)
    seed = scattering.seed if scattering is not None else 0
    rng = mi.PCG32(count, dr.opaque(mi.UInt64, seed), dr.arange(mi.UInt64, count))
    k = dr.opaque(mi.Float, scattering.phase_k if scattering is not None else 0.0)
    iso = dr.opaque(mi.Float, iso)
    ids = dr.arange(mi.UInt32, count)
    start = dr.max(L)  # the photon's emitted power, Russian roulette's reference
    final = [mi.Point3f(x), mi.Vector3f(d), mi.Color3f(L), dr.zeros(mi.UInt32, count)]
    weights = getattr(tally, "weights", None)
    records, steps = [], 0
    last = scatter.MAX_ORDERS if scattering is not None else 0
    for order in range(last + 1):
        if scattering is not None:
            target, channel = scatter.free_flight(rng)
        else:  # single scattering: no collision
            target, channel = dr.full(mi.Float, dr.inf, dr.width(L)), dr.zeros(mi.UInt32, 1)
        into = acc if order == 0 else atomic
        out = _leg(
            into, medium, surfaces, x, d, L, ds_min, max_steps, scale, paper, pfeuti_update,
            target, channel, iso, tally, 0, order == 0,
        )  # fmt: skip
        dr.eval(into, *out)  # one launch per leg
        n_steps, x_end, v, L_end, found, x_c, d_c, ratio, x_s = out[:9]
        surface, cast_x, cast_d, bent, depth = out[9:]
        for array, value in zip(final, (x_end, v, L_end, dr.opaque(mi.UInt32, order)), strict=True):
            dr.scatter(array, value, ids)
        steps += int(dr.sum(Float64(n_steps))[0])
        si = surfaces.hit(cast_x, cast_d, surface)
        surface &= si.is_valid()
        keep = surface & (bent | (order > 0)) & (dr.max(L_end) > 0)  # after an event
        keep &= (mi.UInt32(si.bsdf().flags()) & SMOOTH) != 0  # a mirror shows none (view.py)
        position, normal = mi.Point3f(si.p), mi.Vector3f(si.sh_frame.n)
        if order == last:
            dr.eval(keep, position, normal)
            records.append(record(position, cast_d, L_end, normal, keep))
            break
        # the next leg: from the collisions, or off the surfaces the others reached
        sigma_s = mi.Color3f(
            trilinear_packed(medium.scatter, medium.dims, 1, x_s, active=found)[0].xyz
        )
        omega = scatter.schlick_direction(
            k, d_c, mi.Point2f(rng.next_float32(), rng.next_float32())
        )
        bounce = surface & ~found
        W, x_next, omega = _bounce(
            surfaces, si, L_end, depth, bounce, rng, L * sigma_s * ratio, x_c, omega, found
        )
        survives, W = scatter.roulette(W, start, order, rng.next_float32())
        next_leg = (found | bounce) & survives & (dr.max(W) > 0)
        dr.eval(keep, position, normal, next_leg, W, x_next, omega, rng)  # one kernel
        records.append(record(position, cast_d, L_end, normal, keep))
        alive = dr.compress(next_leg)
        if dr.width(alive) == 0:
            break
        alive = dr.gather(mi.UInt32, alive, scatter.coherent_order(x_next, omega, alive, medium.n))
        x = dr.gather(mi.Point3f, x_next, alive)
        d = dr.gather(mi.Vector3f, omega, alive)
        L = dr.gather(mi.Color3f, W, alive)
        ids, start = dr.gather(mi.UInt32, ids, alive), dr.gather(mi.Float, start, alive)
        rng.state = dr.gather(mi.UInt64, rng.state, alive)
        rng.inc = dr.gather(mi.UInt64, rng.inc, alive)
        if weights is not None:
            weights = dr.gather(mi.Float, weights, alive)
            tally = weight_tally(weights)
    return steps, final, SurfacePhotons.concat(records)


def _bounce(surfaces, si, L_end, depth, bounce, rng, W_scatter, x_c, omega, found):
    """The next leg's weight, start (voxel coordinates) and direction: the medium collisions'
    (``found``) as given, and for the photons that reached a surface (``bounce``) its BSDF's
    importance sample, ``W = L̃ / P · f cos/pdf`` with ``P = ⅓ Σ_c T_c``."""
    T = dr.exp(-depth)
    survival = (T.x + T.y + T.z) / 3.0
    bs, f = si.bsdf().sample(
        IMPORTANCE, si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()),
        bounce,
    )  # fmt: skip
    wo = si.to_world(bs.wo)
    W_bounce = L_end / dr.maximum(survival, 1e-30) * mi.Color3f(f)
    W_bounce = dr.select(bounce & (bs.pdf > 0), W_bounce, 0.0)
    start = surfaces.voxel(si.spawn_ray(wo).o)
    W = dr.select(found, W_scatter, W_bounce)
    return W, dr.select(found, x_c, start), dr.select(found, omega, wo)
