"""The Ray actors: plain classes here, made remote by :func:`photonmap.cluster.connect.spawn`.

Each actor is one long-lived process that imports photonmap once, selects the driver's device
(``llvm`` with as many Dr.Jit threads as the CPUs it reserved, or ``cuda``), loads the scene once
and keeps its pipeline between tasks, so later tasks pay neither the import, the scene load nor
the stages whose inputs did not change.
"""

from __future__ import annotations

import os
import time
import warnings

import numpy as np

from .frames import Frame
from .job import FrameState, SceneJob


def _start(device: str, threads: int) -> None:
    import drjit as dr

    import photonmap

    photonmap.set_device(device)
    if device == "cpu":
        dr.set_thread_count(max(1, int(threads)))


class _Worker:
    """Common to both actors: device set-up and a description of where it runs."""

    def __init__(self, device: str, threads: int):
        _start(device, threads)
        self.started = time.perf_counter()

    def where(self) -> dict:
        """Process id and node name (tests kill workers by pid; the benchmark reports both)."""
        return {"pid": os.getpid(), "node": os.uname().nodename}


class FrameWorker(_Worker):
    """Renders frames of a sequence; one :class:`~.job.FrameState` (pipeline and stage cache)
    lives as long as the actor."""

    def __init__(self, job: SceneJob, device: str = "cpu", threads: int = 1):
        super().__init__(device, threads)
        self.state = FrameState(job)

    def render(self, frame: Frame) -> tuple[np.ndarray, dict]:
        """Frame ``frame`` as float32 (h, w, 3) radiance, with what it cost: seconds (wall and
        CPU), the stages it reran, the warnings raised, the worker's pid."""
        t0, c0 = time.perf_counter(), time.process_time()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            pipe = self.state.apply(frame)
            image = np.asarray(pipe.render(), dtype=np.float32)
        info = {
            "seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time() - c0,
            "recomputed": list(pipe.recomputed),
            "warnings": sorted({str(w.message) for w in caught}),
            **self.where(),
        }
        return image, info


class BlockWorker(_Worker):
    """Runs blocks of memoryless progressive iterations (Knaus & Zwicker 2011) of
    one SPPM pipeline, built from ``job`` by the first block (so a scene that fails to load is
    that task's error, not a dead actor) and kept; returns their per-pixel sums."""

    def __init__(self, job: SceneJob, device: str = "cpu", threads: int = 1):
        super().__init__(device, threads)
        self.job = job
        self.pipe = None
        self.load_seconds = 0.0
        self.warnings: list[str] = []

    def render_block(self, first: int, count: int):
        """``BlockSums`` of iterations ``first … first + count − 1`` (1-based), with timings."""
        from .job import build_pipeline

        t0, c0 = time.perf_counter(), time.process_time()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            if self.pipe is None:
                self.pipe = build_pipeline(self.job)
                self.load_seconds = time.perf_counter() - t0
            sums = self.pipe.render_block(first, count)
        self.warnings = sorted(set(self.warnings) | {str(w.message) for w in caught})
        info = {
            "seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time() - c0,
            "load_seconds": self.load_seconds,
            "warnings": self.warnings,
            **self.where(),
        }
        return sums, info
