"""Shared helpers of the photonmap benchmarks (DESIGN.md: "Speed is measured by `benchmarks/`").

Every benchmark script writes ``benchmarks/results/<name>.json`` (machine information, all raw
samples and their medians) and ``benchmarks/results/<name>.md`` (a markdown table). The helpers
here are deliberately plain: medians of repeated runs, wall-clock timing that waits for Dr.Jit's
queue, machine information, a per-stage kernel profile, JSON and markdown writing.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import contextmanager
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parent.parent


# ---------------------------------------------------------------------------------------- timing
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
    if "cache_hit" in entry:
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


# --------------------------------------------------------------------------------- machine info
def cpu_model() -> str:
    """The CPU model name from /proc/cpuinfo (or ``platform.processor()``)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info() -> dict:
    """CPU, core count, load, library versions, git revision and date of this run."""
    info: dict = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "cpu_model": cpu_model(),
        "cores": os.cpu_count(),
        "cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "platform": platform.platform(),
        "python": sys.version.split()[0],
    }
    try:
        info["load_average"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:  # pragma: no cover
        pass
    for module in ("mitsuba", "drjit", "numpy"):
        try:
            info[module] = __import__(module).__version__
        except Exception:  # pragma: no cover - reported, never fatal
            info[module] = None
    try:
        import mitsuba as mi

        info["mitsuba_variant"] = mi.variant()
    except Exception:  # pragma: no cover
        pass
    info["llvm"] = os.environ.get("DRJIT_LIBLLVM_PATH")
    info["git"] = git_revision()
    return info


def git_revision() -> dict | None:
    """The commit of the working tree and whether it has uncommitted changes."""
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return {"commit": commit, "dirty": bool(dirty)}


# ------------------------------------------------------------------------------------- output
def _jsonable(value):
    """``json.dump`` default: NumPy scalars/arrays, paths, enums; NaN stays NaN (JSON5-style)."""
    try:
        import numpy as np

        if isinstance(value, np.generic):
            return value.item()
        if isinstance(value, np.ndarray):
            return value.tolist()
    except ImportError:  # pragma: no cover
        pass
    if isinstance(value, Path):
        return str(value)
    return str(value)


def write_json(path: Path | str, data) -> Path:
    """Write ``data`` as indented JSON, creating the folder; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, default=_jsonable) + "\n")
    return path


def write_text(path: Path | str, text: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def fmt(value, digits: int = 1) -> str:
    """A number for a table cell: fixed ``digits`` decimals, ``–`` for None/NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if isinstance(value, int):
        return f"{value:,}"
    return f"{value:,.{digits}f}"


def markdown_table(headers: Sequence[str], rows: Sequence[Sequence], align: str = "") -> str:
    """A GitHub markdown table; ``align`` is one character per column (``l``/``r``), default
    left for the first column and right for the rest."""
    align = align or "l" + "r" * (len(headers) - 1)
    rule = ["---:" if a == "r" else "---" for a in align]
    lines = ["| " + " | ".join(headers) + " |", "| " + " | ".join(rule) + " |"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)
