"""Box grids: ``n_x × n_y × n_z`` cubic voxels fitted to the media's bounding
box, ``grid = N`` voxels along its longest side (``core.grid.GridBox.fitted``).

Oracles: the grid's extent and voxel size from the bounding box; the flat index ``(k·n_y + j)·n_x
+ i`` and trilinear reads against NumPy / SciPy; the memory estimate proportional to
``n_x·n_y·n_z``; a sphere voxelized on a box grid against its analytic inside test; the octree of a
box grid equal to the octree of the cube it pads to (its range pyramid pads by edge replication
either way); and a fog-only 10 × 5 × 4 box against Mitsuba ``volpath`` at full depth, lit by a
point light and by a constant environment (photons through the box's unequal faces).
(The mipmap pyramid and its filter on box grids: ``test_adaptive_reconstruction.py``.)
"""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

import mitsuba_reference
from photonmap import VolumePipeline
from photonmap.core.arrays import to_jit
from photonmap.core.errors import ParameterError
from photonmap.core.grid import GridBox, flat_index, pack, trilinear_packed, voxel_of
from photonmap.core.image import block_means
from photonmap.volume.octree import build_octree
from photonmap.volume.params import check_grid, memory_estimate
from photonmap.volume.scene import from_mitsuba
from photonmap.volume.voxelize import voxelize

T = mi.ScalarTransform4f
LONG_BOX = (np.array([-5.0, -2.5, -2.0]), np.array([5.0, 2.5, 2.0]))  # the issue's 10 × 5 × 4

# ------------------------------------------------------------------------------------------------
# The grid box


def test_fitted_box_has_n_voxels_along_the_longest_side_and_cubic_voxels():
    box = GridBox.fitted(*LONG_BOX, 40, margin=0.0)
    assert box.dims == (40, 20, 16) and box.n == 40 and box.h == 0.25
    np.testing.assert_allclose(box.lo, LONG_BOX[0])
    np.testing.assert_allclose(box.hi, LONG_BOX[1])
    np.testing.assert_allclose(box.extent / np.array(box.dims), box.h)  # cubic voxels
    assert box.shape == (16, 20, 40) and box.voxels == 40 * 20 * 16
    # with a margin: h = extent/(n − 2·margin), the fewest voxels that hold extent + margins
    box = GridBox.fitted(*LONG_BOX, 40, margin=2.0)
    assert box.h == pytest.approx(10.0 / 36) and box.dims == (40, 22, 19)
    assert np.all(np.array(box.lo) + 2 * box.h <= LONG_BOX[0] + 1e-9)
    assert np.all(box.hi - 2 * box.h >= LONG_BOX[1] - 1e-9)
    # a thin slab keeps at least 4 voxels; a cube is GridBox.around's cube
    assert GridBox.fitted([0, 0, 0], [10, 0.1, 10], 32, margin=0.0).dims == (32, 4, 32)
    cube = ([-1.0, 0.0, 2.0], [1.0, 2.0, 4.0])
    assert GridBox.fitted(*cube, 24) == GridBox.around(*cube, 24)


def test_bad_dims_are_refused():
    with pytest.raises(ParameterError, match="largest = n"):
        GridBox((0.0, 0.0, 0.0), 1.0, 16, (8, 8, 8))
    with pytest.raises(ParameterError, match="dims must be three integers in 4..n"):
        GridBox((0.0, 0.0, 0.0), 1.0, 16, (16, 3, 8))


def long_fog_box(light: dict, width: int = 8, height: int = 6) -> dict:
    """A 10 × 5 × 4 box of coloured fog (``null`` boundary, isotropic) with ``light``, seen from
    the front and above."""
    return {
        "type": "scene",
        "fog": {
            "type": "homogeneous",
            "sigma_t": {"type": "rgb", "value": [0.3, 0.45, 0.7]},
            "albedo": {"type": "rgb", "value": [0.95, 0.85, 0.7]},
        },
        "fog_box": {
            "type": "cube",
            "to_world": T().scale([5.0, 2.5, 2.0]),
            "bsdf": {"type": "null"},
            "interior": {"type": "ref", "id": "fog"},
        },
        "light": light,
        "sensor": {
            "type": "perspective",
            "fov": 50.0,
            "to_world": T().look_at(origin=[1.0, 3.0, 13.0], target=[0, -0.3, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}},
        },
    }


