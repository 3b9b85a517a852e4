"""Cornell-box scenes of Steinhurst (2007) §1.4 as Mitsuba 3 scene dicts.

The dissertation gives no geometry, camera or light power, so these are ours: the box of the
Cornell University Program of Computer Graphics measurements ("Cornell Box Data"), idealised to a
rectangular box of 556.0 × 548.8 × 559.2 mm (width x, height y, depth z) open at the front
(z = 0), with the 130 × 105 mm light at the centre of the ceiling, 0.5 mm below it. World units
are **metres** (the published millimetres / 1000), so photon powers are in W for radiances in
W m⁻² sr⁻¹. Wall reflectances are the RGB approximations of the measured spectra used by the
common PBRT / Mitsuba versions (white 0.725/0.71/0.68, red 0.63/0.065/0.05, green
0.14/0.45/0.091); the light's radiance (18.387, 13.987, 6.754) and its grey 0.78 diffuse BSDF
are those of Mitsuba's Cornell box. The camera is the published one: at (278, 273, −800) mm looking
along +z, vertical field of view 39.3°, 512 × 512 pixels (Steinhurst's image size). Red is the left
wall (x = 556 mm), green the right one (x = 0).

Scenes (all for ``--method surface``; the default integrator is Mitsuba's ``path``):

- :func:`cornell_steinhurst` — Fig 1.2: a mirror sphere and a glass sphere (n = 1.5) under the
  ceiling light; the glass sphere's caustic lies on the floor under it, most of it in the
  camera's view.
- :func:`cornell_spot_indirect` — Fig 1.2 (b) / Fig 6.14: the ceiling light replaced by a white
  diffuse disk that a spot light below aims straight up at, so all light the camera sees is
  indirect.
- :func:`cornell_glossy_floor` — Fig 7.5 / 6.16: a Lambertian + glossy "wooden" floor (a
  ``blendbsdf`` of a brown ``diffuse`` and a Beckmann ``roughconductor`` lobe standing in for
  Steinhurst's Phong lobe) reflecting a checkerboard back wall.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

MM = 1e-3  # the published data are in millimetres; world units are metres
WIDTH, HEIGHT, DEPTH = 556.0 * MM, 548.8 * MM, 559.2 * MM
LIGHT_SIZE = (130.0 * MM, 105.0 * MM)  # x, z
LIGHT_DROP = 0.5 * MM  # the light sits this far below the ceiling
LIGHT_RADIANCE = (18.387, 13.9873, 6.75357)
LIGHT_REFLECTANCE = 0.78
WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
CAMERA_ORIGIN = (278.0 * MM, 273.0 * MM, -800.0 * MM)
CAMERA_TARGET = (278.0 * MM, 273.0 * MM, 0.0)
CAMERA_FOV = 39.3  # degrees

SPHERE_RADIUS = 100.0 * MM
MIRROR_CENTER = (380.0 * MM, SPHERE_RADIUS, 370.0 * MM)  # left, back, resting on the floor
GLASS_CENTER = (175.0 * MM, SPHERE_RADIUS, 185.0 * MM)  # right, front, resting on the floor

FLOOR_DIFFUSE = (0.3, 0.2, 0.12)  # the glossy floor's Lambertian base, a dark wood-like brown

DISK_RADIUS = 150.0 * MM  # the white disk of the indirect variant, centred on the ceiling
SPOT_HEIGHT = 150.0 * MM  # the spot light under it, aimed straight up


def cornell_steinhurst(width: int = 512, height: int = 512) -> dict:
    """The Cornell box with the ceiling light, a mirror sphere (left, back) and a glass sphere
    (right, front; n = 1.5) of radius 100 mm resting on the floor (Steinhurst Fig 1.2)."""
    scene = empty_box(width, height)
    scene["light"] = ceiling_light()
    scene["mirror_sphere"] = {
        "type": "sphere",
        "center": list(MIRROR_CENTER),
        "radius": SPHERE_RADIUS,
        "bsdf": {"type": "conductor", "material": "none"},
    }
    scene["glass_sphere"] = {
        "type": "sphere",
        "center": list(GLASS_CENTER),
        "radius": SPHERE_RADIUS,
        "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0},
    }
    return scene


def cornell_spot_indirect(width: int = 512, height: int = 512) -> dict:
    """The empty Cornell box lit only indirectly: a white diffuse disk of radius 150 mm just below
    the ceiling centre and a spot light 150 mm above the floor whose cone (cut-off angle = the
    disk's angular radius) ends on the disk's rim (Steinhurst Fig 1.2 b). The spot emits the
    power of the standard ceiling light."""
    scene = empty_box(width, height)
    centre = np.array([WIDTH / 2, HEIGHT - LIGHT_DROP, DEPTH / 2])
    scene["disk"] = {
        "type": "disk",
        "to_world": frame(centre, (DISK_RADIUS, 0, 0), (0, 0, DISK_RADIUS), (0, -1, 0)),
        "bsdf": diffuse(WHITE),
    }
    cutoff = np.arctan(DISK_RADIUS / (centre[1] - SPOT_HEIGHT))
    beam = 0.75 * cutoff
    # Mitsuba's spot fall-off is linear in θ from the beam width to the cut-off angle, so the
    # cone's weighted solid angle is ∫ falloff dω = 2π (1 − (sin θ_c − sin θ_b)/(θ_c − θ_b)).
    cone = 2 * np.pi * (1 - (np.sin(cutoff) - np.sin(beam)) / (cutoff - beam))
    intensity = np.array(LIGHT_RADIANCE) * np.pi * LIGHT_SIZE[0] * LIGHT_SIZE[1] / cone
    spot = (WIDTH / 2, SPOT_HEIGHT, DEPTH / 2)
    scene["spot"] = {
        "type": "spot",
        "to_world": _look_up(spot),
        "cutoff_angle": float(np.degrees(cutoff)),
        "beam_width": float(np.degrees(beam)),
        "intensity": rgb(intensity),
    }
    return scene


def cornell_glossy_floor(
    width: int = 512, height: int = 512, roughness: float = 0.1, glossy: float = 0.5
) -> dict:
    """The Cornell box with the ceiling light, a Lambertian + glossy floor and a checkerboard back
    wall the floor reflects (Steinhurst Fig 7.5). The floor's BRDF is ``(1 − glossy)·ρ_d/π +
    glossy·f_mirror,α`` (``blendbsdf``): a brown Lambertian term and a perfectly reflecting
    Beckmann microfacet lobe of ``roughness`` α — Steinhurst's "Lambertian + one Phong lobe"."""
    scene = empty_box(width, height)
    scene["light"] = ceiling_light()
    scene["floor"]["bsdf"] = {
        "type": "blendbsdf",
        "weight": float(glossy),
        "diffuse": diffuse(FLOOR_DIFFUSE),
        "glossy": {
            "type": "roughconductor",
            "material": "none",
            "distribution": "beckmann",
            "alpha": float(roughness),
        },
    }
    scene["back"]["bsdf"] = {
        "type": "diffuse",
        "reflectance": {
            "type": "checkerboard",
            "color0": rgb(WHITE),
            "color1": rgb(np.array(WHITE) * 0.25),
            "to_uv": _uv_scale(8.0),
        },
    }
    return scene


def empty_box(width: int, height: int) -> dict:
    """Camera, ``path`` integrator and the five walls (unit-normal quads facing inwards)."""
    w, h, d = WIDTH, HEIGHT, DEPTH
    return {
        "type": "scene",
        "integrator": {"type": "path"},
        "sensor": _camera(width, height),
        "floor": wall((w / 2, 0, d / 2), (w / 2, 0, 0), (0, 0, d / 2), (0, 1, 0), WHITE),
        "ceiling": wall((w / 2, h, d / 2), (w / 2, 0, 0), (0, 0, d / 2), (0, -1, 0), WHITE),
        "back": wall((w / 2, h / 2, d), (w / 2, 0, 0), (0, h / 2, 0), (0, 0, -1), WHITE),
        "red_wall": wall((w, h / 2, d / 2), (0, h / 2, 0), (0, 0, d / 2), (-1, 0, 0), RED),
        "green_wall": wall((0, h / 2, d / 2), (0, h / 2, 0), (0, 0, d / 2), (1, 0, 0), GREEN),
    }


def ceiling_light() -> dict:
    """The 130 × 105 mm area light facing down, centred 0.5 mm below the ceiling."""
    centre = (WIDTH / 2, HEIGHT - LIGHT_DROP, DEPTH / 2)
    half_x, half_z = LIGHT_SIZE[0] / 2, LIGHT_SIZE[1] / 2
    return {
        "type": "rectangle",
        "to_world": frame(centre, (half_x, 0, 0), (0, 0, half_z), (0, -1, 0)),
        "bsdf": diffuse(LIGHT_REFLECTANCE),
        "emitter": {"type": "area", "radiance": rgb(LIGHT_RADIANCE)},
    }


def wall(centre, half_u, half_v, normal, reflectance) -> dict:
    """A diffuse quad (:func:`frame`) of the given RGB ``reflectance``."""
    return {
        "type": "rectangle",
        "to_world": frame(centre, half_u, half_v, normal),
        "bsdf": diffuse(reflectance),
    }


def frame(centre, half_u, half_v, normal):
    """The affine map of Mitsuba's unit ``rectangle``/``disk`` (local z = normal) onto the quad or
    disk with half-axes ``half_u``, ``half_v`` and unit ``normal``."""
    matrix = np.eye(4)
    matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = half_u, half_v, normal, centre
    return mi.ScalarTransform4f(matrix)


def _look_up(position):
    """A spot light's frame at ``position`` whose cone axis (local +z) points along +y."""
    return frame(position, (1, 0, 0), (0, 0, -1), (0, 1, 0))


def _camera(width: int, height: int) -> dict:
    return {
        "type": "perspective",
        "fov": CAMERA_FOV,
        "fov_axis": "y",
        "to_world": mi.ScalarTransform4f().look_at(
            origin=list(CAMERA_ORIGIN), target=list(CAMERA_TARGET), up=[0, 1, 0]
        ),
        # a box pixel filter, as the photonmap pipelines use, so that Mitsuba's reference
        # renders of these scenes are comparable pixel by pixel
        "film": {
            "type": "hdrfilm",
            "width": int(width),
            "height": int(height),
            "rfilter": {"type": "box"},
        },
    }


def _uv_scale(factor: float):
    return mi.ScalarTransform3f().scale([factor, factor])


def diffuse(reflectance) -> dict:
    """A Mitsuba ``diffuse`` BSDF dict of the given RGB ``reflectance`` (or grey value)."""
    return {"type": "diffuse", "reflectance": rgb(reflectance)}


def rgb(value) -> dict:
    """A Mitsuba ``rgb`` texture dict of ``value`` (three channels, or one grey value)."""
    return {
        "type": "rgb",
        "value": np.broadcast_to(np.asarray(value, dtype=np.float64), 3).tolist(),
    }
