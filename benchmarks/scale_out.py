"""Benchmark: scaling out on Ray (issue 15 item 5) — throughput with 1 and 2 workers here, the
per-block overheads, and a model of N machines built from those measurements.

Measured on one private Ray instance (2 CPUs, loopback; :func:`photonmap.cluster.connect.
start_local`), each worker an actor with 1 CPU and 1 Dr.Jit thread:

- **progressive**: memoryless SPPM (beyond-seeds §2) of ``cornell_steinhurst``; warm workers
  (scene loaded, kernels compiled by one block each) run ``--blocks`` blocks of ``--block``
  iterations through the driver's task loop and in-order merge (:mod:`photonmap.cluster.schedule`,
  the same code ``render --workers`` runs); iterations/s with 1 and 2 workers, median of
  ``--repeats``. ``headline.scaling_2_workers`` = rate(2) / rate(1) (goal ≥ 1.7). For scale, the
  same iterations in this process with Dr.Jit's own 2 threads.
- **sequence**: a light path of the volume method (``glass_sphere_fog``), frames/s with 1 and 2
  warm frame workers (each keeps its voxel grids and octree: a light move reruns S5–S9).
- **overheads**: worker start (process, photonmap import, scene load, first block with kernel
  compilation), block round trip minus the worker's own compute time (scheduling +
  serialisation + transfer of the H×W×3 float64 sums), the driver's merge of one block and the
  store's put/get of one block.

**Model** of N machines, each like one measured worker: a worker turns out ``b`` iterations in
``b/r + o_w`` seconds (``r`` its rate, ``o_w`` the per-block round trip overhead, hidden by the
second queued block except for its serialisation); the driver handles one block at a time in
``t_d = merge + get + payload / bandwidth`` seconds. So

    rate(N) = min(N · b / (b/r + o_w), b / t_d)

and the knee, where the driver saturates, is N* = (b/r + o_w) / t_d. It is drawn for the measured
block size and for 4× larger blocks, with the payload crossing a 10 Gbit/s network, and, as a
pessimistic bound for a film-quality render, with 1920×1080 sums (the driver's merge, store and
network costs scaled by the pixel count, the iterations' cost kept as measured). Sequences the
same way with frames (the driver writes each frame: ``t_d`` = get + write).

The machine is shared with other agents (2 cores): the load average before and after is
recorded, and the 2-worker numbers are only as good as the free cores were.
``python benchmarks/scale_out.py [--quick] [--repeats R]`` writes
``benchmarks/results/scale_out.json``, ``.md`` and ``.png``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from report import RESULTS, fmt, machine_info, markdown_table, write_json, write_text
from timing import summarize

NAME = "scale_out"
BANDWIDTH = 10e9 / 8  # bytes/s of the driver's network link in the model (10 Gbit/s)
MODEL_N = (1, 2, 4, 8, 16, 32, 64)
FILM = (1920, 1080)  # the film-sized image of the model's pessimistic curves


def progressive_job(args):
    from photonmap.cluster.job import SceneJob

    params = {"photons_per_iteration": args.photons, "seed": 1, "mode": "memoryless"}
    return SceneJob("cornell_steinhurst", "sppm", params, width=args.width, height=args.height)


def sequence_frames(args):
    from photonmap.cluster.frames import parse_frames

    light = [{"position": [0.3, 3.0, 0.5]}, {"position": [0.7, 2.0, 0.5]}]
    spec = parse_frames({"frames": args.frames + 2, "light": light})  # +1 warm-up per worker
    return spec.frames


def sequence_job(args):
    from photonmap.cluster.job import SceneJob

    params = {"grid": args.grid, "photons": args.volume_photons}
    return SceneJob("glass_sphere_fog", "volume", params, width=args.width, height=args.height)


@contextmanager
def warm_actors(ray, worker_class, job, workers, warm_call):
    """``workers`` actors, each having run one task (``warm_call(actor, i)``); yields the actors,
    the seconds each took to become ready (start + first task, kernel compilation included) and
    the last warm-up's info."""
    from photonmap.cluster.connect import Placement, spawn

    with spawn(ray, worker_class, Placement(workers, 1.0, 0.0, 1, "cpu"), job) as actors:
        t0 = time.perf_counter()
        refs = [warm_call(a, i) for i, a in enumerate(actors)]
        ready = []
        for ref in refs:
            _, info = ray.get(ref)
            ready.append(time.perf_counter() - t0)
        yield actors, ready, info


