"""Timed frames of the volume method (Sun et al. 2008), as ``volume_table1.py`` measures them.

A *full render* clears the stage cache, so every stage runs ("all passes are executed for each
frame", Pfeuti 2009's protocol); a *light-change frame* moves the point light by about a voxel
(``set_light``: photon generation, tracing, smoothing, view grids and viewing rerun); a
*view-only frame* moves the camera a little (``set_camera``: only viewing reruns). Frame times are
wall-clock of change + render with Dr.Jit synchronised; kernel history is on, to count the
kernels each frame compiled. Warm-up frames of the same kind run first, until one compiles no
kernel.
"""

from __future__ import annotations

import dataclasses
import math
import random
import time
from collections.abc import Callable, Sequence

import numpy as np

from timing import kernel_history, median, stage_medians, summarize, sync


def make_pipeline(scene: str, grid: int, width: int, height: int, photons: int, **scene_params):
    """Load the built-in ``scene`` at ``width``×``height`` and build its ``VolumePipeline``;
    returns the pipeline and the seconds spent (scene building + conversion)."""
    from photonmap import VolumePipeline
    from photonmap.scenes import load_scene

    start = time.perf_counter()
    mi_scene, defaults = load_scene(scene, width=width, height=height, **scene_params)
    pipe = VolumePipeline(mi_scene, grid=grid, **{**defaults, "photons": int(photons)})
    return pipe, time.perf_counter() - start


def frame(pipe, change: Callable[[], None] | None = None) -> dict:
    """One frame: apply ``change`` (or clear the stage cache: a full render) and render. Returns
    the wall-clock milliseconds (change + render), the per-stage milliseconds, the stats and the
    Dr.Jit kernels compiled during the frame (kernel history is on to count them)."""
    with kernel_history() as launches:
        sync()
        start = time.perf_counter()
        if change is None:
            pipe.invalidate()
        else:
            change()
        pipe.render()
        sync()
        wall = 1e3 * (time.perf_counter() - start)
    compiled = [k for k in launches if k.get("compiled")]
    return {
        "wall_ms": wall,
        "stages_ms": dict(pipe.timer.ms),
        "stages_total_ms": float(sum(pipe.timer.ms.values())),
        "recomputed": list(pipe.recomputed),
        "stats": {k: float(v) for k, v in pipe.stats.items()},
        "kernels_compiled": len(compiled),
        "compile_ms": float(sum(k.get("backend_time_ms", 0.0) for k in compiled)),
    }


def warm_up(pipe, change: Callable[[int], Callable[[], None]] | None, minimum: int, limit: int = 5):
    """Untimed frames until one compiles no Dr.Jit kernel, at least ``minimum`` of them (the first
    render in a process traces some kernels differently from later ones, so one warm-up render is
    not always enough). ``change(i)`` gives the change of frame ``i`` (None: full renders)."""
    frames = []
    for i in range(limit):
        f = frame(pipe, None if change is None else change(i))
        frames.append(
            {k: f[k] for k in ("wall_ms", "kernels_compiled", "compile_ms", "recomputed")}
        )
        if i + 1 >= minimum and f["kernels_compiled"] == 0:
            break
    return frames


def compiles(samples: Sequence[dict]) -> dict:
    """The kernels the frames compiled and the milliseconds it took."""
    return {
        "kernels": int(sum(s["kernels_compiled"] for s in samples)),
        "ms": float(sum(s["compile_ms"] for s in samples)),
    }


_FIRST_RENDER = [True]


def warm_up_full(pipe) -> list[dict]:
    """Warm-up full renders: at least two for the first pipeline of the process (its second render
    traces some kernels differently from the first), one afterwards; more while kernels compile."""
    minimum = 2 if _FIRST_RENDER[0] else 1
    _FIRST_RENDER[0] = False
    return warm_up(pipe, None, minimum=minimum)


def measure_full(pipe, runs: int) -> dict:
    """Warm-up, then ``runs`` timed full renders (every stage runs); medians and raw samples."""
    warm = warm_up_full(pipe)
    samples = [frame(pipe) for _ in range(runs)]
    stages = stage_medians([s["stages_ms"] for s in samples])
    stats = samples[-1]["stats"]
    march_s = 1e-3 * stages.get("photon tracing", math.nan)
    tracing_ms = stages.get("photon generation", 0.0) + stages.get("photon tracing", 0.0)
    steps = stats.get("steps", 0)
    return {
        "warmup": warm,
        "stages_ms": stages,
        "total_ms": median(s["stages_total_ms"] for s in samples),
        "wall_ms": median(s["wall_ms"] for s in samples),
        "paper_tracing_equivalent_ms": tracing_ms,
        "steps": int(stats.get("steps", 0)),
        "msteps": stats.get("steps", 0) / 1e6,
        "photons_generated": int(stats.get("photons_generated", 0)),
        "photons_propagated": int(stats.get("photons_propagated", 0)),
        "steps_per_photon": stats.get("steps", 0) / max(stats.get("photons_propagated", 0), 1),
        # the march stage alone (S6/S7)
        "march_msteps_per_s": steps / 1e6 / march_s if march_s > 0 else math.nan,
        # generation + march, like the paper's "photon tracing" column
        "ns_per_step": 1e6 * tracing_ms / steps if steps else math.nan,
        "compiled_during_timed_runs": compiles(samples),
        "samples": samples,
    }


