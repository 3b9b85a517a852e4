"""Benchmark: the sweeps of Sun et al. 2008 Table 1 on the volume pipeline (issue item 8).

Spec seed-000-002 §3.1 (Table 1 transcribed) and §5.7 oracle 34 (performance shape). Scene:
``mesh_in_fog`` (a glass trefoil-knot mesh in grey fog, spec §3.3 MESH) at a 128³ grid and
640×480. The eleven rows of Table 1:

* rows 1–4: 10k / 20k / 40k / 80k triangles at an occupied extent of 103³ voxels, 1024² photons;
* rows 5–8: extents 64³ / 77³ / 90³ / 103³ at 20k triangles, 1024² photons;
* rows 9–11: 256² / 512² / 1024² initial photons at 20k triangles, extent 103³.

Rows 2, 8 and 11 are the same configuration in the paper; it is measured once and shown in all
three. For each configuration: warm-up full renders (JIT compilation; at least two, until one
compiles no kernel), then ``runs`` timed full renders from scratch — the stage cache is cleared so
every stage runs ("all passes are executed for each frame", Pfeuti's protocol) — and the median of
each stage.

Headline (20k triangles, extent 103, 1024² photons): ``light_runs`` light-change frames (the point
light moves by about a voxel each frame with ``set_light``, to a position no earlier run used;
photon generation, tracing, smoothing, view grids and viewing rerun) = "full frame (light change +
view)", and ``view_runs`` view-only frames (``set_camera`` to a slightly different origin; only
viewing reruns). Targets on the 2-core CPU:
full frame ≤ 0.5 s, view-only ≤ 0.25 s. The same two numbers for ``glass_sphere_fog`` go into
``secondary``. A profile of the headline light-change frame (stage shares, Dr.Jit kernels per
stage, photon marching with and without deposition, deposit count) says what bounds the time.

Column mapping to the paper: its "voxelization" ↔ our voxelization; its "photon tracing" ↔ our
photon generation + photon tracing; its total additionally holds gradient, octree, irradiance
merging and the viewing pass (≈ 68–76 ms together), so it compares with our total of all stages.

Writes ``benchmarks/results/volume_table1.json`` and ``.md`` (``--quick``: ``*_quick.*``) and
prints the markdown. ``python benchmarks/volume_table1.py [--quick] [--runs N] [--rows 1,9,11]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import random
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from report import RESULTS, fmt, machine_info, markdown_table, write_json, write_text
from timing import kernel_history, median, profiling_timer, stage_medians, summarize, sync

NAME = "volume_table1"
SCENE = "mesh_in_fog"
SECONDARY_SCENE = "glass_sphere_fog"
PAPER_PHOTONS = (256**2, 512**2, 1024**2)
TARGETS_S = {"full_frame_s": 0.5, "view_only_s": 0.25}
QUICK_ROWS = (9, 11)


@dataclasses.dataclass(frozen=True)
class PaperRow:
    """One row of [Sun] Table 1 (times in ms on an NVIDIA GeForce 8800 Ultra)."""

    number: int
    sweep: str
    triangles: int
    extent: int  # occupied voxels per side (of 128)
    photon_index: int  # 0, 1, 2 → 256², 512², 1024² initial photons
    msteps: float
    voxelization_ms: float
    tracing_ms: float
    total_ms: float

    @property
    def photons(self) -> int:
        return PAPER_PHOTONS[self.photon_index]


PAPER_TABLE1 = (
    PaperRow(1, "triangles", 10_000, 103, 2, 3.81, 14.55, 136.85, 225.20),
    PaperRow(2, "triangles", 20_000, 103, 2, 3.81, 24.40, 138.10, 238.15),
    PaperRow(3, "triangles", 40_000, 103, 2, 3.81, 49.90, 134.70, 258.40),
    PaperRow(4, "triangles", 80_000, 103, 2, 3.81, 90.35, 135.75, 299.65),
    PaperRow(5, "extent", 20_000, 64, 2, 1.12, 16.40, 63.55, 148.00),
    PaperRow(6, "extent", 20_000, 77, 2, 1.82, 18.80, 85.20, 175.05),
    PaperRow(7, "extent", 20_000, 90, 2, 2.72, 21.45, 108.60, 201.75),
    PaperRow(8, "extent", 20_000, 103, 2, 3.81, 24.40, 138.10, 238.15),
    PaperRow(9, "photons", 20_000, 103, 0, 0.24, 25.85, 63.40, 159.60),
    PaperRow(10, "photons", 20_000, 103, 1, 0.95, 24.90, 80.10, 175.95),
    PaperRow(11, "photons", 20_000, 103, 2, 3.81, 24.40, 138.10, 238.15),
)
HEADLINE = {"triangles": 20_000, "extent": 103}  # and the largest photon count


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------ measurement
def make_pipeline(scene: str, grid: int, width: int, height: int, photons: int, **scene_params):
    """Load the built-in ``scene`` at ``width``×``height`` and build its ``VolumePipeline``;
    returns the pipeline and the seconds spent (scene building + conversion)."""
    from photonmap import VolumePipeline
    from photonmap.scenes import load_scene

    start = time.perf_counter()
    mi_scene, defaults = load_scene(scene, width=width, height=height, **scene_params)
    pipe = VolumePipeline(mi_scene, grid=grid, **{**defaults, "photons": int(photons)})
    return pipe, time.perf_counter() - start


def _frame(pipe, change: Callable[[], None] | None = None) -> dict:
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
        frame = _frame(pipe, None if change is None else change(i))
        frames.append(
            {k: frame[k] for k in ("wall_ms", "kernels_compiled", "compile_ms", "recomputed")}
        )
        if i + 1 >= minimum and frame["kernels_compiled"] == 0:
            break
    return frames


def _compiles(samples: Sequence[dict]) -> dict:
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
    samples = [_frame(pipe) for _ in range(runs)]
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
        "compiled_during_timed_runs": _compiles(samples),
        "samples": samples,
    }


# Light and camera moves get a random fraction on top, so that no run reuses a position of an
# earlier run: a value baked into a kernel would otherwise hit Dr.Jit's on-disk kernel cache and
# hide the compilation a real light move pays.
_JITTER = random.Random(time.time_ns())


def _nudge_light(pipe, start, i: int, step: float = 1.0) -> Callable[[], None]:
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
    offset = amount * pipe.scene.box.h * np.array([1.0, 0.0, 0.0])
    position = np.asarray(start.position, dtype=np.float64) + offset
    return lambda: pipe.set_light(0, position=position)


def _nudge_camera(pipe, origin: np.ndarray, i: int) -> Callable[[], None]:
    """A change moving the camera origin by ``i + 1`` steps of 1% of the box size (alternating
    sides of its start), still aimed at the box centre."""
    sign = 1.0 if i % 2 == 0 else -1.0
    amount = sign * (i + 1 + _JITTER.uniform(0.0, 0.25))
    offset = amount * 0.01 * pipe.scene.box.size * np.array([1.0, 0.5, 0.0])
    target = np.asarray(pipe.scene.box.center, dtype=np.float64)
    return lambda: pipe.set_camera(origin=origin + offset, target=target)


def _camera_origin(pipe) -> np.ndarray:
    matrix = np.array(pipe.scene.sensor.world_transform().matrix, dtype=np.float64)[..., 0]
    return matrix[:3, 3].copy()


def _frames_summary(frames: Sequence[dict], warm: Sequence[dict]) -> dict:
    return {
        "wall_ms": summarize([f["wall_ms"] for f in frames]),
        "stages_ms": stage_medians([f["stages_ms"] for f in frames]),
        "recomputed": frames[-1]["recomputed"],
        "compiled_during_timed_runs": _compiles(frames),
        "warmup": list(warm),
        "samples": list(frames),
    }


def measure_interactive(pipe, light_runs: int, view_runs: int) -> dict:
    """Light-change and view-only frames (each after untimed warm-up frames of the same kind) on a
    pipeline whose stages are up to date; restores the light and camera afterwards."""
    origin = _camera_origin(pipe)
    start = dataclasses.replace(pipe.scene.lights[0])
    frame = iter(range(10**6))  # every frame gets a new light position / camera origin
    # a light move may compile kernels in every frame (values baked into kernels): then warming
    # up longer does not help, and the timed frames include (and record) the compilation
    warm_light = warm_up(pipe, lambda _: _nudge_light(pipe, start, next(frame)), 1, limit=2)
    light = [_frame(pipe, _nudge_light(pipe, start, next(frame))) for _ in range(light_runs)]
    warm_view = warm_up(pipe, lambda _: _nudge_camera(pipe, origin, next(frame)), 1, limit=2)
    view = [_frame(pipe, _nudge_camera(pipe, origin, next(frame))) for _ in range(view_runs)]
    pipe.scene.lights[0] = start
    pipe.set_camera(origin=origin, target=np.asarray(pipe.scene.box.center, dtype=np.float64))
    return {
        "full_frame_s": 1e-3 * median(f["wall_ms"] for f in light),
        "view_only_s": 1e-3 * median(f["wall_ms"] for f in view),
        "light_change": _frames_summary(light, warm_light),
        "view_only": _frames_summary(view, warm_view),
        "stats": light[-1]["stats"],
    }


# ----------------------------------------------------------------------------------- profile
def profile_frame(pipe) -> dict:
    """Dr.Jit kernels launched per stage during one light-change frame (kernel history on)."""
    from photonmap.core.timer import StageTimer

    saved = pipe.timer
    pipe.timer = profiling_timer(StageTimer)()
    try:
        # a light position not used before, as in a real light move
        frame = _frame(pipe, _nudge_light(pipe, pipe.scene.lights[0], 0, step=0.5))
        stages = {}
        for stage, kernels in pipe.timer.kernels.items():
            jit = [k for k in kernels if k.get("type") == "JIT"]
            top = max(jit, key=lambda k: k.get("execution_time_ms", 0.0), default=None)
            stages[stage] = {
                "stage_ms": frame["stages_ms"].get(stage),
                "launches": len(kernels),
                "jit_kernels": len(jit),
                "kernel_ms": sum(k.get("execution_time_ms", 0.0) for k in kernels),
                "compiled": sum(1 for k in jit if k.get("compiled")),
                "compile_ms": sum(k.get("backend_time_ms", 0.0) for k in jit if k.get("compiled")),
                "top_kernel": top,
            }
        return {"frame_wall_ms": frame["wall_ms"], "stages": stages}
    finally:
        pipe.timer = saved


class _CountingDr:
    """Forwards to ``drjit``, but every ``scatter_reduce`` traced while ``armed`` also adds 1 per
    active lane to its own slot of ``counter`` (used to count the deposits of the marching
    kernel). Dr.Jit may trace a loop body more than once and keeps only the last trace, so the
    slots of discarded traces stay 0; every executed slot of the rasteriser counts each deposit
    once."""

    SLOTS = 64

    def __init__(self, dr, uint64, uint32):
        self._dr, self._uint32 = dr, uint32
        self.counter = dr.zeros(uint64, self.SLOTS)
        self.armed, self.calls = False, 0

    def __getattr__(self, name):
        return getattr(self._dr, name)

    def scatter_reduce(self, *args, **kwargs):
        if self.armed:
            active = kwargs.get("active", args[4] if len(args) > 4 else True)
            index = kwargs.get("index", args[3] if len(args) > 3 else None)
            width = self._dr.width(index)
            slot = min(self.calls, self.SLOTS - 1)
            self.calls += 1
            self._dr.scatter_reduce(
                self._dr.ReduceOp.Add,
                self.counter,
                self._dr.full(type(self.counter), 1, width),
                self._dr.full(self._uint32, slot, width),
                active=active,
                mode=self._dr.ReduceMode.Local,
            )
        return self._dr.scatter_reduce(*args, **kwargs)


def profile_march(pipe, repeats: int = 1) -> dict:
    """Photon marching (S6/S7) on the cached photons of ``pipe``: as is, without deposition (the
    S7 rasteriser replaced by a no-op) and with a deposit counter. Depends on the internals of
    ``photonmap.volume.march``; any failure is reported instead of raised."""
    import drjit as dr
    import mitsuba as mi

    from photonmap.volume import march

    out: dict = {}
    try:
        photons = pipe.stage_output("photon generation")
        grids = pipe.stage_output("march grids")
        p, h = pipe.params, pipe.scene.box.h

        def run():
            return march.march(photons, grids, ds_min=p.ds_min, fidelity=p.fidelity, voxel_size=h)

        def time_march():
            run()  # warm-up (compiles this variant)
            times, result = [], None
            for _ in range(repeats):
                sync()
                start = time.perf_counter()
                result = run()
                sync()
                times.append(time.perf_counter() - start)
            return median(times), result

        full_s, result = time_march()
        out["with_deposits_s"] = full_s
        out["steps"] = int(result.steps)
        original = march.deposit_segment
        march.deposit_segment = lambda *args, **kwargs: None
        try:
            bare_s, bare = time_march()
        finally:
            march.deposit_segment = original
        out["without_deposits_s"] = bare_s
        out["without_deposits_steps"] = int(bare.steps)
        out["deposition_share"] = max(0.0, 1.0 - bare_s / full_s) if full_s > 0 else math.nan
        out["msteps_per_s_with_deposits"] = result.steps / 1e6 / full_s
        out["msteps_per_s_without_deposits"] = bare.steps / 1e6 / bare_s
    except Exception as exc:  # noqa: BLE001 - a profile must never break the benchmark
        out["error"] = f"{type(exc).__name__}: {exc}"
        return out

    # deposits: count the lanes reaching the rasteriser's scatters
    proxy = _CountingDr(dr, dr.uint64_array_t(mi.Float), mi.UInt32)
    original, real_dr = march.deposit_segment, march.dr

    def counting(*args, **kwargs):
        proxy.armed = True
        try:
            return original(*args, **kwargs)
        finally:
            proxy.armed = False

    try:
        if getattr(original, "__globals__", None) is not vars(march):
            raise RuntimeError("deposit_segment does not read drjit from the march module")
        march.dr, march.deposit_segment = proxy, counting
        run()
        counts = [int(c) for c in np.asarray(proxy.counter) if c > 0]
        if not counts or proxy.calls >= proxy.SLOTS:
            raise RuntimeError(f"cannot attribute the deposit counts ({proxy.calls} scatters)")
        deposits = counts[0]
        out["deposits"] = deposits
        out["scatter_sites_executed"] = len(counts)
        out["scatters_traced"] = proxy.calls
        out["deposits_consistent"] = all(c == deposits for c in counts)
        out["deposits_per_step"] = deposits / max(out["steps"], 1)
        out["mdeposits_per_s"] = deposits / 1e6 / out["with_deposits_s"]
    except Exception as exc:  # noqa: BLE001
        out["deposits_error"] = f"{type(exc).__name__}: {exc}"
    finally:
        march.dr, march.deposit_segment = real_dr, original
    return out


def stage_shares(stages_ms: dict[str, float]) -> dict[str, float]:
    total = sum(stages_ms.values())
    return {k: v / total for k, v in stages_ms.items()} if total > 0 else {}


# -------------------------------------------------------------------------------------- run
def _photon_counts(photons: Sequence[int] | None) -> tuple[int, int, int]:
    """Our counts for the paper's 256², 512², 1024² (positional; the last fills the rest)."""
    photons = list(photons or PAPER_PHOTONS)
    if not 1 <= len(photons) <= 3 or any(int(p) < 1 for p in photons):
        raise ValueError(f"give one to three positive photon counts, got {photons}")
    photons += [photons[-1]] * (3 - len(photons))
    return tuple(int(p) for p in photons)


