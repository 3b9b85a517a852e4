"""Scaling out on Ray: throughput with 1 and 2 workers here, the per-block overheads, and a model
of N machines built from those measurements.

Measured on one private Ray instance (2 CPUs, loopback; :func:`photonmap.cluster.connect.
start_local`), each worker an actor with 1 CPU and 1 Dr.Jit thread:

- **progressive**: memoryless SPPM (Knaus & Zwicker 2011) of ``cornell_steinhurst``; warm workers
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

**Model** of N machines, each like one measured worker (:mod:`scale_out_model`): a worker turns
out ``b`` iterations in ``b/r + o_w`` seconds (``r`` its rate, ``o_w`` the per-block round trip
overhead, hidden by the second queued block except for its serialisation); the driver handles one
block at a time in ``t_d = merge + get + payload / bandwidth`` seconds. So

    rate(N) = min(N · b / (b/r + o_w), b / t_d)

and the knee, where the driver saturates, is N* = (b/r + o_w) / t_d. It is drawn for the measured
block size and for 4× larger blocks, with the payload crossing a 10 Gbit/s network, and, as a
pessimistic bound for a film-quality render, with 1920×1080 sums (the driver's merge, store and
network costs scaled by the pixel count, the iterations' cost kept as measured). Sequences the
same way with frames (the driver writes each frame: ``t_d`` = get + write).

The machine may be shared (2 cores): the load average before and after is
recorded, and the 2-worker numbers are only as good as the free cores were.
``python benchmarks/scale_out.py [--quick] [--repeats R]`` writes
``benchmarks/results/scale_out.json``, ``.md`` and ``.png`` (``_quick`` with ``--quick``).
"""

from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager

import numpy as np

import report
from report import fmt
from scale_out_model import BANDWIDTH, FILM, curves_of, plot
from timing import summarize

NAME = "scale_out"


def progressive_job(args):
    from photonmap.cluster.job import SceneJob

    params = {"photons": args.photons, "seed": 1, "mode": "memoryless"}
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


def measure(args) -> dict:
    """Everything measured: on a private 2-CPU Ray instance, then in this process alone."""
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
    return {"load_before": load_before, "progressive": progressive, "sequence": sequence,
            "driver": driver, "local": local, "load_after": os.getloadavg()}  # fmt: skip


def headline(m: dict, curves: dict, block: int) -> dict:
    it = [p["iterations_per_s"]["median"] for p in m["progressive"]]
    cores = [p["cores_obtained"]["median"] for p in m["progressive"]]
    fr = [s["frames_per_s"]["median"] for s in m["sequence"]]
    film = f"{FILM[0]}x{FILM[1]} sums"
    knee = {name: c["knee"] for name, c in curves["progressive"].items()}
    return {
        "scaling_2_workers": it[1] / it[0],
        "projected_scaling_2_free_cores": (it[1] / cores[1]) / (it[0] / cores[0]) * 2,
        "cores_obtained": cores,
        "scaling_2_workers_frames": fr[1] / fr[0],
        "iterations_per_s": it,
        "frames_per_s": fr,
        "goal": 1.7,
        "knee_workers": knee[f"block {block}"],
        "knee_workers_4x_block": knee[f"block {4 * block}"],
        "knee_workers_frames": curves["sequence"]["1 frame/task"]["knee"],
        "knee_workers_film": knee[f"{film}, block {block}"],
        "knee_workers_film_4x_block": knee[f"{film}, block {4 * block}"],
    }


def markdown(result: dict) -> str:
    h, d, block = result["headline"], result["driver"], result["settings"]["block"]
    suffix = "_quick" if result["settings"]["quick"] else ""
    it, fr, cores = h["iterations_per_s"], h["frames_per_s"], h["cores_obtained"]
    first = result["progressive"][0]
    o_block = first["block_round_trip_overhead_s"]["median"]
    rows = [
        ["progressive, iterations/s", fmt(it[0], 2), fmt(it[1], 2), fmt(it[1] / it[0], 2)],
        ["sequence, frames/s", fmt(fr[0], 2), fmt(fr[1], 2), fmt(fr[1] / fr[0], 2)],
    ]
    before, after = result["load_average_before"][0], result["load_average_after"][0]
    return "\n".join([
        f"# scale_out{suffix}: Ray workers on this machine (load {before:.1f} before, "
        f"{after:.1f} after)",
        "",
        report.markdown_table(["", "1 worker", "2 workers", "scaling"], rows),
        "",
        f"CPU cores the workers obtained (CPU seconds / wall): 1 worker {cores[0]:.2f}, "
        f"2 workers {cores[1]:.2f}; scaling if 2 workers had had 2× the CPU of 1: "
        f"{h['projected_scaling_2_free_cores']:.2f}",
        f"in-process, Dr.Jit 2 threads: {result['in_process_2_threads_iterations_per_s']:.2f} "
        "iterations/s",
        f"worker ready (start + scene load + first block): {first['ready_s']['median']:.2f} s "
        f"(scene load {first['scene_load_s']:.3f} s); block round-trip overhead "
        f"{o_block * 1e3:.1f} ms; merge {d['merge_s']['median'] * 1e3:.2f} ms; store put/get "
        f"{d['store_put_get_s']['median'] * 1e3:.2f} ms of {d['payload_bytes']:,} bytes",
        f"model knee (driver saturates): {h['knee_workers']:.0f} workers at block {block}, "
        f"{h['knee_workers_4x_block']:.0f} at block {4 * block}; sequences "
        f"{h['knee_workers_frames']:.0f}; with {FILM[0]}x{FILM[1]} sums (driver costs × pixels, "
        f"iterations as measured): {h['knee_workers_film']:.1f} at block {block}, "
        f"{h['knee_workers_film_4x_block']:.1f} at block {4 * block}",
        "",
    ])  # fmt: skip


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "small sizes, *_quick.* outputs")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--width", type=int, default=160)
    parser.add_argument("--height", type=int, default=120)
    parser.add_argument("--photons", type=int, default=50_000, help="photons per iteration")
    parser.add_argument("--block", type=int, default=4, help="iterations per block")
    parser.add_argument("--blocks", type=int, default=8, help="blocks per timed run")
    parser.add_argument("--frames", type=int, default=8, help="timed frames per run")
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--volume-photons", type=int, default=65536)
    args = parser.parse_args(argv)
    if args.quick:
        args.width, args.height, args.photons, args.blocks, args.frames = 64, 48, 10_000, 4, 4
        args.grid, args.volume_photons, args.repeats = 32, 4096, 1
    m = measure(args)
    curves = curves_of(m, args)
    result = {
        "machine": report.machine_info(),
        "load_average_before": [round(x, 2) for x in m["load_before"]],
        "load_average_after": [round(x, 2) for x in m["load_after"]],
        "settings": {k: v for k, v in vars(args).items() if k not in ("out_dir", "tmp")},
        "progressive": m["progressive"],
        "sequence": m["sequence"],
        "driver": m["driver"],
        "in_process_2_threads_iterations_per_s": m["local"],
        "model": {"bandwidth_bytes_per_s": BANDWIDTH, **curves},
        "headline": headline(m, curves, args.block),
    }
    text = markdown(result)
    stem = report.results_stem(args.out_dir, NAME, args.quick)
    measured = {"progressive": result["headline"]["iterations_per_s"],
                "sequence": result["headline"]["frames_per_s"]}  # fmt: skip
    plot(stem.with_suffix(".png"), curves, measured)
    return report.publish(stem, result, text)


if __name__ == "__main__":
    sys.exit(main() and 0)
