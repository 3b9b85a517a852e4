"""Ctrl-C at any moment: SIGINT sent at random times to tiny renders of every
method, to ``reference`` and to the real ``photonmap`` process (its import included) ends each
either with the image reached so far written whole or with nothing written — never a partial
file, never a traceback — with exit status 130 and one line ``interrupted: ...`` saying which.

The random times are drawn from a seeded generator over each command's own measured duration,
so most interrupts land mid-render; an interrupt that lands after the command finished leaves
exit status 0 and the complete image, which the assertions accept as well."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from photonmap.cli import app
from photonmap.core.image import read_image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SIZE = ["--width", "64", "--height", "48"]
CASES = {  # command lines of a fraction of a second to a second (after the first run)
    "volume": ["render", "glass_sphere_fog", *SIZE, "--set", "grid=16", "--set", "photons=4096"],
    "surface": ["render", "examples/cornell_box.xml", "--method", "surface", *SIZE,
                "--set", "photons=20000", "--set", "caustic_photons=0", "--set", "fg_rays=4"],
    "screen": ["render", "cornell_ispm", *SIZE],
    "sppm": ["render", "examples/cornell_box.xml", "--method", "sppm", *SIZE, "--time", "0.5",
             "--preview-every", "0.15", "--set", "photons=20000"],
    "vcm": ["render", "examples/cornell_box.xml", "--method", "vcm", *SIZE, "--time", "0.5",
            "--preview-every", "0.15"],
    "reference": ["reference", "examples/cornell_box.xml", *SIZE, "--spp", "4096", "--time", "0.5"],
}  # fmt: skip
RUNS = 30


@pytest.fixture
def quiet_sigint():
    """A late SIGINT (after a command returned) must not stop the test session."""
    previous = signal.signal(signal.SIGINT, lambda *_: None)
    yield
    signal.signal(signal.SIGINT, previous)


def invoke(args, out, delay=None):
    """Run the command in this process, SIGINT after ``delay`` seconds; (result, seconds)."""
    timer = None
    if delay is not None:
        timer = threading.Timer(delay, os.kill, (os.getpid(), signal.SIGINT))
        timer.start()
    start = time.perf_counter()
    try:
        result = CliRunner().invoke(app, [*args, "-o", str(out)])
    finally:
        if timer is not None:
            timer.cancel()
            timer.join()
    return result, time.perf_counter() - start


def check_outcome(name, code, output, out, complete=None) -> bool:
    """The rules of the module docstring; returns whether the command was interrupted."""
    lines = output.strip().splitlines()
    said = [line for line in lines if line.startswith("interrupted")]
    assert "Traceback" not in output and "Error" not in output.replace("error:", ""), output
    assert code in (0, 130), f"{name}: exit {code}\n{output}"
    assert not [f for f in os.listdir(out.parent) if f.endswith(".tmp")]  # no partial write left
    if code == 130:
        assert len(said) == 1 and lines[-1] == said[0], output  # one line, the last
        assert out.exists() == said[0].startswith(f"interrupted: wrote {out}"), output
    else:
        assert not said and out.exists(), output
    if out.exists():
        image = read_image(str(out))  # whole and readable
        assert image.shape == (48, 64, 3) and np.all(np.isfinite(image))
        if complete is not None:  # a one-shot method writes the finished render or nothing
            np.testing.assert_array_equal(image, complete)
    return code == 130


def test_sigint_at_random_times_in_process(tmp_path, quiet_sigint):
    rng = random.Random(21)
    durations, complete = {}, {}
    for name, args in CASES.items():  # the first run compiles the kernels; the second is timed
        for _ in range(2):
            out = tmp_path / f"{name}.exr"
            result, seconds = invoke(args, out)
            assert result.exit_code == 0, result.output
        durations[name] = seconds
        if name in ("volume", "surface", "screen"):
            complete[name] = read_image(str(out))
        out.unlink()
    interrupted = 0
    names = list(CASES)
    for run in range(RUNS):
        name = names[run % len(names)]
        out = tmp_path / f"{name}.exr"
        delay = rng.uniform(0.0, 1.2 * durations[name])
        result, seconds = invoke(CASES[name], out, delay)
        if result.exit_code == 0:  # finished before the interrupt: the machine got faster
            durations[name] = min(durations[name], seconds)
        assert result.exception is None or isinstance(result.exception, SystemExit), (
            name, delay, result.output)  # fmt: skip
        interrupted += check_outcome(name, result.exit_code, result.output, out,
                                     complete.get(name))  # fmt: skip
        last = (result.output.strip().splitlines() or [""])[-1]
        print(f"{name:9} SIGINT at {delay:.2f} s of {durations[name]:.2f}: {result.exit_code} {last}")
        if out.exists():
            out.unlink()
    assert interrupted >= RUNS // 3  # most interrupts landed mid-command


def photonmap_process(args) -> subprocess.Popen:
    """The real ``photonmap`` process (``python -m photonmap``) with Ctrl-C's default action:
    a test session started in the background (``cmd &``, ``nohup``) ignores SIGINT, and a child
    inherits an ignored signal, which would make every interrupt here a no-op."""
    env = {**os.environ, "PYTHONPATH": os.path.join(ROOT, "src")}
    return subprocess.Popen(
        [sys.executable, "-m", "photonmap", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def run_process(args, delay):
    """:func:`photonmap_process`, SIGINT after ``delay`` s."""
    proc = photonmap_process(args)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    return proc.returncode, out + err


@pytest.mark.parametrize("delay", [0.3, 1.0, 2.2, 3.5])
def test_sigint_to_the_process(tmp_path, delay):
    """The process: during the package import (the first delays) and during the iterations.
    Exit status 130 at the process level, one line, the image of whole iterations or none."""
    out = tmp_path / "y.exr"
    args = [*CASES["sppm"][:-6], "--time", "30", "--set", "photons=20000"]
    code, output = run_process([*args, "-o", str(out)], delay)
    assert code == 130, output
    assert check_outcome("sppm process", code, output, out)


def test_sigint_stops_the_viewer(tmp_path):
    """``view``: the server stops, one line, exit 130; the URL it printed holds the token the
    server requires."""
    import socket

    import httpx

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = photonmap_process(["view", "glass_sphere_fog", "--no-browser", "--port", str(port),
                              "--width", "32", "--set", "grid=16", "--set", "photons=1024"])  # fmt: skip
    try:
        first = proc.stderr.readline()
        while first and not first.startswith("photonmap view:"):
            first = proc.stderr.readline()
        url = first.split()[2]
        assert url.startswith(f"http://127.0.0.1:{port}/?token=")
        deadline = time.monotonic() + 300  # a guard against a hang, not a speed bound
        while True:
            try:
                page = httpx.get(url, timeout=5)
                break
            except httpx.TransportError:
                assert time.monotonic() < deadline
                time.sleep(0.1)
        assert page.status_code == 200 and "photonmap_token" in page.headers["set-cookie"]
        assert httpx.get(url.split("?")[0] + "api/state").status_code == 403  # no token
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, out + err
    lines = (out + err).strip().splitlines()
    assert lines[-1] == "interrupted: the viewer stopped, nothing written"
    assert "Traceback" not in out + err


def test_sigint_twice(tmp_path):
    """Ctrl-C twice in a row: exit 130, one line, nothing partial left — whether the second
    stops the process at once (it arrived while Python ran) or was folded into the first (both
    arrived during one Dr.Jit kernel: Python runs a handler once per burst)."""
    out = tmp_path / "y.exr"
    args = [*CASES["sppm"][:-6], "--time", "30", "--set", "photons=500000",
            "-o", str(out)]  # fmt: skip
    proc = photonmap_process(args)
    time.sleep(3.0)
    proc.send_signal(signal.SIGINT)
    time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    output = stdout + stderr
    assert proc.returncode == 130, output
    last = output.strip().splitlines()[-1]
    assert last in ("interrupted again: stopped at once, nothing more written",) or (
        last.startswith("interrupted: ")), output  # fmt: skip
    assert "Traceback" not in output
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]
    if out.exists():
        assert read_image(str(out)).shape == (48, 64, 3)
