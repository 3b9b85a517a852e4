"""S5 — photon generation for lights anywhere (Pfeuti 2009 §3.1.4, Listing A.3; Sun et al. 2008
§4.3).

How a light's photons are made depends on the light (:func:`emission_mode`):

- ``"plane"`` — a point or spot light with the whole grid in front of it, and every directional
  light: the **photon plane**. A square between the light and the grid covers the whole grid as seen
  from the light; photon ``i`` starts at plane point ``Q_i`` of a 2D point set (Hammersley by
  default, Pfeuti §4.1 Table 4.1), travels along ``d₀ = normalize(Q_i − P_L)`` (point/spot) or the
  light direction (directional) and enters the grid at the slab-test entry point ``x₀``. Energy
  (physically normalised — the default; Pfeuti's text and listing disagree):
  ``Φ_i = I(d₀)·(A/N)·cos³θ_i/d²`` for point/spot lights — the solid angle of the photon's plane
  cell, so ``Σ Φ_i → I·Ω_plane`` (tested) — and ``Φ_i = E·A/N`` for a directional light (``A`` in
  world units); ``fidelity="paper"``: Pfeuti's constant ``Φ_i = I·(A/N)/d²`` (no cosine, a
  vignetted image).
- ``"cone"`` (ours) — a point or spot light **inside the grid**, or beside it where no plane in
  front of the light covers the grid (the photon plane assumes a light outside it): photons start at
  the light with stratified directions in a cone (axis ``c``, half-angle ``θ_max``): the whole
  sphere for a point light, the cutoff cone for a spot light. The 2D point ``(u, w)`` maps to
  ``cos θ = 1 − u(1 − cos θ_max)``, ``φ = 2πw``, an area-preserving map, so every photon carries
  the same solid angle ``Ω/N`` with ``Ω = 2π(1 − cos θ_max)`` and ``Φ_i = I(d_i)·Ω/N``
  (``Σ Φ_i → 4πI`` for a point light).
- ``"area"`` (ours) — an area emitter (sphere, rectangle, mesh) is sampled on its surface:
  ``p`` from the shape's ``sample_position`` (density ``p_A``), and the direction by cosine
  about the normal (density ``cos θ_e/π``, what Mitsuba's ``AreaLight.sample_ray`` does) where
  ``p`` lies inside the grid's bounding sphere, else uniformly in the cone of that sphere seen
  from ``p`` (density ``1/Ω_p``, so that distant lights waste few photons). Either way
  ``Φ = L_e(p, ω)·cos θ_e / (p_A · p_ω · N)``: ``π·L_e/(p_A N)`` — Mitsuba's ``sample_ray``
  weight over N — or ``L_e·cos θ_e·Ω_p/(p_A N)``.
- ``"environment"`` (ours) — a ``constant`` or ``envmap`` emitter lights the grid through its
  faces. The radiance arriving along ``ω`` crosses the box through the faces facing ``−ω``,
  whose projected area is ``A_⊥(ω) = Σ_a A_a |ω_a|`` (``A_a`` the area of the face normal to
  axis ``a``), so the power entering is ``∫ L(ω) A_⊥(ω) dω``. The direction is drawn by the
  emitter's own ``sample_direction`` (density ``p(ω)``, importance sampling an envmap), the face
  with probability ``A_a|ω_a|/A_⊥`` and the point uniformly on it:
  ``Φ = L(ω)·A_⊥(ω)/(p(ω)·N)``. (For a constant ``L``: ``Σ Φ → L·4π·A_total/4 = πL·A_total``.)

Photons that start outside the grid move to where they enter it (slab test); photons that miss
it carry no power, and the marcher never activates them. Photons from 2D
point sets are listed in Morton order of the point so that neighbouring SIMD lanes deposit into
neighbouring voxels (the deposited sums are exact and do not depend on the order); area and
environment photons use the Hammersley set of 4 and 5 dimensions (``(i+½)/N, Φ₂(i), Φ₃(i), …``,
Cranley–Patterson-shifted by the seed). A spot light's intensity falls off as Mitsuba's ``spot``
plugin's (:func:`spot_falloff`; neither paper has spot lights). All positions here are in
**voxel units** of the grid (:mod:`photonmap.core.grid`); powers in watts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core import arrays, sampling
from ..core.errors import SceneError
from ..core.grid import GridBox, grid_dims, grid_extent
from .scene import EMITTER_KINDS, Light

PLANE_DISTANCE = (
    1.0  # d: the plane's distance from a point light (any d > 0 gives the same photons)
)


@dataclass
class Photons:
    """Photons on their way into the grid: entry point (voxel units), unit direction, RGB power Φ
    (W). Photons that miss the grid have zero power."""

    origin: mi.Point3f
    direction: mi.Vector3f
    power: mi.Color3f
    generated: int  # photons placed on the plane, hits and misses
    entering: int = -1  # photons that enter the grid (Sun Table 2 "photons propagated")

    @property
    def count(self) -> int:
        """Photons that enter the grid."""
        return self.entering if self.entering >= 0 else dr.width(self.power)


@dataclass
class PhotonPlane:
    """The photon plane: ``Q(u, w) = corner + u·S·e₁ + w·S·e₂`` for ``(u, w) ∈ [0,1]²`` (voxel units)."""

    corner: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    side: float  # S, voxel units
    normal: np.ndarray  # c, the central axis (towards the grid)


def _basis(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([0.0, 0.0, 1.0]) if abs(c[1]) > 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, c)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(c, e1)


def _corners(n) -> np.ndarray:
    """The eight corners of the grid of extent ``n`` (:func:`~.grid.grid_dims`), voxel units."""
    nx, ny, nz = grid_dims(n)
    return np.array(
        [[x, y, z] for x in (0, nx) for y in (0, ny) for z in (0, nz)], dtype=np.float64
    )


def _centre(box: GridBox) -> np.ndarray:
    """The grid's centre in voxel units."""
    return np.asarray(box.dims, dtype=np.float64) / 2.0


