"""Built-in scenes of the volume pipeline as Mitsuba 3 scene dicts: the papers' scene kinds (a glass
ball, a noisy cube, a mesh; Sun et al. 2008 Fig 6 and Table 1, Pfeuti 2009 Fig 4.9) with parameters
of ours, which the papers do not give.

World units: the unit cube [0, 1]³ is the 128³ grid box, so one voxel is 1/128 and a coefficient of
0.003/voxel is 0.384 in world units. Scene parameters (positions, sizes) are in **voxels**.

Every scene has the same surroundings: a ``cube`` with a ``null`` BSDF filling [0, 1]³ whose
interior medium is the grey fog (σ_s = κ = 0.003/voxel, albedo 1) — the medium-bearing shape that
defines the grid box; a ``point`` light at (64, 400, 64) voxels, above the box (outside the grid, so
the photon plane covers it); a ``perspective`` camera at 30° elevation aimed at the box centre. The
refractive object is a ``dielectric`` (``int_ior = ior``, ``ext_ior = 1``) with an absorbing
interior medium (κ = σ_a = (0.004, 0.002, 0.001)/voxel) and the fog as its exterior medium.

The scenes also render with Mitsuba's ``volpath`` (their default integrator) for ground truth. The
fog's phase function is Mitsuba's default (isotropic) and there is no table shape: compare with the
pipeline at ``phase_k = 0`` and ``table = 0``; the ``*_DEFAULTS`` are the demo settings. A point
light seen through a smooth dielectric is a delta-delta path that ``volpath`` cannot sample (no
caustics): pass ``light_radius > 0`` for a small spherical light of the same intensity.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from .meshes import to_mitsuba_mesh, torus_knot

N = 128
VOXEL = 1.0 / N
FOG = 0.003  # σ_s = κ of the grey fog, per voxel
GLASS_KAPPA = (0.004, 0.002, 0.001)  # κ = σ_a of the glass, per voxel
LIGHT_POSITION = (64.0, 400.0, 64.0)  # voxels
INTENSITY = 40.0  # W/sr (grey) of the point light
CENTER = np.array([64.0, 64.0, 64.0])  # voxels
FOG_REF = {"type": "ref", "id": "fog"}

SPHERE_DEFAULTS = {"table": 0.8, "phase_k": 0.3}
CUBE_DEFAULTS = {**SPHERE_DEFAULTS, "ior_noise": 0.02, "sigma_s_noise": 0.5, "noise_scale": 16.0}
MESH_DEFAULTS = dict(SPHERE_DEFAULTS)


def homogeneous(sigma_s, sigma_a) -> dict:
    """A ``homogeneous`` medium from per-voxel σ_s and σ_a (scalars or RGB), in world units.

    Mitsuba reads an ``rgb`` σ_t as a colour in [0, 1], so the magnitude goes into ``scale``.
    """
    sigma_s = np.broadcast_to(np.asarray(sigma_s, dtype=np.float64), 3) / VOXEL
    sigma_t = sigma_s + np.broadcast_to(np.asarray(sigma_a, dtype=np.float64), 3) / VOXEL
    scale = float(sigma_t.max()) or 1.0
    albedo = np.divide(sigma_s, sigma_t, out=np.zeros(3), where=sigma_t > 0)
    return {
        "type": "homogeneous",
        "sigma_t": _rgb(sigma_t / scale),
        "albedo": _rgb(albedo),
        "scale": scale,
    }


def camera(width: int, height: int, elevation: float = 30.0, azimuth: float = 35.0) -> dict:
    """A perspective camera on a sphere around the box centre, framing the whole box (the papers
    give no camera)."""
    fov = 40.0
    distance = 0.5 * np.sqrt(3.0) / np.sin(np.radians(fov / 2))  # box's bounding sphere
    e, a = np.radians(elevation), np.radians(azimuth)
    direction = np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
    target = CENTER * VOXEL
    return {
        "type": "perspective",
        "fov": fov,
        "fov_axis": "smaller",
        "to_world": mi.ScalarTransform4f().look_at(
            origin=(target + distance * direction).tolist(), target=target.tolist(), up=[0, 1, 0]
        ),
        "film": {"type": "hdrfilm", "width": int(width), "height": int(height)},
    }


def light(position, intensity, radius: float = 0.0) -> dict:
    """A point light (voxel units), or for ``radius > 0`` a spherical area light of the same
    intensity (radiance I/(πr²)) whose caustics Mitsuba's ``volpath`` can render."""
    position = (np.asarray(position, dtype=np.float64) * VOXEL).tolist()
    intensity = np.broadcast_to(np.asarray(intensity, dtype=np.float64), 3)
    if radius <= 0:
        return {"type": "point", "position": position, "intensity": _rgb(intensity)}
    r = radius * VOXEL
    emitter = {"type": "area", "radiance": _rgb(intensity / (np.pi * r * r))}
    return {"type": "sphere", "center": position, "radius": r, "emitter": emitter}


