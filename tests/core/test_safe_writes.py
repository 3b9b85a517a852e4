"""Writes that cannot lose data: every image goes to a temporary file in the
target's directory and is renamed into place, so a failed write leaves the previous file intact
and says so in one line (exit status 1 for I/O, 2 for a path the user can fix); an output that
is not a regular file is refused before any work."""

from __future__ import annotations

import errno
import os
import stat
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from photonmap.cli import app
from photonmap.core import image as image_io
from photonmap.core.errors import OutputError, WriteError
from photonmap.core.image import read_image, write_bytes, write_image

SURFACE = ["examples/cornell_box.xml", "--method", "surface", "--width", "32", "--height", "24",
           "--set", "photons=2000", "--set", "caustic_photons=0", "--set", "fg_rays=2",
           "--set", "emitter_spp=0"]  # fmt: skip
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _image(value: float, shape=(24, 32)) -> np.ndarray:
    return np.full((*shape, 3), value, np.float32)


def _temporaries(folder) -> list[str]:
    return [name for name in os.listdir(folder) if name.endswith(".tmp")]


def _disk_full(fd, data):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_failed_write_keeps_the_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "prev.exr"
    write_image(str(path), _image(0.25))
    before = path.read_bytes()
    monkeypatch.setattr(image_io, "_write_all", _disk_full)
    with pytest.raises(WriteError, match="No space left on device; the previous file"):
        write_image(str(path), _image(0.75, (48, 64)))
    assert path.read_bytes() == before and np.all(read_image(str(path)) == 0.25)
    assert _temporaries(tmp_path) == []
    with pytest.raises(WriteError):  # no previous file: nothing is left behind
        write_image(str(tmp_path / "new.png"), _image(0.5))
    assert sorted(os.listdir(tmp_path)) == ["prev.exr"]


def test_rewrite_keeps_permissions_and_links(tmp_path):
    target = tmp_path / "real.exr"
    write_image(str(target), _image(0.1))
    os.chmod(target, 0o640)
    link = tmp_path / "link.exr"
    link.symlink_to(target)
    write_image(str(link), _image(0.9))
    assert link.is_symlink() and np.all(read_image(str(target)) == 0.9)
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o640
    assert _temporaries(tmp_path) == []


def test_a_real_failing_disk_keeps_the_previous_file(tmp_path):
    """The kernel refuses the write (file-size limit, as a full disk would): the previous file
    stays whole and readable."""
    path = tmp_path / "prev.exr"
    write_image(str(path), _image(0.25))
    before = path.read_bytes()
    code = (
        "import resource, signal, sys, numpy as np\n"
        "from photonmap.core.image import write_image\n"
        "from photonmap.core.errors import WriteError\n"
        "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))\n"
        "try:\n"
        "    write_image(sys.argv[1], np.random.default_rng(0).random((64, 64, 3)))\n"
        "except WriteError as exc:\n"
        "    print(exc)\n"
    )
    env = {**os.environ, "PYTHONPATH": os.path.join(ROOT, "src")}
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True,
                         env=env, timeout=120)  # fmt: skip
    assert "could not write" in out.stdout and "previous file" in out.stdout, out.stderr
    assert path.read_bytes() == before and np.all(read_image(str(path)) == 0.25)
    assert _temporaries(tmp_path) == []


def test_cli_write_failure_is_one_line_exit_1(tmp_path, monkeypatch):
    path = tmp_path / "prev.exr"
    write_image(str(path), _image(0.25))
    before = path.read_bytes()
    monkeypatch.setattr(image_io, "_write_all", _disk_full)
    result = CliRunner().invoke(app, ["render", *SURFACE, "-o", str(path)])
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert lines[-1].startswith("error: could not write") and "No space left" in lines[-1]
    assert "Traceback" not in result.output and result.exception.__class__ is SystemExit
    assert path.read_bytes() == before and _temporaries(tmp_path) == []


def test_output_that_is_not_a_regular_file_is_refused_before_work(tmp_path):
    """As ``-o`` naming /dev/full (through a link, for the extension): a FIFO stands in for the
    device, so that a failure of this test can never replace a device file."""
    fifo = tmp_path / "device"
    os.mkfifo(fifo)
    link = tmp_path / "full.exr"
    link.symlink_to(fifo)
    result = CliRunner().invoke(app, ["render", *SURFACE, "-o", str(link)])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        f"error: output '{link}' is not a regular file (a device, pipe or socket): give a file path"
    ]
    with pytest.raises(OutputError, match="not a regular file"):
        write_bytes(str(link), b"x")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and link.is_symlink()


def test_a_path_the_user_can_fix_is_exit_2(tmp_path, monkeypatch):
    def denied(fd, data):
        raise OSError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(image_io, "_write_all", denied)
    with pytest.raises(OutputError, match="Permission denied; choose another path"):
        write_image(str(tmp_path / "x.png"), _image(0.5))
    assert OutputError("x").exit_code == 2 and WriteError("x").exit_code == 1


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs Linux CPU affinity")
def test_an_exr_is_written_on_one_core(tmp_path):
    """On a machine (or container) with one core, Dr.Jit starts one worker thread, and Mitsuba's
    OpenEXR writer then waits forever for a second one: photonmap gives Dr.Jit at least two."""
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from photonmap.core.image import read_image, write_image\n"
        "write_image(sys.argv[1], np.full((8, 8, 3), 0.5, np.float32))\n"
        "print(read_image(sys.argv[1]).mean())\n"
    )
    env = {**os.environ, "PYTHONPATH": os.path.join(ROOT, "src")}
    one = min(os.sched_getaffinity(0))
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "a.exr")], env=env,
                         capture_output=True, text=True, timeout=120,
                         preexec_fn=lambda: os.sched_setaffinity(0, {one}))  # fmt: skip
    assert out.returncode == 0 and float(out.stdout) == 0.5, out.stderr
