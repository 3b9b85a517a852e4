"""How the benchmarks time: medians of repeated runs, wall-clock timing that waits for Dr.Jit's
queue (kernels run asynchronously, so a clock stopped before ``dr.sync_thread()`` measures only
the launch), budgets of compute time (or of steps) with the clock stopped at checkpoints, and a
per-stage profile of the Dr.Jit kernels a render launches.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass


# ------------------------------------------------------------------------------------ medians
def median(values: Iterable[float]) -> float:
    """The median of ``values`` (NaN for none)."""
    values = [float(v) for v in values]
    return statistics.median(values) if values else math.nan


def summarize(samples: Sequence[float]) -> dict:
    """``{"median", "min", "max", "samples"}`` of a list of measurements."""
    samples = [float(s) for s in samples]
    if not samples:
        return {"median": math.nan, "min": math.nan, "max": math.nan, "samples": []}
    return {
        "median": median(samples),
        "min": min(samples),
        "max": max(samples),
        "samples": samples,
    }


def stage_medians(runs: Sequence[dict[str, float]]) -> dict[str, float]:
    """Per-key medians over runs of ``{stage: ms}`` dicts, in first-seen key order (a stage
    missing from a run counts as 0 ms there)."""
    keys: list[str] = []
    for run in runs:
        keys += [k for k in run if k not in keys]
    return {k: median(run.get(k, 0.0) for run in runs) for k in keys}


# ------------------------------------------------------------------------------------- clocks
def sync() -> None:
    """Wait until Dr.Jit has finished all queued work (no-op without Dr.Jit)."""
    try:
        import drjit as dr
    except ImportError:  # pragma: no cover
        return
    dr.sync_thread()


def timed(fn: Callable, *args, **kwargs) -> tuple[float, object]:
    """Run ``fn`` and return ``(seconds, result)``, synchronising Dr.Jit before and after."""
    sync()
    start = time.perf_counter()
    result = fn(*args, **kwargs)
    sync()
    return time.perf_counter() - start, result


@dataclass(frozen=True)
class Budget:
    """What one run gets: ``each`` seconds of compute, or ``each`` steps (iterations) with
    ``steps``. Benchmarks compare methods at equal time; the tests run them with a count, which
    does the same work on any machine, however fast or loaded."""

    each: float
    steps: bool = False

    def marks(self, seconds: Sequence[float], steps: Sequence[float]) -> list[float]:
        """The checkpoints below the budget (``seconds`` or ``steps``, by its unit), then the
        budget itself."""
        return [m for m in (steps if self.steps else seconds) if m < self.each] + [self.each]

    def describe(self) -> str:
        return f"{self.each:g} {'steps' if self.steps else 's'} each"


STEP_MARKS = tuple(2**k for k in range(20))  # checkpoints of a budget of steps: 1, 2, 4, 8, …


def checkpoints(step: Callable[[], object], budget: Budget, marks: Sequence[float]) -> Iterator:
    """Call ``step()`` until it has used ``budget`` (each call :func:`timed`); yields the
    seconds spent each time the seconds (or, for a budget of steps, the calls) first pass one of
    ``budget.marks(marks, STEP_MARKS)``. Between the calls the clock is stopped, so the caller
    can measure the image at each yield without it counting."""
    spent, calls = 0.0, 0
    left = budget.marks(marks, STEP_MARKS)
    while left:
        spent += timed(step)[0]
        calls += 1
        used = calls if budget.steps else spent
        if used >= left[0]:
            while left and used >= left[0]:
                left.pop(0)
            yield spent


# --------------------------------------------------------------------------------- kernel profile
@contextmanager
def kernel_history():
    """Capture Dr.Jit's kernel launches inside the block (``dr.JitFlag.KernelHistory``).

    Yields a list that is filled on exit with one dict per launch (``kernel_summary`` keys). Use
    for profiling passes only: recording adds a little overhead per launch.
    """
    import drjit as dr

    launches: list[dict] = []
    dr.kernel_history()  # drop anything recorded before
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        try:
            yield launches
        finally:
            launches += [kernel_summary(k) for k in dr.kernel_history()]


def kernel_summary(entry: dict) -> dict:
    """The JSON-friendly part of one ``dr.kernel_history()`` entry (times in ms)."""
    out = {"type": str(entry.get("type", "")).split(".")[-1]}
    for key in ("hash", "size", "operation_count", "input_count", "output_count"):
        if key in entry:
            out[key] = entry[key] if isinstance(entry[key], str) else int(entry[key])
    for key in ("execution_time", "codegen_time", "backend_time"):
        if key in entry:
            out[key + "_ms"] = float(entry[key])
    if "cache_hit" in entry:  # in memory; else loaded from the disk cache, or compiled
        out["in_memory"] = bool(entry["cache_hit"])
        out["compiled"] = not (bool(entry["cache_hit"]) or bool(entry.get("cache_disk", False)))
    return out


def profiling_timer(base_cls):
    """A subclass of the stage timer ``base_cls`` that also records the Dr.Jit kernels each stage
    launched: ``timer.kernels[stage]`` is a list of ``kernel_summary`` dicts. Kernel history must
    be enabled (``kernel_history()``) while it runs."""
    import drjit as dr

    class ProfilingTimer(base_cls):
        def __init__(self):
            super().__init__()
            self.kernels: dict[str, list[dict]] = {}

        @contextmanager
        def __call__(self, stage: str):
            dr.sync_thread()
            dr.kernel_history()  # launches before this stage belong to no stage
            with super().__call__(stage):
                yield
            self.kernels.setdefault(stage, []).extend(
                kernel_summary(k) for k in dr.kernel_history()
            )

        def reset(self):
            super().reset()
            self.kernels = {}

    return ProfilingTimer
