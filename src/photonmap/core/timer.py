"""Per-stage wall-clock timing (milliseconds), synchronising Dr.Jit before reading the clock."""

from __future__ import annotations

import time
from contextlib import contextmanager

import drjit as dr


class StageTimer:
    """Records the milliseconds of each named stage of the most recent run.

    ``with timer("photon tracing"): ...`` — the block must ``dr.eval`` what it produces; the timer
    waits for Dr.Jit's queue on entry and exit so the time is the stage's own.
    """

    def __init__(self):
        self.ms: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str):
        dr.sync_thread()
        start = time.perf_counter()
        try:
            yield
        finally:
            dr.sync_thread()
            self.ms[stage] = self.ms.get(stage, 0.0) + 1e3 * (time.perf_counter() - start)

    def reset(self):
        self.ms = {}

    @property
    def total(self) -> float:
        return sum(self.ms.values())

    def table(self, title: str = "stage timings"):
        """A rich table of the recorded stages, in the order they ran, plus the total."""
        from rich.table import Table

        t = Table(title=title)
        t.add_column("stage")
        t.add_column("ms", justify="right")
        for stage, ms in self.ms.items():
            t.add_row(stage, f"{ms:.1f}")
        t.add_row("total", f"{self.total:.1f}", style="bold")
        return t
