"""Memory estimated before allocation in every method: settings that cannot
fit are refused in one line naming what takes the memory, before any work, through the CLI and
the Python API alike; arrays past Dr.Jit's 2³² entries are refused too; the available memory
honours ``ulimit -v`` and ``--max-memory``."""

from __future__ import annotations

import os
import resource
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from photonmap import METHODS, ParameterError, ScreenPipeline, SurfacePipeline
from photonmap.cli import app
from photonmap.core.memory import available_memory, parse_size, set_memory_limit
from photonmap.surface import memory as surface_memory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BOX = "examples/cornell_box.xml"
SIZE = ["--width", "64", "--height", "48"]


def render(*args):
    return CliRunner().invoke(app, ["render", *map(str, args)])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([BOX, "--method", "surface", "--set", "photons=1e12"],
         "these surface settings need about"),
        ([BOX, "--method", "sppm", "--set", "photons=1e12"],
         "these sppm settings need about"),
        ([BOX, "--method", "screen", "--set", "photons=1000000000000"],
         "these screen settings need about"),
        (["glass_sphere_fog", "--set", "photons=2147483648"], "or fewer photons"),
        ([BOX, "--method", "surface", "--set", "photons=2000000", "--max-memory", "256M"],
         "but only 256.0 MB is available: lower photons"),
        ([BOX, "--method", "screen", "--set", "photons=4900000000", "--set", "bounces=1",
          "--max-memory", "1P"], "more than Dr.Jit's limit of 2³² per array"),
    ],
)
def test_refused_in_one_line_before_any_work(tmp_path, args, message):
    out = tmp_path / "x.exr"
    result = render(*args, *SIZE, "-o", out)
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.strip().splitlines() if not line.startswith("method")]
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], lines
    assert "of memory (" in lines[0] or "Dr.Jit's limit" in lines[0] or "needs about" in lines[0]
    assert not out.exists()


def test_max_memory_is_checked():
    result = render(BOX, "-o", "x.exr", "--max-memory", "lots")
    assert result.exit_code == 2
    assert "--max-memory: expected a size such as 8G" in result.output
    assert parse_size("1.5G") == 3 << 29 and parse_size("2e9") == 2 * 10**9


def test_address_space_limit_counts():
    """``ulimit -v 12G`` (the issue's SIGSEGV at 6.3 GB of photons=2e7): refused before work."""
    env = {**os.environ, "PYTHONPATH": os.path.join(ROOT, "src")}

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (12 << 30, 12 << 30))

    out = subprocess.run(
        [sys.executable, "-m", "photonmap", "render", BOX, "--method", "surface", *SIZE,
         "--set", "photons=2e7", "-o", "/tmp/never-written.exr"],
        cwd=ROOT, env=env, capture_output=True, text=True, preexec_fn=limit, timeout=120,
    )  # fmt: skip
    assert out.returncode == 2, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("error: these surface settings need about") and "is available" in last
    assert not os.path.exists("/tmp/never-written.exr")


@pytest.mark.parametrize("method", ["surface", "sppm", "screen", "volume"])
def test_python_api_refuses_before_allocating(method):
    Pipeline = METHODS[method].pipeline
    scene = "glass_sphere_fog" if method == "volume" else BOX
    small = {"volume": {"grid": 16, "photons": 1024}, "surface": {"photons": 1000},
             "sppm": {"photons": 1000}, "screen": {"photons": 16**2}}[method]
    pipe = Pipeline(scene, **small)
    huge = {"volume": {"photons": 2**31 - 1}, "surface": {"photons": 10**12},
            "sppm": {"photons": 10**12}, "screen": {"photons": 10**12}}[method]
    with pytest.raises(ParameterError, match="needs? about"):
        pipe.set_params(**huge)
    assert pipe.params == METHODS[method].pipeline(scene, **small).params  # unchanged
    with pytest.raises(ParameterError, match="needs? about"):
        Pipeline(scene, **{**small, **huge})
    try:
        set_memory_limit("64M")
        pipe.set_camera(width=4096, height=4096)
        with pytest.raises(ParameterError, match="needs? about .* but only 64.0 MB"):
            pipe.render()
    finally:
        set_memory_limit(None)


def test_a_frame_is_checked_once_not_against_what_it_holds():
    """The memory a pipeline keeps between frames is not counted against it again: an unchanged
    frame renders under any limit; a new size is checked again."""
    pipe = ScreenPipeline("cornell_ispm", photons=16**2, width=32, height=24)
    pipe.render()
    try:
        set_memory_limit(1)
        pipe.render()  # the same parameters and size: no new check
        pipe.set_camera(width=64, height=48)
        with pytest.raises(ParameterError, match="but only 1 B is available"):
            pipe.render()
    finally:
        set_memory_limit(None)
    assert available_memory() is None or available_memory() > 1


def test_the_estimate_grows_with_the_budget_the_depth_and_the_image():
    from photonmap.core.photon_memory import UNBOUNDED_RECORDS
    from photonmap.core.photon_trace import CHUNK

    p = SurfacePipeline(BOX, photons=1000).params
    parts, entries = surface_memory.estimate(p, 64, 48, max_depth=9)
    per_path = surface_memory.PATH_BYTES + CHUNK * surface_memory.SLOT_BYTES
    assert parts["photon tracing and maps"] == 1000 * (per_path + 8 * surface_memory.RECORD_BYTES)
    unbounded, _ = surface_memory.estimate(p, 64, 48, max_depth=-1)
    assert unbounded["photon tracing and maps"] == 1000 * (
        per_path + UNBOUNDED_RECORDS * surface_memory.RECORD_BYTES
    )
    bigger, _ = surface_memory.estimate(p, 128, 96, max_depth=9)
    assert bigger["eye pass and final gather"] == 4 * parts["eye pass and final gather"]
    assert entries["photons × CHUNK record slots"] == max(1000, p.caustic_photons) * CHUNK
