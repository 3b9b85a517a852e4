"""What the O17 reductions depend on: a parameter study of the photon-map traffic of Steinhurst
2007's reorderings (§3.3–3.5) against the uncached naive figure.

O17's hard targets: tiled direction-binning + hashed moves ≥ 4× less than the uncached naive
figure (20 B per visited kd-tree node, §3.5) on the Cornell box and ≥ 10× on the bushy box
(Sponza's role). The ratio depends on settings the dissertation leaves open or gives only in
passing: the final-gather rays N_FG (Cornell's 50 GB is N = 50; Fig 3.9 uses 100), the global
photon count (never given), the number of direction bins ("the correct tradeoff is found
experimentally"), and the hash grid G. For each scene a window of the 512 × 512 image (the
dissertation's pixel footprint) is rendered with exact k = 100
k-NN final gathers on the heap-order kd-tree and traced once per (N_FG, photons); every order and
bin count is a permutation of that one trace, fed to the LRU simulator (128 KB, 128-byte lines,
fully associative, 16 × 16 tiles):

1. N_FG ∈ {32, 50, 100} × photons ∈ {100 k, 500 k} at 32 bins;
2. bins ∈ {8, 16, 32, 64, 128, 256, 512} at the setting where dir-binning + hashed reduces most;
3. the hash grid G ∈ {2, 5, 8, 16} there (at the best bin count).

    PYTHONPATH=src .venv/bin/python benchmarks/steinhurst_o17_study.py [--quick] [--sweeps-only]

(at load 3–4 on two cores: the (N_FG, photons) table ~13 min, the sweeps of both scenes ~13 min;
``--sweeps-only`` redoes only the latter.)
"""

from __future__ import annotations

import os
import time
from dataclasses import replace

import photonmap  # noqa: F401 - selects the Mitsuba variant
import report
from photonmap.analysis.bandwidth import bandwidth_table
from photonmap.analysis.stream import cropped_scene, trace_final_gathers
from photonmap.surface.gather_batch import OrderParams
from report import fmt, markdown_table

NAME = "steinhurst_o17_study"
ORDERS = ("tiled_dirbin", "tiled_dirbin_hashed", "tiled_hilbert")
BINNED = ("tiled_dirbin", "tiled_dirbin_hashed")  # the orders the bin count changes
TARGET = {"cornell_steinhurst": 4.0, "cornell_bushes": 10.0}  # O17, dir-binning + hashed
# window (x, y, w, h) of the 512² image (inside steinhurst_tables' windows), scene-specific
# surface parameters, hash grid G (Cornell 5, Sponza 8: §3.4.3)
SCENES = {
    "cornell_steinhurst": ((192, 288, 32, 16), {}, 5),
    "cornell_bushes": ((192, 256, 32, 16), dict(radius=0.02), 8),
}
FG_RAYS = (32, 50, 100)
PHOTONS = (100_000, 500_000)
BINS = (8, 16, 32, 64, 128, 256, 512)
GRIDS = (2, 5, 8, 16)
QUICK = ((240, 288, 16, 16), (4, 8), (5000,), (8, 32), (5,))


def reductions(trace, params: OrderParams, orders=ORDERS) -> dict:
    """Uncached naive bytes / simulated bytes (128 KB, 128 B) of each order."""
    rows = bandwidth_table(trace, orders, 128 * 1024, 128, params)
    return {r["order"]: r["reduction_vs_uncached"] for r in rows}


def trace(name: str, window, surface: dict, photons: int, fg_rays: int):
    """The final-gather trace of ``name``'s window at one (photons, N_FG) setting."""
    x, y, w, h = window
    scene = cropped_scene(name, 512, (x, y), (w, h))
    return trace_final_gathers(
        scene, **surface, photons=photons, fg_rays=fg_rays, caustic_photons=0, emitter_spp=0, k=100
    )


