"""``benchmarks/caustic_design.py`` and ``examples/caustic_design.py`` in their quick modes: the
benchmark writes its JSON schema and the photon-mapping optimisation lowers the true loss within
the quick run's budget of steps (a count: the same run on any machine); the example runs end to
end and writes its pictures. Speed is measured by the benchmark itself."""

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
    return out, result, bench.QUICK_STEPS


def test_quick_benchmark_writes_schema(quick):
    out, result, steps = quick
    data = json.loads((out / "caustic_design_quick.json").read_text())
    assert data == json.loads(json.dumps(result, default=str))
    for name in ("caustic_design_quick.png", "caustic_design_images_quick.png"):
        assert (out / name).stat().st_size > 500
    assert "| seconds | steps | true loss |" in (out / "caustic_design_quick.md").read_text()
    headline = data["headline"]
    assert headline["steps_each"] == steps >= 2
    assert finite(headline["loss_ratio_vs_ptracer_at_equal_steps"])
    assert headline["loss_ratio_vs_ptracer_at_equal_steps"] == pytest.approx(
        headline["ptracer_final_true_loss"] / headline["photonmap_final_true_loss"]
    )
    for method in ("photonmap", "ptracer"):
        res = data["methods"][method]
        assert res["steps"] == steps and finite(res["median_step_s"])
        assert res["rows"][-1]["steps"] == steps and res["rows"][-1]["seconds"] == res["seconds"]
        assert [r["steps"] for r in res["rows"]] == sorted({r["steps"] for r in res["rows"]})
        assert all(finite(r["true_loss"]) for r in res["rows"])
        assert headline[f"{method}_steps"] == res["steps"]
    assert len(data["machine"]["load_average"]) == 3 and len(data["load_average_after"]) == 3


def test_photon_mapping_lowers_the_loss(quick):
    rows = quick[1]["methods"]["photonmap"]["rows"]
    assert rows[0]["seconds"] == 0 and rows[-1]["true_loss"] < 0.95 * rows[0]["true_loss"]


def test_example_runs_quick(tmp_path):
    spec = importlib.util.spec_from_file_location("caustic_design_example", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    final = example.main(["--quick", "--out", str(tmp_path)])
    assert finite(final)
    for name in ("target", "estimate", "ptracer", "side_by_side"):
        assert (tmp_path / f"{name}.png").stat().st_size > 100
