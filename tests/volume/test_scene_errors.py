"""Bad scenes raise a SceneError that says what to fix, never a NaN image (issue item 9)."""

import numpy as np
import pytest

from photonmap import VolumePipeline, mi
from photonmap.core.errors import PhotonmapError, SceneError
from photonmap.scenes import load_scene
from photonmap.scenes.meshes import to_mitsuba_mesh, torus_knot
from photonmap.volume.scene import from_mitsuba

NAN, INF = float("nan"), float("inf")


def scene_dict(bsdf=None, interior=None, **entries) -> dict:
    """A glass sphere with an absorbing interior, a point light and a perspective camera;
    ``bsdf``/``interior`` update the sphere's, ``entries`` replace (None: remove) scene entries."""
    glass = {
        "type": "sphere",
        "center": [0.5, 0.5, 0.5],
        "radius": 0.25,
        "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0, **(bsdf or {})},
        "interior": {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.2, **(interior or {})},
    }
    to_world = mi.ScalarTransform4f().look_at(origin=[0.5, 1.5, 3], target=[0.5] * 3, up=[0, 1, 0])
    d = {
        "type": "scene",
        "glass": glass,
        "light": {"type": "point", "position": [0.5, 3.0, 0.5], "intensity": 10.0},
        "sensor": {
            "type": "perspective",
            "to_world": to_world,
            "film": {"type": "hdrfilm", "width": 8, "height": 8},
        },
    }
    d.update(entries)
    return {k: v for k, v in d.items() if v is not None}


def read(d: dict):
    return from_mitsuba(load_scene(d)[0])


def test_valid_base_scene():
    vs = read(scene_dict())
    np.testing.assert_allclose(vs.objects[0].medium.sigma_s, 0.1, rtol=1e-5)
    np.testing.assert_allclose(vs.objects[0].medium.sigma_a, 0.4, rtol=1e-5)


def test_scene_error_is_a_photonmap_error():
    assert issubclass(SceneError, PhotonmapError)


@pytest.mark.parametrize(
    "interior, match",
    [
        ({"sigma_t": NAN}, "non-finite"),
        ({"sigma_t": INF}, "non-finite"),
        ({"sigma_t": -1.0}, "negative"),
        ({"scale": -2.0}, "negative"),
        ({"albedo": 1.5}, "albedo in \\[0, 1\\]"),
    ],
)
def test_bad_coefficients(interior, match):
    with pytest.raises(SceneError, match=match):
        read(scene_dict(interior=interior))


def test_bad_fog_coefficients():
    fog_box = {
        "type": "cube",
        "bsdf": {"type": "null"},
        "interior": {"type": "homogeneous", "sigma_t": NAN},
    }
    with pytest.raises(SceneError, match="fog.*non-finite"):
        read(scene_dict(glass=None, fog_box=fog_box))


def test_negative_rgb_coefficient_rejected_at_load():
    with pytest.raises(SceneError, match="Mitsuba could not load"):
        load_scene(scene_dict(interior={"sigma_t": {"type": "rgb", "value": [-1.0, 0.5, 0.5]}}))


@pytest.mark.parametrize(
    "bsdf", [{"int_ior": 0.9}, {"int_ior": 1.2, "ext_ior": 1.33}, {"int_ior": NAN}]
)
def test_index_below_one_or_nan(bsdf):
    with pytest.raises(SceneError, match="n >= 1"):
        read(scene_dict(bsdf=bsdf))


def test_no_light():
    with pytest.raises(SceneError, match="no light"):
        read(scene_dict(light=None))
    # an environment alone lights the scene (photons through the grid's faces)
    (sky,) = read(scene_dict(light={"type": "constant"})).lights
    assert sky.kind == "environment"


def test_no_refractive_or_medium_shape():
    with pytest.raises(SceneError, match="no refractive or medium-bearing shape"):
        read(scene_dict(glass=None))
    # an opaque wall is a surface the volume method shades, not a medium
    with pytest.raises(SceneError, match="no refractive or medium-bearing shape"):
        read(scene_dict(glass=None, wall={"type": "cube", "bsdf": {"type": "diffuse"}}))


