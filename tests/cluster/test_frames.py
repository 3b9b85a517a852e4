"""Frame specs (photonmap.cluster.frames), block plans (.progressive) and the refusals of the
cluster CLI that happen before any Ray work: bad specs, bad keys, bad output patterns, bad
addresses."""

import json
import socket
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from photonmap import BlockSums
from photonmap.cli import app
from photonmap.cluster import progressive
from photonmap.cluster.connect import ClusterError, parse_address, probe
from photonmap.cluster.frames import FrameSpecError, check_pattern, parse_frames
from photonmap.cluster.job import FrameState, SceneJob
from photonmap.cluster.progressive import (
    MAX_BLOCK,
    TIMED_BLOCK,
    InOrder,
    block_size,
    blocks,
    check_job,
)
from photonmap.core.errors import ParameterError

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_path_interpolates_keyframes_evenly():
    spec = parse_frames(
        {
            "frames": 5,
            "camera": [{"origin": [0.0, 1.0, 4.0]}, {"origin": [2.0, 1.0, 0.0]}],
            "set": [{"photons": 1000, "sampler": "a"}, {"photons": 2001, "sampler": "b"},
                    {"photons": 3000, "sampler": "c"}],
            "light": {"position": [1, 2, 3]},
            "width": 32,
        }
    )  # fmt: skip
    assert [f.index for f in spec.frames] == [0, 1, 2, 3, 4]
    assert [f.camera["origin"][0] for f in spec.frames] == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert [f.camera["origin"][2] for f in spec.frames] == [4.0, 3.0, 2.0, 1.0, 0.0]
    # three keyframes over five frames: at 0, 2, 4; integers stay integers, text steps
    assert [f.set["photons"] for f in spec.frames] == [1000, 1500, 2001, 2500, 3000]
    assert [f.set["sampler"] for f in spec.frames] == ["a", "a", "b", "b", "c"]
    assert all(f.light == {"position": [1, 2, 3]} for f in spec.frames)
    assert spec.width == 32 and spec.height is None


def test_list_form_puts_frame_values_over_the_shared_ones():
    spec = parse_frames(
        {"frames": [{"set": {"photons": 10}}, {"set": {"photons": 20, "seed": 2}}],
         "set": {"seed": 7}, "method": "surface"}
    )  # fmt: skip
    assert [f.set for f in spec.frames] == [{"photons": 10, "seed": 7}, {"photons": 20, "seed": 2}]
    assert spec.method == "surface"


@pytest.mark.parametrize(
    "data, words",
    [
        ([], "JSON object"),
        ({"camera": {}}, "no 'frames'"),
        ({"frames": 0}, "1…"),
        ({"frames": "3"}, "frame count"),
        ({"frames": 2, "zoom": 1}, "unknown key"),
        ({"frames": 2, "camera": {"eye": [0, 0, 0]}}, "unknown camera key"),
        ({"frames": 2, "camera": []}, "empty list"),
        ({"frames": [{"set": {"photons": 1}}, {"set": {"k": 2}}]}, "differ in which set keys"),
        ({"frames": [{"light": {"position": [0, 0, 0]}}, {}]}, "differ in which light keys"),
        ({"frames": 3, "light": [{"position": [0, 1]}, {"position": [0, 1, 2]}]}, "one length"),
        ({"frames": 3, "camera": [{"origin": [0, 1]}, {"origin": [0, 1, 2]}]}, "3 numbers"),
        ({"frames": 2, "set": {"radius": float("nan")}}, "finite"),
        ({"frames": 2, "set": {"radius": {"a": 1}}}, "expected a number"),
        ({"frames": [{"zoom": 1}]}, "unknown key"),
        ({"frames": [{"light": {"index": 0}}, {"light": {"index": 1}}]}, "light index"),
        ({"frames": 2, "width": 0}, "width"),
    ],
)
def test_bad_specs_are_refused(data, words):
    with pytest.raises(FrameSpecError, match=words):
        parse_frames(data)


@pytest.mark.parametrize("pattern", ["out/frame.png", "out/%s.png", "out/%d-%d.png"])
def test_output_pattern_needs_one_frame_number(pattern):
    with pytest.raises(FrameSpecError):
        check_pattern(pattern)


