"""``benchmarks/compare_commits.py``: it reads what ``photonmap render --timings`` prints (every
stage, the total and the counters), and its medians and time-to-equal-error ratio are what its
docstring defines. Its interleaved renders of two revisions are measured by running it."""

import pytest
from typer.testing import CliRunner

from benchmarks_import import benchmark
from photonmap.cli import app


@pytest.fixture(scope="module")
def bench():
    return benchmark("compare_commits")


def test_reads_the_timings_the_cli_prints(bench, tmp_path, monkeypatch):
    monkeypatch.setenv("COLUMNS", "1000")  # as the script runs it: lines unwrapped
    args = ["render", "examples/cornell_box.xml", "--method", "sppm", "-o",
            str(tmp_path / "a.exr"), "--width", "16", "--height", "16",
            "--set", "iterations=2", "--set", "photons=1000", "--set", "transport=photons",
            "--timings"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    stages, counters = bench.parse_timings(result.stdout)
    assert stages["total"] > 0 and {"eye pass", "photon pass"} <= set(stages), stages
    assert counters["photons"] == 2000 and counters["gathers"] == 2 * 16 * 16, counters


def test_medians_and_time_to_equal_error(bench):
    def run(total, error, photons):
        return {"stages_ms": {"eye pass": total / 2, "total": total}, "error": error,
                "counters": {"photons": photons}}  # fmt: skip

    side = bench.summary([run(3000, 0.2, 10), run(1000, 0.1, 30), run(2000, 0.4, 20)])
    assert side["seconds"] == 2.0 and side["error"] == 0.2
    assert side["stages_ms"] == {"eye pass": 1000, "total": 2000}
    assert side["counters"] == {"photons": 20}
    faster = {"seconds": 1.0, "error": 0.2}
    assert bench.time_to_equal_error(side, faster) == pytest.approx(0.5)
    noisier = {"seconds": 1.0, "error": 0.4}  # 4× the time for half the error: 2× rev's
    assert bench.time_to_equal_error(side, noisier) == pytest.approx(2.0)