def in_front(light: Light, box: GridBox) -> bool:
    """Whether the whole grid lies in front of the point or spot ``light`` (every corner at a
    positive depth along the axis towards the grid's centre), as the photon plane needs."""
    p = box.to_voxel(light.position)
    c = _centre(box) - p
    if np.linalg.norm(c) == 0:
        return False
    return bool(np.all((_corners(box.dims) - p) @ (c / np.linalg.norm(c)) > 0))


def emission_mode(light: Light, box: GridBox) -> str:
    """How S5 makes the photons of ``light`` (module docstring): ``"plane"``, ``"cone"``,
    ``"area"`` or ``"environment"``."""
    if light.kind in EMITTER_KINDS:
        return light.kind
    if light.kind == "directional" or in_front(light, box):
        return "plane"
    return "cone"


def photon_plane(light: Light, box: GridBox) -> PhotonPlane:
    """The square photon plane that covers the grid as seen from ``light`` (Pfeuti 2009 §3.1.4).

    Raises :class:`SceneError` for a light that has none (the plane-based ``emission="adaptive"``
    cannot use it; ``emission="uniform"`` emits such lights from the light itself)."""
    corners = _corners(box.dims)
    if light.kind in EMITTER_KINDS:
        raise SceneError(
            f"the scene's {light.kind} light has no photon plane: emission='adaptive' places its "
            "photons on a plane in front of point, spot and directional lights outside the grid. "
            "Use emission='uniform', which samples area and environment lights themselves"
        )
    if light.kind == "directional":
        c = np.asarray(light.direction, dtype=np.float64)
        c = c / np.linalg.norm(c)
        e1, e2 = _basis(c)
        centre = _centre(box)
        rel = corners - centre
        a = float(np.max(np.abs(np.stack([rel @ e1, rel @ e2]))))
        depth = float(np.max(np.abs(rel @ c))) + 1.0
        origin = centre - depth * c
        return PhotonPlane(origin - a * e1 - a * e2, e1, e2, 2 * a, c)

    if not in_front(light, box):
        raise SceneError(
            f"the {light.kind} light at {np.round(light.position, 4).tolist()} lies inside or beside "
            "the volume grid; the photon plane of emission='adaptive' needs the whole grid in front "
            "of the light. Use emission='uniform' (it emits such a light's photons from "
            "its position), or move the light outside the grid box (grid_bbox)"
        )
    p = box.to_voxel(light.position)
    c = _centre(box) - p
    c = c / np.linalg.norm(c)
    e1, e2 = _basis(c)
    rel = corners - p
    depth = rel @ c
    d = PLANE_DISTANCE
    a = float(np.max(np.maximum(np.abs(rel @ e1), np.abs(rel @ e2)) * d / depth))
    centre = p + d * c
    return PhotonPlane(centre - a * e1 - a * e2, e1, e2, 2 * a, c)


