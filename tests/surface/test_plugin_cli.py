"""The ``photon_mapper`` plugin and ``photonmap render --method surface``."""

import mitsuba as mi
import numpy as np
import pytest
from typer.testing import CliRunner

from photonmap.cli import app
from photonmap.core.image import read_image
from photonmap.scenes import SCENES
from photonmap.surface.pipeline import SurfacePipeline

PARAMS = {"photons": 20_000, "caustic_photons": 5_000, "k": 50, "fg_rays": 4, "seed": 2}


def test_plugin_renders_like_the_pipeline():
    scene = mi.load_dict(SCENES["cornell_steinhurst"].build(width=16, height=16))
    image = mi.render(
        scene, integrator=mi.load_dict({"type": "photon_mapper", **PARAMS, "structure": "kdtree"})
    )
    direct = SurfacePipeline(scene, structure="kdtree", **PARAMS).render()
    assert np.array(image).shape == (16, 16, 3)
    assert np.array_equal(np.array(image), np.array(direct))


def test_plugin_rejects_unknown_parameters():
    with pytest.raises(RuntimeError, match="photon_mapper: unknown parameter"):
        mi.load_dict({"type": "photon_mapper", "fgrays": 3})


def test_cli_surface_method(tmp_path):
    out = tmp_path / "c.exr"
    args = [
        "render",
        "cornell_spot_indirect",
        "-o",
        str(out),
        "--width",
        "16",
        "--height",
        "12",
        "--set",
        "photons=20000",
        "--set",
        "fg_rays=4",
        "--set",
        "structure=kdtree",
        "--timings",
    ]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "final gather" in result.stdout
    image = read_image(str(out))
    assert image.shape == (12, 16, 3) and np.all(np.isfinite(image)) and image.mean() > 0
    bad = CliRunner().invoke(
        app, ["render", "cornell_steinhurst", "-o", str(out), "--set", "grid=64"]
    )
    assert bad.exit_code == 2 and "valid keys" in bad.output
