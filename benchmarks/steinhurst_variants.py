"""Two variants of Steinhurst 2007's bandwidth setting, for ``steinhurst_tables.py``: the glossy
floor whose lobe narrows (Fig 6.17, oracle O26: the naive order's traffic falls, the coherent
orders' stays about constant) and the bushy box at the dissertation's Sponza setting (N_FG = 200,
§2.6.2.1, Fig 1.3; oracle O17's ≥ 10× for tiled direction-binning + hashed).
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor

from photonmap.analysis.bandwidth import WAYS, cache_sweep
from photonmap.analysis.stream import cropped_scene, trace_final_gathers
from photonmap.surface.gather_batch import OrderParams
from report import fmt, markdown_table, records_table

MANY_BINS = 128  # the direction-binned orders again with 128 bins (A1's sweep: the best here)
SPONZA = dict(photons=100_000, fg_rays=200, radius=0.02)  # bushes at Sponza's N_FG (§2.6.2.1)
# Fig 6.17 / O26: the glossy floor's lobe narrowed (Beckmann α; Phong n ≈ 2/α² − 2), window on it
GLOSSY = ((224, 432, 64, 32), dict(photons=100_000, fg_rays=32), (0.3, 0.1, 0.03), 0.8)
GLOSSY_ORDERS = ("naive", "tiled_dirbin_hashed", "tiled_hilbert")


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
    rows = [{**r, "order": o} for o, r in s["table"].items()]
    return (
        "## Bushy box at the Sponza setting (O17)\n\n"
        f"cornell_bushes, the whole {s['image']}² image, N_FG {s['params']['fg_rays']}, "
        f"{s['bins']} direction bins, G = {s['hash_grid']}: {s['gathers']:,} final gathers, "
        f"{s['node_visits']:,} node reads (uncached naive {s['uncached_GB_per_image']:.0f} "
        f"GB/image), streamed in {s['simulate_s']:.0f} s, load {s['load_average']}\n\n"
        + records_table(
            rows,
            [
                ("order", "order", None),
                ("GB/image", "GB_per_image", 2),
                ("vs uncached", lambda r: fmt(r["reduction_vs_uncached"], 1) + "×", None),
                ("8-way/full", "set_associative_ratio", 2),
            ],
        )
        + "\n"
    )


def glossy_sweep(quick: bool, quick_config) -> dict:
    """GB per image of three orders as the floor's glossy lobe narrows (Fig 6.17, O26: naive
    order falls, the coherent orders stay about constant); ``quick_config`` is the quick run's
    ``(window, surface, grid)``."""
    window, surface, roughness, weight = GLOSSY
    if quick:
        window, surface, _ = quick_config
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


def glossy_markdown(glossy: dict) -> str:
    return (
        f"## glossy floor (Fig 6.17, O26)\n\nwindow {glossy['window']}, glossy weight "
        f"{glossy['glossy_weight']}, GB/image at 128 KB against the Beckmann roughness:\n\n"
        + markdown_table(
            ["order", *[f"α {a}" for a in glossy["roughness"]]],
            [[o, *[fmt(v, 2) for v in c]] for o, c in glossy["GB"].items()],
        )
        + "\n"
    )
