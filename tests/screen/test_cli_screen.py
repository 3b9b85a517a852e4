"""``photonmap render --method screen``."""

import mitsuba as mi
import numpy as np
from typer.testing import CliRunner

from photonmap import ScreenPipeline
from photonmap.cli import app
from photonmap.screen.pipeline import STAGES

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_render_cornell_ispm_with_screen_keys(tmp_path):
    exr = tmp_path / "x.exr"
    keys = ["bounces=1", "photons=400", "radius=0.05", "splat=icosahedron", "subsample=2",
            "shadows=hard", "isg_samples=4+7", "light_size=0.01"]  # fmt: skip
    sets = [a for k in keys for a in ("--set", k)]
    result = run(
        "render", "cornell_ispm", "-o", exr, "--width", 40, "--height", 30, *sets, "--timings"
    )
    assert result.exit_code == 0, result.output
    image = np.array(mi.Bitmap(str(exr)))[..., :3]
    ref = ScreenPipeline("cornell_ispm", width=40, height=30, bounces=1, photons=400,
                         radius=0.05, splat="icosahedron", subsample=2, shadows="hard",
                         isg_samples="4+7", light_size=0.01).render()  # fmt: skip
    assert np.allclose(image, np.array(ref), atol=1e-6)
    for stage in STAGES:
        assert stage in result.stdout
    assert "photons" in result.stdout


def test_scene_default_method_is_screen_and_bad_keys_exit_2(tmp_path):
    result = run("render", "cornell_ispm", "-o", tmp_path / "x.png", "--set", "radius=-1")
    assert result.exit_code == 2 and "radius must be >= 0, got -1.0" in result.output
    result = run("render", "cornell_ispm", "-o", tmp_path / "x.png", "--set", "splat=disc")
    assert result.exit_code == 2 and "splat must be one of quad, icosahedron" in result.output
    result = run("render", "cornell_ispm", "-o", tmp_path / "x.png", "--set", "subsample=1.5")
    assert result.exit_code == 2 and "cannot read '1.5' as int" in result.output
    assert "cornell_ispm" in run("scenes").stdout


def test_spp_does_not_apply_to_the_screen_method(tmp_path):
    """The screen pipeline casts one primary ray per pixel centre: --spp 1 is accepted, any other
    count exits 2 with a clear error, and spp is no screen --set key."""
    out = tmp_path / "x.png"
    small = ["--width", 16, "--height", 12, "--set", "photons=64"]
    result = run("render", "cornell_ispm", "-o", out, "--spp", 4, *small)
    assert result.exit_code == 2 and "--spp does not apply to the screen method" in result.output
    assert not out.exists()
    assert run("render", "cornell_ispm", "-o", out, "--spp", 1, *small).exit_code == 0
    result = run("render", "cornell_ispm", "-o", out, "--set", "spp=1")
    assert result.exit_code == 2 and "unknown --set key 'spp'" in result.output