def progressive_rate(ray, args, workers: int) -> dict:
    """Iterations/s of warm workers through the driver's task loop and in-order merge."""
    from photonmap.cluster.progressive import InOrder
    from photonmap.cluster.schedule import run_tasks
    from photonmap.cluster.workers import BlockWorker

    rates, overhead, shares = [], [], []
    warm = lambda a, i: a.render_block.remote(1000 + i, 1)  # noqa: E731
    with warm_actors(ray, BlockWorker, progressive_job(args), workers, warm) as (
        actors, ready, info,
    ):  # fmt: skip
        for rep in range(args.repeats):
            first = 1 + rep * args.blocks * args.block
            tasks = [(f, (f, args.block)) for f in range(first, first + args.blocks * args.block,
                                                           args.block)]  # fmt: skip
            merged, t0, cpu = InOrder(first), time.perf_counter(), 0.0
            for key, (sums, block_info) in run_tasks(ray, actors, "render_block", tasks):
                cpu += block_info["cpu_seconds"]
                merged.add(key, sums)
            wall = time.perf_counter() - t0
            rates.append(merged.sums.iterations / wall)
            shares.append(cpu / wall)
        for _ in range(args.repeats):  # one block at a time: round trip − compute
            t0 = time.perf_counter()
            _, block_info = ray.get(actors[0].render_block.remote(1, 1))
            overhead.append(time.perf_counter() - t0 - block_info["seconds"])
    return {
        "workers": workers,
        "iterations_per_s": summarize(rates),
        "cores_obtained": summarize(shares),
        "ready_s": summarize(ready),
        "scene_load_s": info["load_seconds"],
        "block_round_trip_overhead_s": summarize(overhead),
    }


def sequence_rate(ray, args, workers: int) -> dict:
    """Frames/s of warm frame workers (each rendered one frame of the path first)."""
    from photonmap.cluster.schedule import run_tasks
    from photonmap.cluster.workers import FrameWorker
    from photonmap.core.image import write_image

    frames = sequence_frames(args)
    rates, write, shares = [], [], []
    warm = lambda a, i: a.render.remote(frames[i])  # noqa: E731
    with warm_actors(ray, FrameWorker, sequence_job(args), workers, warm) as (actors, ready, _):
        for _ in range(args.repeats):
            tasks = [(f.index, (f,)) for f in frames[2:]]
            t0, cpu = time.perf_counter(), 0.0
            for _key, (image, frame_info) in run_tasks(ray, actors, "render", tasks):
                cpu += frame_info["cpu_seconds"]
                tw = time.perf_counter()
                write_image(os.path.join(args.tmp, "frame.png"), np.array(image))
                write.append(time.perf_counter() - tw)
            wall = time.perf_counter() - t0
            rates.append(len(tasks) / wall)
            shares.append(cpu / wall)
    return {
        "workers": workers,
        "frames_per_s": summarize(rates),
        "cores_obtained": summarize(shares),
        "ready_s": summarize(ready),
        "driver_write_s": summarize(write),
    }


def driver_costs(ray, args) -> dict:
    """The driver's per-block work: merging one block, and a put/get of one through the store."""
    from photonmap import BlockSums

    shape = (args.height, args.width, 3)
    a = BlockSums(np.random.default_rng(0).random(shape), args.block)
    b = BlockSums(np.random.default_rng(1).random(shape), args.block)
    merge, store = [], []
    for _ in range(max(5, args.repeats)):
        t0 = time.perf_counter()
        a.merge(b)
        merge.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ray.get(ray.put(b))
        store.append(time.perf_counter() - t0)
    return {
        "payload_bytes": int(a.total.nbytes),
        "merge_s": summarize(merge),
        "store_put_get_s": summarize(store),
    }


