"""Distributed rendering on a local Ray cluster that this module starts (2 worker CPUs on the
loopback address): the merged progressive image equals the single-process one
bit for bit, also when a worker is killed mid-run or the driver is interrupted; a sequence comes
out complete, each file holding its own frame, with the workers' stage caches kept between
frames, also when a worker dies for good."""

import json
import os
import re
import signal

import numpy as np
import pytest
import ray
from typer.testing import CliRunner

from photonmap.cli import app
from photonmap.cluster.connect import remove_session_files, spawn, start_local
from photonmap.cluster.frames import parse_frames
from photonmap.cluster.job import FrameState, SceneJob, build_pipeline
from photonmap.cluster.progressive import Watch, render_progressive
from photonmap.cluster.schedule import run_tasks
from photonmap.cluster.workers import FrameWorker
from photonmap.core.errors import SceneError
from photonmap.core.image import read_image

ITERATIONS, BLOCK = 6, 2
SPPM = SceneJob(
    "cornell_steinhurst", "sppm",
    {"photons": 8000, "seed": 5, "mode": "memoryless"}, width=48, height=36,
)  # fmt: skip
VOLUME = SceneJob("glass_sphere_fog", "volume", {"grid": 32, "photons": 4096}, width=48, height=36)
LIGHT_PATH = {"frames": 4, "light": [{"position": [0.3, 3.0, 0.5]}, {"position": [0.7, 2.0, 0.5]}]}


@pytest.fixture(scope="module")
def address():
    """A private Ray instance with 2 CPUs (one worker each), shut down after the module."""
    addr = start_local(ray, 2)
    yield addr
    ray.shutdown()
    remove_session_files()


@pytest.fixture(scope="module")
def single():
    """The single-process memoryless render: ``run(iterations=N)`` of one pipeline."""
    pipe = build_pipeline(SPPM)
    return pipe.run(iterations=ITERATIONS).numpy(), pipe


