"""Steinhurst 2007's reordering results (Ch. 3, 4 and 7: photon-map bandwidth per gather order)
reproduced on our scenes.

For the Cornell box (``cornell_steinhurst``, the dissertation's Fig 1.2) and the bushy box
(``cornell_bushes``, many small occluders in Sponza's role) the surface method renders the whole
512 × 512 image with exact k = 100 k-NN final gathers on the heap-order kd-tree; every gather's
exact stream of 20-byte photon-record reads (about 2 G reads per order) is streamed through the
cache simulator (fully associative LRU at 8 KB–1 MB, 128-byte lines; 8-way set-associative at
128 KB beside it) — Table 3.1 at the dissertation's full scale. The tile and line-size sweeps and
the CPU timings use a window of the 512² image (the dissertation's pixel footprint), scaled to
the image. Written beside the dissertation's numbers:

- Table 3.1 (bytes per image by gather order) and the reduction of each order against the
  uncached naive figure (20 B per visited node, §3.5) — O16, O17;
- Fig 3.9 (bytes vs cache size, one streamed pass per order gives every size; plot in ``docs/``) — O19;
- Fig 3.5 (bytes vs tile size) — O18; Fig 4.1 / Table 4.1 (bytes vs line size) — O21;
- 8-way set-associative vs fully associative misses — O20;
- the chip model of Ch. 7 fed with these counts: tiles/s at 90 GB/s per order — O27;
- CPU wall time of the final gathers (Dr.Jit k-NN on this machine) per order, medians of runs;
- Table 4.1 and Fig 4.1 (``structures``, :mod:`steinhurst_structures`): the Cornell window's
  gathers on the kd-tree, the kdB-tree and block hashing, fetches per distinct block per order,
  and bytes vs line size for kd vs kdB — O21;
- the glossy floor (Fig 6.17) and the bushy box at the Sponza setting (``--only sponza_setting``),
  :mod:`steinhurst_variants`.

    PYTHONPATH=src .venv/bin/python benchmarks/steinhurst_tables.py [--quick]
    PYTHONPATH=src .venv/bin/python benchmarks/steinhurst_tables.py --only structures
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

import photonmap  # noqa: F401 - selects the Mitsuba variant
import report
import timing
from photonmap.analysis.bandwidth import WAYS, line_sweep, plot_sweep, tile_sweep
from photonmap.analysis.hardware import TABLE_7_10, from_trace
from photonmap.analysis.stream import cropped_scene, trace_final_gathers
from photonmap.surface.gather_batch import ORDERS, OrderParams
from photonmap.surface.pipeline import SurfacePipeline
from steinhurst_structures import structures_markdown, structures_study
from steinhurst_tables_report import markdown
from steinhurst_variants import MANY_BINS, glossy_sweep, sponza_markdown, sponza_setting

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
BINNED = ("tiled_dirbin", "tiled_dirbin_hashed")
# window of the 512² image (x, y, w, h) for the sweeps and CPU timings, surface parameters
# (N_FG 50: the dissertation's Cornell figure, §2.6.2.1), hash grid G (Cornell 5, Sponza 8)
SCENES = {
    "cornell_steinhurst": ((192, 288, 64, 32), dict(photons=100_000, fg_rays=50), 5),
    "cornell_bushes": ((192, 256, 64, 32), dict(photons=100_000, fg_rays=50, radius=0.02), 8),
}
QUICK = ((240, 288, 16, 16), dict(photons=5000, fg_rays=4), None)


def structures(quick: bool) -> dict:
    """Table 4.1 and Fig 4.1 on the Cornell window (:mod:`steinhurst_structures`)."""
    window, surface, grid = QUICK if quick else SCENES["cornell_steinhurst"]
    return structures_study(window, surface, grid or 5, quick, LINES[:2] if quick else LINES)


def glossy(quick: bool) -> dict:
    """Fig 6.17 (:mod:`steinhurst_variants`)."""
    return glossy_sweep(quick, QUICK)


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
    each tile's gathers are as coherent as at full size): bytes scaled to the image."""
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


