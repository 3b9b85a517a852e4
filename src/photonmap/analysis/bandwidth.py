"""Photon-map bandwidth per gather order, cache size, line size and tile size (Steinhurst 2007
Table 3.1, Figs 3.5, 3.9, 4.1; spec seed-001 §2.6, §3.3, oracles O16–O21).

Every figure is bytes moved from memory for the final gathers of one render: line misses of the
simulated cache (:mod:`.cache`) × line size, beside the dissertation's uncached naive figure of 20
bytes per visited kd-tree node (§3.5). Reductions are reported against that uncached figure, as the
dissertation does (spec A6), and against the cached naive order.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..surface.gather_batch import ORDERS, OrderParams
from .cache import merge_repeats, misses, set_associative_misses, stack_distances
from .stream import GatherTrace

FLOOR_BYTES = 8 * 1024  # smallest cache any sweep reports: distances below are left as bounds
WAYS = 8  # the set-associative option (spec §2.6: 8-way ≈ +39 % fetches)


def _curve(trace, order, line_bytes, capacities_bytes, params) -> np.ndarray:
    """Misses of a fully associative LRU cache of each capacity (bytes) for ``order``."""
    stream = merge_repeats(trace.lines(order, line_bytes, params))
    floor = max(1, min(FLOOR_BYTES, min(capacities_bytes)) // line_bytes)
    return misses(stack_distances(stream, floor), np.asarray(capacities_bytes) // line_bytes)


def bandwidth_table(
    trace: GatherTrace,
    orders=ORDERS,
    cache_bytes: int = 128 * 1024,
    line_bytes: int = 128,
    params: OrderParams | None = None,
    ways: int | None = None,
) -> list[dict]:
    """One row per order: line misses, bytes, reduction vs the uncached naive figure and vs the
    cached naive order; with ``ways``, also the misses of a ``ways``-way set-associative cache of
    the same size and their ratio to the fully associative misses (O20)."""
    rows = []
    uncached = trace.uncached_bytes()
    for order in orders:
        missed = int(_curve(trace, order, line_bytes, [cache_bytes], params)[0])
        row = {
            "order": order,
            "misses": missed,
            "bytes": missed * line_bytes,
            "reduction_vs_uncached": uncached / max(missed * line_bytes, 1),
        }
        if ways:
            stream = merge_repeats(trace.lines(order, line_bytes, params))
            sets = max(1, cache_bytes // line_bytes // ways)
            row["misses_set_associative"] = set_associative_misses(stream, sets, ways)
            row["set_associative_ratio"] = row["misses_set_associative"] / max(missed, 1)
        rows.append(row)
    naive = next((r["bytes"] for r in rows if r["order"] == "naive"), None)
    for row in rows:
        if naive:
            row["fraction_of_cached_naive"] = row["bytes"] / naive
    return rows


def cache_sweep(trace, orders, sizes_bytes, line_bytes=128, params=None) -> dict:
    """Bytes per image for each cache size (Fig 3.9): one stack-distance pass per order."""
    return {
        o: (_curve(trace, o, line_bytes, sizes_bytes, params) * line_bytes).tolist() for o in orders
    }


def line_sweep(trace, orders, lines_bytes, cache_bytes=128 * 1024, params=None) -> dict:
    """Bytes per image for each line size at a fixed cache size (Fig 4.1, kd-tree)."""
    return {
        o: [int(_curve(trace, o, line, [cache_bytes], params)[0]) * line for line in lines_bytes]
        for o in orders
    }


def tile_sweep(trace, orders, tiles, cache_bytes=128 * 1024, line_bytes=128, params=None) -> dict:
    """Bytes per image for each tile edge (Fig 3.5)."""
    params = params or OrderParams()
    return {
        o: [
            int(_curve(trace, o, line_bytes, [cache_bytes], replace(params, tile=t))[0])
            * line_bytes
            for t in tiles
        ]
        for o in orders
    }


def plot_sweep(curves: dict, xs, xlabel: str, path: str, title: str, uncached=None) -> None:
    """Bytes per image against ``xs`` on log-log axes, one line per order (PNG at ``path``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for order, ys in curves.items():
        ax.plot(xs, np.asarray(ys) / 1e6, marker="o", label=order)
    if uncached:
        ax.axhline(uncached / 1e6, color="k", linestyle="--", label="uncached naive (20 B/node)")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("photon-map traffic per image (MB)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


SWEEPS = {
    "cache": ("cache size (KB)", [8, 16, 32, 64, 128, 256, 512, 1024]),
    "line": ("cache line (bytes)", [64, 128, 256, 512, 1024]),
    "tile": ("tile edge (pixels)", [4, 8, 16, 32, 64]),
}
SWEEP_ORDERS = ("naive", "tiled", "tiled_dirbin", "tiled_dirbin_hashed", "tiled_hilbert")


def sweep(trace, kind: str, orders, cache_bytes, line_bytes, params=None) -> tuple[list, dict]:
    """``(xs, curves)`` of the sweep ``kind`` (:data:`SWEEPS`) over ``orders``."""
    _, xs = SWEEPS[kind]
    if kind == "cache":
        return xs, cache_sweep(trace, orders, [x * 1024 for x in xs], line_bytes, params)
    if kind == "line":
        return xs, line_sweep(trace, orders, xs, cache_bytes, params)
    return xs, tile_sweep(trace, orders, xs, cache_bytes, line_bytes, params)