def _v(a) -> mi.Vector3f:
    """An opaque 3-vector: a moved light reuses the compiled kernels."""
    return mi.Vector3f(*[dr.opaque(mi.Float, float(x)) for x in a])


def _s(x: float) -> mi.Float:
    return dr.opaque(mi.Float, float(x))


def box_entry(o: mi.Point3f, d: mi.Vector3f, n):
    """Slab test of the ray ``o + t d`` against the grid ``[0, n_x] × [0, n_y] × [0, n_z]``
    (``n``: :func:`~.grid.grid_dims`): ``(hit, t_near, t_far)``."""
    inv = dr.rcp(d)
    t0 = (0.0 - o) * inv
    t1 = (grid_extent(n) - o) * inv
    t_near = dr.maximum(dr.max(dr.minimum(t0, t1)), 0.0)
    t_far = dr.min(dr.maximum(t0, t1))
    return t_near < t_far, t_near, t_far


def spot_falloff(cos_theta, cos_inner: float, cos_outer: float):
    """Mitsuba's ``spot`` profile: 1 inside the beam (``cos θ ≥ cos_inner``), then linear in the
    angle, ``(θ_cutoff − θ)/(θ_cutoff − θ_beam)``, and 0 from the cutoff (``cos θ ≤ cos_outer``)."""
    cutoff, beam = math.acos(cos_outer), math.acos(min(cos_inner, 1.0))
    angle = dr.acos(dr.clip(cos_theta, -1.0, 1.0))
    ramp = (_s(cutoff) - angle) * _s(1.0 / max(cutoff - beam, 1e-12))
    return dr.select(cos_theta > cos_outer, dr.select(cos_theta >= cos_inner, 1.0, ramp), 0.0)


def plane_photons(light: Light, box: GridBox, plane: PhotonPlane, u, w, fidelity="physical"):
    """Start point, direction and power of the photons at plane points ``(u, w)`` (before the
    grid test): the energy formulas of the module docstring."""
    count = dr.width(u)
    side = _s(plane.side)
    q = _v(plane.corner) + u * side * _v(plane.e1) + w * side * _v(plane.e2)
    area = plane.side**2
    intensity = mi.Color3f(_v(light.intensity))
    if light.kind == "directional":
        d = dr.zeros(mi.Vector3f, count) + _v(plane.normal)
        return q, d, intensity * _s(area * box.h**2 / count) + dr.zeros(mi.Color3f, count)

    p = _v(box.to_voxel(light.position))
    d = dr.normalize(q - p)
    cell = _s(area / (count * PLANE_DISTANCE**2))
    if fidelity == "paper":
        scale = cell + dr.zeros(mi.Float, count)
    else:
        scale = cell * dr.dot(d, _v(plane.normal)) ** 3  # the cell's solid angle, dA·cos³θ/d²
    if light.kind == "spot":
        scale *= _spot(light, d)
    return p + dr.zeros(mi.Point3f, count), d, intensity * scale


def _spot(light: Light, d: mi.Vector3f) -> mi.Float:
    axis = _v(np.asarray(light.direction) / np.linalg.norm(light.direction))
    return spot_falloff(dr.dot(d, axis), light.cos_inner, light.cos_outer)


