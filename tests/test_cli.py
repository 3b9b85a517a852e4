"""The ``photonmap`` command (issue item 6): render, scenes, compare; quiet when not a terminal."""

import io
import math
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console
from typer.testing import CliRunner

from photonmap import VolumePipeline, mi
from photonmap.cli import app
from photonmap.core.image import compare as compare_images
from photonmap.core.image import write_image
from photonmap.core.progress import stage_progress
from photonmap.scenes import SCENES
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
    exr.parent.mkdir()
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
    assert "unknown --set key 'gird' for the volume method" in result.output
    for key in ("grid", "photons", "eps", "eps2", "ds_min", "ds_max", "phase_k", "sampler"):
        assert f" {key}," in result.output or f" {key}\n" in result.output
    assert "fidelity" in result.output
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["-o", "x.jpg"], "must end in .exr (linear) or .png"),
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


S = Path(__file__).resolve().parents[1] / "examples"  # plain Mitsuba files, as a user writes them


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--width", "0"], "--width must lie in 1 … 16384 pixels, got 0"),
        (["--width", "-5"], "--width must lie in 1 … 16384 pixels, got -5"),
        (["--height", "100000"], "--height must lie in 1 … 16384 pixels, got 100000"),
        (["--seed", "-1"], "seed must lie in [0, 4294967295]"),
        (["--spp", "0"], "--spp must be at least 1"),
        (["--set", "photons=1.5"], "cannot read '1.5' as int"),
        (["--set", "grid_bbox=0,0,1"], "expected six numbers"),
        (["--set", "triangles=many"], "cannot read 'many' as int"),
    ],
)
def test_bad_inputs_are_refused_before_any_work(tmp_path, args, message):
    """Each bad input is a one-line error, exit 2, and nothing is written."""
    result = run("render", "mesh_in_fog", "-o", tmp_path / "x.png", *SMALL, *args)
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert "Traceback" not in result.output and len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("method", ["volume", "surface", "screen"])
def test_every_method_refuses_a_negative_seed(tmp_path, method):
    result = run("render", f"{S}/cornell_box.xml", "--method", method, "-o", tmp_path / "x.exr",
                 "--seed", "-1")  # fmt: skip
    assert result.exit_code == 2 and "seed must lie in [0, 4294967295]" in result.output


def test_output_paths_are_checked_before_rendering(tmp_path):
    missing = run("render", "glass_sphere_fog", "-o", tmp_path / "no" / "x.png", *SMALL)
    assert missing.exit_code == 2 and "does not exist; create it" in missing.output
    assert not (tmp_path / "no").exists()  # -o no longer creates directories
    folder = run("render", "glass_sphere_fog", "-o", tmp_path, *SMALL)
    assert folder.exit_code == 2 and "must end in .exr" in folder.output
    (tmp_path / "d.png").mkdir()
    dirname = run("render", "glass_sphere_fog", "-o", tmp_path / "d.png", *SMALL)
    assert dirname.exit_code == 2 and "is a directory" in dirname.output


def test_image_memory_is_estimated_before_rendering():
    from photonmap.core.errors import ParameterError
    from photonmap.core.memory import check_image_memory

    assert check_image_memory("surface", 64, 48, 2, available=1 << 30) > 64 * 48 * 2
    with pytest.raises(ParameterError, match=r"16384×16384 image .* needs about .* GB"):
        check_image_memory("volume", 16384, 16384, 1, available=8 << 30)


def test_width_alone_keeps_the_aspect_ratio_and_scene_parameters_are_settable(tmp_path):
    out = tmp_path / "x.exr"
    result = run("render", "mesh_in_fog", "-o", out, *SMALL, "--width", 40,
                 "--set", "triangles=400", "--set", "extent=0.5", "--set", "ior=1.3",
                 "--set", "grid_bbox=0,0,0,1,1,1", "--no-timings")  # fmt: skip
    assert result.exit_code == 0, result.output
    film = SCENES["mesh_in_fog"].build()["sensor"]["film"]
    assert tuple(mi.Bitmap(str(out)).size()) == (40, round(40 * film["height"] / film["width"]))