# Light and camera moves get a random fraction on top, so that no run reuses a position of an
# earlier run: a value baked into a kernel would otherwise hit Dr.Jit's on-disk kernel cache and
# hide the compilation a real light move pays.
_JITTER = random.Random(time.time_ns())


def nudge_light(pipe, start, i: int, step: float = 1.0) -> Callable[[], None]:
    """A change moving light 0 from ``start`` (a Light) by about ``(i + 1)·step`` voxels in x,
    alternating sides, or turning a directional light by as many milliradians."""
    sign = 1.0 if i % 2 == 0 else -1.0
    amount = sign * ((i + 1) * step + _JITTER.uniform(0.0, 0.25))
    if start.kind == "directional":
        angle = 1e-3 * amount
        d = np.asarray(start.direction, dtype=np.float64)
        c, s = math.cos(angle), math.sin(angle)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return lambda: pipe.set_light(0, direction=rot @ d)
    offset = amount * pipe.world.box.h * np.array([1.0, 0.0, 0.0])
    position = np.asarray(start.position, dtype=np.float64) + offset
    return lambda: pipe.set_light(0, position=position)


def nudge_camera(pipe, origin: np.ndarray, i: int) -> Callable[[], None]:
    """A change moving the camera origin by ``i + 1`` steps of 1% of the box size (alternating
    sides of its start), still aimed at the box centre."""
    sign = 1.0 if i % 2 == 0 else -1.0
    amount = sign * (i + 1 + _JITTER.uniform(0.0, 0.25))
    offset = amount * 0.01 * pipe.world.box.size * np.array([1.0, 0.5, 0.0])
    target = np.asarray(pipe.world.box.center, dtype=np.float64)
    return lambda: pipe.set_camera(origin=origin + offset, target=target)


def _camera_origin(pipe) -> np.ndarray:
    matrix = np.array(pipe.sensor.world_transform().matrix, dtype=np.float64)[..., 0]
    return matrix[:3, 3].copy()


def _frames_summary(frames: Sequence[dict], warm: Sequence[dict]) -> dict:
    return {
        "wall_ms": summarize([f["wall_ms"] for f in frames]),
        "stages_ms": stage_medians([f["stages_ms"] for f in frames]),
        "recomputed": frames[-1]["recomputed"],
        "compiled_during_timed_runs": compiles(frames),
        "warmup": list(warm),
        "samples": list(frames),
    }


def measure_interactive(pipe, light_runs: int, view_runs: int) -> dict:
    """Light-change and view-only frames (each after untimed warm-up frames of the same kind) on a
    pipeline whose stages are up to date; restores the light and camera afterwards."""
    origin = _camera_origin(pipe)
    start = dataclasses.replace(pipe.world.lights[0])
    count = iter(range(10**6))  # every frame gets a new light position / camera origin
    # a light move may compile kernels in every frame (values baked into kernels): then warming
    # up longer does not help, and the timed frames include (and record) the compilation
    warm_light = warm_up(pipe, lambda _: nudge_light(pipe, start, next(count)), 1, limit=2)
    light = [frame(pipe, nudge_light(pipe, start, next(count))) for _ in range(light_runs)]
    warm_view = warm_up(pipe, lambda _: nudge_camera(pipe, origin, next(count)), 1, limit=2)
    view = [frame(pipe, nudge_camera(pipe, origin, next(count))) for _ in range(view_runs)]
    pipe.world.lights[0] = start
    pipe.set_camera(origin=origin, target=np.asarray(pipe.world.box.center, dtype=np.float64))
    return {
        "full_frame_s": 1e-3 * median(f["wall_ms"] for f in light),
        "view_only_s": 1e-3 * median(f["wall_ms"] for f in view),
        "light_change": _frames_summary(light, warm_light),
        "view_only": _frames_summary(view, warm_view),
        "stats": light[-1]["stats"],
    }
