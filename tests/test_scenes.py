"""Built-in scenes (spec seed-000-002 §3.3) and reading Mitsuba scenes into a VolumeScene."""

import numpy as np
import pytest

from photonmap import PhotonmapWarning, mi
from photonmap.core.errors import ParameterError, SceneError
from photonmap.core.scene_info import pick_method
from photonmap.scenes import SCENES, load_scene
from photonmap.scenes.meshes import to_mitsuba_mesh, torus_knot
from photonmap.scenes.volume_scenes import INTENSITY
from photonmap.volume.scene import from_mitsuba

SMALL = {"width": 32, "height": 24}
V = 128.0  # voxels per world unit
GLASS_SIGMA_A = np.array([0.004, 0.002, 0.001]) * V


VOLUME_SCENES = [name for name, b in SCENES.items() if b.pipeline == "volume"]


def test_every_builtin_takes_its_parameters_and_picks_its_method():
    """Every built-in loads with each scene parameter it advertises and returns its pipeline
    defaults; a file (no built-in) renders with ``sppm``, which models everything in it."""
    for name, builtin in SCENES.items():
        assert builtin.description
        scene, defaults = load_scene(name, **{**builtin.params, **SMALL})
        assert defaults == builtin.defaults
        assert pick_method(scene) == "sppm"
    assert VOLUME_SCENES == ["glass_sphere_fog", "perlin_cube", "mesh_in_fog"]
    assert {"ior_noise", "sigma_s_noise", "noise_scale"} <= set(SCENES["perlin_cube"].defaults)


@pytest.mark.parametrize("name", VOLUME_SCENES)
def test_builtin_reads_as_volume_scene(name):
    scene, defaults = load_scene(name, **SMALL)
    assert defaults == SCENES[name].defaults
    vs = from_mitsuba(scene)
    # The fog box [0, 1]³ is the grid box: 1 voxel = 1/128.
    assert vs.box.n == 128 and vs.box.size == pytest.approx(1.0)
    np.testing.assert_allclose(vs.box.lo, 0.0, atol=1e-6)
    np.testing.assert_allclose(vs.fog.sigma_s, 0.003 * V, rtol=1e-5)
    np.testing.assert_allclose(vs.fog.sigma_a, 0.0, atol=1e-6)
    assert vs.fog.ior == 1.0
    (obj,) = vs.objects
    assert obj.medium.ior == pytest.approx(1.5)
    np.testing.assert_allclose(obj.medium.sigma_a, GLASS_SIGMA_A, rtol=1e-5)
    sigma_s = 0.002 * V if name == "perlin_cube" else 0.0
    np.testing.assert_allclose(obj.medium.sigma_s, sigma_s, rtol=1e-5, atol=1e-9)
    (light,) = vs.lights
    assert light.kind == "point"
    np.testing.assert_allclose(light.position, np.array([64, 400, 64]) / V, rtol=1e-6)
    np.testing.assert_allclose(light.intensity, INTENSITY)
    assert vs.sensor.class_name() == "PerspectiveCamera"
    assert tuple(vs.sensor.film().size()) == (32, 24)
    assert vs.environment is None


def test_sphere_geometry_and_params():
    scene, defaults = load_scene("glass_sphere_fog", ior=1.1, intensity=7.0, phase_k=0.0, **SMALL)
    assert defaults["phase_k"] == 0.0 and defaults["table"] == 0.8
    vs = from_mitsuba(scene)
    assert vs.objects[0].medium.ior == pytest.approx(1.1)
    np.testing.assert_allclose(vs.lights[0].intensity, 7.0)
    bbox = vs.objects[0].shape.bbox()
    np.testing.assert_allclose(np.array(bbox.center()).ravel() * V, [64, 72, 64], atol=1e-3)
    np.testing.assert_allclose(np.array(bbox.extents()).ravel() * V, 64, atol=1e-3)


def test_cube_is_turned_and_inside_the_box():
    vs = from_mitsuba(load_scene("perlin_cube", **SMALL)[0])
    lo, hi = (
        np.array(v).ravel() * V
        for v in (vs.objects[0].shape.bbox().min, vs.objects[0].shape.bbox().max)
    )
    assert np.all(hi - lo > 61) and np.all(lo > 6) and np.all(hi < 122)  # not axis-aligned