def in_process_rate(args) -> float:
    """Iterations/s of one process with Dr.Jit's 2 threads (the same blocks, no Ray)."""
    from photonmap.cluster.job import build_pipeline

    pipe = build_pipeline(progressive_job(args))
    pipe.render_block(1000, 1)  # kernels compiled
    t0 = time.perf_counter()
    pipe.render_block(1, args.block * 2)
    return args.block * 2 / (time.perf_counter() - t0)


def model(rate_1: float, per_unit_overhead: float, driver_s: float, unit: int, ns=MODEL_N):
    """Throughput of N workers like the measured one (module docstring):
    ``min(N · unit / (unit/rate_1 + overhead), unit / driver_s)``; returns the curve and the
    knee N* where the driver saturates."""
    work = unit / rate_1 + per_unit_overhead
    curve = [min(n * unit / work, unit / driver_s) for n in ns]
    return {"n": list(ns), "throughput": curve, "knee": work / driver_s, "unit": unit}


def plot(path: Path, curves: dict, measured: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, (kind, label) in zip(axes, (("progressive", "iterations/s"),
                                        ("sequence", "frames/s")), strict=True):  # fmt: skip
        for name, c in curves[kind].items():
            line = ax.plot(c["n"], c["throughput"], marker=".", label=f"{name} (knee {c['knee']:.0f})")
            if c["knee"] <= 64:
                ax.axvline(c["knee"], color=line[0].get_color(), ls=":", lw=0.8)
        ideal = [n * measured[kind][0] for n in MODEL_N]
        ax.plot(MODEL_N, ideal, "k--", lw=0.8, label="ideal (N × 1 worker)")
        ax.plot([1, 2], measured[kind], "ks", label="measured here")
        ax.set_xlim(0.8, 80)
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel("workers (machines like one measured worker)")
        ax.set_ylabel(label)
        ax.set_title(f"{kind}: model from the measured overheads")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, *_quick.* outputs")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--width", type=int, default=160)
    parser.add_argument("--height", type=int, default=120)
    parser.add_argument("--photons", type=int, default=50_000, help="photons per iteration")
    parser.add_argument("--block", type=int, default=4, help="iterations per block")
    parser.add_argument("--blocks", type=int, default=8, help="blocks per timed run")
    parser.add_argument("--frames", type=int, default=8, help="timed frames per run")
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--volume-photons", type=int, default=65536)
    parser.add_argument("--out-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.quick:
        args.width, args.height, args.photons, args.blocks, args.frames = 64, 48, 10_000, 4, 4
        args.grid, args.volume_photons, args.repeats = 32, 4096, 1
    import tempfile

    import ray

    from photonmap.cluster.connect import start_local

    args.tmp = tempfile.mkdtemp()
    load_before = os.getloadavg()
    start_local(ray, 2)
    try:
        progressive = [progressive_rate(ray, args, w) for w in (1, 2)]
        sequence = [sequence_rate(ray, args, w) for w in (1, 2)]
        driver = driver_costs(ray, args)
    finally:
        ray.shutdown()
    local = in_process_rate(args)
    load_after = os.getloadavg()

    it = [p["iterations_per_s"]["median"] for p in progressive]
    cores = [p["cores_obtained"]["median"] for p in progressive]
    fr = [s["frames_per_s"]["median"] for s in sequence]
    o_block = progressive[0]["block_round_trip_overhead_s"]["median"]
    t_block = driver["merge_s"]["median"] + driver["store_put_get_s"]["median"]
    t_block += driver["payload_bytes"] / BANDWIDTH
    frame_bytes = args.width * args.height * 3 * 4
    t_frame = sequence[0]["driver_write_s"]["median"] + frame_bytes / BANDWIDTH
    # the same iterations with film-sized sums: every driver cost grows with the pixels
    t_film = t_block * FILM[0] * FILM[1] / (args.width * args.height)
    film = f"{FILM[0]}x{FILM[1]} sums"
    curves = {
        "progressive": {
            f"block {args.block}": model(it[0], o_block, t_block, args.block),
            f"block {4 * args.block}": model(it[0], o_block, t_block, 4 * args.block),
            f"{film}, block {args.block}": model(it[0], o_block, t_film, args.block),
            f"{film}, block {4 * args.block}": model(it[0], o_block, t_film, 4 * args.block),
        },
        "sequence": {"1 frame/task": model(fr[0], 0.0, t_frame, 1)},
    }
    result = {
        "machine": machine_info(),
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in load_after],
        "settings": {k: v for k, v in vars(args).items() if k not in ("out_dir", "tmp")},
        "progressive": progressive,
        "sequence": sequence,
        "driver": driver,
        "in_process_2_threads_iterations_per_s": local,
        "model": {"bandwidth_bytes_per_s": BANDWIDTH, **curves},
        "headline": {
            "scaling_2_workers": it[1] / it[0],
            "projected_scaling_2_free_cores": (it[1] / cores[1]) / (it[0] / cores[0]) * 2,
            "cores_obtained": cores,
            "scaling_2_workers_frames": fr[1] / fr[0],
            "iterations_per_s": it,
            "frames_per_s": fr,
            "goal": 1.7,
            "knee_workers": curves["progressive"][f"block {args.block}"]["knee"],
            "knee_workers_4x_block": curves["progressive"][f"block {4 * args.block}"]["knee"],
            "knee_workers_frames": curves["sequence"]["1 frame/task"]["knee"],
            "knee_workers_film": curves["progressive"][f"{film}, block {args.block}"]["knee"],
            "knee_workers_film_4x_block": curves["progressive"][
                f"{film}, block {4 * args.block}"
            ]["knee"],
        },
    }
    suffix = "_quick" if args.quick else ""
    rows = [
        ["progressive, iterations/s", fmt(it[0], 2), fmt(it[1], 2), fmt(it[1] / it[0], 2)],
        ["sequence, frames/s", fmt(fr[0], 2), fmt(fr[1], 2), fmt(fr[1] / fr[0], 2)],
    ]
    h = result["headline"]
    text = "\n".join([
        f"# scale_out{suffix}: Ray workers on this machine (load {load_before[0]:.1f} before, "
        f"{load_after[0]:.1f} after)",
        "",
        markdown_table(["", "1 worker", "2 workers", "scaling"], rows),
        "",
        f"CPU cores the workers obtained (CPU seconds / wall): 1 worker {cores[0]:.2f}, "
        f"2 workers {cores[1]:.2f}; scaling if 2 workers had had 2× the CPU of 1: "
        f"{h['projected_scaling_2_free_cores']:.2f}",
        f"in-process, Dr.Jit 2 threads: {local:.2f} iterations/s",
        f"worker ready (start + scene load + first block): "
        f"{progressive[0]['ready_s']['median']:.2f} s (scene load "
        f"{progressive[0]['scene_load_s']:.3f} s); block round-trip overhead "
        f"{o_block * 1e3:.1f} ms; merge {driver['merge_s']['median'] * 1e3:.2f} ms; store put/get "
        f"{driver['store_put_get_s']['median'] * 1e3:.2f} ms of {driver['payload_bytes']:,} bytes",
        f"model knee (driver saturates): {h['knee_workers']:.0f} workers at block {args.block}, "
        f"{h['knee_workers_4x_block']:.0f} at block {4 * args.block}; sequences "
        f"{h['knee_workers_frames']:.0f}; with {film} (driver costs × pixels, iterations as "
        f"measured): {h['knee_workers_film']:.1f} at block {args.block}, "
        f"{h['knee_workers_film_4x_block']:.1f} at block {4 * args.block}",
        "",
    ])  # fmt: skip
    write_json(args.out_dir / f"{NAME}{suffix}.json", result)
    write_text(args.out_dir / f"{NAME}{suffix}.md", text)
    plot(args.out_dir / f"{NAME}{suffix}.png", curves, {"progressive": it, "sequence": fr})
    print(text)
    return result


if __name__ == "__main__":
    sys.exit(main() and 0)