def study(name: str, window, surface: dict, grid: int, fg_rays, photons, bins, grids) -> dict:
    w, h = window[2:]
    params = OrderParams(grid=grid)
    settings, best, best_trace = [], None, None
    for n_photons in photons:
        for n_fg in fg_rays:
            start = time.perf_counter()
            t = trace(name, window, surface, n_photons, n_fg)
            traced = time.perf_counter() - start
            red = reductions(t, params)
            row = {
                "fg_rays": n_fg,
                "photons": n_photons,
                "stored_photons": t.photons,
                "map_lines_128B": t.footprint_lines(128),
                "gathers": len(t.batch),
                "visits_per_gather": t.visits / len(t.batch),
                "gathers_per_tile": len(t.batch) / ((w // 16) * (h // 16)),
                "reduction_vs_uncached": red,
                "trace_s": traced,
                "simulate_s": time.perf_counter() - start - traced,
            }
            settings.append(row)
            print(name, n_photons, n_fg, {k: round(v, 2) for k, v in red.items()}, flush=True)
            if (
                best is None
                or red["tiled_dirbin_hashed"] > best["reduction_vs_uncached"]["tiled_dirbin_hashed"]
            ):
                best, best_trace = row, t
    out = {
        "window": window,
        "surface": surface,
        "hash_grid": grid,
        "settings": settings,
        "best": {"fg_rays": best["fg_rays"], "photons": best["photons"]},
        "target_dirbin_hashed": TARGET[name],
    }
    return {**out, **sweeps(best_trace, params, bins, grids)}


def sweeps(best_trace, params: OrderParams, bins, grids) -> dict:
    """The bin-count sweep at the best setting, then the hash grid at the best bin count."""
    start = time.perf_counter()
    by_bins = {
        b: reductions(best_trace, replace(params, bins=b), BINNED if b != 32 else ORDERS)
        for b in bins
    }
    best_bins = max(bins, key=lambda b: by_bins[b]["tiled_dirbin_hashed"])
    by_grid = {
        g: reductions(
            best_trace, replace(params, bins=best_bins, grid=g), ("tiled_dirbin_hashed",)
        )["tiled_dirbin_hashed"]
        for g in grids
    }
    return {
        "bins": {str(b): r for b, r in by_bins.items()},
        "best_bins": best_bins,
        "grid": {str(g): r for g, r in by_grid.items()},
        "sweeps_s": time.perf_counter() - start,
        "load_average": os.getloadavg(),
    }


def verdict(name: str, s: dict) -> str:
    """Which settings meet O17's target for this scene."""
    target = s["target_dirbin_hashed"]
    met = [
        f"N_FG {r['fg_rays']}, {r['photons'] // 1000}k photons, 32 bins "
        f"({r['reduction_vs_uncached']['tiled_dirbin_hashed']:.2f}×)"
        for r in s["settings"]
        if r["reduction_vs_uncached"]["tiled_dirbin_hashed"] >= target
    ]
    met += [
        f"{b} bins at the best setting ({r['tiled_dirbin_hashed']:.2f}×)"
        for b, r in s["bins"].items()
        if r["tiled_dirbin_hashed"] >= target and b != "32"
    ]
    met += [
        f"G = {g} at {s['best_bins']} bins ({v:.2f}×)" for g, v in s["grid"].items() if v >= target
    ]
    best = max(
        [r["reduction_vs_uncached"]["tiled_dirbin_hashed"] for r in s["settings"]]
        + [r["tiled_dirbin_hashed"] for r in s["bins"].values()]
        + list(s["grid"].values())
    )
    if met:
        return f"**{name}: O17's ≥ {target:g}× is met** by " + "; ".join(met) + "."
    return (
        f"**{name}: no setting meets O17's ≥ {target:g}×** for tiled dir-binning + hashed; "
        f"the best is {best:.2f}×."
    )


def markdown(result: dict) -> str:
    parts = [
        "# O17 parameter study: reductions vs the uncached naive figure\n",
        "Uncached naive bytes (20 B per visited kd-tree node, §3.5) / simulated bytes "
        "(128 KB fully associative LRU, 128-byte lines, 16×16 tiles, k = 100 on the heap-order "
        f"kd-tree). Load average {result['load_average']}; {result['elapsed_s']:.0f} s in all.\n",
    ]
    if result.get("sweeps_only"):
        t = result["table_run"]
        parts.append(
            "The (N_FG, photons) tables are those of an earlier run (load average "
            f"{t['load_average']}, {t['elapsed_s']:.0f} s); this run re-traced each scene's best "
            "setting and redid the bin and hash-grid sweeps.\n"
        )
    for name, s in result["scenes"].items():
        parts.append(
            f"## {name}\n\nwindow {s['window']} of 512×512, hash grid G = {s['hash_grid']}, "
            f"surface {s['surface'] or 'defaults'}; O17 target for dir-binning + hashed: "
            f"≥ {s['target_dirbin_hashed']:g}×\n"
        )
        parts.append(
            markdown_table(
                [
                    "N_FG",
                    "photons",
                    "stored",
                    "gathers/tile",
                    "nodes/gather",
                    *ORDERS,
                ],
                [
                    [
                        r["fg_rays"],
                        f"{r['photons'] // 1000}k",
                        f"{r['stored_photons']:,}",
                        fmt(r["gathers_per_tile"], 0),
                        fmt(r["visits_per_gather"], 0),
                        *[fmt(r["reduction_vs_uncached"][o], 2) + "×" for o in ORDERS],
                    ]
                    for r in s["settings"]
                ],
            )
        )
        b = s["best"]
        parts.append(
            f"\nDirection bins at N_FG {b['fg_rays']}, {b['photons'] // 1000}k photons "
            "(tiled Hilbert does not depend on them):\n"
        )
        parts.append(
            markdown_table(
                ["bins", *BINNED],
                [[k, *[fmt(r[o], 2) + "×" for o in BINNED]] for k, r in s["bins"].items()],
            )
        )
        parts.append(
            f"\nHash grid G at {s['best_bins']} bins (dir-binning + hashed): "
            + ", ".join(f"G {g}: {v:.2f}×" for g, v in s["grid"].items())
            + "\n"
        )
        parts.append(verdict(name, s) + "\n")
    parts.append("## what drives the ratio\n\n" + result["explanation"] + "\n")
    return "\n".join(parts)


EXPLANATION = """\
The uncached figure charges 20 B per visited node, the cache 128 B per line miss, so an order
beats it by `visits / (6.4 · misses)`: each fetched line must be read 6.4 × the reduction times
before it is evicted (≥ 26 reads per fetch for 4×, ≥ 64 for 10×). That reuse comes from the
gathers of one tile that land in the same part of the photon map while its lines are cached
(1,024 lines = 6,144 photons at 128 KB). Measured above:

1. **Photons per gather footprint** dominates: 5 × the photons (100 k → 500 k emitted; 0.2 M →
   1 M stored) cuts dir-binning + hashed from 4.8× to 1.2× (Cornell) and 5.7× to 1.4× (bushes),
   tiled Hilbert from 20× to 4.8×. With more photons each k = 100 gather covers a 5 × smaller
   area, so a tile's gathers share 5 × fewer photons, and the map has 5 × more lines.
2. **N_FG**: 32 → 100 rays raise dir-binning + hashed 3.2× → 4.8× (Cornell) and 3.3× → 5.7×
   (bushes); tiled Hilbert grows about linearly (7.4× → 20×, 8.6× → 24×), as it sorts all of a
   tile's gathers by position and more gathers per tile means more per cached region. The
   relevant quantity is gathers per tile per photon, N_FG · 256 / N_PM.
3. **Direction bins**: with 32 bins, direction-binning alone gains nothing (1.0–1.15×): a bin
   (1/32 of the sphere, ~0.4 sr) seen from the 256 pixels of a tile lands on a patch of the scene
   whose photons need more lines than the cache holds, and the bin is walked pixel by pixel, so
   the patch is streamed through the cache once per pixel. Narrower bins shrink the patch:
   dir-binning alone rises 0.6× → 1.1× → 3.3× → 7.2× at 8, 32, 128, 512 bins (Cornell) and
   0.6× → 1.0× → 4.3× → 13× (bushes); the hashed queues regroup a bin's requests by world cell
   and lift the small bin counts (Cornell 2.9× at 8 bins, 4.8× at 32, 6.8× at 128, 7.5× at 512;
   bushes 2.3×, 5.7×, 8.2×, 9.1×). At 512 bins a bin is ~0.025 sr and holds ~40 of a tile's
   gathers at N_FG = 100, and the queues add little or, on the bushes, cost (9.1× vs 13×).
4. **Hash grid G** (at the best bin count, 512): Cornell G = 2 / 5 / 8 / 16 → 7.4× / 7.5× /
   6.0× / 4.8×, bushes 13.5× / 10.1× / 9.1× / 9.0×: coarse cells keep a bin's already-coherent
   requests together; fine cells spread them over the 17 queues, whose collisions flush early.

The dissertation gives neither its photon count (A12) nor its bin count (A1); its 50 GB at
N_FG = 50 imply 50 GB / 20 B / (512² · 50) ≈ 190 node visits per gather against our 300–370
(a different traversal or map). With 100 k photons and N_FG = 100 our Cornell box reaches O17's
4× at the default 32 bins; the bushy box reaches its 10× only with 512 bins and G ≤ 5.
"""


def main(argv=None) -> dict:
    ap = report.arguments(__doc__, "tiny configuration (smoke test)")
    ap.add_argument(
        "--sweeps-only",
        action="store_true",
        help="keep the (N_FG, photons) table of the previous run's JSON; re-trace its best "
        "setting and redo the bin and hash-grid sweeps",
    )
    args = ap.parse_args(argv)
    start = time.perf_counter()
    load_start = os.getloadavg()
    stem = report.results_stem(args.out_dir, NAME, args.quick)
    previous = report.previous_results(stem.with_suffix(".json")) if args.sweeps_only else {}
    scenes = {}
    for name, (window, surface, grid) in SCENES.items():
        config = (window, FG_RAYS, PHOTONS, BINS, GRIDS)
        if args.quick:
            config = QUICK
        window, fg, photons, bins, grids = config
        if args.sweeps_only:
            s = previous["scenes"][name]
            best = trace(name, window, surface, s["best"]["photons"], s["best"]["fg_rays"])
            scenes[name] = {**s, **sweeps(best, OrderParams(grid=grid), bins, grids)}
        else:
            scenes[name] = study(name, window, surface, grid, fg, photons, bins, grids)
    result = {
        "name": NAME,
        "quick": args.quick,
        "machine": report.machine_info(),
        "load_average_start": load_start,
        "load_average": os.getloadavg(),
        "elapsed_s": time.perf_counter() - start,
        "cache": {"bytes": 128 * 1024, "line": 128, "tile": 16, "k": 100},
        "scenes": scenes,
        "verdict": {name: verdict(name, s) for name, s in scenes.items()},
        "explanation": EXPLANATION,
        "sweeps_only": args.sweeps_only,  # the (N_FG, photons) table is the previous run's
    }
    if args.sweeps_only:
        result["table_run"] = {
            k: previous.get(k) for k in ("elapsed_s", "load_average", "load_average_start")
        }
    text = markdown(result)
    return report.publish(stem, result, text)


if __name__ == "__main__":
    main()