@pytest.mark.parametrize("extent", [64, 103])
def test_mesh_scene_extent_and_triangles(extent):
    vs = from_mitsuba(load_scene("mesh_in_fog", triangles=10000, extent=extent, **SMALL)[0])
    mesh = vs.objects[0].shape
    assert mesh.is_mesh() and abs(mesh.face_count() / 10000 - 1) < 0.003  # 0.0012
    size = (np.array(mesh.bbox().max) - np.array(mesh.bbox().min)).ravel() * V
    assert size.max() == pytest.approx(extent, rel=1e-4)


@pytest.mark.parametrize("triangles", [2900, 10000, 20000, 40000, 80000])
def test_torus_knot_watertight_outward(triangles):
    vertices, faces = torus_knot(triangles)
    assert abs(len(faces) / triangles - 1) < 0.003  # at most 0.0014 measured
    # Every edge shared by exactly two faces, in opposite directions (closed, consistently oriented).
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    directed = {tuple(e) for e in edges.tolist()}
    assert len(directed) == len(edges)
    assert all((b, a) in directed for a, b in directed)
    # Outward orientation: positive signed volume, close to the tube's π·a²·length.
    v0, v1, v2 = (vertices[faces[:, i]] for i in range(3))
    volume = np.einsum("ij,ij->", v0, np.cross(v1, v2)) / 6.0
    assert 0.9 < volume / (np.pi * 0.5**2 * 31.9) < 1.0  # 0.937 (2900) … 0.998 (80000)


def test_to_mitsuba_mesh():
    vertices, faces = torus_knot(500)
    mesh = to_mitsuba_mesh("knot", vertices, faces, bsdf=mi.load_dict({"type": "dielectric"}))
    assert mesh.face_count() == len(faces) and mesh.vertex_count() == len(vertices)
    assert mesh.bsdf().class_name() == "SmoothDielectric"


def test_area_lights():
    """Area emitters stay Mitsuba emitters (S5 samples their surface; their
    photon powers are tested in tests/volume/test_lights_anywhere.py); an edit re-keys them."""
    scene = load_scene("glass_sphere_fog", light_radius=4.0, **SMALL)[0]
    (light,) = from_mitsuba(scene).lights
    assert light.kind == "area" and light.emitter.get_shape().class_name() == "Sphere"
    np.testing.assert_allclose(light.intensity, 1.0)
    to_world = mi.ScalarTransform4f().translate([0.5, 2, 0.5]).rotate([1, 0, 0], 90).scale(0.25)
    lamp = {
        "type": "rectangle",
        "to_world": to_world,
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [8, 4, 2]}},
    }
    scene = mi.load_dict({"type": "scene", "glass": _glass(), "sensor": _camera(), "lamp": lamp})
    (light,) = from_mitsuba(scene).lights
    assert light.kind == "area" and light.emitter.get_shape().class_name() == "Rectangle"
    params = mi.traverse(light.emitter)
    params["radiance.value"] = mi.Color3f(1.0, 1.0, 1.0)
    params.update()
    assert from_mitsuba(scene).lights[0].fingerprint != light.fingerprint


def _camera():
    to_world = mi.ScalarTransform4f().look_at(origin=[0.5, 1.5, 3], target=[0.5] * 3, up=[0, 1, 0])
    return {
        "type": "perspective",
        "to_world": to_world,
        "film": {"type": "hdrfilm", "width": 8, "height": 8},
    }


def _glass(**extra):
    return {
        "type": "sphere",
        "center": [0.5, 0.5, 0.5],
        "radius": 0.25,
        "bsdf": {"type": "dielectric", "int_ior": 1.33, "ext_ior": 1.0},
        **extra,
    }


