"""Regenerate the procedural meshes of ``examples/``: ``gem.ply`` (glass_mesh_glints.xml) and
``lamp_shade.ply`` (veach_lamp.xml). Needs only NumPy and SciPy:

    python examples/meshes/make_meshes.py

``gem.ply``: a round brilliant-style gem, the convex hull of its table, crown, girdle and
pavilion rings (flat facets; the XML asks Mitsuba for face normals). Its pavilion is steep, so
much of the light that enters is totally internally reflected several times before it leaves:
the glints need paths of more than 8 segments. Girdle radius 1, lying on its table (culet up) on
y = 0.

``lamp_shade.ply``: an open hemispherical bowl (radius 1, centre at the origin, opening upward:
y ≤ 0), a single surface, for a two-sided metal reflector around a light.

``pool_water.ply`` (pool.xml): a water surface, the heightfield of a few travelling waves over
the square [−1.5, 1.5]² about y = 0 (peak height 0.067), 64 × 64 cells, faces counter-clockwise
seen from above (normals up, into the air); no normals in the file, so Mitsuba interpolates its
vertex normals and the surface refracts smoothly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull

HERE = Path(__file__).resolve().parent


def ring(n: int, radius: float, y: float, offset: float = 0.0) -> np.ndarray:
    """``n`` points on a horizontal circle of ``radius`` at height ``y``, the first at angle
    ``offset`` (radians)."""
    a = offset + 2 * np.pi * np.arange(n) / n
    return np.stack([radius * np.cos(a), np.full(n, y), radius * np.sin(a)], axis=-1)


def convex_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The convex hull of ``points`` as a triangle mesh with outward (counter-clockwise) faces."""
    hull = ConvexHull(points)
    used = np.unique(hull.simplices)
    remap = np.full(len(points), -1)
    remap[used] = np.arange(len(used))
    vertices, faces = points[used], remap[hull.simplices]
    v0, v1, v2 = (vertices[faces[:, i]] for i in range(3))
    flip = np.einsum("ij,ij->i", np.cross(v1 - v0, v2 - v0), hull.equations[:, :3]) < 0
    faces[flip] = faces[flip][:, ::-1]
    return vertices, faces


def gem(sides: int = 16, table: float = 0.55, crown_deg: float = 34.0,
        pavilion_deg: float = 41.0, girdle: float = 0.03, tilt_deg: float = 180.0):  # fmt: skip
    """A brilliant-style gem (girdle radius 1): ``sides``-fold girdle, half as many table and
    crown/pavilion facet rings (offset by half a step, so the hull cuts kite facets), the crown
    at ``crown_deg`` and the pavilion at ``pavilion_deg`` to the girdle plane; tilted by
    ``tilt_deg`` about the x axis (180: upside down, on its table) and lifted so that its
    lowest point is on y = 0."""
    crown = np.tan(np.radians(crown_deg)) * (1 - table)
    depth = np.tan(np.radians(pavilion_deg))
    half = sides // 2
    step = np.pi / half
    points = np.concatenate([
        ring(half, table, girdle / 2 + crown),  # table
        ring(half, (1 + table) / 2, girdle / 2 + crown / 2, step / 2),  # crown main facets
        ring(sides, 1.0, girdle / 2, step / 4),  # girdle
        ring(sides, 1.0, -girdle / 2, step / 4),
        ring(half, 0.5, -girdle / 2 - depth / 2, step / 2),  # pavilion main facets
        [[0.0, -girdle / 2 - depth, 0.0]],  # culet
    ])  # fmt: skip
    t = np.radians(tilt_deg)
    rot = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    vertices, faces = convex_mesh(points @ rot.T)
    vertices[:, 1] -= vertices[:, 1].min()
    return vertices, faces


def bowl(rings: int = 16, sides: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """An open hemisphere of radius 1 (y ≤ 0, rim at y = 0): ``rings`` latitude bands from the
    rim to a pole vertex at the bottom, ``sides`` segments around; faces wind counter-clockwise
    seen from inside (normals point into the bowl, up at the bottom)."""
    theta = np.linspace(0.0, np.pi / 2, rings + 1)[:-1]  # 0 at the rim
    a = 2 * np.pi * np.arange(sides) / sides
    r, y = np.cos(theta)[:, None], -np.sin(theta)[:, None]
    grid = np.stack([r * np.cos(a), np.broadcast_to(y, (rings, sides)), r * np.sin(a)], axis=-1)
    vertices = np.concatenate([grid.reshape(-1, 3), [[0.0, -1.0, 0.0]]])
    faces = []
    for i in range(rings - 1):
        for j in range(sides):
            a0, a1 = i * sides + j, i * sides + (j + 1) % sides
            b0, b1 = a0 + sides, a1 + sides
            faces += [(a0, a1, b1), (a0, b1, b0)]
    pole, last = len(vertices) - 1, (rings - 1) * sides
    faces += [(last + j, last + (j + 1) % sides, pole) for j in range(sides)]
    faces = np.array(faces)
    v0, v1, v2 = (vertices[faces[:, i]] for i in range(3))
    inward = -(v0 + v1 + v2) / 3  # the centre of the sphere is the origin
    flip = np.einsum("ij,ij->i", np.cross(v1 - v0, v2 - v0), inward) < 0
    faces[flip] = faces[flip][:, ::-1]
    return vertices, faces


def water(cells: int = 64, half: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """The heightfield ``y = h(x, z)`` of three waves (wavelengths 1.1, 0.7 and 0.45, amplitudes
    0.03, 0.025 and 0.012: curvatures up to about 6, so the waves focus light about 1 below) on
    a ``cells`` × ``cells`` grid over ``[−half, half]²``, two triangles a cell, counter-clockwise
    seen from above."""
    t = np.linspace(-half, half, cells + 1)
    x, z = np.meshgrid(t, t, indexing="xy")
    y = np.zeros_like(x)
    waves = (((0.8, 0.6), 1.1, 0.03, 0.0), ((-0.3, 0.95), 0.7, 0.025, 1.3),
             ((0.95, -0.3), 0.45, 0.012, 2.1))  # (direction, wavelength, amplitude, phase)
    for (kx, kz), wavelength, amplitude, phase in waves:
        y += amplitude * np.sin(2 * np.pi * (kx * x + kz * z) / wavelength + phase)
    vertices = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="xy")
    a = (j * (cells + 1) + i).ravel()  # the cell's corner at (x_i, z_j)
    b, c, d = a + 1, a + cells + 1, a + cells + 2  # (x_i+1, z_j), (x_i, z_j+1), (x_i+1, z_j+1)
    # seen from above (+y) with x right and z down, counter-clockwise is a → c → b
    faces = np.concatenate([np.stack([a, c, b], -1), np.stack([b, c, d], -1)])
    return vertices, faces


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A binary little-endian PLY of float32 positions and triangles."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(vertices)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    tri = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", 3)])
    tri["n"], tri["i"] = 3, faces
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(np.asarray(vertices, "<f4").tobytes())
        f.write(tri.tobytes())


def main() -> None:
    for name, (vertices, faces) in {"gem.ply": gem(), "lamp_shade.ply": bowl(),
                                 "pool_water.ply": water()}.items():
        write_ply(HERE / name, vertices, faces)
        print(f"{name}: {len(vertices)} vertices, {len(faces)} triangles")


if __name__ == "__main__":
    main()
