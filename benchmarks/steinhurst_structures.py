"""Steinhurst 2007, Table 4.1 and Fig 4.1, for ``steinhurst_tables.py --only structures``: the
same final gathers of the Cornell window on the kd-tree, the kdB-tree and block hashing
(:mod:`photonmap.analysis.structures`) — memory-block fetches per distinct block for every order
(Table 4.1's "average number of memory-block fetches", read as fetches per distinct block), bytes
against the line size for kd vs kdB (Fig 4.1) and block hashing's accuracy (oracle O21).
"""

from __future__ import annotations

import os
import time

import numpy as np

from photonmap.analysis.bandwidth import line_sweep
from photonmap.analysis.stream import cropped_scene, trace_final_gathers
from photonmap.analysis.structures import STRUCTURES, fetches_per_block, recall, structure_trace
from photonmap.surface.gather_batch import OrderParams
from report import fmt, markdown_table, records_table

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
CACHE, LINE = 128 * 1024, 128


def structure_facts(trace, traces: dict, exact, sample) -> dict:
    """Lines read per gather and the size of each structure; block hashing's recall."""
    kdb, _, kdb_reads = traces["kdbtree"].build(LINE)[:3]
    bh, found_bh, reads_bh = traces["blockhash"].build(LINE)[:3]
    return {
        "kdtree": {
            "reads_per_gather": trace.visits / len(trace.batch),
            "structure_lines": trace.footprint_lines(LINE),
        },
        "kdbtree": {
            "reads_per_gather": kdb_reads.mean(),
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


def structures_study(window, surface: dict, grid: int, quick: bool, lines) -> dict:
    """Table 4.1 and Fig 4.1 on the window ``(x, y, w, h)`` of the Cornell box's 512² image."""
    x, y, w, h = window
    scene = cropped_scene("cornell_steinhurst", 512, (x, y), (w, h))
    params = dict(surface, caustic_photons=0, emitter_spp=0, k=100)
    start = time.perf_counter()
    trace = trace_final_gathers(scene, **params)
    scale = 512 * 512 / (w * h)
    order_params = OrderParams(grid=grid)
    traces = {s: structure_trace(trace, s) for s in STRUCTURES}
    table = {
        o: {s: fetches_per_block(t, o, CACHE, LINE, order_params) for s, t in traces.items()}
        for o in STRUCTURE_ORDERS
    }
    sample = slice(None, None, 8)
    exact = traces["kdbtree"].build(LINE)[1][sample]
    line_sweep_gb = {
        s: {
            o: [v * scale / 1e9 for v in c]
            for o, c in line_sweep(traces[s], LINE_ORDERS, lines, params=order_params).items()
        }
        for s in ("kdtree", "kdbtree")
    }
    crossover = {
        o: next((line for line, kd, kdb in zip(lines, line_sweep_gb["kdtree"][o],
                 line_sweep_gb["kdbtree"][o], strict=True) if kdb < kd), None)
        for o in LINE_ORDERS
    }  # fmt: skip
    accuracy = {}
    for a in BH_ACCURACY[:1] if quick else BH_ACCURACY:
        t = structure_trace(trace, "blockhash", accuracy=a)
        found, reads = t.build(LINE)[1:3]
        accuracy[a] = {
            "recall": recall(found[sample], exact),
            "reads_per_gather": reads.mean(),
            **{o: fetches_per_block(t, o, CACHE, LINE, order_params) for o in LINE_ORDERS},
        }
    return {
        "window": window,
        "params": params,
        "gathers": len(trace.batch),
        "photons": trace.photons,
        "image_scale": scale,  # bytes of the window → bytes of a 512 × 512 image
        "table": table,
        "doc_table_4_1": DOC_TABLE_4_1,
        "structures": structure_facts(trace, traces, exact, sample),
        "lines": lines,
        "line_sweep_GB": line_sweep_gb,
        "kdb_beats_kd_from_line": crossover,
        "blockhash_accuracy": accuracy,
        "seconds": time.perf_counter() - start,
        "load_average": os.getloadavg(),
    }


SHORT = {"kdtree": "kd", "kdbtree": "kdB", "blockhash": "BH"}


def _table_4_1(s: dict) -> str:
    """Fetches per distinct block on each structure beside the dissertation's."""

    columns = [("order", "order", None)]
    columns += [(SHORT[x], lambda r, x=x: r[x]["fetches_per_block"], 2) for x in STRUCTURES]
    columns += [(f"doc {SHORT[x]}", lambda r, x=x: r["doc"][x], 1) for x in STRUCTURES]
    columns += [
        (
            "kdB/kd",
            lambda r: r["kdbtree"]["fetches_per_block"] / r["kdtree"]["fetches_per_block"],
            2,
        ),
        ("doc kdB/kd", lambda r: r["doc"]["kdbtree"] / r["doc"]["kdtree"], 2),
        ("kdB/kd bytes", lambda r: r["kdbtree"]["misses"] / max(r["kdtree"]["misses"], 1), 2),
    ]
    rows = [{**r, "order": o, "doc": s["doc_table_4_1"][o]} for o, r in s["table"].items()]
    return records_table(rows, columns)


def structures_markdown(s: dict) -> str:
    """Table 4.1 (measured beside the dissertation's) and the Fig 4.1 line sweep."""
    f, table = s["structures"], s["table"]
    gb = 128 * s["image_scale"] / 1e9  # GB per image of one miss
    misses = [[o, *[fmt(r[x]["misses"] * gb, 2) for x in STRUCTURES]] for o, r in table.items()]
    misses.append(
        ["distinct lines", *[fmt(table["naive"][x]["distinct_lines"]) for x in STRUCTURES]]
    )
    sweep = [[st, o, *[fmt(v, 2) for v in c]]
             for st, curves in s["line_sweep_GB"].items() for o, c in curves.items()]  # fmt: skip
    accuracy = [
        [a, fmt(r["recall"], 3), fmt(r["reads_per_gather"], 1),
         *[fmt(r[o]["fetches_per_block"], 2) for o in LINE_ORDERS],
         *[fmt(r[o]["misses"] * gb, 2) for o in LINE_ORDERS]]
        for a, r in s["blockhash_accuracy"].items()
    ]  # fmt: skip
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
        _table_4_1(s),
        "\nGB per 512 × 512 image (misses × 128 B) and distinct lines touched:\n",
        markdown_table(["order", *[f"{x} GB" for x in STRUCTURES]], misses),
        "\nGB/image vs line size (128 KB cache), kd-tree vs kdB-tree (Fig 4.1):\n",
        markdown_table(["structure", "order", *map(str, s["lines"])], sweep),
        "\nkdB-tree below the kd-tree from line size (bytes): "
        + ", ".join(f"{o} {v}" for o, v in s["kdb_beats_kd_from_line"].items())
        + " (dissertation: 256 B in naive order)\n",
        "Block hashing's accuracy A (blocks read per gather at most), 128 B lines:\n",
        markdown_table(
            [
                "A",
                "recall",
                "lines/gather",
                *[f"fetches/block {o}" for o in LINE_ORDERS],
                *[f"GB {o}" for o in LINE_ORDERS],
            ],
            accuracy,
        ),  # fmt: skip
    ]
    return "\n".join(parts) + "\n"
