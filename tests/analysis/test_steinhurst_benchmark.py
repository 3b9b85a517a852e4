"""Smoke test of ``benchmarks/steinhurst_tables.py`` in quick mode: it runs end to end and writes
the JSON (with its headline keys) and markdown. Correctness only; no timing assertions."""

from __future__ import annotations

import json

from benchmarks_import import benchmark


def test_quick_run_writes_tables(tmp_path):
    result = benchmark("steinhurst_tables").main(["--quick", "--out-dir", str(tmp_path)])
    data = json.loads((tmp_path / "steinhurst_tables_quick.json").read_text())
    assert (tmp_path / "steinhurst_tables_quick.md").is_file()
    headline = data["headline"]
    for scene in ("cornell_steinhurst", "cornell_bushes"):
        for key in ("traffic_reduction_dirbin_hashed", "traffic_reduction_tiled_hilbert"):
            assert headline[key][scene] > 0
        table = data["scenes"][scene]["table"]
        # O16's end points hold even at this tiny size: whole-image Hilbert moves the least
        assert table["hilbert"]["GB_per_image"] <= table["naive"]["GB_per_image"]
    assert headline["cpu_speedup_best_order"] > 0
    structures = data["structures"]["table"]  # Table 4.1: every order on the three structures
    assert all(len(row) == 3 and row["kdtree"]["misses"] > 0 for row in structures.values())
    assert len(data["load_average"]) == 3 and result["headline"] == headline
    sponza = benchmark("steinhurst_tables").main(
        ["--quick", "--only", "sponza_setting", "--out-dir", str(tmp_path)]
    )
    assert sponza["headline"]["traffic_reduction_dirbin_hashed_sponza_setting"] > 0
    assert "Sponza setting" in (tmp_path / "steinhurst_tables_quick.md").read_text()
