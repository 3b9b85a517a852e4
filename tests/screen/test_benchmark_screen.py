"""Smoke test of ``benchmarks/screen_table1.py``: quick mode at a tiny size writes the JSON with
the ``headline`` the lead's tooling reads, and what it reports is what the pipeline did. Speed is
not asserted."""

import json

import pytest

from benchmarks_import import benchmark


def test_quick_run_writes_the_headline(tmp_path):
    screen_table1 = benchmark("screen_table1")
    args = ["--quick", "--frames", "1", "--warmup", "0", "--width", "64", "--height", "48",
            "--out-dir", tmp_path]  # fmt: skip
    screen_table1.main([str(a) for a in args])
    data = json.loads((tmp_path / "screen_table1_quick.json").read_text())
    head = data["headline"]
    # fps is 1000 / the median frame; the stage timers lie inside the timed frame
    assert head["fps_cornell_1024x768"] == pytest.approx(1e3 / head["frame_ms_median"])
    assert sum(head["stages_ms"].values()) <= head["frame_ms_median"]
    assert set(head["stages_ms"]) >= {"eye G-buffer", "photon tracing", "splatting"}
    # "camera move (photons kept)": the eye side reruns, the light side does not
    moved = set(head["camera_move_stages_ms"])
    assert {"eye G-buffer", "splatting", "composite"} <= moved
    assert not {"light G-buffer", "photon tracing"} & moved
    assert [r["splat"] for r in data["rows"]] == ["quad", "icosahedron"]
    # each row carries the thesis fps of its own ROWS entry
    table = {(t, label, scene, s, b, soft, hard, splat)
             for t, label, scene, _, s, b, soft, hard, splat in screen_table1.ROWS}  # fmt: skip
    keys = ("table", "scene", "builtin", "subsample", "bounces", "thesis_fps_soft",
            "thesis_fps_hard", "splat")  # fmt: skip
    assert all(tuple(r[k] for k in keys) in table for r in data["rows"])
    assert "Headline" in (tmp_path / "screen_table1_quick.md").read_text()
