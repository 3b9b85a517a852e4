"""Steinhurst 2007's reordering results reproduced on our scenes (issue 13 items 3, 4, 7, 8; spec
seed-001 §3.3, §3.7, oracles O16–O21, O27).

For the Cornell box (``cornell_steinhurst``, the dissertation's Fig 1.2) and the bushy box
(``cornell_bushes``, many small occluders in Sponza's role) the surface method renders the whole
512 × 512 image with exact k = 100 k-NN final gathers on the heap-order kd-tree; every gather's
exact stream of 20-byte photon-record reads (about 2 G reads per order) is streamed through the
cache simulator (fully associative LRU at 8 KB–1 MB, 128-byte lines; 8-way set-associative at
128 KB beside it) — Table 3.1 at the dissertation's full scale. The tile and line-size sweeps and
the CPU timings use a window of the 512² image (the dissertation's pixel footprint; spec A17),
scaled to the image. Written beside the dissertation's numbers:

- Table 3.1 (bytes per image by gather order) and the reduction of each order against the
  uncached naive figure (20 B per visited node, §3.5) — O16, O17;
- Fig 3.9 (bytes vs cache size, one streamed pass per order gives every size; plot in ``docs/``) — O19;
- Fig 3.5 (bytes vs tile size) — O18; Fig 4.1 / Table 4.1 (bytes vs line size) — O21;
- 8-way set-associative vs fully associative misses — O20;
- the chip model of Ch. 7 fed with these counts: tiles/s at 90 GB/s per order — O27;
- CPU wall time of the final gathers (Dr.Jit k-NN on this machine) per order, medians of runs;
- Table 4.1 and Fig 4.1 (``structures``): the Cornell window's gathers on the kd-tree, the
  kdB-tree and block hashing (:mod:`photonmap.analysis.structures`), fetches per distinct block
  (spec A7) per order, and bytes vs line size for kd vs kdB — O21.

    PYTHONPATH=src .venv/bin/python benchmarks/steinhurst_tables.py [--quick]
    PYTHONPATH=src .venv/bin/python benchmarks/steinhurst_tables.py --only structures
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import photonmap  # noqa: E402,F401
import report  # noqa: E402
import timing  # noqa: E402
from photonmap.analysis.bandwidth import (  # noqa: E402
    WAYS,
    cache_sweep,
    line_sweep,
    plot_sweep,
    tile_sweep,
)
from photonmap.analysis.hardware import TABLE_7_10, from_trace  # noqa: E402
from photonmap.analysis.stream import cropped_scene, trace_final_gathers  # noqa: E402
from photonmap.analysis.structures import (  # noqa: E402
    STRUCTURES,
    fetches_per_block,
    recall,
    structure_trace,
)
from photonmap.surface.gather_batch import ORDERS, OrderParams  # noqa: E402
from photonmap.surface.pipeline import SurfacePipeline  # noqa: E402

NAME = "steinhurst_tables"
CACHE_KB = [8, 16, 32, 64, 128, 256, 512, 1024]
LINES = [64, 128, 256, 512, 1024]
TILES = [4, 8, 16, 32]
PRACTICAL = ("tiled", "tiled_dirbin", "tiled_dirbin_hashed", "tiled_hilbert", "hilbert")

# Table 3.1 (GB per 512 × 512 image; Sponza's column for the bushy scene) and the uncached naive
# figures of §2.6.4; whole-image Hilbert on Cornell: 15 MB (§3.4.1)
DOC = {
    "cornell_steinhurst": {
        "uncached": 50.0,
        "tiled": 50.0,
        "tiled_dirbin": 13.0,
        "tiled_dirbin_hashed": 12.0,
        "tiled_hilbert": 9.0,
        "hilbert": 0.015,
    },
    "cornell_bushes": {
        "uncached": 367.0,
        "tiled": 357.0,
        "tiled_dirbin": 58.0,
        "tiled_dirbin_hashed": 31.0,
        "tiled_hilbert": 19.0,
    },
}
READS_BUDGET = 9 << 30  # the full image's line reads held in memory (about 2 B per read)
MANY_BINS = 128  # the direction-binned orders again with 128 bins (A1's sweep: the best here)
BINNED = ("tiled_dirbin", "tiled_dirbin_hashed")
SPONZA = dict(photons=100_000, fg_rays=200, max_radius=0.02)  # bushes at Sponza's N_FG (§2.6.2.1)
# window of the 512² image (x, y, w, h) for the sweeps and CPU timings, surface parameters
# (N_FG 50: the dissertation's Cornell figure, §2.6.2.1), hash grid G (Cornell 5, Sponza 8)
SCENES = {
    "cornell_steinhurst": ((192, 288, 64, 32), dict(photons=100_000, fg_rays=50), 5),
    "cornell_bushes": ((192, 256, 64, 32), dict(photons=100_000, fg_rays=50, max_radius=0.02), 8),
}
QUICK = ((240, 288, 16, 16), dict(photons=5000, fg_rays=4), None)
# Fig 6.17 / O26: the glossy floor's lobe narrowed (Beckmann α; Phong n ≈ 2/α² − 2), window on it
GLOSSY = ((224, 432, 64, 32), dict(photons=100_000, fg_rays=32), (0.3, 0.1, 0.03), 0.8)
GLOSSY_ORDERS = ("naive", "tiled_dirbin_hashed", "tiled_hilbert")
# Table 4.1: "average number of memory-block fetches" (read as fetches per distinct block, A7);
# Cornell box, 16×16 tiles, 128 KB cache, 128 B lines
STRUCTURE_ORDERS = ("naive", "tiled_dirbin", "tiled_dirbin_hashed", "tiled_hilbert", "hilbert")
DOC_TABLE_4_1 = {
    "naive": {"kdtree": 23_045, "kdbtree": 11_755, "blockhash": 73_523},
    "tiled_dirbin": {"kdtree": 3_927, "kdbtree": 4_397, "blockhash": 20_316},
    "tiled_dirbin_hashed": {"kdtree": 2_590, "kdbtree": 2_870, "blockhash": 9_912},
    "tiled_hilbert": {"kdtree": 1_215, "kdbtree": 1_134, "blockhash": 2_350},
    "hilbert": {"kdtree": 1.6, "kdbtree": 1.8, "blockhash": 3.1},
}
LINE_ORDERS = ("naive", "tiled_hilbert")  # Fig 4.1 (a) and (b)
BH_ACCURACY = (20, 40, 80)  # block hashing's A: the dissertation's 20, then more blocks read


def structures_study(quick: bool) -> dict:
    """Table 4.1 and Fig 4.1 on the Cornell window: the same final gathers on the kd-tree, the
    kdB-tree and block hashing (O21)."""
    window, surface, grid = QUICK if quick else SCENES["cornell_steinhurst"]
    x, y, w, h = window
    scene = cropped_scene("cornell_steinhurst", 512, (x, y), (w, h))
    params = dict(surface, caustic_photons=0, emitter_spp=0, k=100)
    start = time.perf_counter()
    trace = trace_final_gathers(scene, **params)
    scale = 512 * 512 / (w * h)
    order_params = OrderParams(grid=grid or 5)
    traces = {s: structure_trace(trace, s) for s in STRUCTURES}
    table = {
        o: {s: fetches_per_block(t, o, 128 * 1024, 128, order_params) for s, t in traces.items()}
        for o in STRUCTURE_ORDERS
    }
    kdb, found_kdb = traces["kdbtree"].build(128)[:2]
    bh, found_bh, reads_bh = traces["blockhash"].build(128)[:3]
    sample = slice(None, None, 8)
    exact = found_kdb[sample]
    facts = {
        "kdtree": {
            "reads_per_gather": trace.visits / len(trace.batch),
            "structure_lines": trace.footprint_lines(128),
        },
        "kdbtree": {
            "reads_per_gather": traces["kdbtree"].build(128)[2].mean(),
            "structure_lines": kdb.lines,
            "leaves": int(np.count_nonzero(kdb.kind == 1)),
            "fan_out": kdb.fan_out,
            "leaf_photons": kdb.leaf_capacity,
        },
        "blockhash": {
            "reads_per_gather": reads_bh.mean(),
            "structure_lines": bh.lines,
            "blocks": bh.blocks,
            "orphaned_blocks": bh.orphaned,
            "dropped_bucket_entries": bh.dropped,
            "recall": recall(found_bh[sample], exact),
        },
    }
    lines = LINES[:2] if quick else LINES
    line_sweep_gb = {
        s: {
            o: [v * scale / 1e9 for v in c]
            for o, c in line_sweep(traces[s], LINE_ORDERS, lines, params=order_params).items()
        }
        for s in ("kdtree", "kdbtree")
    }
    crossover = {
        o: next(
            (
                line
                for line, kd, kdb_gb in zip(
                    lines, line_sweep_gb["kdtree"][o], line_sweep_gb["kdbtree"][o], strict=True
                )
                if kdb_gb < kd
            ),
            None,
        )
        for o in LINE_ORDERS
    }
    accuracy = {}
    for a in BH_ACCURACY[:1] if quick else BH_ACCURACY:
        t = structure_trace(trace, "blockhash", accuracy=a)
        found, reads = t.build(128)[1:3]
        accuracy[a] = {
            "recall": recall(found[sample], exact),
            "reads_per_gather": reads.mean(),
            **{o: fetches_per_block(t, o, 128 * 1024, 128, order_params) for o in LINE_ORDERS},
        }
    return {
        "window": window,
        "params": params,
        "gathers": len(trace.batch),
        "photons": trace.photons,
        "image_scale": scale,  # bytes of the window → bytes of a 512 × 512 image
        "table": table,
        "doc_table_4_1": DOC_TABLE_4_1,
        "structures": facts,
        "lines": lines,
        "line_sweep_GB": line_sweep_gb,
        "kdb_beats_kd_from_line": crossover,
        "blockhash_accuracy": accuracy,
        "seconds": time.perf_counter() - start,
        "load_average": os.getloadavg(),
    }


def structures_markdown(s: dict) -> str:
    """Table 4.1 (measured beside the dissertation's) and the Fig 4.1 line sweep."""
    f = s["structures"]
    parts = [
        "## Data structures (Table 4.1, Fig 4.1, O21)\n",
        f"Cornell window {s['window']} of 512×512, {s['gathers']:,} final gathers (k 100), "
        f"{s['photons']:,} photons; 128 KB fully associative LRU, 128 B lines. Fetches per "
        "distinct block = misses / distinct lines of the structure the gathers touch (spec A7). "
        f"Lines read per gather: kd-tree {f['kdtree']['reads_per_gather']:.0f} (20-byte "
        f"records), kdB-tree {f['kdbtree']['reads_per_gather']:.1f}, block hashing "
        f"{f['blockhash']['reads_per_gather']:.1f} (recall of the exact k nearest "
        f"{f['blockhash']['recall']:.2f}, {f['blockhash']['orphaned_blocks']:,} of "
        f"{f['blockhash']['blocks']:,} blocks orphaned); load average {s['load_average']}\n",
    ]
    rows = []
    for order, r in s["table"].items():
        doc = s["doc_table_4_1"][order]
        rows.append(
            [
                order,
                *[report.fmt(r[x]["fetches_per_block"], 2) for x in STRUCTURES],
                *[report.fmt(doc[x], 1) for x in STRUCTURES],
                report.fmt(r["kdbtree"]["fetches_per_block"] / r["kdtree"]["fetches_per_block"], 2),
                report.fmt(doc["kdbtree"] / doc["kdtree"], 2),
                report.fmt(r["kdbtree"]["misses"] / max(r["kdtree"]["misses"], 1), 2),
            ]
        )
    parts.append(
        report.markdown_table(
            [
                "order",
                "kd",
                "kdB",
                "BH",
                "doc kd",
                "doc kdB",
                "doc BH",
                "kdB/kd",
                "doc kdB/kd",
                "kdB/kd bytes",
            ],
            rows,
        )
    )
    gb = 128 * s["image_scale"] / 1e9  # GB per image of one miss
    parts.append("\nGB per 512 × 512 image (misses × 128 B) and distinct lines touched:\n")
    parts.append(
        report.markdown_table(
            ["order", *[f"{x} GB" for x in STRUCTURES]],
            [
                [order, *[report.fmt(r[x]["misses"] * gb, 2) for x in STRUCTURES]]
                for order, r in s["table"].items()
            ]
            + [
                [
                    "distinct lines",
                    *[report.fmt(s["table"]["naive"][x]["distinct_lines"]) for x in STRUCTURES],
                ]
            ],
        )
    )
    parts.append("\nGB/image vs line size (128 KB cache), kd-tree vs kdB-tree (Fig 4.1):\n")
    parts.append(
        report.markdown_table(
            ["structure", "order", *map(str, s["lines"])],
            [
                [st, o, *[report.fmt(v, 2) for v in c]]
                for st, curves in s["line_sweep_GB"].items()
                for o, c in curves.items()
            ],
        )
    )
    parts.append(
        "\nkdB-tree below the kd-tree from line size (bytes): "
        + ", ".join(f"{o} {v}" for o, v in s["kdb_beats_kd_from_line"].items())
        + " (dissertation: 256 B in naive order)\n"
    )
    parts.append("Block hashing's accuracy A (blocks read per gather at most), 128 B lines:\n")
    parts.append(
        report.markdown_table(
            [
                "A",
                "recall",
                "lines/gather",
                *[f"fetches/block {o}" for o in LINE_ORDERS],
                *[f"GB {o}" for o in LINE_ORDERS],
            ],
            [
                [
                    a,
                    report.fmt(r["recall"], 3),
                    report.fmt(r["reads_per_gather"], 1),
                    *[report.fmt(r[o]["fetches_per_block"], 2) for o in LINE_ORDERS],
                    *[report.fmt(r[o]["misses"] * gb, 2) for o in LINE_ORDERS],
                ]
                for a, r in s["blockhash_accuracy"].items()
            ],
        )
    )
    return "\n".join(parts) + "\n"


def sponza_setting(quick: bool) -> dict:
    """O17's bushy target at the dissertation's Sponza setting: N_FG = 200 (§2.6.2.1, Fig 1.3),
    128 direction bins, G = 8, on the whole 512² image. Its line reads do not fit in memory
    (about 12 G), so both orders walk the tree while they stream (one per core)."""
    size = 64 if quick else 512
    params = dict(SPONZA, caustic_photons=0, emitter_spp=0, k=100)
    if quick:
        params.update(photons=5000, fg_rays=8)
    trace = trace_final_gathers(
        cropped_scene("cornell_bushes", size, (0, 0), (size, size)), **params
    )
    runs = [
        ("tiled_dirbin_hashed", OrderParams(grid=8, bins=MANY_BINS)),
        ("tiled_hilbert", OrderParams(grid=8)),
    ]
    start = time.perf_counter()
    with ThreadPoolExecutor(2) as pool:
        counts = list(
            pool.map(lambda r: trace.simulate(r[0], [128], [128 * 1024], WAYS, r[1]), runs)
        )
    uncached = trace.uncached_bytes()
    scale = 512 * 512 / (size * size)
    return {
        "image": size,
        "params": params,
        "bins": MANY_BINS,
        "hash_grid": 8,
        "gathers": len(trace.batch),
        "node_visits": trace.visits,
        "uncached_GB_per_image": uncached * scale / 1e9,
        "simulate_s": time.perf_counter() - start,
        "load_average": os.getloadavg(),
        "table": {
            o: {
                "GB_per_image": int(c.misses[0, 0]) * 128 * scale / 1e9,
                "reduction_vs_uncached": uncached / max(int(c.misses[0, 0]) * 128, 1),
                "set_associative_ratio": int(c.set_associative[0]) / max(int(c.misses[0, 0]), 1),
            }
            for (o, _), c in zip(runs, counts, strict=True)
        },
    }


def sponza_markdown(s: dict) -> str:
    return (
        "## Bushy box at the Sponza setting (O17)\n\n"
        f"cornell_bushes, the whole {s['image']}² image, N_FG {s['params']['fg_rays']}, "
        f"{s['bins']} direction bins, G = {s['hash_grid']}: {s['gathers']:,} final gathers, "
        f"{s['node_visits']:,} node reads (uncached naive {s['uncached_GB_per_image']:.0f} "
        f"GB/image), streamed in {s['simulate_s']:.0f} s, load {s['load_average']}\n\n"
        + report.markdown_table(
            ["order", "GB/image", "vs uncached", "8-way/full"],
            [
                [
                    o,
                    report.fmt(r["GB_per_image"], 2),
                    report.fmt(r["reduction_vs_uncached"], 1) + "×",
                    report.fmt(r["set_associative_ratio"], 2),
                ]
                for o, r in s["table"].items()
            ],
        )
        + "\n"
    )


def glossy_sweep(quick: bool) -> dict:
    """GB per image of three orders as the floor's glossy lobe narrows (Fig 6.17, O26: naive
    order falls, the coherent orders stay about constant)."""
    window, surface, roughness, weight = GLOSSY
    if quick:
        window, surface, _ = QUICK
        roughness = roughness[:1]
    x, y, w, h = window
    out = {"window": window, "glossy_weight": weight, "roughness": list(roughness), "GB": {}}
    for alpha in roughness:
        scene = cropped_scene(
            "cornell_glossy_floor", 512, (x, y), (w, h), roughness=alpha, glossy=weight
        )
        trace = trace_final_gathers(scene, **surface, caustic_photons=0, emitter_spp=0, k=100)
        curves = cache_sweep(trace, GLOSSY_ORDERS, [128 * 1024], 128, OrderParams(grid=5))
        for order, c in curves.items():
            out["GB"].setdefault(order, []).append(c[0] * 512 * 512 / (w * h) / 1e9)
    out["load_average"] = os.getloadavg()
    return out


def full_image_table(name: str, params: dict, grid: int, size: int) -> dict:
    """Table 3.1, Fig 3.9 and O20 on the whole ``size``² image: every final gather of the render
    walked once (its line reads kept), then replayed through the caches once per order, two
    orders at a time (one per core); the direction-binned orders also with 128 bins (A1)."""
    start = time.perf_counter()
    trace = trace_final_gathers(cropped_scene(name, size, (0, 0), (size, size)), **params)
    trace_s = time.perf_counter() - start
    start = time.perf_counter()
    stored = trace.store_reads(128, READS_BUDGET)
    store_s = time.perf_counter() - start
    caps = [128 * 1024] + [kb * 1024 for kb in CACHE_KB if kb != 128]  # 8-way at the first
    runs = [(o, OrderParams(grid=grid)) for o in ORDERS]
    runs += [(o, OrderParams(grid=grid, bins=MANY_BINS)) for o in BINNED]

    def run(job):
        t = time.perf_counter()
        c = trace.simulate(job[0], [128], caps, ways=WAYS, params=job[1])
        return c, time.perf_counter() - t

    start = time.perf_counter()
    with ThreadPoolExecutor(2) as pool:
        labels = [o if p.bins == 32 else f"{o}@{p.bins}" for o, p in runs]
        counts = dict(zip(labels, pool.map(run, runs), strict=True))
    simulate_s = time.perf_counter() - start
    uncached = trace.uncached_bytes()
    scale = 512 * 512 / (size * size)
    table = {}
    for order, (c, seconds) in counts.items():
        missed = int(c.misses[0, 0])
        table[order] = {
            "GB_per_image": missed * 128 * scale / 1e9,
            "reduction_vs_uncached": uncached / max(missed * 128, 1),
            "fetches_per_map_line": missed / trace.footprint_lines(128),
            "set_associative_ratio": int(c.set_associative[0]) / max(missed, 1),
            "simulate_s": seconds,
        }
    sizes = [128] + [kb for kb in CACHE_KB if kb != 128]
    by_size = np.argsort(sizes)
    return {
        "image": size,
        "params": params,
        "hash_grid": grid,
        "gathers": len(trace.batch),
        "node_visits": trace.visits,
        "visits_per_gather": trace.visits / len(trace.batch),
        "photons": trace.photons,
        "map_lines_128B": trace.footprint_lines(128),
        "trace_s": trace_s,
        "reads_stored": stored,
        "store_s": store_s,
        "simulate_s": simulate_s,
        "ns_per_visit_per_order": simulate_s * 2 / len(runs) / trace.visits * 1e9,
        "uncached_GB_per_image": uncached * scale / 1e9,
        "load_average": os.getloadavg(),
        "table": table,
        "cache_sweep_GB": {
            o: [int(c.misses[0, i]) * 128 * scale / 1e9 for i in by_size]
            for o, (c, _) in counts.items()
        },
        "hardware": from_trace(
            trace, {o: t["GB_per_image"] * 1e9 / scale for o, t in table.items()}, size * size
        ),
    }


def window_sweeps(name: str, window, params: dict, grid: int) -> dict:
    """Figs 3.5 and 4.1 on a window of the 512² image (the dissertation's pixel footprint, so
    each tile's gathers are as coherent as at full size; spec A17): bytes scaled to the image."""
    x, y, w, h = window
    trace = trace_final_gathers(cropped_scene(name, 512, (x, y), (w, h)), **params)
    scale = 512 * 512 / (w * h)
    order_params = OrderParams(grid=grid)
    tiles = [t for t in TILES if w % t == 0 and h % t == 0]
    sweep_orders = ("tiled_dirbin", "tiled_dirbin_hashed", "tiled_hilbert")
    tile_curves = tile_sweep(trace, sweep_orders, tiles, params=order_params)
    line_orders = ("naive", "tiled_dirbin_hashed", "tiled_hilbert")
    line_curves = line_sweep(trace, line_orders, LINES, params=order_params)
    return {
        "window": window,
        "gathers": len(trace.batch),
        "tiles": tiles,
        "lines": LINES,
        "tile_sweep_GB": {o: [v * scale / 1e9 for v in c] for o, c in tile_curves.items()},
        "line_sweep_GB": {o: [v * scale / 1e9 for v in c] for o, c in line_curves.items()},
        "load_average": os.getloadavg(),
    }


def study(name: str, window, surface: dict, grid: int, quick: bool, sweeps: bool) -> dict:
    params = dict(surface, caustic_photons=0, emitter_spp=0, k=100)
    out = full_image_table(name, params, grid, 64 if quick else 512)
    if sweeps:
        out["window_sweeps"] = window_sweeps(name, window, params, grid)
    x, y, w, h = window
    out["cpu_window"] = window
    out["cpu"] = cpu_times(cropped_scene(name, 512, (x, y), (w, h)), params, 1 if quick else 3)
    return out


def cpu_times(scene, params: dict, repeats: int) -> dict:
    """Milliseconds of the final-gather stage (Dr.Jit k-NN gathers on the kd-tree and the hash
    grid, this CPU) per order: medians of ``repeats`` renders after a warm-up render."""
    out = {}
    for structure in ("kdtree", "hash"):
        pipe = SurfacePipeline(scene, **params, lookup="knn", structure=structure)
        pipe.render()  # photon maps and kernel compilation
        runs = {o: [] for o in ORDERS}
        for _ in range(repeats):
            for order in ORDERS:
                pipe.set_params(gather_order=order)
                pipe.render()
                runs[order].append(pipe.timer.ms["final gather"])
        out[structure] = {o: timing.summarize(r) for o, r in runs.items()}
    return out


def markdown(result: dict) -> str:
    parts = ["# Steinhurst 2007 tables reproduced\n"]
    for name, s in result["scenes"].items():
        doc = DOC[name]
        parts.append(
            f"## {name}\n\nthe whole {s['image']}×{s['image']} image, {s['gathers']:,} final "
            f"gathers (N_FG {s['params']['fg_rays']}, k 100, {s['params']['photons']:,} photon "
            f"paths), {s['node_visits']:,} kd-tree node reads ({s['visits_per_gather']:.0f} per "
            f"gather; walked once in {s['store_s']:.0f} s, then {s['simulate_s']:.0f} s for the "
            f"{len(s['table'])} orders on two cores), {s['photons']:,} photons "
            f"({s['map_lines_128B']:,} lines of 128 B); "
            f"uncached naive {s['uncached_GB_per_image']:.1f} GB/image (dissertation "
            f"{doc['uncached']:g} GB{'' if name == 'cornell_steinhurst' else ', Sponza'}); "
            f"load average {s.get('load_average', 'not recorded')}\n"
        )
        rows = []
        for order, r in s["table"].items():
            d = doc.get(order)
            rows.append(
                [
                    order,
                    report.fmt(r["GB_per_image"], 2),
                    report.fmt(r["reduction_vs_uncached"], 1) + "×",
                    report.fmt(d, 3) if d else "—",
                    report.fmt(doc["uncached"] / d, 1) + "×" if d else "—",
                    report.fmt(r["fetches_per_map_line"], 2),
                    report.fmt(r["set_associative_ratio"], 2),
                    *[
                        report.fmt(s["cpu"][k][order]["median"], 0) if order in ORDERS else "—"
                        for k in ("kdtree", "hash")
                    ],
                ]
            )
        parts.append(
            report.markdown_table(
                [
                    "order",
                    "GB/image",
                    "vs uncached",
                    "doc GB",
                    "doc vs uncached",
                    "fetches/line",
                    "8-way/full",
                    "CPU ms kd",
                    "CPU ms hash",
                ],
                rows,
            )
        )
        parts.append("\nGB/image vs cache size (KB " + ", ".join(map(str, CACHE_KB)) + "):\n")
        parts.append(
            report.markdown_table(
                ["order", *[f"{kb}K" for kb in CACHE_KB]],
                [[o, *[report.fmt(v, 2) for v in c]] for o, c in s["cache_sweep_GB"].items()],
            )
        )
        if "window_sweeps" in s:
            ws = s["window_sweeps"]
            parts.append(
                f"\nGB/image vs tile edge (window {ws['window']} of the 512² image, scaled):\n"
            )
            parts.append(
                report.markdown_table(
                    ["order", *map(str, ws["tiles"])],
                    [[o, *[report.fmt(v, 2) for v in c]] for o, c in ws["tile_sweep_GB"].items()],
                )
            )
            parts.append("\nGB/image vs line size (128 KB, same window):\n")
            parts.append(
                report.markdown_table(
                    ["order", *map(str, ws["lines"])],
                    [[o, *[report.fmt(v, 2) for v in c]] for o, c in ws["line_sweep_GB"].items()],
                )
            )
        hw = s["hardware"]
        parts.append("\nChip model (Ch. 7) fed with these counts, R_IC = 0:\n")
        parts.append(
            report.markdown_table(
                ["order", "GB/image", "GFLOPs/image", "tiles/s (90 GB/s)", "tiles/s (500 GFLOPS)"],
                [
                    [
                        o,
                        report.fmt(h["GB_per_image"], 2),
                        report.fmt(h["GFLOPs_per_image"], 1),
                        report.fmt(h["tiles_per_s_memory"], 0),
                        report.fmt(h["tiles_per_s_compute"], 0),
                    ]
                    for o, h in hw.items()
                ],
            )
        )
        parts.append("")
    glossy = result.get("glossy")
    if glossy:
        parts.append(
            f"## glossy floor (Fig 6.17, O26)\n\nwindow {glossy['window']}, glossy weight "
            f"{glossy['glossy_weight']}, GB/image at 128 KB against the Beckmann roughness:\n"
        )
        parts.append(
            report.markdown_table(
                ["order", *[f"α {a}" for a in glossy["roughness"]]],
                [[o, *[report.fmt(v, 2) for v in c]] for o, c in glossy["GB"].items()],
            )
        )
        parts.append("")
    if result.get("structures"):
        parts.append(structures_markdown(result["structures"]))
    if result.get("sponza_setting"):
        parts.append(sponza_markdown(result["sponza_setting"]))
    parts.append("## headline\n")
    parts.append("\n".join(f"- {k}: {v}" for k, v in result["headline"].items()))
    return "\n".join(parts) + "\n"


def headline_of(scenes: dict, sponza: dict | None, out: Path) -> dict:
    """The issue's headline numbers from the per-scene results (and the Sponza-setting run),
    with the irradiance-cache and CIS figures of ``steinhurst_ic_cis.py``'s results in ``out``."""
    headline = {
        "traffic_reduction_dirbin_hashed": {},  # uncached naive bytes / order's bytes, per scene
        "traffic_reduction_tiled_hilbert": {},
        "traffic_reduction_dirbin_hashed_128_bins": {},
        "set_associative_ratio": {},  # 8-way / fully associative misses, dir-binning + hashed
        "cpu_speedup_best_order_per_scene": {},  # naive / best practical order, kd-tree gathers
        "cpu_best_order": {},
    }
    for name, s in scenes.items():
        t = s["table"]
        headline["traffic_reduction_dirbin_hashed"][name] = t["tiled_dirbin_hashed"][
            "reduction_vs_uncached"
        ]
        headline["traffic_reduction_tiled_hilbert"][name] = t["tiled_hilbert"][
            "reduction_vs_uncached"
        ]
        headline["traffic_reduction_dirbin_hashed_128_bins"][name] = t[
            f"tiled_dirbin_hashed@{MANY_BINS}"
        ]["reduction_vs_uncached"]
        headline["set_associative_ratio"][name] = t["tiled_dirbin_hashed"]["set_associative_ratio"]
        cpu = s["cpu"]["kdtree"]
        best = min(PRACTICAL, key=lambda o: cpu[o]["median"])
        speedup = cpu["naive"]["median"] / cpu[best]["median"]
        headline["cpu_speedup_best_order_per_scene"][name] = speedup
        headline["cpu_best_order"][name] = best
    headline["cpu_speedup_best_order"] = min(headline["cpu_speedup_best_order_per_scene"].values())
    if sponza:
        headline["traffic_reduction_dirbin_hashed_sponza_setting"] = sponza["table"][
            "tiled_dirbin_hashed"
        ]["reduction_vs_uncached"]
    ic_cis = out / "steinhurst_ic_cis.json"
    if ic_cis.is_file():  # written by benchmarks/steinhurst_ic_cis.py
        other = json.loads(ic_cis.read_text())["headline"]
        for key in ("ic_gathers_saved", "cis_rays_ratio_vs_brdf"):
            headline[key] = other[key]
    return headline


STUDIES = {
    "structures": (structures_study, structures_markdown),
    "sponza_setting": (sponza_setting, sponza_markdown),
}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny configuration (smoke test)")
    ap.add_argument("--out-dir", default=str(report.RESULTS))
    ap.add_argument("--plot", default=str(report.REPO / "docs" / "steinhurst_cache_size.png"))
    ap.add_argument(
        "--scenes",
        default=",".join([*SCENES, "glossy_floor", "structures"]),
        help="scenes (and the glossy_floor / structures studies) to run; the others keep their "
        "results of the previous run's JSON",
    )
    ap.add_argument(
        "--only",
        choices=list(STUDIES),
        help="run only this study, written into the previous run's results (sponza_setting: "
        "about 12 G node reads, 20-40 minutes)",
    )
    args = ap.parse_args(argv)
    out = Path(args.out_dir)
    stem = NAME + ("_quick" if args.quick else "")
    previous = out / f"{stem}.json"
    if args.only:  # this study alone, written into the previous run's results
        study_fn, render = STUDIES[args.only]
        found = study_fn(args.quick)
        result = json.loads(previous.read_text()) if previous.is_file() else {}
        result[args.only] = found
        if "scenes" in result:
            result["headline"] = headline_of(result["scenes"], result.get("sponza_setting"), out)
            report.write_text(out / f"{stem}.md", markdown(result))
        report.write_json(out / f"{stem}.json", result)
        print(render(found))
        return result
    scenes = json.loads(previous.read_text())["scenes"] if previous.is_file() else {}
    for name, (window, surface, grid) in SCENES.items():
        if name not in args.scenes.split(","):
            continue
        if args.quick:
            window, surface, _ = QUICK
        sweeps = not args.quick and name == "cornell_steinhurst"
        scenes[name] = study(name, window, surface, grid or 5, args.quick, sweeps)
        print(f"{name}: done", flush=True)
    previous_glossy = json.loads(previous.read_text()).get("glossy") if previous.is_file() else None
    glossy = glossy_sweep(args.quick) if "glossy_floor" in args.scenes.split(",") else None
    glossy = glossy or previous_glossy
    structures = (
        structures_study(args.quick)
        if "structures" in args.scenes.split(",")
        else json.loads(previous.read_text()).get("structures")
        if previous.is_file()
        else None
    )
    sponza = json.loads(previous.read_text()).get("sponza_setting") if previous.is_file() else None
    headline = headline_of(scenes, sponza, out)
    result = {
        "name": NAME,
        "quick": args.quick,
        "machine": report.machine_info(),
        "load_average": os.getloadavg(),  # at the end of this run; per scene in its study
        "doc_table_3_1_GB": DOC,
        "doc_table_7_10": TABLE_7_10,
        "scenes": scenes,
        "glossy": glossy,
        "structures": structures,
        "sponza_setting": sponza,
        "headline": headline,
    }
    report.write_json(out / f"{stem}.json", result)
    report.write_text(out / f"{stem}.md", markdown(result))
    if not args.quick:
        cornell = scenes["cornell_steinhurst"]
        plot_sweep(
            {o: np.asarray(c) * 1e9 for o, c in cornell["cache_sweep_GB"].items()},
            CACHE_KB,
            "cache size (KB)",
            args.plot,
            "Cornell box, whole 512×512 image, 128 B lines",
            cornell["uncached_GB_per_image"] * 1e9,
        )
    print(markdown(result))
    return result


if __name__ == "__main__":
    main()