def run(
    grid: int = 128,
    width: int = 640,
    height: int = 480,
    photons: Sequence[int] | None = None,
    rows: Sequence[int] | None = None,
    runs: int = 3,
    out_dir: Path | str | None = RESULTS,
    light_runs: int = 3,
    view_runs: int = 5,
    secondary: bool = True,
    profile: bool = True,
    quick: bool = False,
    log: Callable[[str], None] = _log,
) -> dict:
    """Run the benchmark and return the result dict; with ``out_dir`` also write
    ``volume_table1.json`` and ``.md`` there (``volume_table1_quick.*`` when ``quick``).

    ``photons`` replaces the paper's (256², 512², 1024²) initial photon counts, ``rows`` selects
    rows of Table 1 (1–11; quick: 9 and 11), ``runs`` timed full renders per row (quick: 1),
    ``light_runs``/``view_runs`` the headline's light-change and view-only frames (quick: 1/2).
    """
    import photonmap  # noqa: F401 - selects the Mitsuba variant

    counts = _photon_counts(photons)
    if quick:
        runs, light_runs, view_runs = 1, min(light_runs, 1), min(view_runs, 2)
        rows = rows or QUICK_ROWS
    selected = [r for r in PAPER_TABLE1 if rows is None or r.number in set(rows)]
    if rows is not None and len(selected) != len(set(rows)):
        raise ValueError(f"rows must be numbers 1–{len(PAPER_TABLE1)}, got {list(rows)}")
    if min(runs, light_runs, view_runs) < 1:
        raise ValueError("runs, light_runs and view_runs must be at least 1")
    started = time.perf_counter()
    result: dict = {
        "benchmark": NAME,
        "machine": machine_info(),
        "settings": {
            "scene": SCENE,
            "grid": grid,
            "width": width,
            "height": height,
            "photon_counts": dict(zip(["256^2", "512^2", "1024^2"], counts, strict=True)),
            "runs": runs,
            "light_runs": light_runs,
            "view_runs": view_runs,
            "quick": quick,
            "protocol": (
                "per configuration: untimed warm-up full renders (2 for the first pipeline of the "
                "process, else 1; more until one compiles no Dr.Jit kernel), then `runs` full "
                "renders with the stage cache cleared (every stage runs); medians per stage. "
                "Interactive frames: warm-up frames of the same kind until one compiles nothing "
                "(at most 2), then the timed frames, each with a light position / camera origin "
                "never used before (a random fraction is added, so Dr.Jit's on-disk kernel cache "
                "cannot hide per-move compilation). Frame times are wall-clock of change + "
                "render, Dr.Jit synchronised; kernel history is on to count compilations."
            ),
            "targets_s": TARGETS_S,
        },
        "rows": [],
    }

    measured: dict[tuple, dict] = {}
    for row in selected:
        config = (row.triangles, row.extent, counts[row.photon_index])
        if config not in measured:
            log(
                f"row {row.number}: {row.triangles} triangles, extent {row.extent}, "
                f"{config[2]} photons ..."
            )
            pipe, setup_s = make_pipeline(
                SCENE, grid, width, height, config[2], triangles=row.triangles, extent=row.extent
            )
            m = measure_full(pipe, runs)
            m["setup_s"] = setup_s
            m["measured_for_row"] = row.number
            measured[config] = m
            del pipe
            log(
                f"  total {m['total_ms']:.0f} ms, tracing {m['stages_ms']['photon tracing']:.0f}"
                f" ms, {m['msteps']:.2f} Msteps"
            )
        result["rows"].append(
            {
                "row": row.number,
                "sweep": row.sweep,
                "triangles": row.triangles,
                "extent": row.extent,
                "photons": config[2],
                "paper": {
                    "photons": row.photons,
                    "msteps": row.msteps,
                    "voxelization_ms": row.voxelization_ms,
                    "photon_tracing_ms": row.tracing_ms,
                    "total_ms": row.total_ms,
                    "hidden_ms": round(row.total_ms - row.voxelization_ms - row.tracing_ms, 2),
                    "ns_per_step": row.tracing_ms / row.msteps,  # ms per Mstep = ns per step
                },
                "ours": measured[config],
            }
        )

    log(f"headline: {SCENE}, 20k triangles, extent 103, {counts[2]} photons ...")
    pipe, _ = make_pipeline(SCENE, grid, width, height, counts[2], **HEADLINE)
    warm = warm_up_full(pipe)
    inter = measure_interactive(pipe, light_runs, view_runs)
    result["headline"] = {
        "scene": SCENE,
        **HEADLINE,
        "photons": counts[2],
        "grid": grid,
        "width": width,
        "height": height,
        "full_frame_s": inter["full_frame_s"],
        "view_only_s": inter["view_only_s"],
        "warmup_full_renders": warm,
        "targets_s": TARGETS_S,
        "meets_targets": {k: inter[k] <= v for k, v in TARGETS_S.items()},
        "light_change": inter["light_change"],
        "view_only": inter["view_only"],
        "stats": inter["stats"],
    }
    log(f"  full frame {inter['full_frame_s']:.2f} s, view only {inter['view_only_s']:.2f} s")

    if profile:
        log("profile ...")
        light_stages = inter["light_change"]["stages_ms"]
        shares = stage_shares(light_stages)
        prof = {
            "light_change_stage_ms": light_stages,
            "light_change_stage_share": shares,
            "slowest_stage": max(shares, key=shares.get) if shares else None,
            "kernels": profile_frame(pipe),
            "march": profile_march(pipe, repeats=1 if quick else 2),
        }
        full = measured.get((HEADLINE["triangles"], HEADLINE["extent"], counts[2]))
        if full is not None:
            prof["full_render_stage_share"] = stage_shares(full["stages_ms"])
        result["profile"] = prof
    del pipe

    if secondary:
        log(f"secondary: {SECONDARY_SCENE}, {counts[2]} photons ...")
        pipe, _ = make_pipeline(SECONDARY_SCENE, grid, width, height, counts[2])
        warm_up_full(pipe)
        sec = measure_interactive(pipe, light_runs, view_runs)
        result["secondary"] = {
            "scene": SECONDARY_SCENE,
            "photons": counts[2],
            "full_frame_s": sec["full_frame_s"],
            "view_only_s": sec["view_only_s"],
            "light_change_stages_ms": sec["light_change"]["stages_ms"],
            "view_only_stages_ms": sec["view_only"]["stages_ms"],
            "stats": sec["stats"],
            "samples": {"light_change": sec["light_change"], "view_only": sec["view_only"]},
        }
        del pipe
        log(f"  full frame {sec['full_frame_s']:.2f} s, view only {sec['view_only_s']:.2f} s")

    result["elapsed_s"] = time.perf_counter() - started
    result["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    result["markdown"] = markdown(result)
    if out_dir is not None:
        stem = NAME + ("_quick" if quick else "")
        result["files"] = {
            "json": str(Path(out_dir) / f"{stem}.json"),
            "markdown": str(Path(out_dir) / f"{stem}.md"),
        }
        write_text(result["files"]["markdown"], result["markdown"] + "\n")
        write_json(result["files"]["json"], result)
    return result


# ----------------------------------------------------------------------------------- report
def _photon_label(count: int) -> str:
    side = math.isqrt(count)
    return f"{side}²" if side * side == count else f"{count:,}"


def markdown(result: dict) -> str:
    """The markdown report: Table 1 beside the paper, the headline and the profile."""
    from photonmap.volume.params import STAGES

    s, m = result["settings"], result["machine"]
    lines = [
        f"# Volume pipeline vs Sun et al. 2008 Table 1 ({s['scene']}, {s['grid']}³, "
        f"{s['width']}×{s['height']})",
        "",
        f"{m['cpu_model']}, {m['cores']} cores, Mitsuba {m['mitsuba']}, Dr.Jit {m['drjit']} "
        f"({m.get('mitsuba_variant')}), {m['date']}, load average at start "
        f"{m.get('load_average')}. Medians of {s['runs']} full renders (every stage runs) after "
        f"warm-up renders. Paper: NVIDIA GeForce 8800 Ultra.",
        "",
        "Stage times in ms. *tracing* = our photon generation + march (the paper's 'photon "
        "tracing'); ns/step = tracing / steps, as for the paper. The paper's total also holds "
        "gradient, octree, irradiance merging and the viewing pass; ours is the sum of all "
        "stages. Rows 2, 8 and 11 are one configuration, measured once.",
        "",
    ]
    headers = [
        "#",
        "tris",
        "extent",
        "photons",
        "voxel.",
        "mater.",
        "grad.",
        "octree",
        "march grids",
        "gen.",
        "march",
        "smooth",
        "view grids",
        "view",
        "**total**",
        "tracing",
        "Msteps",
        "propag.",
        "ns/step",
        "paper Msteps",
        "paper voxel.",
        "paper tracing",
        "paper total",
        "paper ns/step",
    ]
    body, seen = [], {}
    for row in result["rows"]:
        o, p = row["ours"], row["paper"]
        st = o["stages_ms"]
        first = seen.setdefault(o["measured_for_row"], row["row"])
        label = str(row["row"]) + ("" if first == row["row"] else f" (= {first})")
        body.append(
            [
                label,
                f"{row['triangles'] // 1000}k",
                f"{row['extent']}³",
                _photon_label(row["photons"]),
                *[fmt(st.get(k)) for k in STAGES],
                f"**{fmt(o['total_ms'])}**",
                fmt(o["paper_tracing_equivalent_ms"]),
                fmt(o["msteps"], 2),
                fmt(o["photons_propagated"]),
                fmt(o["ns_per_step"], 0),
                fmt(p["msteps"], 2),
                fmt(p["voxelization_ms"], 2),
                fmt(p["photon_tracing_ms"], 2),
                fmt(p["total_ms"], 2),
                fmt(p["ns_per_step"], 1),
            ]
        )
    lines += [markdown_table(headers, body), ""]

    h = result["headline"]
    lines += [
        f"## Headline ({h['triangles'] // 1000}k triangles, extent {h['extent']}³, "
        f"{_photon_label(h['photons'])} photons, {h['grid']}³, {h['width']}×{h['height']})",
        "",
        f"Medians of {s['light_runs']} light-change and {s['view_runs']} view-only frames "
        "(min–max in brackets), wall-clock of change + render.",
        "",
    ]
    sec = result.get("secondary")
    heads = ["frame", f"{h['scene']} (s)"]
    if sec:
        heads.append(f"{sec['scene']} (s)")
    heads += ["target (s)", "met"]

    def cell(frames: dict) -> str:
        w = frames["wall_ms"]
        return f"{fmt(1e-3 * w['median'], 2)} ({fmt(1e-3 * w['min'], 2)}–{fmt(1e-3 * w['max'], 2)})"

    table = []
    for key, part, label in (
        ("full_frame_s", "light_change", "full frame (light change + view)"),
        ("view_only_s", "view_only", "view only (camera change)"),
    ):
        cells = [label, cell(h[part])]
        if sec:
            cells.append(cell(sec["samples"][part]))
        cells += [fmt(TARGETS_S[key], 2), "yes" if h["meets_targets"][key] else "no"]
        table.append(cells)
    lines += [markdown_table(heads, table), ""]
    stage_rows = [
        [stage, fmt(ms), fmt(h["view_only"]["stages_ms"].get(stage))]
        for stage, ms in h["light_change"]["stages_ms"].items()
    ]
    lines += [
        markdown_table(["stage (headline, ms)", "light change", "view only"], stage_rows),
        "",
    ]

    prof = result.get("profile")
    if prof:
        lines += ["## What bounds the light-change frame", ""]
        kernels = prof["kernels"]["stages"]
        rows = []
        for stage, ms in prof["light_change_stage_ms"].items():
            k = kernels.get(stage, {})
            top = k.get("top_kernel") or {}
            rows.append(
                [
                    stage,
                    fmt(ms),
                    f"{100 * prof['light_change_stage_share'][stage]:.1f}%",
                    fmt(k.get("launches")),
                    fmt(k.get("compiled")),
                    fmt(k.get("compile_ms")),
                    fmt(top.get("execution_time_ms")),
                    fmt(top.get("size")),
                    fmt(top.get("operation_count")),
                ]
            )
        lines += [
            "Median stage times of the light-change frames; kernel columns from one more "
            "light-change frame with the kernel history per stage (a light position not used "
            "before).",
            "",
            markdown_table(
                [
                    "stage",
                    "median ms",
                    "share",
                    "kernels",
                    "compiled",
                    "compile ms",
                    "top kernel ms",
                    "top kernel width",
                    "top kernel ops",
                ],
                rows,
            ),
            "",
        ]
        mp = prof["march"]
        if "error" in mp:
            lines.append(f"Marching profile unavailable: {mp['error']}")
        else:
            text = (
                f"Photon marching alone ({mp['steps'] / 1e6:.2f} M steps): "
                f"{mp['with_deposits_s']:.2f} s with deposition "
                f"({mp['msteps_per_s_with_deposits']:.1f} M steps/s), "
                f"{mp['without_deposits_s']:.2f} s with the S7 rasteriser removed "
                f"({mp['msteps_per_s_without_deposits']:.1f} M steps/s): deposition is "
                f"{100 * mp['deposition_share']:.0f}% of the marching time."
            )
            if "deposits" in mp:
                text += (
                    f" {mp['deposits'] / 1e6:.1f} M voxel deposits "
                    f"({mp['deposits_per_step']:.2f} per step, "
                    f"{mp['mdeposits_per_s']:.1f} M deposits/s)."
                )
            lines.append(text)
        lines.append("")
    compiled = h["light_change"]["compiled_during_timed_runs"]
    if compiled["kernels"]:
        lines += [
            f"Each light move compiled Dr.Jit kernels: {compiled['kernels']} in "
            f"{s['light_runs']} timed frames, {compiled['ms']:.0f} ms of LLVM compilation in "
            "total, included in the frame times.",
            "",
        ]
    stats = h["stats"]
    if stats.get("photons_propagated"):
        lines += [
            f"Headline photons: {int(stats['photons_generated']):,} generated, "
            f"{int(stats['photons_propagated']):,} propagated, "
            f"{stats['steps'] / 1e6:.2f} M steps "
            f"({stats['steps'] / stats['photons_propagated']:.1f} per propagated photon; "
            "Sun Table 2: 46–75 steps per photon, 3–18% of 1024² photons propagated).",
            "",
        ]
    lines.append(
        f"Benchmark wall time {result['elapsed_s']:.0f} s; load average at the end "
        f"{result.get('load_average_end')}."
    )
    return "\n".join(lines)


# -------------------------------------------------------------------------------------- CLI
def _ints(text: str) -> list[int]:
    return [int(x) for x in text.replace(" ", "").split(",") if x]


def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smoke test: 1 run, rows 9 and 11")
    parser.add_argument("--runs", type=int, default=3, help="timed full renders per row")
    parser.add_argument("--rows", type=_ints, default=None, help="rows of Table 1, e.g. 1,9,11")
    parser.add_argument("--light-runs", type=int, default=3, help="headline light-change frames")
    parser.add_argument("--view-runs", type=int, default=5, help="headline view-only frames")
    parser.add_argument("--grid", type=int, default=128)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument(
        "--photons", type=_ints, default=None, help="counts for the paper's 256²,512²,1024²"
    )
    parser.add_argument("--out-dir", type=Path, default=RESULTS)
    parser.add_argument("--no-secondary", action="store_true", help=f"skip {SECONDARY_SCENE}")
    parser.add_argument("--no-profile", action="store_true", help="skip the profile")
    args = parser.parse_args(argv)
    result = run(
        grid=args.grid,
        width=args.width,
        height=args.height,
        photons=args.photons,
        rows=args.rows,
        runs=args.runs,
        out_dir=args.out_dir,
        light_runs=args.light_runs,
        view_runs=args.view_runs,
        secondary=not args.no_secondary,
        profile=not args.no_profile,
        quick=args.quick,
    )
    print(result["markdown"])
    return result


if __name__ == "__main__":
    main()
