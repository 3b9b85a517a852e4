"""``benchmarks/caustic_design.py`` and ``examples/caustic_design.py`` in their quick modes: the
benchmark writes its JSON schema for its three problems, finds what Mitsuba's integrators cannot
render, and the photon-mapping optimisation lowers the tutorial's true loss within the quick
run's budget of steps (a count: the same run on any machine); the example runs end to end and
writes its pictures. Speed is measured by the benchmark itself."""

import importlib.util
import json
import math
from pathlib import Path

import drjit as dr
import pytest

from benchmarks_import import benchmark

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "caustic_design.py"


def finite(value) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("caustic_design")
    flag = dr.flag(dr.JitFlag.OptimizeCalls)
    bench = benchmark("caustic_design")
    result = bench.main(["--quick", "--out-dir", str(out)])
    assert dr.flag(dr.JitFlag.OptimizeCalls) == flag  # restored for the tests that follow
    return out, result, bench.QUICK


def test_quick_benchmark_writes_schema(quick):
    out, result, budgets = quick
    data = json.loads((out / "caustic_design_quick.json").read_text())
    assert data == json.loads(json.dumps(result, default=str))
    assert list(data["problems"]) == ["tutorial", "pool", "window"]
    assert (out / "caustic_design_quick.png").stat().st_size > 500
    assert "| seconds | steps | true loss |" in (out / "caustic_design_quick.md").read_text()
    for name, problem in data["problems"].items():
        assert (out / f"caustic_design_images_{name}_quick.png").stat().st_size > 500
        headline, steps = problem["headline"], budgets[name]["steps"]
        assert headline["steps_each"] == steps >= 2
        assert sorted([*problem["methods"], *problem["skipped"]]) == sorted(
            ["photonmap", "ptracer", "prb", "prb_projective"]
        )
        assert headline["renders_nothing"] == sorted(problem["skipped"])
        for method, res in problem["methods"].items():
            assert res["steps"] == steps and finite(res["median_step_s"])
            assert res["rows"][-1]["steps"] == steps
            assert res["rows"][-1]["seconds"] == res["seconds"]
            assert [r["steps"] for r in res["rows"]] == sorted({r["steps"] for r in res["rows"]})
            assert all(finite(r["true_loss"]) for r in res["rows"])
            assert headline[f"{method}_steps"] == res["steps"]
        finals = {m: problem["methods"][m]["rows"][-1]["true_loss"] for m in headline["competitors"]}
        if finals:
            assert headline["loss_ratio_vs_best_mitsuba"] == pytest.approx(
                min(finals.values()) / headline["photonmap_final_true_loss"]
            )
        else:
            assert headline["loss_ratio_vs_best_mitsuba"] is None
        assert headline["tutorial_ptracer_fraction_of_initial"] == pytest.approx(
            data["problems"]["tutorial"]["headline"]["ptracer_fraction_of_initial"]
        )
    assert len(data["machine"]["load_average"]) == 3 and len(data["load_average_after"]) == 3


def test_what_mitsuba_cannot_render(quick):
    """The problems' premise: Mitsuba's path tracers never reach the tutorial's directional
    light, and its particle tracer connects nothing to a camera behind water or glass."""
    problems = quick[1]["problems"]
    assert sorted(problems["tutorial"]["skipped"]) == ["prb", "prb_projective"]
    assert list(problems["pool"]["skipped"]) == list(problems["window"]["skipped"]) == ["ptracer"]


def test_photon_mapping_lowers_the_loss(quick):
    rows = quick[1]["problems"]["tutorial"]["methods"]["photonmap"]["rows"]
    assert rows[0]["seconds"] == 0 and rows[-1]["true_loss"] < 0.95 * rows[0]["true_loss"]


@pytest.mark.parametrize("problem", ["tutorial", "pool"])
def test_example_runs_quick(tmp_path, problem):
    spec = importlib.util.spec_from_file_location("caustic_design_example", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    final = example.main(["--quick", "--problem", problem, "--out", str(tmp_path)])
    assert finite(final)
    for name in ("target", "estimate", "check", "side_by_side"):
        assert (tmp_path / f"{name}.png").stat().st_size > 100
