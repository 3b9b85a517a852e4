"""Smoke test of ``benchmarks/volume_table1.py`` (issue item 8): the script runs end to end in
quick mode on a tiny configuration and writes a JSON whose schema the lead's tooling reads.
Correctness only; speed is measured by the benchmark itself (DESIGN.md)."""

import json
import math

import pytest

from benchmarks_import import benchmark
from photonmap.volume.pipeline import STAGES


@pytest.fixture(scope="module")
def volume_table1():
    return benchmark("volume_table1")


def _positive(value) -> bool:
    return isinstance(value, int | float) and math.isfinite(value) and value > 0


def test_paper_table_is_transcribed(volume_table1):
    rows = volume_table1.PAPER_TABLE1
    assert [r.number for r in rows] == list(range(1, 12))
    assert [r.triangles for r in rows[:4]] == [10_000, 20_000, 40_000, 80_000]
    assert [r.extent for r in rows[4:8]] == [64, 77, 90, 103]
    assert [r.photons for r in rows[8:]] == [256**2, 512**2, 1024**2]
    # spec §3.1 derived: total − voxelization − tracing ≈ 68–76 ms
    hidden = [r.total_ms - r.voxelization_ms - r.tracing_ms for r in rows]
    assert all(68 <= h <= 76 for h in hidden)


def test_quick_run_writes_schema(volume_table1, tmp_path):
    result = volume_table1.main(
        [
            "--quick",
            "--grid",
            "32",
            "--width",
            "64",
            "--height",
            "48",
            "--photons",
            "4096",
            "--rows",
            "5,11",
            "--out-dir",
            str(tmp_path),
        ]
    )
    path = tmp_path / "volume_table1_quick.json"
    assert path.is_file() and (tmp_path / "volume_table1_quick.md").is_file()
    data = json.loads(path.read_text())
    assert data == json.loads(json.dumps(result, default=str))

    machine = data["machine"]
    for key in ("cpu_model", "cores", "mitsuba", "drjit", "date"):
        assert machine[key]

    headline = data["headline"]
    assert _positive(headline["full_frame_s"]) and _positive(headline["view_only_s"])
    assert headline["photons"] == 4096 and headline["grid"] == 32
    assert headline["view_only"]["recomputed"] == ["viewing"]
    assert "viewing" in headline["light_change"]["recomputed"]
    assert "voxelization" not in headline["light_change"]["recomputed"]
    secondary = data["secondary"]
    assert _positive(secondary["full_frame_s"]) and _positive(secondary["view_only_s"])

    assert [r["row"] for r in data["rows"]] == [5, 11]
    for row in data["rows"]:
        ours = row["ours"]
        assert row["photons"] == 4096
        for stage in STAGES:
            assert _positive(ours["stages_ms"][stage]), stage
        assert _positive(ours["total_ms"]) and ours["steps"] > 0
        assert ours["photons_propagated"] > 0
        assert len(ours["samples"]) == 1
        assert _positive(row["paper"]["total_ms"])

    profile = data["profile"]
    assert profile["slowest_stage"] in profile["light_change_stage_share"]
    assert math.isclose(sum(profile["light_change_stage_share"].values()), 1.0)
    march = profile["march"]
    assert "error" not in march, march
    assert march["steps"] == march["without_deposits_steps"] > 0
    if "deposits" in march:
        assert march["deposits"] > 0 and march["deposits_consistent"]

    table = (tmp_path / "volume_table1_quick.md").read_text()
    assert "| 11 |" in table and "Headline" in table


def test_rejects_bad_arguments(volume_table1, tmp_path):
    with pytest.raises(ValueError, match="rows"):
        volume_table1.run(rows=[12], out_dir=None)
    with pytest.raises(ValueError, match="photon"):
        volume_table1.run(photons=[1, 2, 3, 4], out_dir=None)


def test_surface_benchmark_masks_the_light_and_its_specular_images():
    """The surface benchmark's error mask drops the pixels that see the light, directly or through
    the mirror and glass spheres, and nothing else of note."""
    import mitsuba as mi
    import numpy as np

    from photonmap.scenes import SCENES

    surface_vs_path = benchmark("surface_vs_path")
    scene = mi.load_dict(SCENES["cornell_steinhurst"].build(width=64, height=64))
    mask = surface_vs_path.light_image_mask(scene, spp=16)
    seen = np.array(
        mi.render(scene, integrator=mi.load_dict({"type": "path", "max_depth": 1}), spp=16)
    )
    assert not mask[seen.max(-1) > 1.0].any()  # the light itself
    assert 0.005 < 1 - mask.mean() < 0.05
    # its images in the spheres are masked: more masked pixels than the light alone covers
    assert (~mask).sum() > 2 * (seen.max(-1) > 0.01).sum()
