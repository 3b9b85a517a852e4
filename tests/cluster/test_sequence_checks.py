"""``render-sequence`` checks every frame before the first one starts: types,
lengths, ranges and memory, each refusal one line naming the frame; and a worker's failure
reaches the user as one plain line naming the frame, without the remote traceback or its colour
codes. No Ray instance is needed: the checks run before Ray starts, and the scheduler is driven
by a stand-in for Ray."""

from __future__ import annotations

import json
import types

import pytest
from typer.testing import CliRunner

from photonmap.cli import app
from photonmap.cluster.connect import ClusterError
from photonmap.cluster.schedule import run_tasks
from photonmap.core.errors import SceneError

BASE = {"method": "volume", "width": 32, "height": 24, "set": {"grid": 16, "photons": 1024}}


def sequence(tmp_path, spec: dict):
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(spec))
    return CliRunner().invoke(app, ["render-sequence", "glass_sphere_fog", "--frames", str(path),
                                    "-o", str(tmp_path / "f%02d.png"), "--workers", "1"])  # fmt: skip


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ({"frames": 2, "camera": {"origin": [0.5, 1.0]}},
         "camera.origin must be 3 numbers [x, y, z], got [0.5, 1.0]"),
        ({"frames": 2, "camera": {"origin": [1, 1, 1], "target": [1, 1, 1]}},
         "frame 0: camera origin and target must differ"),
        ({"frames": 2, "camera": {"fov": 0}}, "camera.fov must be degrees in (0, 180)"),
        ({"frames": [{"set": {"photons": 1024}}, {"set": {"photons": 2**30}}]},
         "frame 1: grid=16 needs about"),
        ({"frames": [{"set": {"photons": 1024}}, {"set": {"photons": "many"}}]},
         "frame 1: photons must be an integer"),
        ({"frames": 2, "light": {"position": [0, 1]}}, "frame 0: light position must be 3 numbers"),
    ],
)
def test_every_frame_is_checked_before_any_work(tmp_path, spec, message):
    result = sequence(tmp_path, {**BASE, **spec, "set": {**BASE["set"], **spec.get("set", {})}})
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], lines
    assert not list(tmp_path.glob("f*.png"))


def test_a_sppm_frame_beyond_memory_names_its_frame(tmp_path):
    spec = {"method": "sppm", "width": 32, "height": 24,
            "frames": [{"set": {"photons": 1000, "iterations": 1}},
                       {"set": {"photons": 10**12, "iterations": 1}}]}  # fmt: skip
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(spec))
    result = CliRunner().invoke(app, ["render-sequence", "examples/cornell_box.xml", "--frames",
                                      str(path), "-o", str(tmp_path / "f%02d.exr")])  # fmt: skip
    assert result.exit_code == 2, result.output
    (line,) = result.output.strip().splitlines()
    assert line.startswith("error: frame 1: these sppm settings need about") and "TB" in line


class _TaskError(Exception):
    """Ray's RayTaskError: ``str`` is the remote traceback with colour codes, ``cause`` the
    worker's exception."""

    def __init__(self, cause):
        super().__init__(
            "\x1b[36mray::FrameWorker.render()\x1b[39m (pid=1, ip=127.0.0.1)\n"
            "Traceback (most recent call last):\n  File \"workers.py\", line 57, in render\n"
            f"{type(cause).__name__}: {cause}"
        )
        self.cause = cause


class _ActorError(Exception):
    pass


class _FakeRay:
    """Just enough of Ray for :func:`run_tasks`: each call returns its result at once, or the
    task's failure."""

    exceptions = types.SimpleNamespace(RayTaskError=_TaskError, RayActorError=_ActorError,
                                       ActorDiedError=_ActorError)  # fmt: skip

    def __init__(self, fail: dict):
        self.fail = fail

    def wait(self, refs, num_returns=1, timeout=None):
        return refs[:1], refs[1:]

    def get(self, ref):
        key = ref
        if key in self.fail:
            raise _TaskError(self.fail[key])
        return f"image {key}"

    def cancel(self, ref):
        pass


class _Actor:
    def __init__(self):
        self.render = types.SimpleNamespace(remote=lambda frame: frame)


def test_a_worker_failure_is_one_line_naming_the_frame():
    ray = _FakeRay({3: MemoryError("std::bad_alloc: out of memory")})
    tasks = [(i, (i,)) for i in range(5)]
    done = []
    with pytest.raises(ClusterError) as info:
        for key, _result in run_tasks(ray, [_Actor()], "render", tasks, label="frame"):
            done.append(key)
    assert str(info.value) == "frame 3: the worker failed: MemoryError: std::bad_alloc: out of memory"
    assert "\x1b" not in str(info.value) and done == [0, 1, 2]


def test_a_workers_own_error_keeps_its_kind_and_names_the_frame():
    ray = _FakeRay({1: SceneError("the scene has no light")})
    with pytest.raises(SceneError, match=r"^frame 1: the scene has no light$"):
        list(run_tasks(ray, [_Actor()], "render", [(i, (i,)) for i in range(3)], label="frame"))