POINT = {"type": "point", "position": [-2.0, 6.0, 1.0], "intensity": 60.0}
SKY = {"type": "constant", "radiance": {"type": "rgb", "value": [0.6, 0.7, 1.0]}}


def test_a_scene_gets_the_box_grid_of_its_fog():
    """The fog box is the grid's box; so is an explicit ``grid_bbox``."""
    scene = mi.load_dict(long_fog_box(POINT))
    assert from_mitsuba(scene, grid=40).box == GridBox.fitted(*LONG_BOX, 40, margin=0.0)
    given = from_mitsuba(scene, grid=30, grid_bbox=([-6, -3, -3], [6, 3, 3])).box  # grid_bbox
    assert given.dims == (30, 15, 15) and given.h == pytest.approx(0.4)


# ------------------------------------------------------------------------------------------------
# Index math against NumPy


def test_flat_index_is_numpys_zyx_ravel():
    dims = (7, 5, 3)  # (n_x, n_y, n_z): arrays of shape (3, 5, 7)
    rng = np.random.default_rng(0)
    i, j, k = (rng.integers(0, c, 200) for c in dims)
    flat = flat_index(mi.UInt32(i), mi.UInt32(j), mi.UInt32(k), dims)
    assert np.array_equal(np.array(flat), np.ravel_multi_index((k, j, i), dims[::-1]))
    back = voxel_of(dr.arange(mi.UInt32, 105), dims)
    expected = np.unravel_index(np.arange(105), dims[::-1])[::-1]
    for ours, ref in zip(back, expected, strict=True):
        assert np.array_equal(np.array(ours), ref)