def test_lights_spot_directional_and_environment():
    scene = mi.load_dict(
        {
            "type": "scene",
            "glass": _glass(),
            "sensor": _camera(),
            "spot": {
                "type": "spot",
                "cutoff_angle": 30.0,
                "beam_width": 20.0,
                "intensity": {"type": "rgb", "value": [1.0, 2.0, 3.0]},
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0.5, 3, 0.5], target=[0.5, 0, 0.5], up=[0, 0, 1]
                ),
            },
            "sun": {"type": "directional", "direction": [0, -1, 1], "irradiance": 2.0},
            "sky": {"type": "constant", "radiance": 0.1},
        }
    )
    vs = from_mitsuba(scene)
    spot, sky, sun = sorted(vs.lights, key=lambda light: light.kind, reverse=True)
    assert spot.kind == "spot" and sun.kind == "directional" and sky.kind == "environment"
    np.testing.assert_allclose(spot.position, [0.5, 3, 0.5], atol=1e-6)
    np.testing.assert_allclose(spot.direction, [0, -1, 0], atol=1e-6)
    np.testing.assert_allclose(spot.intensity, [1, 2, 3], rtol=1e-5)
    assert spot.cos_outer == pytest.approx(np.cos(np.radians(30)))
    assert spot.cos_inner == pytest.approx(np.cos(np.radians(20)))
    np.testing.assert_allclose(sun.direction, np.array([0, -1, 1]) / np.sqrt(2), atol=1e-6)
    np.testing.assert_allclose(sun.intensity, 2.0, rtol=1e-5)
    assert vs.environment is not None and vs.environment.is_environment()
    assert sky.emitter is vs.environment  # the background is a light too


def test_fog_from_sensor_medium_and_margin():
    camera = _camera()
    camera["medium"] = {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.6}
    scene = mi.load_dict(
        {
            "type": "scene",
            "glass": _glass(),
            "sensor": camera,
            "light": {"type": "point", "position": [0.5, 3, 0.5]},
        }
    )
    vs = from_mitsuba(scene, grid=64)
    np.testing.assert_allclose(vs.fog.sigma_s, 0.3, rtol=1e-5)
    np.testing.assert_allclose(vs.fog.sigma_a, 0.2, rtol=1e-5)
    assert vs.objects[0].medium.ior == pytest.approx(1.33)
    np.testing.assert_allclose(vs.objects[0].medium.kappa, 0.0)  # no interior medium: clear
    # No fog box: the sphere's bbox with 6 voxels of margin on every side.
    assert vs.box.n == 64 and vs.box.size == pytest.approx(0.5 * 64 / 52)
    np.testing.assert_allclose(vs.box.center, 0.5, atol=1e-6)
    explicit = from_mitsuba(scene, grid_bbox=([0, 0, 0], [2, 1, 1]))
    assert explicit.box.size == pytest.approx(2.0) and explicit.box.lo[0] == pytest.approx(0.0)


def test_other_shapes_are_opaque_surfaces():
    """A shape that is neither a refractive object nor a fog boundary is an opaque surface the
    volume method shades (volume/surfaces.py); a partly transparent one is named in a warning."""
    scene = {
        "type": "scene",
        "glass": _glass(),
        "sensor": _camera(),
        "floor": {"type": "rectangle"},
        "light": {"type": "point", "position": [0.5, 3, 0.5]},
    }
    assert from_mitsuba(mi.load_dict(scene)).surfaces.names == ["'floor'"]
    scene["floor"]["bsdf"] = {"type": "mask", "opacity": 0.5, "bsdf": {"type": "diffuse"}}
    with pytest.warns(PhotonmapWarning, match="'floor', partly transparent"):
        assert from_mitsuba(mi.load_dict(scene)).surfaces is None


def test_load_scene_inputs(tmp_path):
    scene, defaults = load_scene({"type": "scene", "glass": _glass(), "sensor": _camera()})
    assert isinstance(scene, mi.Scene) and defaults == {}
    assert load_scene(scene) == (scene, {})
    xml = tmp_path / "s.xml"
    xml.write_text(
        '<scene version="3.0.0"><default name="n" value="1.2"/>'
        '<shape type="sphere"><bsdf type="dielectric"><float name="int_ior" value="$n"/>'
        '<float name="ext_ior" value="1"/></bsdf></shape>'
        '<emitter type="point"><point name="position" x="0" y="5" z="0"/></emitter>'
        '<sensor type="perspective"/></scene>'
    )
    scene, defaults = load_scene(str(xml), n=1.4)
    assert defaults == {} and from_mitsuba(scene).objects[0].medium.ior == pytest.approx(1.4)
    with pytest.raises(SceneError, match="glass_sphere_fog.*perlin_cube.*mesh_in_fog"):
        load_scene("no_such_scene")
    with pytest.raises(SceneError, match="built-in scenes"):
        load_scene(tmp_path / "missing.xml")
    with pytest.raises(ParameterError, match="radius"):
        load_scene("glass_sphere_fog", radius=3)
    with pytest.raises(ParameterError, match="only to built-in"):
        load_scene(scene, ior=1.2)