@pytest.mark.parametrize(
    "sensor", [{"type": "orthographic"}, {"type": "thinlens", "aperture_radius": 0.1}]
)
def test_non_perspective_sensor(sensor):
    with pytest.raises(SceneError, match="'perspective' sensor"):
        read(scene_dict(sensor=sensor))


def test_no_sensor():
    with pytest.raises(SceneError, match="no sensor"):
        read(scene_dict(sensor=None))


def test_unsupported_emitter_is_named():
    projector = {"type": "projector", "irradiance": 1.0}
    with pytest.raises(SceneError, match="'beamer' is a Projector"):
        read(scene_dict(beamer=projector))


@pytest.mark.parametrize("kind", ["roughdielectric"])  # thindielectric: test_bounded_fog.py
def test_other_dielectrics(kind):
    d = scene_dict()
    d["glass"]["bsdf"] = {"type": kind}
    with pytest.raises(SceneError, match="'dielectric'"):
        read(d)


def test_open_shapes():
    d = scene_dict()
    d["glass"] = {"type": "cylinder", "bsdf": {"type": "dielectric"}}
    with pytest.raises(SceneError, match="is a Cylinder, an open surface"):
        read(d)
    vertices, faces = torus_knot(1000)
    d["glass"] = to_mitsuba_mesh(
        "holey", vertices, faces[2:], bsdf=mi.load_dict({"type": "dielectric"})
    )
    with pytest.raises(SceneError, match="mesh .glass. is not watertight"):
        read(d)


def test_heterogeneous_medium_is_kept_as_a_field():
    """(Read per voxel by S2, tests/volume/test_heterogeneous.py.)"""
    grid = mi.VolumeGrid(np.ones((2, 2, 2, 1), dtype=np.float32))
    interior = {"type": "heterogeneous", "sigma_t": {"type": "gridvolume", "grid": grid}}
    d = scene_dict()
    d["glass"]["interior"] = interior
    vs = read(d)
    (glass,) = vs.objects
    assert vs.heterogeneous and glass.medium.field is not None and glass.medium.fingerprint
    np.testing.assert_allclose(glass.medium.kappa, 1.0, rtol=1e-6)  # σ_t = 1, scale 1


def test_different_exterior_media():
    d = scene_dict()
    d["fog_a"] = {"type": "homogeneous", "sigma_t": 0.1}
    d["fog_b"] = {"type": "homogeneous", "sigma_t": 0.2}
    d["glass"]["exterior"] = {"type": "ref", "id": "fog_a"}
    d["glass2"] = {
        "type": "sphere",
        "center": [0.5, 0.5, 0.0],
        "radius": 0.1,
        "bsdf": {"type": "dielectric"},
        "exterior": {"type": "ref", "id": "fog_b"},
    }
    with pytest.raises(SceneError, match="same 'exterior' medium"):
        read(d)


@pytest.mark.parametrize(
    "scene",
    [
        scene_dict(glass={"type": "sphere", "radius": 0.25, "bsdf": {"type": "dielectric"}}),
        "cornell_steinhurst",
    ],
    ids=["glass sphere without media", "cornell_steinhurst"],
)
def test_scene_without_fog_is_refused_naming_the_surface_method(scene):
    """No participating medium → a SceneError naming the method to use, not a
    black image (also through the plugin, where Mitsuba wraps the error)."""
    with pytest.raises(SceneError, match="no fog.*--method surface.*SurfacePipeline"):
        VolumePipeline(scene, grid=16, photons=64)
    if isinstance(scene, dict):
        mi_scene = load_scene(scene)[0]
        plugin = mi.load_dict({"type": "volume_photon", "grid": 16, "photons": 64})
        with pytest.raises(RuntimeError) as info:
            mi.render(mi_scene, integrator=plugin)
        assert isinstance(info.value.__cause__, SceneError), info.value
