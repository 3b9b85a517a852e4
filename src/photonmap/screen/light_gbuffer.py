"""Light G-buffers: the first photon hit seen from the light (Yao 2011 §3.1–3.2, Fig 3.2). A texel
stores the power arriving there (its "flux"); the BSDF applies at the first scatter.

- **Spot light**: a square perspective frustum from the light position along the spot axis with
  half-angle θ_outer (the spot's cut-off), one ray per texel centre (u, v) on the image plane at
  unit distance; texel (i, j) carries the incident power Φ_ij = I(ω_ij)·Ω_ij with
  Ω_ij = Δu Δv / (1 + u² + v²)^{3/2} — zero outside the cone, so photon emission matches direct light.
- **Point light** ("emit photon from two hemisphere which cover the point light", §3.2): W_L·H_L
  stratified equal-area directions over the sphere, Ω = 4π/N each.
- **Area light** (rectangle, disk, sphere, mesh; support by sampling): ``emitter.sample_ray`` at
  stratified points of the light, Φ = weight/N (an unbiased estimate of the emitted power Φ_e).
  Direct light samples points on the light (:mod:`.direct`), not its centre as in Yao's thesis
  (whose area light only softens shadows): reference comparisons need it. The virtual light radius
  of the soft shadows is the light's own: :func:`light_radius` (``light_size`` is for spot and point
  lights).

Every texel's first hit is direct light, which :mod:`.direct` shades; :mod:`.light_photons` scatters
photons on from it. I(ω) of spot and point lights comes from Mitsuba's own ``sample_direction``, so
direct light and photons use the same profile (Mitsuba's linear fall-off from the beam width to
the cut-off; the thesis does not give its profile).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.bsdf import intersect_visible, shape_box
from ..core.emission import emitter_powers
from ..core.errors import PhotonmapWarning, SceneError

KINDS = ("spot", "point", "area")
MAX_FRUSTUM_DEG = 80.0  # spots wider than this emit over the sphere like a point light


@dataclass
class Light:
    """One light of the scene as the ``screen`` pipeline sees it: ``kind`` (spot | point | area),
    the Mitsuba ``emitter``, its ``position`` (the bounding-box centre for an area light),
    ``axis`` (spot axis or area normal), ``frame`` (spot and point lights), ``cutoff`` (radians,
    spots) and, for area lights, the emitted ``power`` Φ_e, the ``shape`` and the virtual light
    ``radius`` of the soft shadows (world units, :func:`light_radius`)."""

    kind: str
    emitter: mi.Emitter
    position: np.ndarray
    axis: np.ndarray
    frame: np.ndarray | None  # 3×3 columns: tangent, bitangent, axis (None for area lights)
    cutoff: float = 0.0
    power: np.ndarray | None = None  # area lights: emitted RGB power Φ_e
    shape: mi.Shape | None = None  # area lights: the emitting shape
    radius: float = 0.0  # area lights: virtual light radius L of Eqs 2–5 (world units)


IGNORED_SHARE = 0.05  # the other emitters' share of the power a one-light render may leave out


@dataclass
class LightGBuffer:
    """The light G-buffer (Yao 2011 §3.2), per texel (row-major, ``width × height``): first hit
    ``si`` (a Mitsuba SurfaceInteraction, kept for scattering), incident power ``flux`` (W) and
    ``valid`` (a surface was hit with non-zero flux)."""

    width: int
    height: int
    si: mi.SurfaceInteraction3f
    flux: mi.Color3f
    valid: mi.Bool


def find_light(scene: mi.Scene, index: int = 0, warn: bool = False) -> Light:
    """The ``index``-th spot, point or area emitter of ``scene`` as a :class:`Light`; raise a
    :class:`SceneError` if there is none. The pipeline lights the scene with this one light
    (direct light, shadows, photons); ``warn=True`` refuses a scene whose other emitters carry
    more than :data:`IGNORED_SHARE` of its emitted power (the image would lack their light) and
    otherwise issues a :class:`PhotonmapWarning` naming them (area lights still show their
    emission)."""
    indices = [i for i, e in enumerate(scene.emitters()) if _kind(e) is not None]
    lights = [scene.emitters()[i] for i in indices]
    if not lights:
        names = ", ".join(e.class_name() for e in scene.emitters()) or "none"
        raise SceneError(
            f"the screen pipeline needs a spot, point or area light (scene emitters: {names}); "
            "add one, e.g. {'type': 'spot', 'to_world': ..., 'cutoff_angle': 45}"
        )
    if not 0 <= index < len(lights):
        raise SceneError(f"light index {index} out of range: the scene has {len(lights)} light(s)")
    emitter = lights[index]
    if warn and len(scene.emitters()) > 1:
        others = [_describe(e) for e in scene.emitters() if e is not emitter]
        powers = emitter_powers(scene, samples=1 << 14).sum(axis=1)
        share = 1.0 - powers[indices[index]] / max(powers.sum(), 1e-30)
        if share > IGNORED_SHARE:
            raise SceneError(
                f"the screen method lights the scene with one light ({_describe(emitter)}), and "
                f"the others ({'; '.join(others)}) carry {share:.0%} of the emitted power; "
                "render this scene with --method sppm (or surface)"
            )
        warnings.warn(
            f"the screen method lights the scene with one light ({_describe(emitter)}, light "
            f"index {index}) and ignores the light of: {'; '.join(others)}",
            PhotonmapWarning,
            stacklevel=3,
        )
    kind = _kind(emitter)
    if kind == "area":
        shape = emitter.get_shape()
        ps = shape.sample_position(0.0, mi.Point2f(0.5, 0.5))
        position = np.array(shape_box(shape).center()).ravel()
        axis = np.array(ps.n).ravel()
        power = emitter_powers(scene, samples=1 << 14)[indices[index]]
        return Light(
            kind, emitter, position, axis, None, power=power, shape=shape,
            radius=light_radius(shape),
        )  # fmt: skip
    params = mi.traverse(emitter)
    if "to_world" in params.keys():
        m = np.array(params["to_world"].matrix, dtype=np.float64)[..., 0]
    else:  # Mitsuba's point light exposes only its position
        m = np.eye(4)
        m[:3, 3] = np.array(params["position"], dtype=np.float64).ravel()
    position, axis = m[:3, 3], m[:3, 2] / np.linalg.norm(m[:3, 2])
    frame = np.stack([c / np.linalg.norm(c) for c in (m[:3, 0], m[:3, 1], m[:3, 2])], 1)
    cutoff = 0.0
    if kind == "spot":
        cutoff = math.radians(float(np.array(params["cutoff_angle"]).ravel()[0]))
    return Light(kind, emitter, position, axis, frame, cutoff)


def light_radius(shape: mi.Shape) -> float:
    """The virtual light radius L (Eqs 2–5) of an area light: the radius of the disk with the
    shape's mean projected area A_p, L = √(A_p/π). A flat shape (rectangle, disk, planar mesh: the
    bounding box's thinnest side < 10⁻³ of its longest) faces the receivers with its whole area,
    A_p = A (a disk light gets its own radius); a solid one (sphere, closed mesh) shows a quarter
    of its area on average (Cauchy's formula for convex bodies), A_p = A/4 (a sphere: its
    radius)."""
    area = float(np.array(shape.surface_area()).ravel()[0])
    extent = np.array(shape_box(shape).extents()).ravel()
    flat = extent.min() < 1e-3 * extent.max()
    return math.sqrt(area / (1.0 if flat else 4.0) / math.pi)


def _describe(emitter: mi.Emitter) -> str:
    shape = emitter.get_shape() if hasattr(emitter, "get_shape") else None
    where = f" on shape '{shape.id()}'" if shape is not None and shape.id() else ""
    named = f" '{emitter.id()}'" if emitter.id() else ""
    return f"{emitter.class_name()}{named}{where}"


def _kind(emitter: mi.Emitter) -> str | None:
    name = emitter.class_name()
    if name == "SpotLight":
        return "spot"
    if name == "PointLight":
        return "point"
    if name == "AreaLight" and emitter.get_shape() is not None:
        return "area"
    return None


def intensity(light: Light, d: mi.Vector3f) -> mi.Color3f:
    """Radiant intensity I(ω) (W/sr, RGB) of a spot or point ``light`` along unit world
    directions ``d``."""
    it = dr.zeros(mi.Interaction3f, dr.width(d))
    it.p = mi.Point3f(*(dr.opaque(mi.Float, float(c)) for c in light.position)) + d
    ds, spec = light.emitter.sample_direction(it, mi.Point2f(0.5), True)
    return mi.Color3f(spec)  # I(ω)/dist² at distance 1


def light_gbuffer(
    scene: mi.Scene, light: Light, width: int, height: int, seed: int = 0, half_angle=None
) -> LightGBuffer:
    """The light G-buffer of ``light`` at ``width × height`` texels (module docstring).
    ``half_angle`` (radians) overrides a spot's frustum half-angle (default: its cut-off); ``seed``
    places the stratified samples of area lights."""
    n = width * height
    i = dr.arange(mi.UInt32, n)
    cu, cv = (mi.Float(i % width) + 0.5) / width, (mi.Float(i // width) + 0.5) / height
    # opaque: a literal would compile a new kernel for each light position (~70 ms a drag step)
    origin = mi.Point3f(*(dr.opaque(mi.Float, float(c)) for c in light.position))
    if light.kind == "area":
        jitter = mi.sample_tea_float32(i, mi.UInt32(seed), 4)
        jitter2 = mi.sample_tea_float32(i, mi.UInt32(seed + 0x9E37), 4)
        ray, weight = light.emitter.sample_ray(
            0.0, 0.5, mi.Point2f(cu, cv), mi.Point2f(jitter, jitter2), True
        )
        flux = mi.Color3f(weight) / n
    else:
        theta = light.cutoff if half_angle is None else half_angle
        if light.kind == "spot" and theta <= math.radians(MAX_FRUSTUM_DEG):
            t = math.tan(theta)
            u, v = (2 * cu - 1) * t, (2 * cv - 1) * t
            solid = (2 * t / width) * (2 * t / height) / dr.power(1 + u * u + v * v, 1.5)
            local = dr.normalize(mi.Vector3f(u, v, 1.0))
        else:  # equal-area stratified sphere: z uniform in [-1, 1], φ uniform
            z = 1 - 2 * cv
            r = dr.safe_sqrt(1 - z * z)
            phi = 2 * math.pi * cu
            local = mi.Vector3f(r * dr.cos(phi), r * dr.sin(phi), z)
            solid = dr.full(mi.Float, 4 * math.pi / n, n)
        f = light.frame
        d = mi.Vector3f(
            *(f[k, 0] * local.x + f[k, 1] * local.y + f[k, 2] * local.z for k in range(3))
        )
        ray = mi.Ray3f(origin, d)
        flux = intensity(light, d) * solid
    si = intersect_visible(scene, ray)  # null-BSDF shapes (fog boxes) are invisible
    valid = si.is_valid() & (dr.max(flux) > 0)
    lgb = LightGBuffer(width, height, si, dr.select(valid, flux, 0.0), valid)
    dr.eval(lgb.si, lgb.flux, lgb.valid)
    _check_outside(scene, light, si, ray)
    return lgb


def check_light_outside(scene: mi.Scene, light: Light, rays: int = 32) -> None:
    """Raise a :class:`SceneError` if a spot or point light sits inside closed geometry (rays²
    directions over the whole sphere, see :func:`_check_outside`). Area lights lie on their
    shape and are not checked."""
    if light.kind != "area":
        light_gbuffer(scene, dataclasses.replace(light, kind="point"), rays, rays)


def _check_outside(scene, light: Light, si, ray) -> None:
    """Raise a :class:`SceneError` when the light sits inside closed geometry: most of its rays
    that hit anything hit a back face (the geometric normal points away from the light)."""
    hit = si.is_valid()
    back = hit & (dr.dot(si.sh_frame.n, ray.d) > 0)  # shading normals: Mitsuba flips si.n
    hits, backs = dr.count(hit)[0], dr.count(back)[0]
    if hits and backs > 0.5 * hits:
        raise SceneError(
            f"the {light.kind} light at {np.round(light.position, 4).tolist()} lies inside "
            f"geometry: {backs} of its {hits} first hits are back faces; move the light out of "
            "the closed mesh (or flip the mesh's normals if it is a wall facing the wrong way)"
        )
