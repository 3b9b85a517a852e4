"""The markdown of ``steinhurst_tables.py``: Steinhurst 2007's Table 3.1, Figs 3.5, 3.9 and 4.1
and the Ch. 7 chip model per scene beside the dissertation's numbers, then the glossy floor
(Fig 6.17), the data structures (Table 4.1) and the Sponza setting, and the headline.
"""

from __future__ import annotations

import report
from photonmap.surface.gather_batch import ORDERS
from report import fmt, markdown_table, records_table
from steinhurst_structures import structures_markdown
from steinhurst_variants import glossy_markdown, sponza_markdown


def _sweep_table(label: str, points, curves: dict) -> str:
    """``order`` × ``points`` of GB per image."""
    return markdown_table(
        [label, *points], [[o, *[fmt(v, 2) for v in c]] for o, c in curves.items()]
    )


def scene_markdown(name: str, s: dict, doc: dict, cache_kb) -> str:
    """Table 3.1 of one scene beside the dissertation's (``doc``), its sweeps (``cache_kb``: the
    cache sizes of its cache sweep) and the chip model."""
    rows = [{**r, "order": o, "doc": doc.get(o)} for o, r in s["table"].items()]
    columns = [
        ("order", "order", None),
        ("GB/image", "GB_per_image", 2),
        ("vs uncached", lambda r: fmt(r["reduction_vs_uncached"], 1) + "×", None),
        ("doc GB", lambda r: fmt(r["doc"], 3) if r["doc"] else "—", None),
        ("doc vs uncached", lambda r: fmt(doc["uncached"] / r["doc"], 1) + "×" if r["doc"] else
         "—", None),
        ("fetches/line", "fetches_per_map_line", 2),
        ("8-way/full", "set_associative_ratio", 2),
        *[(f"CPU ms {k}", lambda r, k=key: fmt(s["cpu"][k][r["order"]]["median"], 0)
           if r["order"] in ORDERS else "—", None) for k, key in (("kd", "kdtree"), ("hash", "hash"))],
    ]  # fmt: skip
    hardware = [{**h, "order": o} for o, h in s["hardware"].items()]
    parts = [
        f"## {name}\n\nthe whole {s['image']}×{s['image']} image, {s['gathers']:,} final "
        f"gathers (N_FG {s['params']['fg_rays']}, k 100, {s['params']['photons']:,} photon "
        f"paths), {s['node_visits']:,} kd-tree node reads ({s['visits_per_gather']:.0f} per "
        f"gather; walked once in {s['store_s']:.0f} s, then {s['simulate_s']:.0f} s for the "
        f"{len(s['table'])} orders on two cores), {s['photons']:,} photons "
        f"({s['map_lines_128B']:,} lines of 128 B); "
        f"uncached naive {s['uncached_GB_per_image']:.1f} GB/image (dissertation "
        f"{doc['uncached']:g} GB{'' if name == 'cornell_steinhurst' else ', Sponza'}); "
        f"load average {s.get('load_average', 'not recorded')}\n",
        records_table(rows, columns),
        "\nGB/image vs cache size (KB " + ", ".join(map(str, cache_kb)) + "):\n",
        _sweep_table("order", [f"{kb}K" for kb in cache_kb], s["cache_sweep_GB"]),
    ]
    if "window_sweeps" in s:
        ws = s["window_sweeps"]
        parts += [
            f"\nGB/image vs tile edge (window {ws['window']} of the 512² image, scaled):\n",
            _sweep_table("order", map(str, ws["tiles"]), ws["tile_sweep_GB"]),
            "\nGB/image vs line size (128 KB, same window):\n",
            _sweep_table("order", map(str, ws["lines"]), ws["line_sweep_GB"]),
        ]
    parts += [
        "\nChip model (Ch. 7) fed with these counts, R_IC = 0:\n",
        records_table(
            hardware,
            [
                ("order", "order", None),
                ("GB/image", "GB_per_image", 2),
                ("GFLOPs/image", "GFLOPs_per_image", 1),
                ("tiles/s (90 GB/s)", "tiles_per_s_memory", 0),
                ("tiles/s (500 GFLOPS)", "tiles_per_s_compute", 0),
            ],
        ),  # fmt: skip
        "",
    ]
    return "\n".join(parts)


def markdown(result: dict, cache_kb) -> str:
    """Every part of the results that was run, and the headline."""
    doc = result["doc_table_3_1_GB"]
    parts = ["# Steinhurst 2007 tables reproduced\n"]
    parts += [scene_markdown(n, s, doc[n], cache_kb) for n, s in result["scenes"].items()]
    if result.get("glossy"):
        parts.append(glossy_markdown(result["glossy"]))
    if result.get("structures"):
        parts.append(structures_markdown(result["structures"]))
    if result.get("sponza_setting"):
        parts.append(sponza_markdown(result["sponza_setting"]))
    parts.append("## headline\n")
    parts.append(report.bullets(result["headline"]))
    return "\n".join(parts) + "\n"
