"""A rich progress bar over named stages, shown on a terminal only (DESIGN.md: "Long work shows a
rich progress bar on a terminal and stays quiet when not a TTY")."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager


def interactive(stream=None) -> bool:
    """True if ``stream`` (default: stderr) is a terminal."""
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


@contextmanager
def stage_progress(
    stages: Sequence[str], label: str, console=None, enabled: bool | None = None
) -> Iterator[Callable[[str], None] | None]:
    """Yield a callback ``report(stage)`` that advances a transient progress bar to ``stage`` (one
    of ``stages``), or None when not on a terminal (``enabled`` overrides the check).

    >>> with stage_progress(STAGES, "rendering") as report:
    ...     image = pipe.render(progress=report)
    """
    if enabled is None:
        enabled = interactive(console.file if console is not None else None)
    if not enabled:
        yield None
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        SpinnerColumn,
        TextColumn,
        TimeElapsedColumn,
    )

    columns = (
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    )
    order = {name: i for i, name in enumerate(stages)}
    with Progress(*columns, console=console, transient=True) as bar:
        task = bar.add_task(label, total=len(stages))

        def report(stage: str) -> None:
            bar.update(task, completed=order.get(stage, 0), description=f"{label}: {stage}")

        yield report
        bar.update(task, completed=len(stages), description=label)