def headline_of(scenes: dict, sponza: dict | None, out: Path) -> dict:
    """The headline numbers from the per-scene results (and the Sponza-setting run), with the
    irradiance-cache and CIS figures of ``steinhurst_ic_cis.py``'s results in ``out``."""

    def reduction(order: str) -> dict:  # uncached naive bytes / the order's bytes, per scene
        return {n: s["table"][order]["reduction_vs_uncached"] for n, s in scenes.items()}

    def cpu(name: str, order: str) -> float:  # kd-tree final gathers, median ms
        return scenes[name]["cpu"]["kdtree"][order]["median"]

    best = {n: min(PRACTICAL, key=lambda o, n=n: cpu(n, o)) for n in scenes}

    headline = {
        "traffic_reduction_dirbin_hashed": reduction("tiled_dirbin_hashed"),
        "traffic_reduction_tiled_hilbert": reduction("tiled_hilbert"),
        "traffic_reduction_dirbin_hashed_128_bins": reduction(f"tiled_dirbin_hashed@{MANY_BINS}"),
        # 8-way / fully associative misses, dir-binning + hashed
        "set_associative_ratio": {
            n: s["table"]["tiled_dirbin_hashed"]["set_associative_ratio"] for n, s in scenes.items()
        },
        # naive / best practical order, kd-tree gathers
        "cpu_speedup_best_order_per_scene": {n: cpu(n, "naive") / cpu(n, best[n]) for n in scenes},
        "cpu_best_order": best,
    }
    headline["cpu_speedup_best_order"] = min(headline["cpu_speedup_best_order_per_scene"].values())
    if sponza:
        table = sponza["table"]["tiled_dirbin_hashed"]
        headline["traffic_reduction_dirbin_hashed_sponza_setting"] = table["reduction_vs_uncached"]
    other = report.previous_results(out / "steinhurst_ic_cis.json").get("headline", {})
    for key in ("ic_gathers_saved", "cis_rays_ratio_vs_brdf"):
        if key in other:  # written by benchmarks/steinhurst_ic_cis.py
            headline[key] = other[key]
    return headline


STUDIES = {
    "structures": (structures, structures_markdown),
    "sponza_setting": (sponza_setting, sponza_markdown),
}


def only(study: str, quick: bool, out: Path) -> dict:
    """Run one study of :data:`STUDIES` and write it into the previous run's results."""
    run, render = STUDIES[study]
    found = run(quick)
    stem = report.results_stem(out, NAME, quick)
    result = {**report.previous_results(stem.with_suffix(".json")), study: found}
    if "scenes" in result:
        result["headline"] = headline_of(result["scenes"], result.get("sponza_setting"), out)
        report.write_text(stem.with_suffix(".md"), markdown(result, CACHE_KB))
    report.write_json(stem.with_suffix(".json"), result)
    print(render(found))
    return result


def main(argv=None) -> dict:
    ap = report.arguments(__doc__, "tiny configuration (smoke test)")
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
    if args.only:
        return only(args.only, args.quick, out)
    stem = report.results_stem(out, NAME, args.quick)
    previous = report.previous_results(stem.with_suffix(".json"))
    wanted = args.scenes.split(",")
    scenes = previous.get("scenes", {})
    for name, (window, surface, grid) in SCENES.items():
        if name in wanted:
            if args.quick:
                window, surface, _ = QUICK
            sweeps = not args.quick and name == "cornell_steinhurst"
            scenes[name] = study(name, window, surface, grid or 5, args.quick, sweeps)
            print(f"{name}: done", flush=True)
    floor = (glossy(args.quick) if "glossy_floor" in wanted else None) or previous.get("glossy")
    tables_4_1 = structures(args.quick) if "structures" in wanted else previous.get("structures")
    result = {
        "name": NAME,
        "quick": args.quick,
        "machine": report.machine_info(),
        "load_average": os.getloadavg(),  # at the end of this run; per scene in its study
        "doc_table_3_1_GB": DOC,
        "doc_table_7_10": TABLE_7_10,
        "scenes": scenes,
        "glossy": floor,
        "structures": tables_4_1,
        "sponza_setting": previous.get("sponza_setting"),
        "headline": headline_of(scenes, previous.get("sponza_setting"), out),
    }
    text = markdown(result, CACHE_KB)
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
    return report.publish(stem, result, text)


if __name__ == "__main__":
    main()