def _cone(light: Light) -> tuple[np.ndarray, float]:
    """Axis and ``cos θ_max`` of the cone of directions that carry the light's photons: the spot's
    cutoff cone, or the whole sphere (``cos θ_max = −1``) for a point light — in ``"cone"`` mode
    it is inside the grid or beside it, where the grid's corners span a hemisphere or more."""
    if light.kind == "spot":
        axis = np.asarray(light.direction, dtype=np.float64)
        return axis / np.linalg.norm(axis), float(light.cos_outer)
    return np.array([0.0, 0.0, 1.0]), -1.0


def cone_photons(light: Light, box: GridBox, u, w):
    """Start point, direction and power of a point or spot light's photons emitted from its
    position (mode ``"cone"``, module docstring), before the grid test: ``Φ_i = I(d_i)·Ω/N``."""
    count = dr.width(u)
    axis, cos_max = _cone(light)
    e1, e2 = _basis(axis)
    cos_t = 1.0 - u * _s(1.0 - cos_max)
    sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
    sin_p, cos_p = dr.sincos(2.0 * math.pi * w)
    d = (sin_t * cos_p) * _v(e1) + (sin_t * sin_p) * _v(e2) + cos_t * _v(axis)
    scale = _s(2.0 * math.pi * (1.0 - cos_max) / count) + dr.zeros(mi.Float, count)
    if light.kind == "spot":
        scale *= _spot(light, d)
    p = _v(box.to_voxel(light.position)) + dr.zeros(mi.Point3f, count)
    return p, d, mi.Color3f(_v(light.intensity)) * scale


def area_photons(
    light: Light, box: GridBox, count: int, seed: int = 0, aim: bool = True, offset: bool = False
):
    """Start point (voxel units), direction and power of an area emitter's photons (mode
    ``"area"``, module docstring), before the grid test; ``aim`` False: the cosine lobe
    everywhere (:func:`emit_everywhere`); ``offset``: start off the surface by Mitsuba's spawn
    offset, where a cast from there must not find the emitter itself (opaque surfaces)."""
    emitter = light.emitter
    u = sampling.hammersley_nd(count, 4, seed)
    ps = light.shape.sample_position(0.0, mi.Point2f(u[0], u[1]))
    si = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
    radius = _s(0.5 * float(np.linalg.norm(box.extent)))  # the grid's bounding sphere (opaque)
    to_centre = _v(box.center) - ps.p
    dist = dr.norm(to_centre)
    far = (dist > radius) & aim
    cos_max = dr.safe_sqrt(1.0 - dr.square(radius / dist))
    cos_t = 1.0 - u[2] * (1.0 - cos_max)
    sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
    sin_p, cos_p = dr.sincos(2.0 * math.pi * u[3])
    in_cone = mi.Frame3f(to_centre / dist).to_world(
        mi.Vector3f(sin_t * cos_p, sin_t * sin_p, cos_t)
    )
    cosine = si.sh_frame.to_world(mi.warp.square_to_cosine_hemisphere(mi.Point2f(u[2], u[3])))
    d = dr.select(far, in_cone, cosine)
    si.wi = si.to_local(d)
    solid = 2.0 * math.pi * (1.0 - cos_max)
    weight = dr.select(far, dr.maximum(dr.dot(d, ps.n), 0.0) * solid, math.pi)
    power = emitter.eval(si) * weight / (ps.pdf * count)
    start = si.spawn_ray(d).o if offset else ps.p
    origin = mi.Point3f((start - _v(box.lo)) / _s(box.h))
    return origin, d, mi.Color3f(power) * mi.Color3f(_v(light.intensity))


def environment_photons(light: Light, box: GridBox, count: int, seed: int = 0):
    """Start point on the grid's faces (voxel units), direction and power of an environment's
    photons (mode ``"environment"``, module docstring)."""
    u = sampling.hammersley_nd(count, 5, seed)
    it = dr.zeros(mi.Interaction3f, count)
    it.p = _v(box.center) + dr.zeros(mi.Point3f, count)
    ds, weight = light.emitter.sample_direction(it, mi.Point2f(u[0], u[1]))  # L(ω)/p(ω)
    d = -ds.d
    ex, ey, ez = box.extent
    a = dr.abs(d) * _v((ey * ez, ex * ez, ex * ey))  # world areas of the faces normal to x, y, z
    projected = a.x + a.y + a.z  # A_⊥(ω)
    pick = u[2] * projected
    n = _v(box.dims)
    enter = dr.select(d > 0, 0.0, n)  # the entry face's coordinate on each axis
    along_x, along_y = pick < a.x, (pick >= a.x) & (pick < a.x + a.y)
    s, t = u[3] * n, u[4] * n  # the point on the face: (s, t) on its first and second free axis
    origin = mi.Point3f(
        dr.select(along_x, enter.x, s.x),
        dr.select(along_x, s.y, dr.select(along_y, enter.y, t.y)),
        dr.select(along_x | along_y, t.z, enter.z),
    )
    power = mi.Color3f(weight) * projected / count * mi.Color3f(_v(light.intensity))
    return origin, d, dr.select(ds.pdf > 0, power, 0.0)


