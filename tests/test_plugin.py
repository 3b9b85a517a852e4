"""The ``volume_photon`` Mitsuba plugin (issue item 5) and the Mitsuba backend itself (item 1)."""

import numpy as np
import pytest

import photonmap
from photonmap import PhotonmapError, VolumePipeline, mi
from photonmap.core.errors import ParameterError, SceneError
from photonmap.scenes import SCENES
from photonmap.volume.integrator import VolumePhotonIntegrator

PARAMS = {"grid": 32, "photons": 4096}

SCENE_XML = """<scene version="3.0.0">
    <integrator type="volume_photon">
        <integer name="grid" value="32"/>
        <integer name="photons" value="4096"/>
    </integrator>
    <medium type="homogeneous" id="fog">
        <float name="sigma_t" value="0.6"/>
        <float name="albedo" value="1.0"/>
    </medium>
    <shape type="cube" id="fog_box">
        <transform name="to_world">
            <scale value="0.5"/>
            <translate x="0.5" y="0.5" z="0.5"/>
        </transform>
        <bsdf type="null"/>
        <ref name="interior" id="fog"/>
    </shape>
    <shape type="sphere" id="ball">
        <point name="center" x="0.5" y="0.55" z="0.5"/>
        <float name="radius" value="0.25"/>
        <bsdf type="dielectric">
            <float name="int_ior" value="1.5"/>
            <float name="ext_ior" value="1.0"/>
        </bsdf>
        <medium type="homogeneous" name="interior">
            <rgb name="sigma_t" value="0.5, 0.25, 0.125"/>
            <float name="albedo" value="0.0"/>
        </medium>
        <ref name="exterior" id="fog"/>
    </shape>
    <emitter type="point" id="lamp">
        <point name="position" x="0.5" y="3.0" z="0.5"/>
        <rgb name="intensity" value="40, 40, 40"/>
    </emitter>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world">
            <lookat origin="1.4, 1.2, 2.6" target="0.5, 0.45, 0.5" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="20"/>
            <integer name="height" value="10"/>
        </film>
    </sensor>
</scene>
"""


def integrator(**params):
    return mi.load_dict({"type": "volume_photon", **PARAMS, **params})


def sphere_dict(**extra) -> dict:
    return {**SCENES["glass_sphere_fog"].build(width=16, height=12), **extra}


def test_importing_photonmap_registers_the_integrator():
    integ = integrator(eps=0.01)
    assert isinstance(integ, VolumePhotonIntegrator)
    assert integ.options == {} and integ.params == {"grid": 32, "photons": 4096, "eps": 0.01}


def test_builtin_scene_dict_renders_like_the_pipeline():
    scene = mi.load_dict(sphere_dict())
    img = np.array(mi.render(scene, integrator=integrator()))
    assert img.shape == (12, 16, 3)
    assert np.all(np.isfinite(img)) and img.mean() > 0
    ref = np.array(VolumePipeline(scene, **PARAMS).render())
    assert np.array_equal(img, ref)


def test_xml_scene_renders_like_the_pipeline(tmp_path):
    path = tmp_path / "scene.xml"
    path.write_text(SCENE_XML)
    scene = mi.load_file(str(path))
    assert isinstance(scene.integrator(), VolumePhotonIntegrator)
    from_xml = np.array(mi.render(scene))  # the integrator the file names
    assert from_xml.shape == (10, 20, 3)
    assert np.all(np.isfinite(from_xml)) and from_xml.mean() > 0
    given = np.array(mi.render(scene, integrator=integrator()))
    ref = np.array(VolumePipeline(str(path), **PARAMS).render())
    assert np.array_equal(from_xml, ref) and np.array_equal(given, ref)


def test_another_sensor_reuses_the_photons_and_traverse_edits_rerun():
    second = sphere_dict()["sensor"]
    second["film"] = {"type": "hdrfilm", "width": 8, "height": 8}
    second["to_world"] = mi.ScalarTransform4f().look_at(
        origin=[0.5, 2.5, 0.6], target=[0.5, 0.5, 0.5], up=[0, 0, 1]
    )
    scene = mi.load_dict(sphere_dict(top=second))
    integ = integrator()
    first = np.array(mi.render(scene, integrator=integ, sensor=0))
    assert integ.pipeline.recomputed[-1] == "viewing" and len(integ.pipeline.recomputed) > 1
    top = np.array(mi.render(scene, integrator=integ, sensor=1))
    assert top.shape == (8, 8, 3) and integ.pipeline.recomputed == ["viewing"]
    again = np.array(mi.render(scene, integrator=integ, sensor=0))
    assert np.array_equal(first, again)

    params = mi.traverse(scene)
    params["light.position"] = mi.Point3f(0.8, 3.0, 0.5)
    params.update()
    moved = np.array(mi.render(scene, integrator=integ, sensor=0))
    assert integ.pipeline.recomputed[0] == "photon generation"
    assert "octree" not in integ.pipeline.recomputed
    assert np.array_equal(moved, np.array(VolumePipeline(scene, **PARAMS).render()))
    assert not np.array_equal(moved, first)

    params["sensor.x_fov"] = 30.0  # an in-place camera edit: the viewing pass alone reruns
    params.update()
    zoomed = np.array(mi.render(scene, integrator=integ, sensor=0))
    assert integ.pipeline.recomputed == ["viewing"]
    assert not np.array_equal(zoomed, moved)


def test_spp_and_seed_reach_the_pipeline():
    scene = mi.load_dict(sphere_dict())
    integ = integrator()
    a = np.array(mi.render(scene, integrator=integ, spp=2, seed=5))
    assert integ.pipeline.params.spp == 2 and integ.pipeline.params.seed == 5
    ref = VolumePipeline(scene, spp=2, seed=5, **PARAMS)
    assert np.array_equal(a, np.array(ref.render()))
    mi.render(scene, integrator=integ)
    assert integ.pipeline.params.spp == 1 and integ.pipeline.params.seed == 0


def test_plugin_errors_are_photonmap_errors():
    with pytest.raises(RuntimeError, match="unknown parameter.*photonz.*valid:.*grid"):
        mi.load_dict({"type": "volume_photon", "photonz": 3})
    with pytest.raises(RuntimeError, match=r"photons must lie in \[1, "):
        mi.load_dict({"type": "volume_photon", "photons": 0})
    with pytest.raises(RuntimeError, match="grid must be an integer >= 4"):
        mi.load_dict({"type": "volume_photon", "grid": 2})
    cornell = mi.cornell_box()
    cornell["sensor"]["film"].update(width=8, height=8)
    scene = mi.load_dict(cornell)
    with pytest.raises(RuntimeError) as info:
        mi.render(scene, integrator=integrator())
    assert isinstance(info.value.__cause__, SceneError)
    assert "no fog" in str(info.value.__cause__)  # refused, naming --method surface
    with pytest.raises(SceneError, match="no fog"):  # the Python API raises it as itself
        photonmap.render(scene, method="volume")
    assert issubclass(ParameterError, PhotonmapError)
