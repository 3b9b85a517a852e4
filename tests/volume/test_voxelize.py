"""Stage S1 (voxelization): oracles 6–8 of spec seed-000-002 §5.2, and check_closed."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import photonmap  # noqa: F401  (selects the Mitsuba variant)
from photonmap.core.errors import ParameterError, SceneError
from photonmap.core.grid import GridBox
from photonmap.volume.voxelize import COLUMN_JITTER, check_closed, voxelize


def icosphere(level: int, radius: float, center) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a subdivided icosahedron (20·4^level triangles) on a sphere."""
    t = (1 + 5**0.5) / 2
    v = np.array(
        [
            [-1, t, 0],
            [1, t, 0],
            [-1, -t, 0],
            [1, -t, 0],
            [0, -1, t],
            [0, 1, t],
            [0, -1, -t],
            [0, 1, -t],
            [t, 0, -1],
            [t, 0, 1],
            [-t, 0, -1],
            [-t, 0, 1],
        ]
    )
    f = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ]
    )
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(level):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = v[unique].sum(axis=1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = len(v) + inverse.reshape(3, -1)
        v = np.concatenate([v, mid])
        a, b, c = f.T
        f = np.concatenate(
            [
                np.stack(corners, axis=1)
                for corners in (
                    [a, m[0], m[2]],
                    [b, m[1], m[0]],
                    [c, m[2], m[1]],
                    [m[0], m[1], m[2]],
                )
            ]
        )
    return v * radius + np.asarray(center, dtype=np.float64), f


def make_mesh(v: np.ndarray, f: np.ndarray, name: str = "icosphere") -> mi.Mesh:
    mesh = mi.Mesh(name, len(v), len(f))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(v.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(f.astype(np.uint32).ravel())
    params.update()
    return mesh


def mesh_volume(v: np.ndarray, f: np.ndarray) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6.0)


def sphere(center, radius) -> mi.Shape:
    return mi.load_dict({"type": "sphere", "center": list(center), "radius": float(radius)})


def distances(box: GridBox, center, s: int = 1) -> np.ndarray:
    """Distances to ``center`` of the (s·n)³ sample points ([z, y, x]; voxel centres if s = 1)."""
    c = (np.arange(box.n * s) + 0.5) / s
    x = box.lo[0] + box.h * (c + COLUMN_JITTER[0]) - center[0]
    y = box.lo[1] + box.h * (c + COLUMN_JITTER[1]) - center[1]
    z = box.lo[2] + box.h * c - center[2]
    return np.sqrt(z[:, None, None] ** 2 + y[None, :, None] ** 2 + x[None, None, :] ** 2)


def border_mask(b: np.ndarray) -> np.ndarray:
    """Voxels whose clamped 3×3×3 neighbourhood in ``b`` is not uniform (NumPy reference)."""
    n = b.shape[0]
    p = np.pad(b, 1, mode="edge")
    windows = [
        p[z : z + n, y : y + n, x : x + n] for z in range(3) for y in range(3) for x in range(3)
    ]
    return np.max(windows, axis=0) != np.min(windows, axis=0)


BOX = GridBox((0.0, 0.0, 0.0), 40.0, 40)  # voxel units = world units


def test_inside_test_matches_analytic_sphere():
    center, r = (20.3, 19.6, 20.9), 13.7
    b = voxelize(sphere(center, r), BOX, supersample=1).numpy()
    d = distances(BOX, center)
    assert set(np.unique(b)) == {0.0, 1.0}
    clear = np.abs(d - r) > 1e-3
    np.testing.assert_array_equal(b[clear], (d < r)[clear])


def test_inside_test_matches_icosphere_up_to_chordal_error():
    center, r = (20.3, 19.6, 20.9), 14.0
    v, f = icosphere(5, r, center)
    assert len(f) >= 20000
    b = voxelize(make_mesh(v, f), BOX, supersample=1).numpy()
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    r_in = np.min(np.abs(np.einsum("ij,ij->i", normals, v[f[:, 0]] - center)))
    d = distances(BOX, center)
    assert np.all(b[d < r_in - 1e-4] == 1)
    assert np.all(b[d > r + 1e-4] == 0)
    assert np.count_nonzero((d < r_in - 1e-4) | (d > r + 1e-4)) > 0.99 * d.size


@pytest.mark.parametrize("center", [(20.3, 19.6, 20.9), (4.2, 21.1, 3.3)])
def test_coverage_equals_numpy_reference(center):
    """Border-only 4× supersampling against an analytic NumPy evaluation; the second sphere is cut
    by the grid faces (crossings below the grid count, clamped neighbourhoods)."""
    r, s = 11.3, 4
    cov = voxelize(sphere(center, r), BOX).numpy()
    d = distances(BOX, center)
    fine = distances(BOX, center, s)
    n = BOX.n
    blocks = (fine < r).reshape(n, s, n, s, n, s).mean(axis=(1, 3, 5))
    ref = np.where(border_mask(d < r), blocks, (d < r).astype(float))
    near = (np.abs(fine - r) < 1e-3).reshape(n, s, n, s, n, s).sum(axis=(1, 3, 5))
    near = near + (np.abs(d - r) < 1e-3) * s**3
    assert np.all(np.abs(cov - ref) <= near / s**3)
    assert np.count_nonzero(near) < 0.01 * n**3


@pytest.mark.parametrize("kind", ["sphere", "icosphere"])
def test_coverage_values_and_volume(kind):
    center, r = (20.3, 19.6, 20.9), 16.0
    if kind == "sphere":
        shape, volume = sphere(center, r), 4.0 / 3.0 * np.pi * r**3
    else:
        v, f = icosphere(5, r, center)
        shape, volume = make_mesh(v, f), mesh_volume(v, f)
    cov = voxelize(shape, BOX).numpy()
    d = distances(BOX, center)
    np.testing.assert_array_equal(cov * 64, np.round(cov * 64))
    fractional = (cov > 0) & (cov < 1)
    assert np.all(np.abs(d[fractional] - r) < np.sqrt(3) / 2 + 1e-3)
    assert np.all(cov[d < r - 1.8] == 1) and np.all(cov[d > r + 1.8] == 0)
    assert abs(cov.sum() - volume) < 2e-5 * volume  # 9.8e-6 (sphere), 5.7e-7 (icosphere)


@pytest.mark.parametrize("r", [8.0, 12.7])
def test_border_only_equals_full_supersampling(r):
    center = (19.7, 20.2, 20.45)
    v, f = icosphere(4, r, center)
    for shape in (sphere(center, r), make_mesh(v, f)):
        border = voxelize(shape, BOX).numpy()
        full = voxelize(shape, BOX, full_supersample=True).numpy()
        np.testing.assert_array_equal(border, full)
        assert np.count_nonzero((border > 0) & (border < 1)) > 100


def test_thin_plate_is_missed_without_full_supersampling():
    """A2: a plate thinner than a voxel between two layers of centre samples."""
    to_world = mi.ScalarTransform4f().translate([20, 20.2, 20]).scale([8, 0.1, 8])
    plate = mi.load_dict({"type": "cube", "to_world": to_world})
    assert voxelize(plate, BOX).numpy().sum() == 0
    full = voxelize(plate, BOX, full_supersample=True).numpy()
    assert full.sum() == 16 * 16 * 16 / 64  # one layer of fine samples (y = 20.125) inside


@pytest.mark.parametrize("corner", [10.0, 10.125])
def test_aligned_cube_has_exact_volume(corner):
    """Mitsuba's cube (split vertices); faces on voxel faces, then through fine sample centres."""
    to_world = mi.ScalarTransform4f().translate([corner + 10.0] * 3).scale(10.0)
    cube = mi.load_dict({"type": "cube", "to_world": to_world})
    check_closed(cube, "cube")
    cov = voxelize(cube, BOX).numpy()
    assert cov.sum() == 8000.0
    if corner == 10.0:
        assert set(np.unique(cov)) == {0.0, 1.0}


def test_open_mesh_raises_scene_error_naming_it():
    v, f = icosphere(2, 5.0, (20, 20, 20))
    check_closed(make_mesh(v, f), "closed")
    with pytest.raises(SceneError, match="'leaky_ball'.*not watertight"):
        check_closed(make_mesh(v, f[1:]), "leaky_ball")
    with pytest.raises(SceneError, match="'doubled'"):
        check_closed(make_mesh(v, np.concatenate([f, f[:1]])), "doubled")


@pytest.mark.parametrize("kind", ["rectangle", "disk", "cylinder"])
def test_open_shape_types_raise(kind):
    with pytest.raises(SceneError, match=f"(?i)'window'.*{kind}"):
        check_closed(mi.load_dict({"type": kind}), "window")


def test_analytic_sphere_is_closed():
    check_closed(sphere((0, 0, 0), 1.0), "ball")


@pytest.mark.parametrize("supersample", [0, 9, 2.5])
def test_bad_supersample_raises(supersample):
    with pytest.raises(ParameterError):
        voxelize(sphere((20, 20, 20), 5), BOX, supersample=supersample)


def test_shape_outside_the_grid_gives_zero_coverage():
    cov = voxelize(sphere((100, 100, 100), 5), BOX)
    assert dr.all(cov.array == 0)
