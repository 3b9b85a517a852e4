"""The markdown report of ``volume_table1.py``: Sun et al. 2008 Table 1 beside ours, the
interactive headline and the profile of a light-change frame.
"""

from __future__ import annotations

import math

from report import fmt, markdown_table, records_table

STAGE_HEADERS = ("voxel.", "mater.", "grad.", "octree", "march grids", "gen.", "march", "smooth",
                 "view grids", "view")  # fmt: skip


def photon_label(count: int) -> str:
    side = math.isqrt(count)
    return f"{side}²" if side * side == count else f"{count:,}"


def table1_columns(stages) -> list:
    """The columns of the Table 1 rows (``row["label"]`` numbers the rows)."""
    return [
        ("#", "label", None),
        ("tris", lambda r: f"{r['triangles'] // 1000}k", None),
        ("extent", lambda r: f"{r['extent']}³", None),
        ("photons", lambda r: photon_label(r["photons"]), None),
        *[(h, lambda r, s=s: r["ours"]["stages_ms"].get(s), 1)
          for h, s in zip(STAGE_HEADERS, stages, strict=True)],
        ("**total**", lambda r: f"**{fmt(r['ours']['total_ms'])}**", None),
        ("tracing", lambda r: r["ours"]["paper_tracing_equivalent_ms"], 1),
        ("Msteps", lambda r: r["ours"]["msteps"], 2),
        ("propag.", lambda r: r["ours"]["photons_propagated"], 1),
        ("ns/step", lambda r: r["ours"]["ns_per_step"], 0),
        ("paper Msteps", lambda r: r["paper"]["msteps"], 2),
        ("paper voxel.", lambda r: r["paper"]["voxelization_ms"], 2),
        ("paper tracing", lambda r: r["paper"]["photon_tracing_ms"], 2),
        ("paper total", lambda r: r["paper"]["total_ms"], 2),
        ("paper ns/step", lambda r: r["paper"]["ns_per_step"], 1),
    ]  # fmt: skip


def table1(result: dict) -> str:
    """Our rows of Table 1 beside the paper's; a configuration measured for an earlier row is
    labelled ``n (= first)``."""
    from photonmap.volume.params import STAGES

    rows, seen = [], {}
    for row in result["rows"]:
        first = seen.setdefault(row["ours"]["measured_for_row"], row["row"])
        label = str(row["row"]) + ("" if first == row["row"] else f" (= {first})")
        rows.append({**row, "label": label})
    return records_table(rows, table1_columns(STAGES))


def headline(result: dict, targets: dict) -> list[str]:
    """The headline's frame times (with the secondary scene's) and its stage times."""
    h, s, sec = result["headline"], result["settings"], result.get("secondary")
    heads = ["frame", f"{h['scene']} (s)", *([f"{sec['scene']} (s)"] if sec else []),
             "target (s)", "met"]  # fmt: skip

    def cell(frames: dict) -> str:
        w = frames["wall_ms"]
        return f"{fmt(1e-3 * w['median'], 2)} ({fmt(1e-3 * w['min'], 2)}–{fmt(1e-3 * w['max'], 2)})"

    table = []
    for key, part, label in (
        ("full_frame_s", "light_change", "full frame (light change + view)"),
        ("view_only_s", "view_only", "view only (camera change)"),
    ):
        cells = [label, cell(h[part]), *([cell(sec["samples"][part])] if sec else [])]
        table.append(cells + [fmt(targets[key], 2), "yes" if h["meets_targets"][key] else "no"])
    stage_rows = [
        [stage, fmt(ms), fmt(h["view_only"]["stages_ms"].get(stage))]
        for stage, ms in h["light_change"]["stages_ms"].items()
    ]
    return [
        f"## Headline ({h['triangles'] // 1000}k triangles, extent {h['extent']}³, "
        f"{photon_label(h['photons'])} photons, {h['grid']}³, {h['width']}×{h['height']})",
        "",
        f"Medians of {s['light_runs']} light-change and {s['view_runs']} view-only frames "
        "(min–max in brackets), wall-clock of change + render.",
        "",
        markdown_table(heads, table),
        "",
        markdown_table(["stage (headline, ms)", "light change", "view only"], stage_rows),
        "",
    ]