def _spec(tmp_path, data, name="spec.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data) if not isinstance(data, str) else data)
    return path


@pytest.mark.parametrize(
    "data, words",
    [
        ("{not json", "not valid JSON"),
        ({"frames": 2, "set": {"fotons": 10}}, "unknown volume parameter(s) fotons"),
        ({"frames": [{"set": {"fotons": 1}}, {"set": {"fotons": 2}}]}, "unknown set key(s) fotons"),
        ({"frames": 2, "method": "surface", "light": {"position": [0, 1, 0]}},
         "cannot move lights"),
        ({"frames": 2, "method": "warp"}, "unknown method"),
        ({"frames": 2, "light": {"index": 5}}, "no light 5"),
    ],
)  # fmt: skip
def test_render_sequence_refuses_bad_specs_before_any_work(tmp_path, data, words):
    spec = _spec(tmp_path, data)
    result = run("render-sequence", "glass_sphere_fog", "--frames", spec,
                 "-o", tmp_path / "%03d.png", "--workers", 2)  # fmt: skip
    assert result.exit_code == 2, result.output
    assert words in result.output and result.output.startswith("error: ")
    assert len(result.output.strip().splitlines()) == 1
    assert not list(tmp_path.glob("*.png"))


def test_render_sequence_refuses_output_without_frame_number(tmp_path):
    spec = _spec(tmp_path, {"frames": 2})
    result = run("render-sequence", "glass_sphere_fog", "--frames", spec, "-o", tmp_path / "a.png")
    assert result.exit_code == 2 and "frame-number field" in result.output


def test_workers_only_for_the_progressive_method(tmp_path):
    result = run("render", "cornell_steinhurst", "--method", "surface", "--workers", 2,
                 "-o", tmp_path / "a.png")  # fmt: skip
    assert result.exit_code == 2 and "--method sppm" in result.output
    result = run("render", "cornell_steinhurst", "--method", "sppm", "--set", "mode=sppm",
                 "--workers", 2, "-o", tmp_path / "a.png")  # fmt: skip
    assert result.exit_code == 2 and "mode=memoryless" in result.output


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # closed again when the socket is


@pytest.mark.parametrize("address", ["nonsense", "127.0.0.1", "127.0.0.1:99999", "ray://h:1"])
def test_malformed_addresses_are_refused(address):
    with pytest.raises(ClusterError):
        parse_address(address)


def test_unreachable_address_is_one_line_and_fast(tmp_path, monkeypatch):
    """Refused by the probe, before Ray is asked to join (Ray alone retries an address for a
    minute): ``ray.init`` is never called."""
    import ray

    joins = []
    monkeypatch.setattr(ray, "init", lambda *a, **k: joins.append(a or k))
    address = f"127.0.0.1:{_closed_port()}"
    with pytest.raises(ClusterError, match="cannot reach"):
        probe(address)
    result = run("render", "cornell_steinhurst", "--method", "sppm", "--ray", address,
                 "--width", 32, "-o", tmp_path / "a.png")  # fmt: skip
    assert result.exit_code == 2
    assert result.output.startswith(f"error: cannot reach a Ray cluster at {address}")
    assert len(result.output.strip().splitlines()) == 1
    spec = _spec(tmp_path, {"frames": 1, "set": {"grid": 32}})
    result = run("render-sequence", "glass_sphere_fog", "--frames", spec, "--ray", address,
                 "-o", tmp_path / "%d.png")  # fmt: skip
    assert result.exit_code == 2 and "cannot reach" in result.output
    assert joins == []


def test_frame_state_depends_on_the_frame_only():
    """A worker renders frames in any order: a frame applied after another gives the pipeline
    the same camera and parameters as a fresh pipeline given that frame alone."""
    job = SceneJob("cornell_steinhurst", "surface", {}, width=32, height=24)
    a, b = parse_frames(
        {"frames": [{"camera": {"origin": [0.2, 1.0, 3.5]}, "set": {"photons": 1000}},
                    {"camera": {"origin": [-0.4, 1.2, 3.0]}, "set": {"photons": 2000}}]}
    ).frames  # fmt: skip
    state = FrameState(job)
    state.apply(b)
    after_b = state.apply(a)
    fresh = FrameState(job).apply(a)
    for pipe in (after_b, fresh):
        assert pipe.params.photons == 1000
    assert np.array_equal(_pose(after_b), _pose(fresh))
    assert not np.array_equal(_pose(FrameState(job).apply(b)), _pose(fresh))


def _pose(pipe):
    return np.asarray(pipe.sensor.world_transform().matrix, dtype=np.float64)


def test_blocks_cover_the_iterations_in_order_and_stop_at_the_deadline(monkeypatch):
    tasks = list(blocks(10, 4))
    assert tasks == [(1, (1, 4)), (5, (5, 4)), (9, (9, 2))]
    assert [block_size(64, 2), block_size(1000, 2), block_size(3, 4), block_size(None, 2)] == [
        8, MAX_BLOCK, 1, TIMED_BLOCK,
    ]
    now = [100.0]  # a clock of the test's own: the deadline is a fact, not a race
    monkeypatch.setattr(progressive, "time", SimpleNamespace(perf_counter=lambda: now[0]))
    assert list(blocks(None, 2, deadline=99.0)) == []
    timed = blocks(None, 2, deadline=100.05)
    assert [next(timed)[0] for _ in range(3)] == [1, 3, 5]  # open-ended until the deadline
    now[0] = 100.06
    assert next(timed, None) is None


def test_progressive_jobs_are_memoryless_sppm():
    job = SceneJob("cornell_steinhurst", "sppm", {"photons": 10})
    assert check_job(job).params == {"photons": 10, "mode": "memoryless"}
    with pytest.raises(ParameterError, match="mode=memoryless"):
        check_job(SceneJob("cornell_steinhurst", "sppm", {"mode": "sppm"}))
    with pytest.raises(ParameterError, match="render-sequence"):
        check_job(SceneJob("cornell_steinhurst", "surface"))


def test_blocks_merge_in_block_order_whatever_order_they_arrive_in():
    rng = np.random.default_rng(3)
    parts = {f: BlockSums(rng.random((2, 3, 3)) * 10.0 ** rng.integers(-8, 8), 2) for f in
             (1, 3, 5, 7)}  # fmt: skip
    expect = parts[1].merge(parts[3]).merge(parts[5]).merge(parts[7])
    merged = InOrder()
    for first, held in ((5, None), (3, None), (1, 5), (7, 7)):  # arrival → blocks merged so far
        merged.add(first, parts[first])
        assert (merged.sums is None and held is None) or merged.next == held + 2
    assert np.array_equal(merged.sums.total, expect.total) and merged.sums.iterations == 8
