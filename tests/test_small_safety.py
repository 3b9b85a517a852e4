"""Small bad inputs, each a one-line refusal now: an infinite time budget, a camera
whose origin is its target, a scene that is not one, a file Mitsuba cannot render."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from photonmap import METHODS, ParameterError, SceneError, SPPMPipeline, VolumePipeline
from photonmap.cli import app

SIZE = ["--width", "32", "--height", "24"]


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.mark.parametrize(
    "args",
    [
        ["render", "examples/cornell_box.xml", "--method", "sppm", "--time", "inf"],
        ["render", "examples/cornell_box.xml", "--method", "sppm", "--preview-every", "inf"],
        ["reference", "examples/cornell_box.xml", "--time", "inf"],
    ],
)
def test_an_infinite_time_budget_is_refused(tmp_path, args):
    result = invoke(*args, *SIZE, "-o", tmp_path / "x.exr")
    assert result.exit_code == 2
    assert "must be a finite number of seconds > 0, got inf" in result.output
    assert not (tmp_path / "x.exr").exists()


def test_run_refuses_an_infinite_budget():
    pipe = SPPMPipeline("examples/cornell_box.xml", photons=1000)
    with pytest.raises(ParameterError, match="seconds must be finite"):
        pipe.run(seconds=float("inf"))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"origin": [0.5, 0.5, 0.5], "target": [0.5, 0.5, 0.5]}, "origin and target must differ"),
        ({"origin": [0.5, 2.0, 0.5], "target": [0.5, 0.0, 0.5]}, "not along the view direction"),
        ({"origin": [1.0, 2.0]}, "camera origin must be 3 numbers"),
        ({"origin": [float("nan"), 0, 0]}, "camera origin must be finite"),
        ({"fov": 0}, "camera fov must lie in (0, 180)"),
    ],
)
def test_a_degenerate_camera_is_refused(changes, message):
    """The volume method rendered origin == target black; the others' look_at raised a bare
    TypeError for two numbers."""
    volume = VolumePipeline("glass_sphere_fog", grid=16, photons=1024, width=32, height=24)
    with pytest.raises(ParameterError, match=message.replace("(", r"\(").replace(")", r"\)")):
        volume.set_camera(**changes)
    surface = METHODS["surface"].pipeline("examples/cornell_box.xml", photons=1000)
    with pytest.raises(ParameterError):
        surface.set_camera(**changes)


@pytest.mark.parametrize("method", ["volume", "surface", "screen", "sppm"])
@pytest.mark.parametrize("scene", [None, 42, ["glass_sphere_fog"]])
def test_a_scene_that_is_not_one_is_refused(method, scene):
    with pytest.raises(SceneError, match="a scene is a built-in name .* got "):
        METHODS[method].pipeline(scene)


def test_reference_on_a_file_mitsuba_cannot_render(tmp_path):
    scene = tmp_path / "meter.xml"
    scene.write_text(
        '<scene version="3.0.0"><sensor type="radiancemeter"><film type="hdrfilm">'
        '<integer name="width" value="1"/><integer name="height" value="1"/></film></sensor>'
        '<shape type="sphere"/><emitter type="constant"/></scene>'
    )
    result = invoke("reference", scene, "--integrator", "ptracer", "--spp", 1,
                    "-o", tmp_path / "x.exr")  # fmt: skip
    assert result.exit_code == 2, result.output
    assert result.output.strip().splitlines()[-1] == (
        f"error: Mitsuba could not render '{scene}': [Endpoint] Endpoint::sample_direction(): "
        "not implemented!"
    )
    huge = tmp_path / "huge.xml"
    huge.write_text(
        '<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
        '<integer name="width" value="100000"/><integer name="height" value="100000"/></film>'
        '</sensor><shape type="sphere"/><emitter type="constant"/></scene>'
    )
    result = invoke("reference", huge, "--spp", 1, "-o", tmp_path / "x.exr")
    assert result.exit_code == 2 and "these reference settings need about" in result.output
    assert not (tmp_path / "x.exr").exists()