def test_trilinear_reads_of_a_box_grid_match_scipy():
    """Samples at voxel centres, clamp-to-edge (Pfeuti §3.1.1), on a 13 × 9 × 5 grid of five
    channels (two packets), at points inside and outside the grid."""
    rng = np.random.default_rng(1)
    shape = (5, 9, 13)
    grid = rng.uniform(size=(*shape, 5)).astype(np.float32)
    points = rng.uniform(-1.0, 1.0, (3, 500)) * 0.6 + 0.5
    points *= np.array([13.0, 9.0, 5.0])[:, None] * 1.3  # (x, y, z), some beyond the faces
    ours = trilinear_packed(pack([grid], (13, 9, 5)), (13, 9, 5), 2, mi.Point3f(*points))
    ours = np.concatenate([np.array(v).T for v in ours], axis=1)[:, :5]
    coords = points[::-1] - 0.5  # (z, y, x) index coordinates of the voxel-centre samples
    for c in range(5):
        ref = map_coordinates(grid[..., c], coords, order=1, mode="nearest")
        np.testing.assert_allclose(ours[:, c], ref, rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------------------------------------
# Memory


def test_memory_estimate_scales_with_the_voxel_count():
    total, per_voxel = memory_estimate((40, 20, 16), photons=0, threads=2)
    assert total == per_voxel * 40 * 20 * 16
    assert memory_estimate((40, 20, 16), threads=2)[1] == memory_estimate(40, threads=2)[1]
    available = per_voxel * 40 * 20 * 16 + 1024
    check_grid(40, available=available, dims=(40, 20, 16))  # the box fits ...
    with pytest.raises(ParameterError, match=r"40×20×16 voxels.*grid <= 39 fits"):
        check_grid(40, available=available - 2048, dims=(40, 20, 16))
    with pytest.raises(ParameterError, match="40³ voxels"):
        check_grid(40, available=available)  # ... the cube does not


# ------------------------------------------------------------------------------------------------
# Voxelization and octree on a box grid


def test_sphere_voxelized_on_a_box_grid():
    """The centre samples are the analytic inside test; coverage sums to the sphere's volume."""
    box = GridBox.fitted([-2.0, -1.0, -0.5], [2.0, 1.0, 0.5], 32, margin=0.0)
    centre, radius = np.array([0.3, -0.1, 0.05]), 0.45
    sphere = mi.load_dict({"type": "sphere", "center": centre.tolist(), "radius": radius})
    binary = np.array(voxelize(sphere, box, supersample=1))
    assert binary.shape == box.shape == (8, 16, 32)
    k, j, i = np.indices(box.shape)
    x = box.to_world(np.stack([i, j, k], -1) + 0.5)
    np.testing.assert_array_equal(binary, np.linalg.norm(x - centre, axis=-1) < radius)
    coverage = np.array(voxelize(sphere, box))
    assert coverage.sum() * box.h**3 == pytest.approx(4 / 3 * np.pi * radius**3, rel=0.01)


def test_octree_of_a_box_grid_is_that_of_its_padded_cube():
    rng = np.random.default_rng(3)
    shape = (12, 20, 32)
    z, y, x = np.indices(shape)
    ior = 1.0 + 0.2 * (np.hypot(x - 20.0, y - 9.0) < 6) * (z < 7) + 1e-4 * rng.random(shape)
    cube = np.pad(ior, [(0, 32 - s) for s in shape], mode="edge")

    def tensor(a):
        return to_jit(mi.TensorXf, a)

    box, padded = build_octree(tensor(ior)), build_octree(tensor(cube))
    for a, b in ((box.level, padded.level), (box.step_limit, padded.step_limit)):
        np.testing.assert_array_equal(np.array(a)[..., 0], np.array(b)[:12, :20, :32, 0])
    assert len(np.unique(np.array(box.level))) > 2


# ------------------------------------------------------------------------------------------------
# A 10 × 5 × 4 fog box against volpath (full depth)

WIDTH, HEIGHT = 64, 48
# |brightness ratio − 1| and the relative RMSE of 4×4-block means; measured: point 1.035 / 0.087
# (grid 96 and 2¹⁸ photons: 1.013 / 0.052; a grid cube of side 10, the fog in a fifth of it:
# 1.038 / 0.097), sky 0.996 / 0.0108
RATIO_BOUND = {"point": 0.055, "sky": 0.01}
BLOCK_BOUND = {"point": 0.13, "sky": 0.02}


@pytest.mark.parametrize("light", ["point", "sky"])
def test_long_fog_box_matches_volpath(light):
    """Grid 48 (48 × 24 × 20 voxels over the fog box), 2¹⁶ photons, multiple scattering;
    volpath at full depth, 512 spp. The sky's photons enter through the box's faces in
    proportion to their projected areas (``emit.environment_photons``)."""
    scene = long_fog_box(POINT if light == "point" else SKY, WIDTH, HEIGHT)
    with dr.scoped_set_flag(dr.JitFlag.Debug, False):  # volpath's film under Debug: DESIGN.md
        integrator = mi.load_dict({"type": "volpath", "max_depth": -1})
        reference = mitsuba_reference.render(mi.load_dict(scene), integrator=integrator, spp=512)
    reference = reference[..., :3]
    pipe = VolumePipeline(scene, grid=48, photons=2**16, phase_k=0.0, table=0.0, spp=4)
    assert pipe.world.box.dims == (48, 24, 20)
    image = np.array(pipe.render())
    if light == "sky":  # the background seen beside the box is the sky itself in both
        inside = np.any(np.abs(image - np.array([0.6, 0.7, 1.0])) > 1e-3, axis=-1)
        assert 0.2 < inside.mean() < 0.9
    ratio = image.mean() / reference.mean()
    a, b = block_means(image), block_means(reference)
    error = np.sqrt(np.mean((a - b) ** 2)) / b.mean()
    print(f"{light}: ratio {ratio:.4f}, block error {error:.4f}")
    assert abs(ratio - 1) < RATIO_BOUND[light], ratio
    assert error < BLOCK_BOUND[light], error
