"""SPPM parameters, the ``sppm`` plugin and ``photonmap render --method sppm``, and
their bad input."""

import pathlib

import mitsuba as mi
import numpy as np
import pytest
from typer.testing import CliRunner

from photonmap import METHODS, ParameterError
from photonmap.cli import app
from photonmap.core.image import read_image
from photonmap.sppm import SPPMParams, SPPMPipeline

EXAMPLE = str(pathlib.Path(__file__).resolve().parents[2] / "examples/glass_sphere_plane.xml")
SMALL = {"photons": 5_000, "seed": 2}


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"iterations": 0}, "iterations must be >= 1"),
        ({"photons": 0}, "photons must be >= 1"),
        ({"photons": -5}, "photons must be >= 1"),
        ({"alpha": 0.0}, r"alpha must lie in \(0, 1\)"),
        ({"alpha": 1.0}, r"alpha must lie in \(0, 1\)"),
        ({"alpha": 1.5}, r"alpha must lie in \(0, 1\)"),
        ({"radius": -0.1}, "radius must be >= 0"),
        ({"aim": 1.0}, r"aim must lie in \[0, 1\)"),
        ({"mode": "ppm"}, "mode must be one of sppm, memoryless"),
        ({"max_depth": -2}, "max_depth must be >= -1"),
        ({"alpha": float("nan")}, "alpha must be a finite number"),
        ({"iterations": 2.5}, "iterations must be an integer"),
        ({"rr_depth": -1}, "rr_depth must be >= 0"),
        ({"volume_radius": -1.0}, "volume_radius must be >= 0"),
    ],
)
def test_bad_parameters(params, message):
    with pytest.raises(ParameterError, match=message):
        SPPMPipeline(EXAMPLE, **params)


@pytest.mark.parametrize(
    ("budget", "message"),
    [
        ({}, "needs a budget"),
        ({"seconds": 0}, "seconds must be > 0"),
        ({"seconds": -1.0}, "seconds must be > 0"),
        ({"iterations": 0}, "iterations must be >= 1"),
    ],
)
def test_bad_budgets(budget, message):
    pipe = SPPMPipeline(EXAMPLE, **SMALL)
    with pytest.raises(ParameterError, match=message):
        pipe.run(**budget)


def test_method_table_and_defaults():
    assert METHODS["sppm"].pipeline is SPPMPipeline and METHODS["sppm"].params is SPPMParams
    p = SPPMParams()
    assert p.alpha == pytest.approx(2 / 3) and p.radius == 0 and p.mode == "sppm"


def test_step_run_and_render():
    pipe = SPPMPipeline(EXAMPLE, iterations=3, **SMALL)
    pipe.set_camera(width=24, height=18)
    for _ in range(3):
        pipe.step()
    stepped = np.array(pipe.image())
    seen = []
    rendered = np.array(pipe.render(progress=seen.append))  # restarts: the same 3 iterations
    assert seen == ["iteration 1/3", "iteration 2/3", "iteration 3/3"]
    np.testing.assert_array_equal(stepped, rendered)
    assert pipe.mean_radius < pipe.initial_radius()  # the radii shrank
    reports, previews = [], []
    pipe.run(
        iterations=2,
        progress=lambda *a: reports.append(a),
        preview=previews.append,
        preview_every=0.0,
    )
    assert [r[0] for r in reports] == [4, 5] and len(previews) == 2
    timed = SPPMPipeline(EXAMPLE, **SMALL)
    timed.set_camera(width=24, height=18)
    timed.run(seconds=0.5)
    assert timed.iterations >= 1


def test_plugin_renders_like_the_pipeline():
    scene = mi.load_file(EXAMPLE)
    props = {"type": "sppm", "iterations": 2, "photons": 5000, "seed": 2}
    image = np.array(mi.render(scene, integrator=mi.load_dict(props), seed=2))
    direct = SPPMPipeline(scene, iterations=2, **SMALL).render()
    np.testing.assert_array_equal(image, np.array(direct))
    with pytest.raises(RuntimeError, match="sppm: unknown parameter"):
        mi.load_dict({"type": "sppm", "photon_count": 3})


def test_cli(tmp_path):
    out = tmp_path / "sppm.exr"
    runner = CliRunner()
    args = ["render", EXAMPLE, "-o", str(out), "--method", "sppm", "--width", "32"]
    sets = ["--set", "iterations=3", "--set", "photons=4000"]
    result = runner.invoke(app, [*args, *sets, "--preview-every", "0.01"])
    assert result.exit_code == 0, result.output
    assert "sppm: 3 iterations" in result.output
    assert read_image(str(out)).shape == (24, 32, 3)
    result = runner.invoke(app, [*args, "--time", "0.5", "--set", "photons=4000"])
    assert result.exit_code == 0, result.output
    for extra, message in (
        (["--time", "0"], "--time must be a finite number of seconds > 0"),
        (["--set", "alpha=1"], "alpha must lie in (0, 1)"),
        (["--set", "radius=-1"], "radius must be >= 0"),
    ):
        result = runner.invoke(app, [*args, *extra])
        assert result.exit_code == 2 and message in result.output, result.output
    result = runner.invoke(app, ["render", EXAMPLE, "-o", str(out), "--time", "3",
                                 "--method", "surface"])  # fmt: skip
    assert result.exit_code == 2 and "applies to a progressive method" in result.output
    result = runner.invoke(app, ["render", EXAMPLE, "-o", str(out), "--width", "32", "--time",
                                 "0.5", "--set", "photons=4000"])  # a file's method: sppm
    assert result.exit_code == 0 and "sppm:" in result.output, result.output
