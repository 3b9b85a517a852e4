"""Photon-map bandwidth per gather order, cache size, line size and tile size (Steinhurst 2007
Table 3.1, Figs 3.5, 3.9, 4.1).

Every figure is bytes moved from memory for the final gathers of one render: line misses of the
simulated cache (:mod:`.cache`) × line size, beside the dissertation's uncached naive figure of 20
bytes per visited kd-tree node (§3.5). Reductions are reported against that uncached figure, as the
dissertation does (its naive figures are uncached reads), and against the cached naive order.
"""

from __future__ import annotations

import io
import os
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import replace

import numpy as np

from ..core import interrupt
from ..core.image import write_bytes
from ..surface.gather_batch import ORDERS, OrderParams
from .cache import simulate_lines
from .stream import CacheCounts

WAYS = 8  # the set-associative option (Steinhurst 2007 §3.2: 8-way ≈ +39 % fetches)


def counts(trace, order, lines_bytes, capacities_bytes, ways=0, params=None) -> CacheCounts:
    """Misses of ``order`` for every line size and capacity: streamed by the trace itself
    (:meth:`.stream.GatherTrace.simulate`) or, for a trace that only gives its line stream
    (``trace.lines(order, line_bytes, params)``, e.g. another data structure), the same caches fed
    with that stream."""
    if hasattr(trace, "simulate"):
        return trace.simulate(order, lines_bytes, capacities_bytes, ways, params)
    rows, sa, compulsory, reads = [], [], [], 0
    caps = np.asarray(capacities_bytes, np.int64)
    for line in lines_bytes:
        stream = np.asarray(trace.lines(order, line, params), np.int64)
        reads = reads or len(stream)
        capacity = np.maximum(caps // line, 1)
        distinct = np.unique(capacity)
        sets = max(1, int(capacity[0]) // ways) if ways else 0
        m, s, c = simulate_lines(stream, np.diff(distinct, prepend=0), sets, max(ways, 1))
        rows.append(m[np.searchsorted(distinct, capacity)])
        sa.append(s)
        compulsory.append(c)
    return CacheCounts(np.array(rows), np.array(sa) if ways else None, np.array(compulsory), reads)


def _checked(fn, x):
    interrupt.check()  # Ctrl-C: between items
    return fn(x)


def _each(trace, fn, items, line_bytes=None) -> list:
    """``fn`` over ``items``; for a streaming trace on one thread per core (the compiled
    simulation releases the GIL and each order's caches are independent), after walking the
    gathers once and keeping their reads at ``line_bytes`` if they fit in memory."""
    if not hasattr(trace, "simulate") or len(items) < 2:
        return [_checked(fn, x) for x in items]
    if line_bytes is not None:
        trace.store_reads(line_bytes)
    with ThreadPoolExecutor(max(1, min(len(items), os.cpu_count() or 1))) as pool:
        futures = [pool.submit(fn, x) for x in items]
        try:  # Ctrl-C: the orders running finish, the others do not start
            while wait(futures, timeout=0.25).not_done:
                interrupt.check()
        except interrupt.Interrupted:
            for f in futures:
                f.cancel()
            raise
        return [f.result() for f in futures]


def bandwidth_table(
    trace,
    orders=ORDERS,
    cache_bytes: int = 128 * 1024,
    line_bytes: int = 128,
    params: OrderParams | None = None,
    ways: int | None = None,
) -> list[dict]:
    """One row per order: line misses, bytes, reduction vs the uncached naive figure and vs the
    cached naive order; with ``ways``, also the misses of a ``ways``-way set-associative cache of
    the same size and their ratio to the fully associative misses."""
    orders = list(orders)
    results = _each(
        trace,
        lambda o: counts(trace, o, [line_bytes], [cache_bytes], ways or 0, params),
        orders,
        line_bytes,
    )
    uncached = trace.uncached_bytes()
    rows = []
    for order, c in zip(orders, results, strict=True):
        missed = int(c.misses[0, 0])
        row = {
            "order": order,
            "misses": missed,
            "bytes": missed * line_bytes,
            "reduction_vs_uncached": uncached / max(missed * line_bytes, 1),
            "compulsory": int(c.compulsory[0]),
        }
        if ways:
            row["misses_set_associative"] = int(c.set_associative[0])
            row["set_associative_ratio"] = row["misses_set_associative"] / max(missed, 1)
        rows.append(row)
    naive = next((r["bytes"] for r in rows if r["order"] == "naive"), None)
    for row in rows:
        if naive:
            row["fraction_of_cached_naive"] = row["bytes"] / naive
    return rows


def cache_sweep(trace, orders, sizes_bytes, line_bytes=128, params=None) -> dict:
    """Bytes per image for each cache size (Fig 3.9): one pass per order gives every size."""
    orders = list(orders)
    results = _each(
        trace, lambda o: counts(trace, o, [line_bytes], sizes_bytes, 0, params), orders, line_bytes
    )
    return {o: (c.misses[0] * line_bytes).tolist() for o, c in zip(orders, results, strict=True)}


def line_sweep(trace, orders, lines_bytes, cache_bytes=128 * 1024, params=None) -> dict:
    """Bytes per image for each line size at a fixed cache size (Fig 4.1, kd-tree): one pass per
    order feeds every line size."""
    orders = list(orders)
    results = _each(
        trace, lambda o: counts(trace, o, lines_bytes, [cache_bytes], 0, params), orders
    )
    return {
        o: [int(x) * line for x, line in zip(c.misses[:, 0], lines_bytes, strict=True)]
        for o, c in zip(orders, results, strict=True)
    }


def tile_sweep(trace, orders, tiles, cache_bytes=128 * 1024, line_bytes=128, params=None) -> dict:
    """Bytes per image for each tile edge (Fig 3.5)."""
    params = params or OrderParams()

    def bytes_at(order, tile):
        c = counts(trace, order, [line_bytes], [cache_bytes], 0, replace(params, tile=tile))
        return int(c.misses[0, 0]) * line_bytes

    pairs = [(o, t) for o in orders for t in tiles]
    values = iter(_each(trace, lambda pair: bytes_at(*pair), pairs, line_bytes))
    return {o: [next(values) for _ in tiles] for o in orders}


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
    data = io.BytesIO()
    fig.savefig(data, format="png", dpi=110)
    plt.close(fig)
    write_bytes(path, data.getvalue())  # atomic: a failed write keeps the previous file


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
