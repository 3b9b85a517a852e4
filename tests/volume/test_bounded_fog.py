"""Fog where the scene puts it: the interior of its boundary shapes only.

A ``null``- or ``thindielectric``-BSDF closed shape with an interior medium is a fog volume; the
volume method voxelizes it like a refractive object (S1, fractional coverage) and maps coverage to
σ_s and κ (S2), so that outside it σ = 0 (vacuum, or the sensor's medium). The octree splits its
nodes at the fog's boundary (with one voxel of trilinear support), or the marcher's steps would
cross the boundary with κ read on the wrong side (eq (6) of Sun et al. 2008 §4.4).

**Against Mitsuba.** A fog-only box 6 × 3 × 3 in a grid cube of side 6, lit by a point light above,
against ``volpath`` at ``max_depth = 2``: Mitsuba counts scattering events and surface bounces as
depth but not the crossings of a ``null`` boundary, so depth 1 is black here (the point light is
not seen) and depth 2 is direct light plus single scattering, what Sun's method computes (depth 3
is 1.42× brighter, depth 32 1.76×). Measured (grid 48, 64 × 48, 64² photons, 4 spp, volpath 256
spp): brightness ratio 1.012, relative RMSE of 4×4-block means 0.042 (0.024 of it is the
reference's own noise: 256 against 2048 spp). Mutations (by hand, then reverted): fog filling the
whole grid (the behaviour before scene.py) gives ratio 1.58 and error 2.22, and fails
the per-voxel test; an octree that ignores the fog's boundary (pipeline.py: steps across it read
κ outside the fog, so photons cross the box unattenuated) 1.70 and 1.01; a boundary without the
voxel of trilinear support (octree.py) 1.067 and 0.108 (fluence in the box 12 % too high).
"""

import numpy as np
import pytest

from photonmap import VolumePipeline, mi
from photonmap.core.errors import ParameterError, SceneError
from photonmap.core.image import block_means
from photonmap.volume.scene import from_mitsuba

# ------------------------------------------------------------------------------------------------
# Per-voxel σ against analytic boxes

GRID = 16  # the grid box is [0, 16]³: one voxel is one world unit
BOX_A = (np.array([2.25, 3.5, 2.75]), np.array([9.5, 12.25, 11.0]))  # faces on quarter voxels,
BOX_B = (np.array([11.0, 2.5, 4.25]), np.array([14.75, 6.0, 9.5]))  # so coverage is exact at s=4
SPHERE = (np.array([6.0, 8.0, 7.0]), 2.5)  # a clear glass ball inside box A
MEDIUM_A = {"sigma_t": [0.5, 1.0, 0.25], "albedo": [0.8, 0.5, 0.2], "scale": 2.0}
MEDIUM_B = {"sigma_t": [0.3, 0.3, 0.3], "albedo": [0.5, 0.5, 0.5], "scale": 1.0}
MEDIUM_C = {"sigma_t": [0.7, 0.7, 0.7], "albedo": [0.1, 0.1, 0.1], "scale": 1.0}


def rgb(v) -> dict:
    return {"type": "rgb", "value": list(v)}


def homogeneous(m) -> dict:
    return {
        "type": "homogeneous",
        "sigma_t": rgb(m["sigma_t"]),
        "albedo": rgb(m["albedo"]),
        "scale": m["scale"],
    }


def coefficients(m) -> tuple[np.ndarray, np.ndarray]:
    """(σ_s, κ) as Mitsuba defines them: σ_t = scale·sigma_t, σ_s = albedo·σ_t."""
    kappa = m["scale"] * np.asarray(m["sigma_t"])
    return np.asarray(m["albedo"]) * kappa, kappa


def cube(box, bsdf: str, interior) -> dict:
    lo, hi = box
    to_world = (
        mi.ScalarTransform4f()
        .translate((0.5 * (lo + hi)).tolist())
        .scale((0.5 * (hi - lo)).tolist())
    )
    return {"type": "cube", "to_world": to_world, "bsdf": {"type": bsdf}, "interior": interior}


def camera(origin, target, width=8, height=6, fov=45.0) -> dict:
    return {
        "type": "perspective",
        "fov": fov,
        "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}},
    }


def two_boxes() -> dict:
    """Box A (``null``, medium A) holding a clear glass ball whose exterior medium is A, and box B
    (``thindielectric``, medium B), in vacuum."""
    return {
        "type": "scene",
        "fog_a": homogeneous(MEDIUM_A),
        "box_a": cube(BOX_A, "null", {"type": "ref", "id": "fog_a"}),
        "box_b": cube(BOX_B, "thindielectric", homogeneous(MEDIUM_B)),
        "ball": {
            "type": "sphere",
            "center": SPHERE[0].tolist(),
            "radius": SPHERE[1],
            "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0},
            "exterior": {"type": "ref", "id": "fog_a"},
        },
        "light": {"type": "point", "position": [8.0, 40.0, 8.0], "intensity": 100.0},
        "sensor": camera([8, 12, 40], [8, 8, 8]),
    }