def emit(
    light: Light,
    box: GridBox,
    count: int,
    sampler: str = "hammersley",
    seed: int = 0,
    fidelity: str = "physical",
    keep_origin: bool = False,
) -> Photons:
    """Generate ``count`` photons of ``light`` (by its :func:`emission_mode`), started where they
    enter the grid (or where they are, inside it); with ``keep_origin``, where they leave the light
    (a scene with opaque surfaces: the marcher checks the way to the grid, ``surface_march.py``).

    Photons that miss the grid (or leave a spot light's cone) keep zero power: the marcher never
    activates them, and since the plane and cone photons are in Morton order such photons fill
    whole SIMD packets, which cost nothing, so no compaction pass is needed. ``sampler`` is the 2D
    point set of the plane and cone modes; ``fidelity="paper"`` changes the plane's energies only.
    """
    mode = emission_mode(light, box)
    if mode == "area":
        photons = area_photons(light, box, count, seed, offset=keep_origin)
        return enter_grid(*photons, box.dims, compact=True, keep_origin=keep_origin)
    if mode == "environment":
        photons = environment_photons(light, box, count, seed)
        return enter_grid(*photons, box.dims, keep_origin=keep_origin)
    u, w = sampling.coherent_points(sampler, count, seed)
    if mode == "cone":
        return enter_grid(*cone_photons(light, box, u, w), box.dims, keep_origin=keep_origin)
    plane = plane_photons(light, box, photon_plane(light, box), u, w, fidelity)
    return enter_grid(*plane, box.dims, keep_origin=keep_origin)


def enter_grid(
    o: mi.Point3f,
    d: mi.Vector3f,
    power: mi.Color3f,
    n,
    compact: bool = False,
    keep_origin: bool = False,
) -> Photons:
    """Photons from ``o`` along ``d`` (voxel units) moved to where they enter the grid of extent
    ``n`` (:func:`box_entry`; unchanged inside it, or everywhere with ``keep_origin``); those that
    miss it, or carry no power, get zero power — or, with ``compact``, are left out (photons whose
    misses are scattered among the hits, which would idle SIMD lanes of the marcher)."""
    count = dr.width(power)
    hit, t_near, _ = box_entry(o, d, n)
    keep = hit & (dr.max(power) > 0.0)
    if compact:
        index = dr.compress(keep)
        o, d, power, t_near = (dr.gather(type(a), a, index) for a in (o, d, power, t_near))
        keep = dr.full(mi.Bool, True, dr.width(index))
    photons = Photons(
        origin=dr.select(keep, o if keep_origin else o + t_near * d, 0.0),
        direction=d,
        power=dr.select(keep, power, 0.0),
        generated=count,
    )
    dr.eval(photons.origin, photons.direction, photons.power)
    photons.entering = int(dr.count(keep)[0]) if dr.width(keep) and count else 0
    return photons


def emit_at(light: Light, box: GridBox, u, w, fidelity: str = "physical", weight=None) -> Photons:
    """Photons at the photon-plane points ``(u, w) ∈ [0,1]²``, in the given order, entering the
    grid.

    ``weight`` (per photon, optional) multiplies the power: ``1/p(u, w)`` for points drawn from a
    density ``p`` on the plane (Pfeuti §3.2.3), so that the estimator stays unbiased.
    """
    o, d, power = plane_photons(light, box, photon_plane(light, box), u, w, fidelity)
    if weight is not None:
        power *= weight
    return enter_grid(o, d, power, box.dims)


