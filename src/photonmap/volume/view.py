"""S9 — the viewing pass: curved camera rays gathering single scattering (Sun et al. 2008 §4.5;
Pfeuti 2009 §3.1.6, Listing 3.4, Listing A.4).

One ray per pixel (and sample) marches with a fixed step of one voxel (``h = 1``) along the curved
path of eqs (4)–(5), ``x += (h/‖v‖)·v``, ``v += h·∇n(x_old)``, until it leaves the grid. At each step

    L  +=  colScale · σ_s(x) · p(cos θ) · C(x) ⊙ T · (1 − exp(−κ(x)·h)) / κ(x)
    T  ⊙= exp(−κ(x)·h),                               cos θ = (−v · D̂(x)) / ‖v‖

(the step's exact integral with κ and the source constant over it; ours). Sun's and Pfeuti's
rule, kept for ``fidelity="paper"``, adds ``h·σ_s p C ⊙ T`` after ``T ⊙= exp(−κh)``: the
in-scattering of every step attenuated by the whole step, ``κh/2`` too dark (3 % at κh = 0.06),
which the half voxel of optical depth photons miss on entering fog inside the grid (octree.py)
used to hide; with box grids the fog meets the grid's faces. The light scattered inside an
object of index ``n = ‖v‖`` is radiance in that medium; it reaches the eye's medium (index
``n_eye``, where the ray entered the grid) divided by ``(n/n_eye)²`` — radiance over n² is what a
ray conserves across a change of index (Veach 1997 §5.2; ours: the papers render in relative
units, ``fidelity="paper"`` leaves it out). Without it a scattering medium inside glass of index
1.5 came out 2.25× too bright against ``volpath``.

with the Schlick phase function ``p = (1 − k²) / (4π (1 − k cos θ)²)`` (Pfeuti §2.1.3); leaving the
grid adds ``colScale · T ⊙ L_env(v̂)``. This is the single-scattering volume rendering equation with
``∫ p L_i dω' ≈ p(θ(D̂, −ω)) · φ`` (one stored direction per voxel, Sun §4.4), ``C`` being the
fluence ``φ``. The step that reaches the grid's exit face is cut there (``h`` the distance to the
face; ours): with box grids the fog often ends at the grid's face, and a whole last step would add
up to a voxel of fog beyond it (measured: +3 % brightness in a 16-voxel-thick fog box).

Reflective table (Pfeuti §3.1.6): a ray going down through the bottom voxel layer is mirrored at the
plane ``y = 1`` and picks up ``ρ_table/π · C ⊙ T`` (a Lambertian table of albedo ρ lit by the
fluence there; only for ``v_y < 0``, so a reflected ray does not trigger it again, and attenuated by
T, as the table lies inside the fog). ``fidelity="paper"`` adds ``ρ_table · C`` without T, as
Listing A.4 does, and updates ``v += h·n(x)·∇n`` (Listing A.4; eq 5 otherwise, as in the photon
march).

Opaque surfaces of the user's scene (``surfaces.py``; ours, for Sun Fig. 1's table and any
floor or wall): a camera ray ends at the first one, in the grid or beyond it. One Mitsuba cast
per straight stretch gives its distance (again only once the ray has turned by more than
``RECAST_TURN``, in and around refractive objects), the last step is cut there, and the surface
adds its radiance (``shading.py``) weighted by ``colScale·T``; where it has a mirror lobe the ray
goes on in the mirrored direction (:func:`_view_surfaces`). Only rays that meet no surface see
the environment.

Reflective isosurface (Pfeuti §3.1.1, §3.1.6; its text and code disagree on the crossing test): the
first time ``n(x_old) < n_iso ≤ n(x)`` a 10-step bisection finds the crossing, the normal is
``−∇n/‖∇n‖`` and ``R_iso · T ⊙ L_env(r)`` is added for the mirrored direction ``r``; the ray then
continues with weight ``1 − R_iso``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.camera import pixel_means, pixel_rays
from ..core.film_filter import filter_image
from ..core.grid import GridBox, grid_extent, pack, to_tensor, trilinear_packed
from .emit import box_entry
from .shading import shade
from .surfaces import RECAST_TURN

BISECTION_STEPS = 10
MIRROR_BOUNCES = 4  # mirror reflections a camera ray follows at opaque surfaces
MIRROR = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.DeltaReflection)
ENTRY_NUDGE = 1e-4  # voxels: start just inside the grid face


@dataclass
class ViewGrids:
    """Everything S9 reads, in voxel units (C in W/m²), packed for vector gathers:

    - ``main`` — read at every step, 12 channels (three gathers per trilinear corner):
      ``(∇n, κ_rgb, σ_s ⊙ C, D̂)``; the in-scattering source ``σ_s ⊙ C`` is interpolated as one
      product (it differs from the product of interpolants only where σ_s changes within a voxel);
    - ``aux`` — ``(n, C_rgb)``: read at every step only when the isosurface test or the paper's
      ``v += h·n·∇n`` needs n, and for the table.

    ``dims = (n_x, n_y, n_z)``: the grid's extent (a box grid).
    """

    dims: tuple
    main: mi.Float
    aux: mi.Float
    kappa: mi.Float | None = None  # κ alone (4 channels), for shadow rays to surfaces

    @staticmethod
    def build(ior, grad, kappa, sigma_s, C, D_hat, shadows: bool = False) -> ViewGrids:
        dims = tuple(int(c) for c in C.shape[:3])[::-1]
        C, sigma_s = to_tensor(C, dims), to_tensor(sigma_s, dims)
        source = mi.TensorXf(sigma_s.array * C.array, tuple(C.shape))
        main, aux = pack([grad, kappa, source, D_hat], dims), pack([ior, C], dims)
        return ViewGrids(dims, main, aux, pack([kappa], dims) if shadows else None)


@dataclass
class ViewSettings:
    """Appearance parameters of S9 (none of them requires new photons)."""

    phase_k: float = 0.3
    table: tuple = (0.0, 0.0, 0.0)  # ρ_table (RGB); 0 = no table
    iso_ior: float | None = None  # n_iso; None = no reflective isosurface
    iso_reflect: float = 0.04  # R_iso
    paper: bool = False
    spp: int = 1
    seed: int = 0
    hide_emitters: bool = False  # emitters met by camera rays themselves are not shown


STRAIGHT = 1.0 - 1e-5  # cos of the turn below which a camera ray counts as unbent


def _shown(settings: ViewSettings, d0: mi.Vector3f, d: mi.Vector3f, camera: bool = True):
    """Where an emitter met along a ray that left the camera along ``d0`` and arrives along
    ``d`` is shown: everywhere, or with ``hide_emitters`` only where the ray was bent on the way
    or is no camera ray (a mirror's) — Mitsuba hides what the camera ray itself meets, through
    fog and index-matched boundaries (depth 0), not what it meets after a refraction."""
    if not (settings.hide_emitters and camera):
        return True
    return dr.dot(d0, d) < STRAIGHT


def schlick(k: float, cos_theta):
    """Schlick phase function (Pfeuti §2.1.3): ``(1 − k²) / (4π (1 − k cos θ)²)``."""
    return (1.0 - k * k) / (4.0 * math.pi * dr.square(1.0 - k * cos_theta))


def environment(emitter, d: mi.Vector3f, active=True) -> mi.Color3f:
    """Radiance of the environment emitter (or black) seen along world direction ``d``."""
    if emitter is None:
        return dr.zeros(mi.Color3f, dr.width(d))
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(d))
    si.wi = -d
    return mi.Color3f(emitter.eval(si, active))


def _sample(grids: ViewGrids, x: mi.Point3f):
    """``(∇n, κ, σ_s ⊙ C, D)`` at voxel coordinates ``x`` (trilinear)."""
    a, b, c = trilinear_packed(grids.main, grids.dims, 3, x)
    return (
        mi.Vector3f(a.x, a.y, a.z),
        mi.Color3f(a.w, b.x, b.y),
        mi.Color3f(b.z, b.w, c.x),
        mi.Vector3f(c.y, c.z, c.w),
    )


def _sample_aux(grids: ViewGrids, x: mi.Point3f):
    """``(n, C)`` at voxel coordinates ``x`` (trilinear)."""
    (a,) = trilinear_packed(grids.aux, grids.dims, 1, x)
    return a.x, mi.Color3f(a.y, a.z, a.w)


def isosurface_hit(grids: ViewGrids, x_old: mi.Point3f, x: mi.Point3f, iso: float):
    """Bisection (10 steps) on ``[x_old, x]`` for ``n = n_iso``; returns the parameter of the hit
    along the segment and the outward normal ``−∇n/‖∇n‖`` there (Pfeuti §3.1.6)."""
    lo = dr.zeros(mi.Float, dr.width(x))
    hi = dr.ones(mi.Float, dr.width(x))
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        above = _sample_aux(grids, dr.lerp(x_old, x, mid))[0] >= iso
        hi = dr.select(above, mid, hi)
        lo = dr.select(above, lo, mid)
    t = 0.5 * (lo + hi)
    return t, -dr.normalize(_sample(grids, dr.lerp(x_old, x, t))[0])


def _entry(grids: ViewGrids, o: mi.Point3f, d: mi.Vector3f, surf):
    """Where camera rays (voxel origin ``o``, unit ``d``) enter the grid: ``(x, inside,
    (t_surf, cast_x, cast_d, hit, reached))``; with opaque surfaces ``surf`` the cast from the
    camera (``hit``: a surface before the grid; ``t_surf`` from ``x``), else Nones."""
    far = grid_extent(grids.dims)
    enters, t_near, _ = box_entry(o, d, grids.dims)
    x = mi.Point3f(o + (t_near + ENTRY_NUDGE) * d)
    inside = enters & dr.all((x >= 0.0) & (x < far))
    if surf is None:
        return x, inside, (None, None, None, None, None)
    reached = dr.zeros(mi.Bool, dr.width(o))
    t_surf = surf.distance(o, d, True)  # one cast from the camera
    cast_x, cast_d = mi.Point3f(o), mi.Vector3f(d)
    hit = dr.isfinite(t_surf) & (~inside | (t_surf <= t_near + ENTRY_NUDGE))
    inside &= ~hit  # a surface before the grid
    t_surf = t_surf - (t_near + ENTRY_NUDGE)
    return x, inside, (t_surf, cast_x, cast_d, hit, reached)


def _appearance(s: ViewSettings):
    """The table's colour (``/π`` but with ``paper``) and whether there is one, the isosurface's
    index and whether it reflects, its reflectance, the phase function's k: ``(table, table_on,
    iso, iso_on, r_iso, k)``. The values enter the kernel as opaque arrays, so changing them
    does not recompile it."""
    table_rgb = [float(c) * (1.0 if s.paper else 1.0 / math.pi) for c in s.table]
    table = mi.Color3f(*[dr.opaque(mi.Float, c) for c in table_rgb])
    table_on = bool(np.any(np.asarray(s.table) > 0))
    iso_on = s.iso_ior is not None and s.iso_reflect > 0
    iso = dr.opaque(mi.Float, float(s.iso_ior) if iso_on else 0.0)
    r_iso = dr.opaque(mi.Float, s.iso_reflect)
    k = dr.opaque(mi.Float, s.phase_k)
    return table, table_on, iso, iso_on, r_iso, k


@dr.syntax
def _march_loop(grids: ViewGrids, o: mi.Point3f, d: mi.Vector3f, env, s: ViewSettings, surf):
    """The march through the grid (:func:`_march_rays`): ``(L, colScale·T, final direction,
    final x, inside, (t_surf, cast_x, cast_d, hit))``, the last four None without ``surf``."""
    far = grid_extent(grids.dims)
    count = dr.width(o)
    x, inside, (t_surf, cast_x, cast_d, hit, reached) = _entry(grids, o, d, surf)
    n_x = _sample_aux(grids, x)[0]
    n_eye = mi.Float(n_x)  # the index where the ray enters: the camera's medium
    v = mi.Vector3f(n_x * d)
    x_old, v_old, n_old = mi.Point3f(x), mi.Vector3f(v), mi.Float(n_x)
    T = dr.ones(mi.Color3f, count)
    col = dr.ones(mi.Float, count)
    L = dr.zeros(mi.Color3f, count)
    reflected = dr.zeros(mi.Bool, count)
    steps = dr.zeros(mi.UInt32, count)
    max_steps = 4 * max(grids.dims)
    table, table_on, iso, iso_on, r_iso, k = _appearance(s)
    need_n = iso_on or s.paper

    active = mi.Bool(inside)
    while active:
        grad, kappa, source, D = _sample(grids, x)
        if need_n:
            n_x = _sample_aux(grids, x)[0]
        if table_on & (v.y < 0) & (x.y < 1.0):
            # reflective table: mirror at the plane y = 1 and add the lit table (Pfeuti §3.1.6)
            t_hit = (1.0 - x_old.y) / v_old.y
            x = mi.Point3f(x_old + t_hit * v_old)
            v = mi.Vector3f(v_old.x, -v_old.y, v_old.z)
            grad, kappa, source, D = _sample(grids, x)
            n_x, C = _sample_aux(grids, x)
            L += col * table * C * (1.0 if s.paper else T)
        elif iso_on & ~reflected & (n_old < iso) & (n_x >= iso):
            # reflective isosurface (Pfeuti §3.1.6): mirror the environment
            t_iso, normal = isosurface_hit(grids, x_old, x, iso)
            dv = dr.normalize(dr.lerp(v_old, v, t_iso))
            r = dv - 2.0 * dr.dot(dv, normal) * normal
            L += col * r_iso * T * environment(env, r)
            reflected = mi.Bool(True)
            col *= 1.0 - r_iso

        speed = dr.norm(v)
        d = v / speed
        # the step that reaches the grid's exit face ends there: a whole step would count the
        # medium of the face's voxels (clamp-to-edge) beyond the face, where a box grid's fog ends
        t_exit = dr.min(dr.select(d > 0, (far - x) / d, dr.select(d < 0, -x / d, dr.inf)))
        dt = dr.clip(t_exit, 0.0, 1.0)
        if surf is not None:  # cast again once the direction has turned; stop at the surface
            cast = active & (dr.norm(d - cast_d) > RECAST_TURN)
            t_surf = dr.select(cast, surf.distance(x, d, cast), t_surf)
            cast_x = dr.select(cast, x, cast_x)
            cast_d = dr.select(cast, d, cast_d)
            reached = t_surf <= dt
            dt = dr.minimum(dt, dr.maximum(t_surf, 0.0))
            t_surf -= dt
            hit |= active & reached
        cos_theta = -dr.dot(v, D) / (speed * dr.maximum(dr.norm(D), 1e-20))
        tau = kappa * dt
        decay = dr.exp(-tau)
        if s.paper:  # Listing A.4: each sample attenuated by its whole step
            T *= decay
            L += col * schlick(k, cos_theta) * source * T * dt
        else:  # the step's exact integral, κ and the source constant over it
            weight = dr.select(
                tau > 1e-4, (1.0 - decay) / dr.maximum(kappa, 1e-30), dt * (1.0 - 0.5 * tau)
            )
            # radiance scattered at index n = ‖v‖ reaches the eye's medium divided by (n/n_eye)²
            L += col * schlick(k, cos_theta) * source * T * weight * dr.square(n_eye / speed)
            T *= decay
        x_old, v_old, n_old = mi.Point3f(x), mi.Vector3f(v), mi.Float(n_x)
        x = mi.Point3f(x + d * dt)
        v = mi.Vector3f(v + dt * (n_x if s.paper else 1.0) * grad)
        steps += 1
        active = (t_exit > 1.0) & dr.all((x >= 0.0) & (x < far)) & (steps < max_steps)
        if surf is not None:
            active &= ~reached
    return L, col * T, dr.normalize(v), x, inside, (t_surf, cast_x, cast_d, hit)


def _march_rays(
    grids: ViewGrids, o: mi.Point3f, d: mi.Vector3f, env, s: ViewSettings, surf=None, camera=True
):
    """March camera rays (voxel origin ``o``, unit ``d``). Without opaque surfaces ``surf``:
    ``(L, inside)`` with the environment added to the rays that leave the grid. With them
    (:class:`~.surfaces.Surfaces`): ``(L, hit, cast_x, cast_d, weight)`` — a ray ends at the
    first opaque surface, in the grid or beyond it, found by the cast from ``cast_x`` along
    ``cast_d``; ``weight = colScale·T`` is what that surface's radiance counts with, and only the
    rays that meet none see the environment (``camera``: the rays are the camera's own, whose
    environment ``hide_emitters`` may hide, :func:`_shown`)."""
    L, weight, out, x, inside, (t_surf, cast_x, cast_d, hit) = _march_loop(
        grids, o, d, env, s, surf
    )
    sky = weight * environment(env, out)
    if surf is None:
        return L + dr.select(_shown(s, d, out, camera), sky, 0.0), inside
    # beyond the grid: straight on to a surface (cast again if the last step turned), or away
    again = inside & ~hit & (dr.norm(out - cast_d) > RECAST_TURN)
    t_surf = dr.select(again, surf.distance(x, out, again), t_surf)
    cast_x = dr.select(again, x, cast_x)
    cast_d = dr.select(again, out, cast_d)
    hit |= dr.isfinite(t_surf)
    sky = dr.select(_shown(s, d, out, camera), sky, 0.0)
    return dr.select(hit, L, L + sky), hit, cast_x, cast_d, weight


def render_view(
    grids: ViewGrids, box: GridBox, sensor, env, settings: ViewSettings, shading=None
) -> mi.TensorXf:
    """Render the image seen by ``sensor`` (a Mitsuba perspective sensor) — stage S9; with
    ``shading`` (:class:`~.shading.SurfaceShading`) camera rays end at opaque surfaces and add
    their radiance (``shading.py``). The film's reconstruction filter is honoured:
    importance-sampled with ``spp`` > 1, applied to the image of the pixel centres with ``spp``
    = 1 (:mod:`photonmap.core.film_filter`)."""
    w, h = (int(c) for c in sensor.film().crop_size())
    pixels = w * h
    spp = max(int(settings.spp), 1)
    idx = dr.arange(mi.UInt32, pixels * spp)
    if spp > 1:  # jittered samples: the film's filter is importance-sampled (pixel_rays)
        rng = mi.PCG32(pixels * spp, mi.UInt64(settings.seed), mi.UInt64(idx))
        jitter = mi.Point2f(rng.next_float32(), rng.next_float32())
        ray, weight = pixel_rays(sensor, idx // spp, jitter)
    else:  # one ray per pixel centre: the film's filter is applied to the image
        ray, weight = pixel_rays(sensor, idx, mi.Point2f(0.5), filtered=False)
    o = mi.Point3f((ray.o - mi.Point3f(*box.lo)) / box.h)
    d = mi.Vector3f(ray.d)
    if shading is None:
        L, inside = _march_rays(grids, o, d, env, settings)
        sky = dr.select(_shown(settings, d, d), environment(env, d), 0.0)
        L = dr.select(inside, L, sky)
    else:
        L = _view_surfaces(grids, o, d, env, settings, shading)
    if spp > 1:
        image = mi.TensorXf(dr.ravel(pixel_means(mi.Color3f(L * weight), spp)), (h, w, 3))
    else:
        image = filter_image(mi.TensorXf(dr.ravel(L), (h, w, 3)), sensor.film())
    dr.eval(image)
    return image


def _view_surfaces(grids: ViewGrids, o, d, env, settings: ViewSettings, shading) -> mi.Color3f:
    """Camera rays with opaque surfaces: each ends at a surface, which adds its radiance
    (``shading.py``); where the surface has a mirror (delta) reflection lobe — a conductor, the
    coating of a smooth plastic — the ray goes on in the mirrored direction with the lobe's
    weight, through the grid again, up to :data:`MIRROR_BOUNCES` times (only the rays that do
    are marched again)."""
    surfaces = shading.surfaces
    L = dr.zeros(mi.Color3f, dr.width(o))
    lanes = dr.arange(mi.UInt32, dr.width(o))
    throughput = dr.ones(mi.Color3f, dr.width(o))
    for bounce in range(MIRROR_BOUNCES + 1):
        camera = bounce == 0
        L_ray, hit, cast_x, cast_d, weight = _march_rays(
            grids, o, d, env, settings, surfaces, camera
        )
        dr.eval(L_ray, hit, cast_x, cast_d, weight)
        si = surfaces.hit(cast_x, cast_d, hit)
        shown = hit & _shown(settings, d, cast_d, camera)
        L_ray += weight * shade(shading, si, settings.seed + bounce, hit, shown)
        dr.scatter_reduce(dr.ReduceOp.Add, L, throughput * L_ray, lanes)
        if bounce == MIRROR_BOUNCES:
            break
        bs, f = si.bsdf().sample(MIRROR, si, 0.5, mi.Point2f(0.5), hit)
        throughput *= weight * mi.Color3f(f)
        on = hit & (bs.pdf > 0) & (dr.max(throughput) > 0)
        wo = si.to_world(bs.wo)
        start = surfaces.voxel(si.spawn_ray(wo).o)
        dr.eval(L, on, throughput, wo, start)
        alive = dr.compress(on)
        if dr.width(alive) == 0:
            break
        lanes = dr.gather(mi.UInt32, lanes, alive)
        throughput = dr.gather(mi.Color3f, throughput, alive)
        o, d = dr.gather(mi.Point3f, start, alive), dr.gather(mi.Vector3f, wo, alive)
    return L


def sensor_key(sensor) -> tuple:
    """The cache key of S9's camera: the sensor and what can change in it in place
    (``mi.traverse``): pose, field of view, film size and crop."""
    film = sensor.film()
    matrix = np.asarray(sensor.world_transform().matrix, dtype=np.float64)
    fov = mi.traverse(sensor).get("x_fov")
    return (
        id(sensor),
        matrix.tobytes(),
        None if fov is None else float(np.asarray(fov).reshape(-1)[0]),
        tuple(int(c) for c in film.size()),
        tuple(int(c) for c in film.crop_size()),
        tuple(int(c) for c in film.crop_offset()),
        str(film.rfilter()),
        bool(film.sample_border()),
    )