def test_the_method_is_picked_from_the_scene_and_named(tmp_path):
    """A file renders with sppm, which models everything in it (fog, glass, any BSDF); a
    built-in with the method it is made for."""
    for name in ("cornell_box.xml", "fog_box.xml"):
        result = run("render", f"{S}/{name}", "-o", tmp_path / "a.exr", "--width", 16,
                     "--set", "iterations=2", "--set", "photons=2000")  # fmt: skip
        assert result.exit_code == 0, result.output
        assert "method: sppm (renders everything in a Mitsuba file" in result.output


def test_compare_reports_block_errors_and_refuses_bad_images(tmp_path):
    rng = np.random.default_rng(1)
    ref = np.full((8, 8, 3), 0.5, np.float32)
    noisy = ref + rng.choice([-0.1, 0.1], ref.shape).astype(np.float32)
    m = compare_images(noisy, ref)
    assert m["rel_rmse"] == pytest.approx(0.2)
    assert m["block_rel_rmse"] < 0.5 * m["rel_rmse"]  # noise averages out in 4×4 blocks
    biased = compare_images(ref * 1.1, ref)  # ... a bias does not
    assert biased["block_rel_rmse"] == pytest.approx(0.1, rel=1e-5)
    assert biased["brightness"] == pytest.approx(1.1, rel=1e-6)
    write_image(str(tmp_path / "ref.exr"), ref)
    write_image(str(tmp_path / "zero.exr"), 0 * ref)
    (tmp_path / "notes.txt").write_text("not an image")
    out = run("compare", tmp_path / "ref.exr", tmp_path / "ref.exr")
    assert out.exit_code == 0 and "4x4-block relative RMSE 0 " in out.stdout
    text = run("compare", tmp_path / "notes.txt", tmp_path / "ref.exr")
    assert text.exit_code == 2 and "is not an image" in text.output
    black = run("compare", tmp_path / "ref.exr", tmp_path / "zero.exr")
    assert black.exit_code == 2 and "reference image is all zero" in black.output


def test_reference_renders_mitsubas_own_integrator_in_passes(tmp_path, monkeypatch):
    from photonmap.core import reference

    out = tmp_path / "ref.exr"
    result = run("reference", f"{S}/cornell_box.xml", "-o", out, "--spp", 8, "--width", 24)
    assert result.exit_code == 0, result.output
    assert "path: 8 spp" in result.output
    img = np.array(mi.Bitmap(str(out)))
    assert img.shape == (24, 24, 3) and img.mean() > 0.1
    # passes bound the memory: 8 spp in passes of 2 give the mean of the passes
    monkeypatch.setattr(reference, "PASS_MEMORY", reference.BYTES_PER_SAMPLE * 24 * 24 * 2)
    scene = mi.load_file(f"{S}/cornell_box.xml")
    params = mi.traverse(scene.sensors()[0])
    params["film.size"] = params["film.crop_size"] = (24, 24)
    params.update()
    image, info = reference.render_reference(scene, spp=8, integrator="path")
    assert info["passes"] == 4 and info["spp"] == 8
    passes = [np.array(mi.render(scene, spp=2, seed=s))[..., :3]  # the file's own integrator
              for s in range(4)]  # fmt: skip
    assert np.allclose(image, np.mean(passes, axis=0), atol=1e-5)
    bad = run("reference", f"{S}/cornell_box.xml", "-o", out, "--integrator", "bdpt")
    assert bad.exit_code == 2 and "unknown --integrator 'bdpt'" in bad.output


def test_timings_is_a_flag_pair_and_help_says_so():
    """``--timings=false`` was refused while help showed ``<bool>``: help now shows the pair."""
    help_text = run("render", "--help").output
    line = next(x for x in help_text.splitlines() if "--timings" in x)
    assert "--no-timings" in line and "<bool>" not in line