def emit_lights(
    lights: list[Light],
    box: GridBox,
    count: int,
    sampler: str,
    seed: int,
    fidelity: str,
    keep_origin: bool = False,
    scene_bounds=None,
) -> Photons:
    """S5 for every light (Sun §3: "a set of point or directional light sources"), ``count``
    photons of each light (:func:`emit`), concatenated; with ``scene_bounds`` (the centre and
    radius of the scene's bounding sphere, voxel units) every light's photons go everywhere
    (:func:`emit_everywhere`)."""
    if scene_bounds is not None:
        batches = [emit_everywhere(li, box, count, sampler, seed, scene_bounds) for li in lights]
    else:
        batches = [emit(li, box, count, sampler, seed, fidelity, keep_origin) for li in lights]
    return concat(batches)


def emit_everywhere(
    light: Light, box: GridBox, count: int, sampler: str, seed: int, scene_bounds
) -> Photons:
    """S5 when photons bounce off opaque surfaces (ours): the light that surfaces outside the
    grid's silhouette reflect into the fog needs photons there too, so every light emits into
    all its directions — point and spot lights by the ``"cone"`` mode from their position (the
    whole sphere, the cutoff cone), area lights by the cosine lobe of every point, directional
    and environment lights through a square facing their direction that covers the scene's
    bounding sphere (centre ``c``, radius ``R``; ``Φ = E·A/N`` and ``Φ = L(ω)·A/(p(ω)·N)``, ``A``
    the square's world area). Photons start at the light (voxel units) and keep their power."""
    centre, radius = (np.asarray(scene_bounds[0], dtype=np.float64), float(scene_bounds[1]))
    if light.kind in ("point", "spot"):
        u, w = sampling.coherent_points(sampler, count, seed)
        o, d, power = cone_photons(light, box, u, w)
    elif light.kind == "area":
        o, d, power = area_photons(light, box, count, seed, aim=False, offset=True)
    else:
        if light.kind == "directional":
            u, w = sampling.coherent_points(sampler, count, seed)
            axis = np.asarray(light.direction, dtype=np.float64)
            d = _v(axis / np.linalg.norm(axis)) + dr.zeros(mi.Vector3f, count)
            weight = mi.Color3f(_v(light.intensity))
        else:  # environment: the emitter's own direction sampling (L(ω)/p(ω))
            xi = sampling.hammersley_nd(count, 4, seed)
            u, w = xi[2], xi[3]
            it = dr.zeros(mi.Interaction3f, count)
            it.p = _v(box.to_world(centre)) + dr.zeros(mi.Point3f, count)
            ds, weight = light.emitter.sample_direction(it, mi.Point2f(xi[0], xi[1]))
            d, weight = -ds.d, mi.Color3f(weight) * mi.Color3f(_v(light.intensity))
            weight = dr.select(ds.pdf > 0, weight, 0.0)
        frame = mi.Frame3f(d)
        side = 2.0 * radius
        offset = (u - 0.5) * side * frame.s + (w - 0.5) * side * frame.t
        o = mi.Point3f(_v(centre) - (radius + 1.0) * d + offset)
        power = weight * _s(side**2 * box.h**2 / count) + dr.zeros(mi.Color3f, count)
    photons = Photons(mi.Point3f(o), mi.Vector3f(d), mi.Color3f(power), generated=count)
    dr.eval(photons.origin, photons.direction, photons.power)
    photons.entering = int(dr.count(dr.max(photons.power) > 0)[0]) if count else 0
    return photons


def concat(batches: list[Photons]) -> Photons:
    """One photon list from the lists of several lights."""
    if len(batches) == 1:
        return batches[0]

    def cat(cls, field):
        return cls(arrays.concat([getattr(b, field) for b in batches]))

    return Photons(
        origin=cat(mi.Point3f, "origin"),
        direction=cat(mi.Vector3f, "direction"),
        power=cat(mi.Color3f, "power"),
        generated=sum(b.generated for b in batches),
        entering=sum(b.count for b in batches),
    )