PROFILE_COLUMNS = [
    ("stage", "stage", None),
    ("median ms", "ms", 1),
    ("share", lambda r: f"{100 * r['share']:.1f}%", None),
    ("kernels", lambda r: r["kernels"].get("launches"), 1),
    ("compiled", lambda r: r["kernels"].get("compiled"), 1),
    ("compile ms", lambda r: r["kernels"].get("compile_ms"), 1),
    ("top kernel ms", lambda r: r["top"].get("execution_time_ms"), 1),
    ("top kernel width", lambda r: r["top"].get("size"), 1),
    ("top kernel ops", lambda r: r["top"].get("operation_count"), 1),
]


def march_text(mp: dict) -> str:
    if "error" in mp:
        return f"Marching profile unavailable: {mp['error']}"
    text = (
        f"Photon marching alone ({mp['steps'] / 1e6:.2f} M steps): "
        f"{mp['with_deposits_s']:.2f} s with deposition "
        f"({mp['msteps_per_s_with_deposits']:.1f} M steps/s), "
        f"{mp['without_deposits_s']:.2f} s with the S7 rasteriser removed "
        f"({mp['msteps_per_s_without_deposits']:.1f} M steps/s): deposition is "
        f"{100 * mp['deposition_share']:.0f}% of the marching time."
    )
    if "deposits" in mp:
        text += (
            f" {mp['deposits'] / 1e6:.1f} M voxel deposits ({mp['deposits_per_step']:.2f} per "
            f"step, {mp['mdeposits_per_s']:.1f} M deposits/s)."
        )
    return text


def profile(prof: dict) -> list[str]:
    """Stage times and shares of the light-change frames with each stage's kernels."""
    kernels = prof["kernels"]["stages"]
    rows = [
        {"stage": stage, "ms": ms, "share": prof["light_change_stage_share"][stage],
         "kernels": kernels.get(stage, {}), "top": kernels.get(stage, {}).get("top_kernel") or {}}
        for stage, ms in prof["light_change_stage_ms"].items()
    ]  # fmt: skip
    return [
        "## What bounds the light-change frame",
        "",
        "Median stage times of the light-change frames; kernel columns from one more "
        "light-change frame with the kernel history per stage (a light position not used "
        "before).",
        "",
        records_table(rows, PROFILE_COLUMNS),
        "",
        march_text(prof["march"]),
        "",
    ]


def markdown(result: dict, targets: dict) -> str:
    """The markdown report: Table 1 beside the paper, the headline and the profile."""
    s, m, h = result["settings"], result["machine"], result["headline"]
    lines = [
        f"# Volume pipeline vs Sun et al. 2008 Table 1 ({s['scene']}, {s['grid']}³, "
        f"{s['width']}×{s['height']})",
        "",
        f"{m['cpu_model']}, {m['cores']} cores, Mitsuba {m['mitsuba']}, Dr.Jit {m['drjit']} "
        f"({m.get('mitsuba_variant')}), {m['date']}, load average at start "
        f"{m.get('load_average')}. Medians of {s['runs']} full renders (every stage runs) after "
        f"warm-up renders. Paper: NVIDIA GeForce 8800 Ultra.",
        "",
        "Stage times in ms. *tracing* = our photon generation + march (the paper's 'photon "
        "tracing'); ns/step = tracing / steps, as for the paper. The paper's total also holds "
        "gradient, octree, irradiance merging and the viewing pass; ours is the sum of all "
        "stages. Rows 2, 8 and 11 are one configuration, measured once.",
        "",
        table1(result),
        "",
        *headline(result, targets),
        *(profile(result["profile"]) if result.get("profile") else []),
    ]
    compiled = h["light_change"]["compiled_during_timed_runs"]
    if compiled["kernels"]:
        lines += [
            f"Each light move compiled Dr.Jit kernels: {compiled['kernels']} in "
            f"{s['light_runs']} timed frames, {compiled['ms']:.0f} ms of LLVM compilation in "
            "total, included in the frame times.",
            "",
        ]
    stats = h["stats"]
    if stats.get("photons_propagated"):
        lines += [
            f"Headline photons: {int(stats['photons_generated']):,} generated, "
            f"{int(stats['photons_propagated']):,} propagated, "
            f"{stats['steps'] / 1e6:.2f} M steps "
            f"({stats['steps'] / stats['photons_propagated']:.1f} per propagated photon; "
            "Sun Table 2: 46–75 steps per photon, 3–18% of 1024² photons propagated).",
            "",
        ]
    lines.append(
        f"Benchmark wall time {result['elapsed_s']:.0f} s; load average at the end "
        f"{result.get('load_average_end')}."
    )
    return "\n".join(lines)
