"""S5 — photon generation on the photon plane (Pfeuti 2009 §3.1.4, Listing A.3; Sun et al. 2008 §4.3).

A square "photon plane" between the light and the grid covers the whole grid as seen from the light.
Photon ``i`` starts at plane point ``Q_i`` given by a 2D point set (Hammersley by default, Pfeuti
§4.1 Table 4.1), travels along ``d₀ = normalize(Q_i − P_L)`` (point/spot) or the light direction
(directional) and enters the grid at the slab-test entry point ``x₀``; photons that miss the grid
carry no power (spec S5, oracle 17). Photons are listed in Morton order of their plane position so
that neighbouring SIMD lanes deposit into neighbouring voxels (the deposited sums are exact and do
not depend on the order).

Energy (spec S5, A14, physically normalised — the default):

- point / spot / area-derived point light with intensity ``I(d₀)`` (W/sr):
  ``Φ_i = I(d₀) · (A/N) · cos³θ_i / d²`` — the solid angle of the photon's plane cell, so
  ``Σ Φ_i → I · Ω_plane`` (oracle 16);
- directional light with irradiance ``E``: ``Φ_i = E · A / N`` (``A`` in world units);
- ``fidelity="paper"``: the constant per-photon energy of Pfeuti's listing, ``Φ_i = I · (A/N) / d²``
  for point lights (no cosine term, so the image is vignetted).

Spot lights (spec A16): ``I(θ_s) = I₀ · smoothstep(cos θ_outer, cos θ_inner, d₀ · a_spot)``. Area
emitters arrive as several point lights with a cosine lobe (see :class:`~.scene.Light`).
All positions here are in **voxel units** of the grid (spec §0.2).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core import sampling
from ..core.errors import SceneError
from ..core.grid import GridBox
from .scene import Light

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


def _corners(n: int) -> np.ndarray:
    return np.array([[x, y, z] for x in (0, n) for y in (0, n) for z in (0, n)], dtype=np.float64)


def photon_plane(light: Light, box: GridBox) -> PhotonPlane:
    """The square photon plane that covers the grid as seen from ``light`` (spec S5)."""
    corners = _corners(box.n)
    if light.kind == "directional":
        c = np.asarray(light.direction, dtype=np.float64)
        c = c / np.linalg.norm(c)
        e1, e2 = _basis(c)
        centre = np.full(3, box.n / 2.0)
        rel = corners - centre
        a = float(np.max(np.abs(np.stack([rel @ e1, rel @ e2]))))
        depth = float(np.max(np.abs(rel @ c))) + 1.0
        origin = centre - depth * c
        return PhotonPlane(origin - a * e1 - a * e2, e1, e2, 2 * a, c)

    p = box.to_voxel(light.position)
    c = np.full(3, box.n / 2.0) - p
    c = c / np.linalg.norm(c) if np.linalg.norm(c) > 0 else np.array([0.0, -1.0, 0.0])
    e1, e2 = _basis(c)
    rel = corners - p
    depth = rel @ c
    if not np.all(depth > 0):
        raise SceneError(
            f"the {light.kind} light at {np.round(light.position, 4).tolist()} lies inside or beside "
            "the volume grid; the photon plane needs the whole grid in front of the light (spec A49). "
            "Move the light outside the grid box or enlarge/shift the box (grid_bbox)."
        )
    d = PLANE_DISTANCE
    a = float(np.max(np.maximum(np.abs(rel @ e1), np.abs(rel @ e2)) * d / depth))
    centre = p + d * c
    return PhotonPlane(centre - a * e1 - a * e2, e1, e2, 2 * a, c)


def _v(a) -> mi.Vector3f:
    """An opaque 3-vector: a moved light reuses the compiled kernels."""
    return mi.Vector3f(*[dr.opaque(mi.Float, float(x)) for x in a])


def _s(x: float) -> mi.Float:
    return dr.opaque(mi.Float, float(x))


def box_entry(o: mi.Point3f, d: mi.Vector3f, n: int):
    """Slab test of the ray ``o + t d`` against ``[0, n]³``: ``(hit, t_near, t_far)``."""
    inv = dr.rcp(d)
    t0 = (0.0 - o) * inv
    t1 = (float(n) - o) * inv
    t_near = dr.maximum(dr.max(dr.minimum(t0, t1)), 0.0)
    t_far = dr.min(dr.maximum(t0, t1))
    return t_near < t_far, t_near, t_far


def _smoothstep(e0, e1, x):
    t = dr.clip((x - e0) / dr.maximum(e1 - e0, 1e-12), 0.0, 1.0)
    return dr.select(e1 > e0, t * t * (3.0 - 2.0 * t), dr.select(x >= e0, 1.0, 0.0))


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
        axis = _v(np.asarray(light.direction) / np.linalg.norm(light.direction))
        scale *= _smoothstep(_s(light.cos_outer), _s(light.cos_inner), dr.dot(d, axis))
    if light.lobe_normal is not None:
        scale *= dr.maximum(dr.dot(d, _v(light.lobe_normal)), 0.0)
    return p + dr.zeros(mi.Point3f, count), d, intensity * scale


def emit(
    light: Light,
    box: GridBox,
    count: int,
    sampler: str = "hammersley",
    seed: int = 0,
    fidelity: str = "physical",
) -> Photons:
    """Generate ``count`` photons on the light's photon plane, started where they enter the grid.

    Photons that miss the grid (or leave a spot light's cone) keep zero power: the marcher never
    activates them, and since the photons are in Morton order such photons fill whole SIMD
    packets, which cost nothing, so no compaction pass is needed.
    """
    u, w = sampling.coherent_points(sampler, count, seed)
    return emit_at(light, box, u, w, fidelity)


def emit_at(light: Light, box: GridBox, u, w, fidelity: str = "physical", weight=None) -> Photons:
    """Photons at the plane points ``(u, w) ∈ [0,1]²``, in the given order, entering the grid.

    ``weight`` (per photon, optional) multiplies the power: ``1/p(u, w)`` for points drawn from a
    density ``p`` on the plane (Pfeuti §3.2.3, spec A4), so that the estimator stays unbiased.
    """
    count = dr.width(u)
    o, d, power = plane_photons(light, box, photon_plane(light, box), u, w, fidelity)
    if weight is not None:
        power *= weight
    hit, t_near, _ = box_entry(o, d, box.n)
    keep = hit & (dr.max(power) > 0.0)
    photons = Photons(
        origin=dr.select(keep, o + t_near * d, 0.0),
        direction=d,
        power=dr.select(keep, power, 0.0),
        generated=count,
    )
    dr.eval(photons.origin, photons.direction, photons.power)
    photons.entering = int(dr.count(keep)[0]) if count else 0
    return photons


def emit_lights(
    lights: list[Light], box: GridBox, count: int, sampler: str, seed: int, fidelity: str
) -> Photons:
    """S5 for every light (Sun §3: "a set of point or directional light sources"), ``count``
    photons on each light's plane, concatenated."""
    return concat([emit(light, box, count, sampler, seed, fidelity) for light in lights])


def concat(batches: list[Photons]) -> Photons:
    """One photon list from the lists of several lights."""
    if len(batches) == 1:
        return batches[0]

    def cat(cls, field):
        parts = [getattr(b, field) for b in batches]
        return cls(*[dr.concat([part[i] for part in parts]) for i in range(3)])

    return Photons(
        origin=cat(mi.Point3f, "origin"),
        direction=cat(mi.Vector3f, "direction"),
        power=cat(mi.Color3f, "power"),
        generated=sum(b.generated for b in batches),
        entering=sum(b.count for b in batches),
    )
