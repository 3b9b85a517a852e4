"""What every benchmark writes: machine information, result files, tables and plots.

Every benchmark writes ``benchmarks/results/<name>.json`` (machine information, all raw samples
and their medians) and ``benchmarks/results/<name>.md`` (markdown tables), ``<name>_quick.*`` in
its quick mode, and some a ``.png`` plot. The helpers here are deliberately plain.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import subprocess
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parent.parent


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


def load_average() -> list[float]:
    """The 1-, 5- and 15-minute load averages, rounded to 0.01 (the machine may be shared)."""
    return [round(x, 2) for x in os.getloadavg()]


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
        info["load_average"] = load_average()
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


# ----------------------------------------------------------------------------------- command
def integers(text: str) -> list[int]:
    """An option's comma-separated whole numbers (``1e5`` allowed)."""
    return [int(float(x)) for x in text.replace(" ", "").split(",") if x]


def arguments(doc: str, quick: str) -> argparse.ArgumentParser:
    """A benchmark's argument parser: described by the first paragraph of ``doc``, with
    ``--quick`` (``quick`` says what the quick mode runs; it writes ``*_quick.*`` files) and
    ``--out-dir`` (where the result files go; default ``benchmarks/results``)."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help=quick)
    parser.add_argument("--out-dir", type=Path, default=RESULTS, help="folder of the results")
    return parser


# ------------------------------------------------------------------------------------- files
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
    return str(value)


def write_json(path: Path | str, data) -> Path:
    """Write ``data`` as indented JSON, creating the folder; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, default=_jsonable) + "\n")
    return path


def write_text(path: Path | str, text: str) -> Path:
    """Write ``text``, creating the folder; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def results_stem(out_dir: Path | str, name: str, quick: bool = False) -> Path:
    """``out_dir/name`` (``name_quick`` in a quick run): add ``.json``, ``.md``, ``.png``."""
    return Path(out_dir) / (name + ("_quick" if quick else ""))


def write_results(stem: Path, result: dict, text: str) -> None:
    """Write ``stem.md`` (``text``) and ``stem.json`` (``result``)."""
    write_text(stem.with_name(stem.name + ".md"), text)
    write_json(stem.with_name(stem.name + ".json"), result)


def publish(stem: Path, result: dict, text: str) -> dict:
    """:func:`write_results`, then print the markdown; returns ``result``."""
    write_results(stem, result, text)
    print(text)
    return result


def previous_results(path: Path) -> dict:
    """The JSON written by an earlier run at ``path`` ({} if there is none)."""
    return json.loads(path.read_text()) if path.is_file() else {}


# ------------------------------------------------------------------------------------ tables
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


Column = tuple[str, str | Callable[[Mapping], object], int | None]


def records_table(records: Sequence[Mapping], columns: Sequence[Column], align: str = "") -> str:
    """A markdown table with a row per record. Each column is ``(header, value, digits)``:
    ``value`` a key of the record or a function of it, shown with :func:`fmt` at ``digits``
    decimals, or as it is for ``digits`` None."""

    def cell(record: Mapping, value, digits: int | None):
        v = value(record) if callable(value) else record[value]
        return v if digits is None else fmt(v, digits)

    rows = [[cell(r, value, digits) for _, value, digits in columns] for r in records]
    return markdown_table([c[0] for c in columns], rows, align)


def bullets(items: Mapping) -> str:
    """``- key: value`` lines."""
    return "\n".join(f"- {k}: {v}" for k, v in items.items())


# ------------------------------------------------------------------------------------- plots
@contextmanager
def figure(path: Path | str, rows: int = 1, cols: int = 1, size=(6, 4), dpi: int = 110) -> Iterator:
    """A ``rows`` × ``cols`` grid of matplotlib axes (``axes[row][col]``), saved to ``path``
    (Agg backend, tight layout) when the block ends."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(rows, cols, figsize=size, squeeze=False)
    yield axes
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def loglog_curves(
    ax, curves: Mapping[str, Sequence[Mapping]], x: str, y: str, styles: Sequence[str] = ()
) -> None:
    """One log-log line per ``label: rows`` of ``curves``, ``y`` against ``x`` (style ``o-``
    unless ``styles`` gives one per curve)."""
    for i, (label, rows) in enumerate(curves.items()):
        style = styles[i] if styles else "o-"
        ax.loglog([r[x] for r in rows], [r[y] for r in rows], style, label=label)