def _rgb(value) -> dict:
    return {"type": "rgb", "value": np.asarray(value, dtype=np.float64).tolist()}


def _scene(obj, fog, *, width, height, light_position, intensity, light_radius) -> dict:
    """The common surroundings (fog box, light, camera) around the refractive shape ``obj``.

    ``fog`` is a medium dict (referenced by id) or an instantiated medium (used directly).
    """
    fog_ref = fog if isinstance(fog, mi.Medium) else {"type": "ref", "id": "fog"}
    scene = {"type": "scene", "integrator": {"type": "volpath", "max_depth": 64}}
    if not isinstance(fog, mi.Medium):
        scene["fog"] = fog
    scene["fog_box"] = {
        "type": "cube",
        "to_world": mi.ScalarTransform4f().translate([0.5, 0.5, 0.5]).scale(0.5),
        "bsdf": {"type": "null"},
        "interior": fog_ref,
    }
    scene["glass"] = obj
    scene["light"] = light(light_position, intensity, light_radius)
    scene["sensor"] = camera(width, height)
    return scene


def _glass(ior: float, fog_ref, sigma_s: float = 0.0) -> dict:
    """Dielectric BSDF, absorbing (and scattering) interior and fog exterior of the glass."""
    return {
        "bsdf": {"type": "dielectric", "int_ior": float(ior), "ext_ior": 1.0},
        "interior": homogeneous(sigma_s, GLASS_KAPPA),
        "exterior": fog_ref,
    }


def glass_sphere_fog(
    ior: float = 1.5,
    width: int = 640,
    height: int = 480,
    light_position=LIGHT_POSITION,
    intensity=INTENSITY,
    light_radius: float = 0.0,
) -> dict:
    """SPHERE: a glass ball of radius 32 voxels at (64, 72, 64) in grey fog; its volume caustic
    converges just above the table (thin-lens image ≈ 56 voxels below the centre for n = 1.5)."""
    sphere = {
        "type": "sphere",
        "center": (np.array([64.0, 72.0, 64.0]) * VOXEL).tolist(),
        "radius": 32.0 * VOXEL,
        **_glass(ior, FOG_REF),
    }
    return _scene(
        sphere,
        homogeneous(FOG, 0.0),
        width=width,
        height=height,
        light_position=light_position,
        intensity=intensity,
        light_radius=light_radius,
    )


def perlin_cube(
    ior: float = 1.5,
    width: int = 640,
    height: int = 480,
    light_position=LIGHT_POSITION,
    intensity=INTENSITY,
    light_radius: float = 0.0,
    size: float = 60.0,
) -> dict:
    """CUBE: a ``size``-voxel glass cube turned 25° about y and 20° about x, slightly scattering
    (σ_s = 0.002/voxel); the pipeline perturbs n and σ_s with Perlin noise (Pfeuti 2009 Fig 4.9):
    ``n = ior + ior_noise·perlin(x/noise_scale)``, ``σ_s·(1 + sigma_s_noise·perlin(...))``."""
    to_world = (
        mi.ScalarTransform4f()
        .translate((CENTER * VOXEL).tolist())
        .rotate([1, 0, 0], 20.0)
        .rotate([0, 1, 0], 25.0)
        .scale(0.5 * size * VOXEL)
    )
    cube = {"type": "cube", "to_world": to_world, **_glass(ior, FOG_REF, sigma_s=0.002)}
    return _scene(
        cube,
        homogeneous(FOG, 0.0),
        width=width,
        height=height,
        light_position=light_position,
        intensity=intensity,
        light_radius=light_radius,
    )


def mesh_in_fog(
    triangles: int = 20000,
    extent: float = 103.0,
    ior: float = 1.5,
    width: int = 640,
    height: int = 480,
    light_position=LIGHT_POSITION,
    intensity=INTENSITY,
    light_radius: float = 0.0,
) -> dict:
    """MESH: a glass trefoil-knot tube of about ``triangles`` faces lying flat (tilted 20° about x)
    in the box centre, whose largest bounding-box side is ``extent`` voxels (Sun et al. 2008
    Table 1 sweeps: 10k/20k/40k/80k triangles, extents 64/77/90/103)."""
    vertices, faces = torus_knot(triangles)
    t = np.radians(20.0) - np.pi / 2  # knot plane (xy) → horizontal, then tilted
    rot = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    vertices = vertices @ rot.T
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    vertices = (vertices - 0.5 * (lo + hi)) * (extent / np.max(hi - lo)) + CENTER
    fog = mi.load_dict(homogeneous(FOG, 0.0))
    glass = {k: mi.load_dict(v) if isinstance(v, dict) else v for k, v in _glass(ior, fog).items()}
    mesh = to_mitsuba_mesh("glass", vertices * VOXEL, faces, **glass)
    return _scene(
        mesh,
        fog,
        width=width,
        height=height,
        light_position=light_position,
        intensity=intensity,
        light_radius=light_radius,
    )
