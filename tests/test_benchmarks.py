"""Smoke test of ``benchmarks/volume_table1.py``: the script runs end to end in quick mode on a
tiny configuration and writes a JSON whose schema the lead's tooling reads. Correctness only;
speed is measured by the benchmark itself (DESIGN.md)."""

import json
import math

import pytest

from benchmarks_import import benchmark
from photonmap.volume.pipeline import STAGES


@pytest.fixture(scope="module")
def volume_table1():
    return benchmark("volume_table1")


def _number(value) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)


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
    assert headline["photons"] == 4096 and headline["grid"] == 32
    # the headline seconds are the medians of the frames it timed
    view, light = headline["view_only"], headline["light_change"]
    assert headline["full_frame_s"] == pytest.approx(1e-3 * light["wall_ms"]["median"])
    assert headline["view_only_s"] == pytest.approx(1e-3 * view["wall_ms"]["median"])
    # a camera change reruns the viewing pass only; a light change the photon stages, no setup
    assert view["recomputed"] == list(view["stages_ms"]) == ["viewing"]
    assert light["recomputed"] == list(light["stages_ms"]) == list(STAGES[5:])
    assert headline["stats"]["photons_generated"] == 4096
    assert 0 < headline["stats"]["photons_propagated"] <= 4096
    secondary = data["secondary"]
    assert _number(secondary["full_frame_s"]) and _number(secondary["view_only_s"])

    assert [r["row"] for r in data["rows"]] == [5, 11]
    for row in data["rows"]:
        ours = row["ours"]
        assert row["photons"] == 4096 and ours["photons_generated"] == 4096
        assert list(ours["stages_ms"]) == list(STAGES)
        assert all(_number(ms) for ms in ours["stages_ms"].values())
        (sample,) = ours["samples"]  # one timed render: its figures are the row's
        assert sample["recomputed"] == list(STAGES)
        assert ours["total_ms"] == pytest.approx(sum(ours["stages_ms"].values()))
        assert ours["steps"] == sample["stats"]["steps"] > 0
        assert 0 < ours["photons_propagated"] <= 4096
        assert ours["steps_per_photon"] == pytest.approx(ours["steps"] / ours["photons_propagated"])
        paper = volume_table1.PAPER_TABLE1[row["row"] - 1]
        assert row["paper"]["total_ms"] == paper.total_ms and paper.number == row["row"]

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
    assert 0.014 < 1 - mask.mean() < 0.03  # 0.0203 measured (83 of 4096 pixels)
    # its images in the spheres are masked: more masked pixels than the light alone covers
    assert (~mask).sum() > 2 * (seen.max(-1) > 0.01).sum()