def overlap(box) -> np.ndarray:
    """The exact fraction of every voxel [i, i+1)³ inside ``box``, indexed [z, y, x]."""
    lo, hi = box
    edges = np.arange(GRID, dtype=np.float64)
    fx, fy, fz = (
        np.clip(np.minimum(edges + 1, hi[a]) - np.maximum(edges, lo[a]), 0, 1) for a in range(3)
    )
    return fz[:, None, None] * fy[None, :, None] * fx[None, None, :]


@pytest.fixture(scope="module")
def grids() -> dict:
    pipe = VolumePipeline(
        two_boxes(), grid=GRID, grid_bbox=([0, 0, 0], [GRID] * 3), photons=16**2, spp=1
    )
    assert pipe.world.box.h == pytest.approx(1.0)
    pipe.render()
    return pipe.grids


def test_sigma_is_the_medium_inside_each_box_and_zero_outside(grids):
    """Per voxel: σ = Σ (fraction of the voxel in box i) · σ_i; the border voxels' fractions are
    multiples of 1/64 that 4³ supersampling gets exactly. Away from the ball's surface, the
    ball's clear glass (coverage 1) is σ = 0 and n = 1.5."""
    z, y, x = np.meshgrid(*[np.arange(GRID) + 0.5] * 3, indexing="ij")
    distance = np.sqrt((x - SPHERE[0][0]) ** 2 + (y - SPHERE[0][1]) ** 2 + (z - SPHERE[0][2]) ** 2)
    in_ball, off_ball = distance < SPHERE[1] - 2, distance > SPHERE[1] + 2
    expected = {"sigma_s": 0.0, "kappa": 0.0}
    for box, medium in ((BOX_A, MEDIUM_A), (BOX_B, MEDIUM_B)):
        sigma_s, kappa = coefficients(medium)
        fraction = overlap(box)[..., None]
        expected["sigma_s"] = expected["sigma_s"] + fraction * sigma_s
        expected["kappa"] = expected["kappa"] + fraction * kappa
    for name in ("sigma_s", "kappa"):
        got = grids[name]
        np.testing.assert_allclose(got[off_ball], expected[name][off_ball], atol=1e-6)
        np.testing.assert_allclose(got[in_ball], 0.0, atol=1e-6)
    assert np.count_nonzero(overlap(BOX_A)[off_ball] == 0) > 1000  # vacuum voxels were checked
    assert 0 < np.count_nonzero((overlap(BOX_A) % 1 > 0)[off_ball])  # and border voxels
    np.testing.assert_allclose(grids["ior"][in_ball & (distance < 0.5)], 1.5, atol=1e-4)


def test_scene_reading():
    vs = from_mitsuba(mi.load_dict(two_boxes()), grid=GRID)
    a, b = sorted(vs.fog_volumes, key=lambda v: v.name)  # Mitsuba's order, not the dict's
    assert (a.name, b.name) == ("box_a", "box_b")
    for volume, medium in ((a, MEDIUM_A), (b, MEDIUM_B)):
        sigma_s, kappa = coefficients(medium)
        np.testing.assert_allclose(volume.medium.sigma_s, sigma_s, rtol=1e-6)
        np.testing.assert_allclose(volume.medium.kappa, kappa, rtol=1e-6)
    assert vs.fog is a.medium  # the ball's exterior medium is the fog that set_material edits
    np.testing.assert_allclose(vs.surrounding.kappa, 0.0)  # vacuum around the boxes
    assert vs.objects[0].medium.ior == pytest.approx(1.5)


def test_sensor_medium_fills_the_rest():
    d = two_boxes()
    d["sensor"]["medium"] = {"type": "homogeneous", "sigma_t": 0.1, "albedo": 0.5}
    vs = from_mitsuba(mi.load_dict(d), grid=GRID)
    np.testing.assert_allclose(vs.surrounding.sigma_s, 0.05, rtol=1e-6)
    np.testing.assert_allclose(vs.surrounding.sigma_a, 0.05, rtol=1e-6)


