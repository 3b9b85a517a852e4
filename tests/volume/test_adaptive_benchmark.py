"""Smoke test of ``benchmarks/adaptive_vs_reference.py``: the quick mode runs end to end and
writes the JSON (with the ``headline`` object), the markdown and the plot; and the equal-RMSE
interpolation. Correctness only; speed is measured by the benchmark itself."""

import json
import math

import pytest

from benchmarks_import import benchmark


@pytest.fixture(scope="module")
def bench():
    return benchmark("adaptive_vs_reference")


def test_equal_rmse_budget_interpolates_log_log(bench):
    budgets, errors = [100, 400, 1600], [0.4, 0.2, 0.1]
    assert bench.equal_rmse_budget(budgets, errors, 0.2) == pytest.approx(400)
    assert bench.equal_rmse_budget(budgets, errors, 0.1414213) == pytest.approx(800, rel=1e-4)
    assert bench.equal_rmse_budget(budgets, errors, 0.5) == 100
    assert bench.equal_rmse_budget(budgets, errors, 0.05) is None


def test_quick_run_writes_json_markdown_and_plot(bench, tmp_path):
    result = bench.main(["--quick", "--scenes", "SPHERE", "--out-dir", str(tmp_path)])
    stem = tmp_path / "adaptive_vs_reference_quick"
    for suffix in (".json", ".md", ".png"):
        assert stem.with_suffix(suffix).is_file()
    data = json.loads(stem.with_suffix(".json").read_text())
    assert data == json.loads(json.dumps(result, default=str))
    assert set(data["headline"]) == {"SPHERE"}
    assert set(data["headline"]["SPHERE"]) >= {"photon_ratio", "time_ratio", "uniform_placement"}
    scene = data["scenes"]["SPHERE"]
    for variant in ("uniform", "adaptive", "adaptive_uniform_placement"):
        rows = scene["sweep"][variant]
        assert [r["budget"] for r in rows] == data["settings"]["budgets"]
        assert all(0 < r["propagated"] <= r["budget"] for r in rows)
        # the error against the truth falls from the smallest budget to the largest (measured
        # 0.0100 → 0.0071 uniform, 0.0163 → 0.0095 adaptive, 0.0207 → 0.0095 filter only)
        assert 0 < rows[-1]["rmse"] < 0.9 * rows[0]["rmse"]
    # equal-RMSE rows: the target is the reference's RMSE × the tolerance, the ratio is the budgets'
    uniform = {r["budget"]: r["rmse"] for r in scene["sweep"]["uniform"]}
    for row in scene["by_nominal"]:
        target = uniform[row["reference_budget"]] * data["settings"]["rmse_tolerance"]
        assert row["target_rmse"] == pytest.approx(target)
        if row["adaptive_budget"] is not None:
            ratio = row["adaptive_budget"] / row["reference_budget"]
            assert row["photon_ratio"] == pytest.approx(ratio)
    assert "Pilot Photon Marching" in scene["sweep"]["adaptive"][0]["passes_ms"]
    assert len(scene["by_nominal"]) == len(data["settings"]["budgets"])
    assert len(scene["by_nominal_uniform_placement"]) == len(data["settings"]["budgets"])
    assert [r["budget"] for r in scene["ablation"]] == [2**13, 2**14]
    assert all(r["placement_only"] > 0 and r["adaptive"] > 0 for r in scene["ablation"])
    fit = scene["marching_fit"]
    assert math.isfinite(fit["ms_per_million_steps"]) and math.isfinite(
        fit["fixed_ms"]
    )  # noisy at 32³


def test_smallest_budget_bisects_between_a_failing_guess_and_a_known_budget(bench):
    probed = []

    def reaches(budget):
        probed.append(budget)
        return budget >= 1000

    # six geometric bisections of [800, 1600] end within a factor 2^(1/64) above 1000
    assert 1000 <= bench.smallest_budget(reaches, 800, 1600) <= 1000 * 2 ** (1 / 64)
    assert all(800 < b < 1600 for b in probed[1:])
    assert bench.smallest_budget(reaches, 1200, 1600) == 1200  # the guess reaches the target
    assert bench.smallest_budget(reaches, 2000, 1600) == 1600  # a guess above the known budget


def test_marching_fit_recovers_fixed_and_per_step_cost(bench):
    rows = [
        {"steps": s, "stages_ms": {"photon tracing": 80 + 50 * s / 1e6}} for s in (1e6, 2e6, 4e6)
    ]
    fit = bench.marching_fit(rows)
    assert fit["fixed_ms"] == pytest.approx(80) and fit["ms_per_million_steps"] == pytest.approx(50)
