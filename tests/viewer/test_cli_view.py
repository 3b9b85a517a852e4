"""``photonmap view``: arguments are checked before the server starts (exit status 2 with one
``error:`` line); a good command line builds the viewer it describes and serves it on
127.0.0.1 without opening a browser when asked."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

import photonmap.viewer
from photonmap.cli import app

runner = CliRunner()


@pytest.mark.parametrize(
    "args,reason",
    [
        (["no_such_scene"], "no built-in scene or scene file named 'no_such_scene'"),
        (["glass_sphere_fog", "--method", "magic"], "unknown --method 'magic'"),
        (["glass_sphere_fog", "--port", "0"], "--port must lie in 1…65535"),
        (["glass_sphere_fog", "--width", "0"], "--width"),
        (["glass_sphere_fog", "--set", "photons=many"], "photons"),
        (["glass_sphere_fog", "--volumes", "missing.npz"], "--volumes: no such file"),
    ],
)
def test_bad_arguments(args, reason):
    result = runner.invoke(app, ["view", *args])
    assert result.exit_code == 2, result.output
    assert "error:" in result.output and reason in result.output.replace("\n", "")


def test_serves_the_viewer_it_describes(monkeypatch, tmp_path):
    served = {}

    def serve(viewer, host, port, open_browser):
        served.update(state=viewer.state(), host=host, port=port, browser=open_browser)
        viewer.close()

    monkeypatch.setattr(photonmap.viewer, "serve", serve)
    frames = tmp_path / "frames.npz"
    np.savez(frames, sigma_s=np.zeros((3, 32, 32, 32), np.float32))
    result = runner.invoke(app, ["view", "glass_sphere_fog", "--no-browser", "--port", "8123",
                                 "--width", "80", "--set", "grid=32", "--set", "photons=4096",
                                 "--volumes", str(frames)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "http://127.0.0.1:8123/" in result.output
    assert served["host"] == "127.0.0.1" and served["port"] == 8123 and not served["browser"]
    state = served["state"]
    assert state["method"] == "volume" and state["frames"] == 3
    assert (state["camera"]["width"], state["camera"]["height"]) == (80, 60)
    assert state["params"]["photons"] == 4096