def test_set_material_of_the_fog_and_of_one_fog_volume():
    pipe = VolumePipeline(two_boxes(), grid=GRID, photons=16**2)
    pipe.set_material("fog", sigma_s=1.0, sigma_a=0.5)
    a, b = sorted(pipe.world.fog_volumes, key=lambda v: v.name)
    np.testing.assert_allclose(a.medium.kappa, 1.5)
    np.testing.assert_allclose(b.medium.kappa, coefficients(MEDIUM_B)[1])
    pipe.set_material("box_b", sigma_s=0.25)
    np.testing.assert_allclose(b.medium.sigma_s, 0.25)
    with pytest.raises(ParameterError, match="index-matched"):
        pipe.set_material("box_b", ior=1.2)


# ------------------------------------------------------------------------------------------------
# Scenes the volume method refuses or warns about


def scene_with(box_shape: dict) -> dict:
    return {
        "type": "scene",
        "fog_box": box_shape,
        "light": {"type": "point", "position": [0, 5, 0]},
        "sensor": camera([0, 0, 5], [0, 0, 0]),
    }


def test_open_boundary_is_refused():
    shape = {"type": "rectangle", "bsdf": {"type": "null"}, "interior": homogeneous(MEDIUM_B)}
    with pytest.raises(SceneError, match="open surface.*bounding a medium must be closed"):
        from_mitsuba(mi.load_dict(scene_with(shape)))


def test_rough_dielectric_names_the_methods_that_render_it():
    d = scene_with(cube(BOX_A, "null", homogeneous(MEDIUM_B)))
    d["ball"] = {"type": "sphere", "center": [5, 8, 7], "bsdf": {"type": "roughdielectric"}}
    with pytest.raises(SceneError, match=r"shape 'ball' has a RoughDielectric.*--method sppm"):
        from_mitsuba(mi.load_dict(d))


def test_unbounded_exterior_medium_beside_a_fog_box_warns():
    d = two_boxes()
    d["ball"]["exterior"] = homogeneous(MEDIUM_C)  # (Mitsuba shares equal dicts: not MEDIUM_B)
    with pytest.warns(UserWarning, match="exterior medium of 'ball' is bounded by no shape"):
        vs = from_mitsuba(mi.load_dict(d), grid=GRID)
    np.testing.assert_allclose(vs.surrounding.kappa, coefficients(MEDIUM_C)[1], rtol=1e-6)


def test_exterior_medium_other_than_the_sensors_is_refused():
    d = two_boxes()
    d["ball"]["exterior"] = homogeneous(MEDIUM_C)
    d["sensor"]["medium"] = {"type": "homogeneous", "sigma_t": 0.1}
    with pytest.raises(SceneError, match="neither the sensor's medium nor inside"):
        from_mitsuba(mi.load_dict(d))


# ------------------------------------------------------------------------------------------------
# Single scattering in a fog box smaller than the grid, against volpath max_depth = 2

WIDTH, HEIGHT = 64, 48
RATIO_BOUND = 0.025  # |brightness ratio − 1|: measured 0.012
BLOCK_BOUND = 0.08  # relative RMSE of 4×4-block means: measured 0.042


def fog_only_box() -> dict:
    """A 6 × 3 × 3 fog box (σ_t 0.5, albedo 0.9) under a point light, seen from the front."""
    return {
        "type": "scene",
        "fog": {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.9},
        "fog_box": {
            "type": "cube",
            "to_world": mi.ScalarTransform4f().scale([3, 1.5, 1.5]),
            "bsdf": {"type": "null"},
            "interior": {"type": "ref", "id": "fog"},
        },
        "light": {"type": "point", "position": [0, 6, 0], "intensity": 60.0},
        "sensor": camera([0, 1.5, 9], [0, 0, 0], WIDTH, HEIGHT),
    }


@pytest.fixture(scope="module")
def single_scattering() -> np.ndarray:
    integrator = mi.load_dict({"type": "volpath", "max_depth": 2})
    image = mi.render(mi.load_dict(fog_only_box()), integrator=integrator, spp=256)
    return np.array(image)[..., :3]


def test_fog_box_smaller_than_the_grid_matches_volpath_single_scattering(single_scattering):
    pipe = VolumePipeline(
        fog_only_box(), grid=48, photons=64**2, phase_k=0.0, table=0.0, spp=4, scattering="single"
    )
    assert pipe.world.box.size == pytest.approx(6.0)  # the cube around the box: fog in half of it
    ours = np.array(pipe.render())
    ratio = ours.mean() / single_scattering.mean()
    a, b = block_means(ours), block_means(single_scattering)
    error = np.sqrt(np.mean((a - b) ** 2)) / b.mean()
    assert abs(ratio - 1) < RATIO_BOUND, ratio
    assert error < BLOCK_BOUND, error
