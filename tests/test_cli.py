"""The ``photonmap`` command (issue item 6): render, scenes, compare; quiet when not a terminal."""

import io
import math

import numpy as np
import pytest
from rich.console import Console
from typer.testing import CliRunner

from photonmap import VolumePipeline, mi
from photonmap.cli import app
from photonmap.core.image import compare as compare_images
from photonmap.core.image import write_image
from photonmap.core.progress import stage_progress
from photonmap.volume.pipeline import STAGES

runner = CliRunner()
SMALL = ["--set", "grid=32", "--set", "photons=4096"]


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_scenes_lists_the_builtins():
    result = run("scenes")
    assert result.exit_code == 0
    for name in ("glass_sphere_fog", "perlin_cube", "mesh_in_fog"):
        assert name in result.stdout


def test_render_png_and_exr_with_timings(tmp_path):
    png, exr = tmp_path / "x.png", tmp_path / "out" / "x.exr"
    result = run(
        "render", "glass_sphere_fog", "-o", png, "-o", exr, *SMALL,
        "--width", 64, "--height", 48, "--timings",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    bmp = mi.Bitmap(str(png))
    assert tuple(bmp.size()) == (64, 48)
    assert bmp.component_format() == mi.Struct.Type.UInt8 and bmp.srgb_gamma()
    assert bmp.pixel_format() == mi.Bitmap.PixelFormat.RGB
    hdr = mi.Bitmap(str(exr))
    assert tuple(hdr.size()) == (64, 48)
    assert hdr.component_format() == mi.Struct.Type.Float32
    linear = np.array(hdr)
    assert np.all(np.isfinite(linear)) and linear.max() > 0
    # the same render through the API; the PNG is its sRGB tone mapping
    pipe = VolumePipeline("glass_sphere_fog", grid=32, photons=4096, width=64, height=48)
    assert np.array_equal(linear, np.array(pipe.render()))
    srgb = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)
    expected = np.round(np.clip(srgb, 0, 1) * 255)
    assert np.abs(np.array(bmp).astype(float) - expected).max() <= 1
    # the timing table (stdout), one row per stage and the total
    for stage in (*STAGES, "total"):
        assert stage in result.stdout
    assert "photons propagated 4,096" in result.stdout
    # not a terminal: no progress bar, spinner or escape codes; stderr says only what was written
    assert "\x1b[" not in result.output
    assert result.stderr.splitlines() == [f"wrote {png}", f"wrote {exr}"]


def test_unknown_set_key_lists_the_valid_keys(tmp_path):
    result = run("render", "glass_sphere_fog", "-o", tmp_path / "x.png", "--set", "gird=32")
    assert result.exit_code == 2
    assert "unknown --set key 'gird'" in result.output
    for key in ("grid", "photons", "eps", "eps2", "ds_min", "ds_max", "phase_k", "sampler"):
        assert f" {key}," in result.output or f" {key}\n" in result.output
    assert "fidelity" in result.output
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["-o", "x.jpg"], "must end in .exr or .png"),
        (["-o", "x.png", "--set", "grid"], "KEY=VALUE"),
        (["-o", "x.png", "--set", "photons=many"], "cannot read 'many' as int"),
        (["-o", "x.png", "--set", "smoothing=maybe"], "cannot read 'maybe' as bool"),
        (["-o", "x.png", "--set", "photons=0"], "photons must lie in [1, "),
        (["-o", "x.png", "--set", "phase_k=1.5"], "phase_k must lie in (-1, 1)"),
        (["-o", "x.png", "--set", "grid=2048"], "needs about"),
        (["-o", "x.png", "--method", "nope"], "unknown --method 'nope'"),
        (["-o", "x.png", "--method", "screen", "--set", "subsample=0"], "subsample must be"),
    ],
)
def test_bad_arguments_exit_2_with_a_message(tmp_path, args, message):
    args = [tmp_path / a if a.startswith("x.") else a for a in args]
    result = run("render", "glass_sphere_fog", *args)
    assert result.exit_code == 2
    assert message in result.output
    assert "Traceback" not in result.output


def test_unknown_scene_exits_2(tmp_path):
    result = run("render", "no_such_scene", "-o", tmp_path / "x.exr")
    assert result.exit_code == 2 and "glass_sphere_fog" in result.output


def test_compare(tmp_path):
    a = np.full((6, 8, 3), 0.5, np.float32)
    b = a.copy()
    b[2, 3] = [1.0, 0.25, 0.5]
    write_image(str(tmp_path / "a.exr"), a)
    write_image(str(tmp_path / "b.exr"), b)
    same = run("compare", tmp_path / "a.exr", tmp_path / "a.exr")
    assert same.exit_code == 0
    assert "RMSE 0 " in same.stdout and "relative RMSE 0 " in same.stdout
    assert "PSNR inf dB" in same.stdout
    diff = run("compare", tmp_path / "a.exr", tmp_path / "b.exr")
    assert diff.exit_code == 0
    m = compare_images(a, b)
    rmse = math.sqrt((0.5**2 + 0.25**2) / a.size)
    assert m["rmse"] == pytest.approx(rmse)
    assert m["rel_rmse"] == pytest.approx(rmse / np.mean(b))
    assert m["psnr"] == pytest.approx(20 * math.log10(1.0 / rmse))
    assert f"RMSE {m['rmse']:.6g}" in diff.stdout
    assert f"relative RMSE {m['rel_rmse']:.6g}" in diff.stdout
    assert f"PSNR {m['psnr']:.2f} dB" in diff.stdout
    missing = run("compare", tmp_path / "a.exr", tmp_path / "nope.exr")
    assert missing.exit_code == 2 and "no such image" in missing.output


def test_progress_bar_on_a_terminal_only():
    pipe = VolumePipeline("glass_sphere_fog", grid=32, photons=4096, width=16, height=12)
    quiet = io.StringIO()  # not a TTY: no bar, no callback
    with stage_progress(STAGES, "rendering", console=Console(file=quiet)) as report:
        assert report is None
    assert quiet.getvalue() == ""
    terminal = io.StringIO()
    console = Console(file=terminal, force_terminal=True, width=100)
    seen = []
    with stage_progress(STAGES, "rendering", console=console, enabled=True) as report:
        pipe.render(progress=lambda stage: (seen.append(stage), report(stage)))
    assert seen == list(STAGES)
    assert "rendering" in terminal.getvalue() and "10/10" in terminal.getvalue()
