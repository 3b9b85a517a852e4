"""``photonmap reference`` renders the file as Mitsuba does: the path-length settings of its
``<integrator>`` (``max_depth``, ``rr_depth``, ``hide_emitters``, also inside an ``aov``
wrapper) are the reference's defaults; ``--max-depth`` overrides them."""

import re
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest
from typer.testing import CliRunner

import mitsuba_reference
from photonmap.cli import app
from photonmap.core.reference import render_reference

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SIZE = 24
SPP = 256


def _box_file(tmp_path, integrator: str, name: str = "box.xml") -> Path:
    """examples/cornell_box.xml (Mitsuba's own Cornell box) at SIZE² with another integrator."""
    text = (EXAMPLES / "cornell_box.xml").read_text()
    text = re.sub(r"<integrator.*?</integrator>", integrator, text, count=1, flags=re.S)
    text = text.replace('name="width" value="256"', f'name="width" value="{SIZE}"')
    text = text.replace('name="height" value="256"', f'name="height" value="{SIZE}"')
    path = tmp_path / name
    path.write_text(text)
    return path


DEPTH_3 = '<integrator type="path"><integer name="max_depth" value="3"/></integrator>'


def _mitsuba(path: Path, spp: int = SPP, seed: int = 100) -> np.ndarray:
    """Mitsuba's own render of the file, with the file's own integrator."""
    scene = mi.load_file(str(path))
    return mitsuba_reference.render(scene, spp=spp, seed=seed).astype(np.float64)[..., :3]


def test_reference_takes_the_files_max_depth(tmp_path):
    """A file with max_depth 3: the reference is Mitsuba's image of that file (mean within 3 %,
    the noise of 256 spp is ~0.8 %), not the unbounded one, which is ~14 % brighter."""
    path = _box_file(tmp_path, DEPTH_3)
    scene = mi.load_file(str(path))
    image, info = render_reference(scene, spp=SPP, source=path)
    assert info["max_depth"] == 3 and info["rr_depth"] == 5 and not info["hide_emitters"]
    truth = _mitsuba(path)
    assert abs(image.mean() / truth.mean() - 1) < 0.03
    unbounded, info = render_reference(scene, spp=SPP, max_depth=-1)  # an argument overrides
    assert info["max_depth"] == -1
    assert unbounded.mean() / truth.mean() > 1.08
    # 4 x 4 blocks agree too: the setting reaches every pixel, not only the mean
    blocks = lambda im: im.reshape(SIZE // 4, 4, SIZE // 4, 4, 3).mean(axis=(1, 3))  # noqa: E731
    rel = np.abs(blocks(image) - blocks(truth)) / np.maximum(blocks(truth), 0.05)
    assert np.median(rel) < 0.05


def test_reference_reads_the_settings_inside_an_aov_wrapper(tmp_path):
    """``aov`` around ``path`` with max_depth 2, rr_depth 1 and hidden emitters: the reference
    hides the light (the pixels that see it are black in Mitsuba's render too) and matches the
    wrapped integrator's image. The file keeps the example's comment that holds ``--method``:
    Mitsuba reads it, strict XML parsers refuse it, and the wrapper's ``hide_emitters`` is read
    from the file."""
    inner = (
        '<integrator type="path"><integer name="max_depth" value="2"/>'
        '<integer name="rr_depth" value="1"/><boolean name="hide_emitters" value="true"/>'
        "</integrator>"
    )
    path = _box_file(tmp_path, f'<integrator type="aov"><string name="aovs" value="dd:depth"/>'
                               f"{inner}</integrator>")  # fmt: skip
    scene = mi.load_file(str(path))
    image, info = render_reference(scene, spp=SPP, source=path)
    assert (info["max_depth"], info["rr_depth"], info["hide_emitters"]) == (2, 1, True)
    truth = _mitsuba(path)  # the aov image's first three channels: the wrapped path's RGB
    shown, _ = render_reference(scene, spp=SPP, hide_emitters=False)
    light = shown.max(axis=2) > 5.0  # pixels that see the ceiling light (radiance ~ 17)
    assert light.sum() >= 4
    assert image[light].max() < 1.0 and truth[light].max() < 1.0
    assert abs(image.mean() / truth.mean() - 1) < 0.03


def test_cli_reference_defaults_to_the_file_and_max_depth_overrides(tmp_path):
    path = _box_file(tmp_path, DEPTH_3)
    runner = CliRunner()
    out, out_unbounded = tmp_path / "ref.exr", tmp_path / "unbounded.exr"
    result = runner.invoke(app, ["reference", str(path), "-o", str(out), "--spp", str(SPP)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(
        app, ["reference", str(path), "-o", str(out_unbounded), "--spp", str(SPP),
              "--max-depth", "-1"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    image = np.array(mi.Bitmap(str(out)), dtype=np.float64)[..., :3]
    unbounded = np.array(mi.Bitmap(str(out_unbounded)), dtype=np.float64)[..., :3]
    truth = _mitsuba(path)
    assert abs(image.mean() / truth.mean() - 1) < 0.03
    assert unbounded.mean() / truth.mean() > 1.08


def test_settings_of_an_adjoint_integrator():
    """Mitsuba's ``ptracer`` is an AdjointIntegrator, which has no ``hide_emitters`` attribute:
    its settings come from its description (a scene that names it still renders)."""
    from photonmap.core.settings import PathSettings, integrator_settings

    settings = integrator_settings(mi.load_dict({"type": "ptracer", "max_depth": 4}))
    assert settings == PathSettings(max_depth=4, rr_depth=5, hide_emitters=False)


def test_footprint_radius_is_measured_from_the_camera_not_the_near_plane():
    """Mitsuba's perspective camera starts its rays on the near clipping plane; the automatic
    radius must not depend on where that plane is."""
    from photonmap.core.camera import footprint_radius

    def scene(near):
        return mi.load_dict({
            "type": "scene",
            "sensor": {"type": "perspective", "fov": 45, "near_clip": near,
                       "to_world": mi.ScalarTransform4f().look_at(
                           origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 16, "height": 16}},
            "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(10)},
        })  # fmt: skip

    near, far = (footprint_radius(s, s.sensors()[0], 2.0) for s in (scene(0.01), scene(2.0)))
    assert far == pytest.approx(near, rel=1e-3)
    assert near == pytest.approx(2 * 5 * 2 * np.tan(np.radians(22.5)) / 16, rel=0.02)
