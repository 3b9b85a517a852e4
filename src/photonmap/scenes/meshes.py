"""Procedural watertight meshes for the MESH benchmark scene.

The sweeps of Sun et al. 2008 Table 1 need one closed mesh at 10k/20k/40k/80k triangles. :func:`torus_knot`
builds a (p, q) torus-knot tube in NumPy: ``rings × sides`` vertices on a torus-topology grid, two
triangles per quad, so every edge is shared by exactly two faces and all faces wind
counter-clockwise seen from outside (outward normals).
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from ..core.errors import ParameterError


def _knot_curve(t: np.ndarray, p: int, q: int, radius: float):
    """Torus-knot centre line on the torus (major ``radius``, minor 1) and the torus normal there.

    The torus normal is perpendicular to the curve (the curve lies on the torus), never vanishes
    and is periodic, so it is a seam-free frame vector for the tube.
    """
    ring = radius + np.cos(q * t)
    c = np.stack([ring * np.cos(p * t), ring * np.sin(p * t), -np.sin(q * t)], axis=-1)
    n = np.stack(
        [np.cos(q * t) * np.cos(p * t), np.cos(q * t) * np.sin(p * t), -np.sin(q * t)], axis=-1
    )
    return c, n


def torus_knot(
    triangles: int = 20000, p: int = 2, q: int = 3, radius: float = 2.0, tube: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube of radius ``tube`` around the (p, q) torus knot with about ``triangles`` faces.

    The centre line lies on a torus of major ``radius`` and minor radius 1 around the z axis, so
    the mesh spans ``±(radius + 1 + tube)`` in x and y and ``±(1 + tube)`` in z. Rings are spaced
    evenly in arc length and the ring/side counts keep the quads near square. The defaults (a
    trefoil with tube 0.5) do not self-intersect: strands stay ≥ 1.66 apart and the curvature radius
    is ≥ 1.43. Returns ``(vertices (V, 3) float64, faces (F, 3) uint32)``.
    """
    if triangles < 64:
        raise ParameterError(f"torus_knot needs at least 64 triangles, got {triangles}")
    # Arc-length table of the centre line, to space the rings evenly along it.
    t_fine = np.linspace(0.0, 2.0 * np.pi, 8192, endpoint=False)
    c_fine, _ = _knot_curve(t_fine, p, q, radius)
    seg = np.linalg.norm(np.roll(c_fine, -1, axis=0) - c_fine, axis=1)
    s_fine = np.concatenate([[0.0], np.cumsum(seg)])
    length = s_fine[-1]

    sides = max(6, round(np.sqrt(0.5 * triangles * 2.0 * np.pi * tube / length)))
    rings = max(3, round(0.5 * triangles / sides))
    s = np.arange(rings) * (length / rings)
    t = np.interp(s, s_fine, np.append(t_fine, 2.0 * np.pi))

    c, normal = _knot_curve(t, p, q, radius)
    eps = 1e-5
    tangent = _knot_curve(t + eps, p, q, radius)[0] - _knot_curve(t - eps, p, q, radius)[0]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)

    phi = np.arange(sides) * (2.0 * np.pi / sides)
    offset = (
        np.cos(phi)[None, :, None] * normal[:, None]
        + np.sin(phi)[None, :, None] * binormal[:, None]
    )
    vertices = (c[:, None] + tube * offset).reshape(-1, 3)

    # Quad (i, j) → corners a = (i, j), b = (i, j+1), c = (i+1, j+1), d = (i+1, j). With j along
    # the binormal side of the normal, (b − a) × (c − a) ≈ ∂φ × ∂s points outward.
    i, j = np.meshgrid(np.arange(rings), np.arange(sides), indexing="ij")
    i1, j1 = (i + 1) % rings, (j + 1) % sides
    a, b, cc, d = i * sides + j, i * sides + j1, i1 * sides + j1, i1 * sides + j
    faces = np.stack([np.stack([a, b, cc], -1), np.stack([a, cc, d], -1)], axis=2)
    return vertices, faces.reshape(-1, 3).astype(np.uint32)


def to_mitsuba_mesh(name: str, vertices, faces, **objects) -> mi.Mesh:
    """A Mitsuba mesh from NumPy ``vertices`` (V, 3) and ``faces`` (F, 3).

    ``objects`` are instantiated Mitsuba objects attached to the shape, e.g.
    ``bsdf=mi.load_dict({"type": "dielectric"})``, ``interior=medium``, ``exterior=fog``.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float32)
    faces = np.ascontiguousarray(faces, dtype=np.uint32)
    props = mi.Properties()
    for key, obj in objects.items():
        props[key] = obj
    mesh = mi.Mesh(name, len(vertices), len(faces), props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(vertices.ravel())
    params["faces"] = mi.UInt32(faces.ravel())
    params.update()
    return mesh
