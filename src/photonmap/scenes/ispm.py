"""Cornell-box scenes of Yao (2011) Ch. 5 for the ``screen`` pipeline (Figs 5.1–5.7).

All three reuse the Cornell box of :mod:`.cornell` (metres, the published 556 × 548.8 × 559.2 mm
box and camera), at the thesis's 1024 × 768, lit by a spot light 10 mm under the ceiling centre
aimed straight down (the thesis renders its Cornell box from a spot light's G-buffer, §3.1),
with the thesis's two recorded bounces as the file's ``path`` ``max_depth`` 4:

- :func:`cornell_ispm` — the Cornell box with the classic short and tall blocks (Fig 5.1; 34
  triangles against the thesis's 30).
- :func:`cornell_glass_sphere` — a glass sphere (η = 1.5) floating 70 mm above the floor under the
  spot: its refractive caustic focuses 1.5 R from the centre, just above the floor (Figs 5.4/5.5).
- :func:`cornell_mesh` — a diffuse procedurally generated watertight mesh (a trefoil torus-knot
  tube, :func:`.meshes.torus_knot`) of a configurable triangle count standing in for the Happy
  Buddha (50,020), Chinese dragon (26,082) and bunny (32,134) rows of Table 1.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from . import cornell
from .meshes import to_mitsuba_mesh, torus_knot

SPOT_POSITION = (cornell.WIDTH / 2, cornell.HEIGHT - 0.010, cornell.DEPTH / 2)
SPOT_CUTOFF, SPOT_BEAM = 60.0, 50.0  # degrees
SPOT_INTENSITY = (0.60, 0.52, 0.42)  # W/sr, warm white
BLOCK_WHITE = cornell.WHITE
# Classic Cornell blocks (published data, mm): centre of the base, side, height, rotation about y
SHORT_BLOCK = ((185.5, 169.0), 165.0, 165.0, -16.9)
TALL_BLOCK = ((368.5, 351.3), 165.0, 330.0, 17.2)
SPHERE_RADIUS = 0.1
SPHERE_CENTER = (cornell.WIDTH / 2, 0.17, cornell.DEPTH / 2)


def cornell_ispm(width: int = 1024, height: int = 768) -> dict:
    """The Cornell box with the short and tall blocks, lit by a spot light (Yao Fig 5.1)."""
    scene = _box_with_spot(width, height)
    scene["short_block"] = _block(*SHORT_BLOCK)
    scene["tall_block"] = _block(*TALL_BLOCK)
    return scene


def cornell_glass_sphere(width: int = 1024, height: int = 768, ior: float = 1.5) -> dict:
    """A glass sphere (radius 100 mm, η = ``ior``) under the spot: a refractive caustic on the
    floor (Yao's glass sphere row of Table 1)."""
    scene = _box_with_spot(width, height)
    scene["glass_sphere"] = {
        "type": "sphere",
        "center": list(SPHERE_CENTER),
        "radius": SPHERE_RADIUS,
        "bsdf": {"type": "dielectric", "int_ior": float(ior), "ext_ior": 1.0},
    }
    return scene


def cornell_mesh(width: int = 1024, height: int = 768, triangles: int = 20000) -> dict:
    """A diffuse watertight torus-knot mesh of about ``triangles`` faces, 350 mm across, standing
    in the box (the Buddha / dragon / bunny rows of Yao Table 1)."""
    vertices, faces = torus_knot(int(triangles))
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = np.array([cornell.WIDTH / 2, 0.2, cornell.DEPTH / 2])
    vertices = (vertices - 0.5 * (lo + hi)) * (0.35 / np.max(hi - lo)) + centre
    bsdf = mi.load_dict(cornell.diffuse((0.75, 0.75, 0.75)))
    scene = _box_with_spot(width, height)
    scene["mesh"] = to_mitsuba_mesh("mesh", vertices, faces, bsdf=bsdf)
    return scene


def _box_with_spot(width: int, height: int) -> dict:
    scene = cornell.empty_box(width, height)
    # the thesis's transport: direct light and two recorded indirect bounces (B = 2), which is
    # Mitsuba's max_depth 4 (the screen method's default B is the file's max_depth - 2)
    scene["integrator"] = {"type": "path", "max_depth": 4}
    scene["spot"] = {
        "type": "spot",
        "to_world": cornell.frame(SPOT_POSITION, (1, 0, 0), (0, 0, 1), (0, -1, 0)),
        "cutoff_angle": SPOT_CUTOFF,
        "beam_width": SPOT_BEAM,
        "intensity": cornell.rgb(SPOT_INTENSITY),
    }
    return scene


def _block(base_mm, side_mm: float, height_mm: float, angle_deg: float) -> dict:
    """A white box (Mitsuba ``cube``, 12 triangles) standing on the floor."""
    mm = cornell.MM
    to_world = (
        mi.ScalarTransform4f()
        .translate([base_mm[0] * mm, height_mm * mm / 2, base_mm[1] * mm])
        .rotate([0, 1, 0], angle_deg)
        .scale([side_mm * mm / 2, height_mm * mm / 2, side_mm * mm / 2])
    )
    return {"type": "cube", "to_world": to_world, "bsdf": cornell.diffuse(BLOCK_WHITE)}
