"""Distributed memoryless progressive photon mapping (Knaus & Zwicker 2011).

In the memoryless form every iteration ``i`` gathers with the global radius
``r_i = r_1 · i^((α−1)/2)`` and draws its random numbers from ``(seed, i)`` alone
(:func:`photonmap.core.progressive.iteration_seeds`), so iterations are independent and the image
after ``n`` of them is ``(1/n) Σ_i I_i`` whatever process rendered each ``I_i``. The seed stream
belongs to the iteration, not to the worker: a block rescheduled after a crash, or run by
another worker, returns the same sums.

The driver cuts iterations ``1 … n`` into blocks of consecutive iterations, hands them to worker
actors (each loaded the scene once, :class:`~.workers.BlockWorker`) and merges the returned
``BlockSums`` in block order — block k joins only after blocks 1 … k−1 — so the sum's order is
fixed. Against a single process (``run(iterations=n)``, which adds the images one by one) only
the grouping of the float64 additions differs: the totals agree to float64 rounding (≈1e-16
relative) and the float32 images are identical up to one rounding step of float32. With a time
budget (``seconds``) new blocks are handed out until it is spent and the image is that of the
blocks 1 … k that all finished.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from ..core.errors import ParameterError
from .connect import cluster, import_ray, spawn
from .job import SceneJob
from .schedule import run_tasks
from .workers import BlockWorker

BLOCKS_PER_WORKER = 4  # blocks per worker when the iteration count is known (load balance)
MAX_BLOCK = 16  # iterations per block at most (how often previews and merges happen)
TIMED_BLOCK = 2  # iterations per block under a time budget


@dataclass(frozen=True)
class Watch:
    """What a caller sees while :func:`render_progressive` runs: ``preview(image)``, called with
    the merged image at most every ``preview_every`` seconds as blocks arrive, and
    ``on_block(iterations merged, info)`` after each merge."""

    preview: Callable | None = None
    preview_every: float = 10.0
    on_block: Callable[[int, dict], None] | None = None


@dataclass
class ProgressiveResult:
    """What a distributed progressive render returns: the merged ``sums`` (a ``BlockSums``, None
    when no block finished), per-block worker info, whether it was interrupted, wall seconds."""

    sums: object | None
    blocks: list[dict] = field(default_factory=list)
    interrupted: bool = False
    seconds: float = 0.0

    @property
    def iterations(self) -> int:
        return 0 if self.sums is None else self.sums.iterations

    def warnings(self) -> list[str]:
        return sorted({w for info in self.blocks for w in info["warnings"]})


class InOrder:
    """Merges ``BlockSums`` in block order: a block that arrives early waits until every block
    before it has joined, so the sum's grouping is fixed whatever order workers finish in."""

    def __init__(self, first: int = 1):
        self.sums = None  # the merged blocks first … next − 1
        self.next = first
        self._waiting: dict = {}

    def add(self, first: int, sums) -> None:
        self._waiting[first] = sums
        while self.next in self._waiting:
            part = self._waiting.pop(self.next)
            self.sums = part if self.sums is None else self.sums.merge(part)
            self.next += part.iterations


def block_size(iterations: int | None, workers: int) -> int:
    """Iterations per block: about :data:`BLOCKS_PER_WORKER` blocks per worker, at most
    :data:`MAX_BLOCK`; :data:`TIMED_BLOCK` under a time budget."""
    if iterations is None:
        return TIMED_BLOCK
    return max(1, min(MAX_BLOCK, math.ceil(iterations / (BLOCKS_PER_WORKER * workers))))


def blocks(iterations: int | None, size: int, deadline: float | None = None):
    """``(first, (first, count))`` tasks covering iterations ``1 … iterations`` in order; with
    ``deadline`` (a ``time.perf_counter()`` value) and no count, blocks until it passes."""
    first = 1
    while iterations is None or first <= iterations:
        if deadline is not None and time.perf_counter() >= deadline:
            return
        count = size if iterations is None else min(size, iterations - first + 1)
        yield first, (first, count)
        first += count


def check_job(job: SceneJob) -> SceneJob:
    """The job in memoryless mode; refuse another method or ``mode="sppm"``."""
    if job.method != "sppm":
        raise ParameterError(
            f"--workers/--ray distribute the progressive method's iterations (--method sppm); "
            f"the {job.method} method renders in one process (for many frames of any method "
            "use 'photonmap render-sequence')"
        )
    mode = job.params.get("mode", "memoryless")
    if mode != "memoryless":
        raise ParameterError(
            f"distributed rendering needs independent iterations: mode=memoryless (got "
            f"mode={mode}: per-pixel radii depend on every earlier iteration)"
        )
    return SceneJob(**{**job.__dict__, "params": {**job.params, "mode": "memoryless"}})


def render_progressive(
    job: SceneJob,
    iterations: int | None = None,
    seconds: float | None = None,
    workers: int | None = None,
    address: str | None = None,
    block: int | None = None,
    watch: Watch = Watch(),
) -> ProgressiveResult:
    """Render ``iterations`` memoryless iterations of ``job`` (or as many as ``seconds`` allow)
    in blocks of ``block`` iterations on Ray workers (``workers`` local ones, or the cluster at
    ``address``), calling ``watch``'s previews and block callback as blocks arrive
    (:class:`Watch`). Ctrl-C (KeyboardInterrupt) stops the run and returns what was merged
    (``interrupted=True``)."""
    job = check_job(job)
    if iterations is None and seconds is None:
        raise ParameterError("give a budget: iterations (--set iterations=N) or seconds (--time)")
    if iterations is not None and (isinstance(iterations, bool) or iterations < 1):
        raise ParameterError(f"iterations must be a positive integer, got {iterations!r}")
    if block is not None and (isinstance(block, bool) or not 1 <= block <= 1_000_000):
        raise ParameterError(f"block must be a positive integer, got {block!r}")
    ray = import_ray()
    start = time.perf_counter()
    result = ProgressiveResult(None)
    with cluster(workers, address) as place, spawn(ray, BlockWorker, place, job) as actors:
        size = block or block_size(iterations, place.workers)
        deadline = None if seconds is None else start + seconds
        merged, last_preview = InOrder(), start
        try:
            tasks = blocks(iterations, size, deadline)
            for first, (sums, info) in run_tasks(ray, actors, "render_block", tasks,
                                                 label="the block from iteration"):  # fmt: skip
                result.blocks.append({"first": first, "count": sums.iterations, **info})
                merged.add(first, sums)
                result.sums = merged.sums
                if watch.on_block is not None:
                    watch.on_block(result.iterations, info)
                now = time.perf_counter()
                due = now - last_preview >= watch.preview_every
                if watch.preview is not None and result.sums is not None and due:
                    watch.preview(result.sums.image())
                    last_preview = now
        except KeyboardInterrupt:
            result.interrupted = True
    result.seconds = time.perf_counter() - start
    return result