def test_merged_blocks_equal_single_process(address, single, tmp_path):
    out = tmp_path / "box.exr"
    p = SPPM.params
    result = CliRunner().invoke(app, [
        "render", SPPM.scene, "--method", "sppm", "--seed", str(p["seed"]),
        "--set", f"photons={p['photons']}",
        "--set", f"iterations={ITERATIONS}", "--width", str(SPPM.width),
        "--height", str(SPPM.height), "--ray", address, "-o", str(out),
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert f"sppm: {ITERATIONS} iterations in" in result.output
    assert "on 2 worker(s)" in result.output  # both workers took blocks
    image = read_image(str(out))
    assert np.array_equal(image, single[0])  # bit-identical (module docstring of .progressive)
    assert image.mean() > 0.05


def test_worker_killed_mid_run_gives_the_same_image(address, single):
    killed, previews = [], []

    def kill_first(done, info):  # SIGKILL the worker that delivered the first block
        if not killed:
            os.kill(info["pid"], signal.SIGKILL)
            killed.append(info["pid"])

    watch = Watch(preview=previews.append, preview_every=0, on_block=kill_first)
    result = render_progressive(SPPM, ITERATIONS, address=address, block=1, watch=watch)
    pids = {b["pid"] for b in result.blocks}
    assert killed and len(pids) >= 3  # Ray restarted the killed actor and ran its blocks again
    assert sorted(b["first"] for b in result.blocks) == list(range(1, ITERATIONS + 1))
    assert result.iterations == ITERATIONS and not result.interrupted
    image = result.sums.image()
    assert np.array_equal(image, single[0])
    assert 1 <= len(previews) <= len(result.blocks)  # one per arrival once block 1 is in
    assert np.array_equal(previews[-1], image)


def test_interrupted_driver_keeps_what_was_merged(address, single):
    def interrupt(done, info):
        if done:
            raise KeyboardInterrupt

    result = render_progressive(SPPM, ITERATIONS, address=address, block=BLOCK,
                                watch=Watch(on_block=interrupt))  # fmt: skip
    assert result.interrupted and result.iterations >= BLOCK and result.iterations % BLOCK == 0
    expect = single[1].render_block(1, result.iterations).image()
    assert np.array_equal(result.sums.image(), expect)


def _reference(frames):
    """Each frame rendered in this process by a fresh pipeline."""
    return [np.asarray(FrameState(VOLUME).apply(f).render()) for f in frames]


@pytest.fixture(scope="module")
def light_path():
    frames = parse_frames(LIGHT_PATH).frames
    return frames, _reference(frames)


def test_sequence_complete_ordered_and_cached(address, light_path, tmp_path):
    frames, expect = light_path
    spec = tmp_path / "light.json"
    spec.write_text(json.dumps({**LIGHT_PATH, "width": 48, "height": 36, "set": VOLUME.params}))
    result = CliRunner().invoke(app, ["render-sequence", "glass_sphere_fog", "--frames",
                                      str(spec), "-o", str(tmp_path / "f%03d.exr"),
                                      "--ray", address])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.glob("*.exr")) == [f"f{i:03d}.exr" for i in range(4)]
    for i, want in enumerate(expect):
        got = read_image(str(tmp_path / f"f{i:03d}.exr"))
        assert np.abs(got - want).max() <= 1e-6 * np.abs(want).max()  # frame i in file i
    assert not np.allclose(expect[0], expect[-1], rtol=0.05)  # the light did move
    reran = [int(n) for n in re.findall(r"reran (\d+) stage", result.output)]
    # each worker voxelizes once; its later frames rerun only the light's stages S5–S9
    assert sorted(reran) == [5, 5, 10, 10], result.output


def test_sequence_survives_a_worker_that_dies(address, light_path):
    frames, expect = light_path
    from photonmap.cluster.connect import placement

    got = {}
    tasks = [(f.index, (f,)) for f in frames]
    with spawn(ray, FrameWorker, placement(ray, 2), VOLUME) as actors:
        for index, (image, _info) in run_tasks(ray, actors, "render", tasks):
            if not got:
                ray.kill(actors[1])  # gone for good (no restart): its frames go to the other
            assert index not in got
            got[index] = image
    assert sorted(got) == [0, 1, 2, 3]
    for i, want in enumerate(expect):
        assert np.abs(got[i] - want).max() <= 1e-6 * np.abs(want).max()


def test_a_worker_error_reaches_the_driver_as_itself(address):
    """Bad input on a worker (here a scene file the node lacks) is raised as the worker's own
    PhotonmapError, not retried and not reported as a dead worker."""
    job = SceneJob("no/such/scene.xml", "sppm", {"photons": 100})
    with pytest.raises(SceneError, match="neither a built-in nor a file on this node"):
        render_progressive(job, 2, workers=1, address=address)


@pytest.fixture
def quiet_sigint():
    """A late SIGINT (after a command returned) must not stop the test session."""
    previous = signal.signal(signal.SIGINT, lambda *_: None)
    yield
    signal.signal(signal.SIGINT, previous)


def _sigint_when(condition, timeout=120.0):
    """SIGINT this process (from a thread) once ``condition()`` holds."""
    import threading
    import time

    def wait():
        deadline = time.monotonic() + timeout
        while not condition() and time.monotonic() < deadline:
            time.sleep(0.02)
        os.kill(os.getpid(), signal.SIGINT)

    thread = threading.Thread(target=wait, daemon=True)
    thread.start()
    return thread


def test_ctrl_c_on_a_sequence_keeps_whole_frames(address, tmp_path, quiet_sigint):
    """Ctrl-C after the first frame is on disk: the frames written stay whole, one line says how
    many, exit 130."""
    spec = tmp_path / "light.json"
    spec.write_text(json.dumps({**LIGHT_PATH, "frames": 12, "width": 48, "height": 36,
                                "set": VOLUME.params}))  # fmt: skip
    thread = _sigint_when(lambda: any(tmp_path.glob("f*.exr")))
    result = CliRunner().invoke(app, ["render-sequence", "glass_sphere_fog", "--frames", str(spec),
                                      "-o", str(tmp_path / "f%03d.exr"), "--ray", address])  # fmt: skip
    thread.join()
    written = sorted(tmp_path.glob("f*.exr"))
    assert result.exit_code == 130, result.output
    lines = result.output.strip().splitlines()
    assert lines[-1] == f"interrupted: {len(written)} of 12 frames written"
    assert "Traceback" not in result.output and 1 <= len(written) <= 12
    for path in written:
        assert read_image(str(path)).shape == (36, 48, 3)
    assert not list(tmp_path.glob(".*.tmp"))


def test_ctrl_c_on_distributed_sppm_writes_the_merged_blocks(address, tmp_path, quiet_sigint):
    out = tmp_path / "box.exr"
    p = SPPM.params
    args = ["render", SPPM.scene, "--method", "sppm", "--seed", str(p["seed"]),
            "--set", f"photons={p['photons']}",
            "--set", "iterations=400", "--width", str(SPPM.width), "--height", str(SPPM.height),
            "--preview-every", "0.01", "--ray", address, "-o", str(out)]  # fmt: skip
    thread = _sigint_when(out.exists)  # after the first preview: some blocks merged
    result = CliRunner().invoke(app, args)
    thread.join()
    assert result.exit_code == 130, result.output
    last = result.output.strip().splitlines()[-1]
    assert re.fullmatch(rf"interrupted: wrote {re.escape(str(out))} \(the image of \d+ iterations?\)",
                        last), result.output  # fmt: skip
    assert "Traceback" not in result.output
    assert read_image(str(out)).shape == (SPPM.height, SPPM.width, 3)


def test_a_local_instance_runs_its_workers_at_the_drivers_priority(address):
    """Ray's default niceness of 15 would starve the render beside any other busy process."""
    def niceness():
        return os.nice(0)

    assert ray.get(ray.remote(niceness).remote()) == niceness()


def test_a_local_instance_keeps_its_files_in_its_own_temporary_folder(address):
    """Ray left a /tmp/ray/session_* folder per run; a private instance's session
    lives in a temporary folder of its own, removed when it is shut down."""
    from ray._private import worker

    from photonmap.cluster import connect

    session = worker._global_node.get_session_dir_path()
    assert connect._session_dirs and session.startswith(connect._session_dirs[-1] + os.sep)
    assert not session.startswith("/tmp/ray/")
