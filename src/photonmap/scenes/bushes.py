"""The "bushes" variant of the Cornell box (Steinhurst 2007 §5.4, Fig 5.5, Table 5.1: "geometrically
modeled bushes with simple diffuse material properties"): many small
occluders, the role the Sponza atrium plays in Chapter 3 — final-gather rays of neighbouring
pixels scatter over many leaves, so their photon gathers are far less coherent than in the bare
box. The 3DPlants.com models are not available; each bush here is ``leaves`` small two-sided
diffuse quads (green, 24 mm) at seeded random positions and orientations inside a sphere of
radius 110 mm.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import columns
from .cornell import DEPTH, MM, WIDTH, ceiling_light, diffuse, empty_box

LEAF = 12.0 * MM  # half edge of a leaf quad
CROWN = 110.0 * MM  # radius of a bush's crown
LEAF_GREEN = (0.2, 0.5, 0.12)


def cornell_bushes(
    width: int = 512, height: int = 512, bushes: int = 2, leaves: int = 1500, seed: int = 0
) -> dict:
    """The Cornell box with the ceiling light and ``bushes`` bushes of ``leaves`` leaves each,
    standing on the floor in a row from left to right."""
    scene = empty_box(width, height)
    scene["light"] = ceiling_light()
    rng = np.random.default_rng(seed)
    for b in range(bushes):
        x = WIDTH * (b + 1) / (bushes + 1)
        centre = np.array([x, CROWN + 10 * MM, DEPTH * 0.5])
        scene[f"bush_{b}"] = _bush(centre, leaves, rng, f"bush_{b}")
    return scene


def _bush(centre: np.ndarray, leaves: int, rng: np.random.Generator, name: str) -> mi.Mesh:
    """``leaves`` random quads (two triangles each) inside a sphere around ``centre``."""
    direction = rng.normal(size=(leaves, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    at = centre + direction * CROWN * rng.random((leaves, 1)) ** (1 / 3)
    u = rng.normal(size=(leaves, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(u, rng.normal(size=(leaves, 3)))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    corners = [at + LEAF * (su * u + sv * v) for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    vertices = np.stack(corners, axis=1).reshape(-1, 3).astype(np.float32)
    base = 4 * np.arange(leaves)[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "twosided", "bsdf": diffuse(LEAF_GREEN)})
    mesh = mi.Mesh(name, len(vertices), len(faces), props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f(*columns(mi.Float, vertices)))
    params["faces"] = dr.ravel(mi.Vector3u(*faces.astype(np.uint32).T))
    params.update()
    return mesh
