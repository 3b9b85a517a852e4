"""The VCM pipeline as users meet it: parameters and their bad values, scenes it refuses, seeds,
the file's path settings, the ``vcm`` plugin and ``photonmap render --method vcm``."""

import pathlib

import mitsuba as mi
import numpy as np
import pytest
from typer.testing import CliRunner

from photonmap import METHODS, ParameterError, SceneError
from photonmap.cli import app
from photonmap.core.image import read_image
from photonmap.vcm import VCMPipeline

ROOT = pathlib.Path(__file__).resolve().parents[2]
EXAMPLE = str(ROOT / "examples/glass_sphere_plane.xml")
T = mi.ScalarTransform4f


def small_cornell(**film) -> dict:
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=16, height=16, rfilter={"type": "box"}, **film)
    return d


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"iterations": 0}, "iterations must be >= 1"),
        ({"spp": -1}, "spp must lie in"),
        ({"spp": 65}, "spp must lie in"),
        ({"alpha": 1.0}, r"alpha must lie in \(0, 1\)"),
        ({"alpha": 0.0}, r"alpha must lie in \(0, 1\)"),
        ({"radius": -0.1}, "radius must be >= 0"),
        ({"mode": "sppm"}, "mode must be one of vcm, bpt, ppm, pt, lt"),
        ({"max_depth": -2}, "max_depth must be >= -1"),
        ({"photons": 10}, "photons"),
    ],
)
def test_bad_parameters(params, message):
    with pytest.raises(ParameterError, match=message):
        VCMPipeline(small_cornell(), **params)


def test_memory_is_checked_before_anything_is_traced():
    pipe = VCMPipeline(small_cornell())
    with pytest.raises(ParameterError, match="vcm settings need about"):
        pipe.check_memory(size=(16384, 16384))


def fog_scene() -> dict:
    d = small_cornell()
    d["fog"] = {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.5}
    d["sensor"]["medium"] = {"type": "ref", "id": "fog"}
    return d


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(env={"type": "constant"}), "ConstantBackgroundEmitter.*--method sppm"),
        (lambda d: d.update(sun={"type": "directional", "direction": [0, -1, 0]}),
         "DirectionalEmitter.*--method sppm"),
        (lambda d: d["sensor"].update(type="thinlens", aperture_radius=0.05, focus_distance=3.0),
         "pinhole camera.*--method sppm"),
        (lambda d: d["small-box"].update(bsdf={"type": "hair"}), "hair BSDF"),
    ],
)  # fmt: skip
def test_refused_scenes_name_a_method_that_renders_them(edit, message):
    d = small_cornell()
    edit(d)
    with pytest.raises(SceneError, match=message):
        VCMPipeline(mi.load_dict(d))


def test_media_are_refused():
    d = fog_scene()
    with pytest.raises(SceneError, match="participating media.*--method sppm"):
        VCMPipeline(mi.load_dict(d))


def test_same_seed_same_image_other_seed_other_image():
    scene = mi.load_dict(small_cornell())
    a = np.array(VCMPipeline(scene, seed=3).run(iterations=3))
    b = np.array(VCMPipeline(scene, seed=3).run(iterations=3))
    c = np.array(VCMPipeline(scene, seed=4).run(iterations=3))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_max_depth_one_is_the_emission_seen_and_hidden_emitters_are_black():
    scene = mi.load_dict(small_cornell())
    seen = np.array(VCMPipeline(scene, max_depth=1).run(iterations=2))
    lit = seen.max(axis=2) > 0
    assert 0 < lit.sum() < lit.size  # the light's pixels only
    light = lit & (seen.min(axis=2) > 1)  # wholly on the light (radiance 18.4)
    assert light.any()
    hidden = np.array(VCMPipeline(scene, hide_emitters="true").run(iterations=2))
    assert np.all(hidden[light] < 1)


def test_the_file_max_depth_is_the_default():
    path = ROOT / "examples/cornell_glass_sphere.xml"
    pipe = VCMPipeline(str(path))
    assert pipe.settings.max_depth == 32


def test_plugin_renders_like_the_pipeline():
    scene = mi.load_dict(small_cornell())
    integrator = mi.load_dict({"type": "vcm", "iterations": 4, "mode": "bpt"})
    image = np.array(mi.render(scene, integrator=integrator, seed=5))
    expected = np.array(VCMPipeline(scene, iterations=4, mode="bpt", seed=5).render())
    assert image.shape == (16, 16, 3)
    np.testing.assert_allclose(image, expected, rtol=1e-5, atol=1e-6)
    assert "vcm" in METHODS


def test_command_line_renders_with_vcm(tmp_path):
    out = tmp_path / "vcm.exr"
    result = CliRunner().invoke(
        app, ["render", EXAMPLE, "--method", "vcm", "-o", str(out), "--width", "24",
              "--set", "iterations=2"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    image = read_image(str(out))
    assert image.shape == (18, 24, 3) and np.all(np.isfinite(image)) and image.mean() > 0
