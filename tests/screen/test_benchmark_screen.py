"""Smoke test of ``benchmarks/screen_table1.py`` (issue 4 item 6): quick mode at a tiny size
writes the JSON with the ``headline`` the lead's tooling reads. Speed is not asserted."""

import json
import math

from benchmarks_import import benchmark


def test_quick_run_writes_the_headline(tmp_path):
    screen_table1 = benchmark("screen_table1")
    args = ["--quick", "--frames", "1", "--warmup", "0", "--width", "64", "--height", "48",
            "--out-dir", tmp_path]  # fmt: skip
    screen_table1.main([str(a) for a in args])
    data = json.loads((tmp_path / "screen_table1_quick.json").read_text())
    fps = data["headline"]["fps_cornell_1024x768"]
    assert isinstance(fps, float) and math.isfinite(fps) and fps > 0
    assert set(data["headline"]["stages_ms"]) >= {"eye G-buffer", "photon tracing", "splatting"}
    assert [r["splat"] for r in data["rows"]] == ["quad", "icosahedron"]
    assert data["rows"][0]["thesis_fps_soft"] == 27
    assert "Headline" in (tmp_path / "screen_table1_quick.md").read_text()
