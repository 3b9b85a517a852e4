"""The markdown report, the explanation and the plot of ``adaptive_vs_reference.py``: Pfeuti 2009's
adaptive pipeline against the reference pipeline at equal RMSE, per pass in the layout of his
Tables 4.2–4.4.
"""

from __future__ import annotations

from pathlib import Path

import report
from adaptive_sweep import LABELS, PASSES, VARIANTS
from report import fmt, records_table

ABLATION_COLUMNS = ("uniform", "adaptive", "adaptive_uniform_placement", "placement_only")
EQUAL = (("equal_rmse", "adaptive"), ("equal_rmse_uniform_placement", "uniform placement"))


def _met(r: dict) -> str:
    eq, targets = r["eq"], r["targets"]
    met = eq and eq["photon_ratio"] <= targets["photon_ratio"] and eq["time_ratio"] < 1
    return "yes" if met else "no"


HEADLINE_COLUMNS = [
    ("scene", "scene", None),
    ("variant", "variant", None),
    ("ref photons", lambda r: r["reference"]["propagated"], 1),
    ("ref RMSE", lambda r: r["reference"]["rmse"], 5),
    ("target RMSE", "target_rmse", 5),
    ("adaptive photons", lambda r: fmt(r["eq"].get("propagated")) if r["eq"] else "not reached",
     None),
    ("adaptive RMSE", lambda r: fmt(r["eq"].get("rmse"), 5) if r["eq"] else "–", None),
    ("photon ratio", lambda r: r["eq"].get("photon_ratio"), 2),
    ("time ratio", lambda r: r["eq"].get("time_ratio"), 2),
    ("photon-stage time ratio", lambda r: r["eq"].get("photon_stage_time_ratio"), 2),
    ("time ratio (min of runs)", lambda r: r["eq"].get("time_ratio_min"), 2),
    ("targets met", _met, None),
]  # fmt: skip
SWEEP_COLUMNS = [
    ("pipeline", lambda r: LABELS[r["variant"]], None),
    ("budget", "budget", 1),
    ("entered", "propagated", 1),
    ("RMSE", "rmse", 5),
    ("frame ms", "wall_ms", 1),
    ("photon stages ms", "photon_stages_ms", 1),
    ("steps/photon", lambda r: r["steps"] / max(r["propagated"], 1), 1),
]
BY_NOMINAL_COLUMNS = [
    ("scene", "scene", None),
    ("variant", "variant", None),
    ("reference budget", "reference_budget", 1),
    ("adaptive budget", lambda r: fmt(r["adaptive_budget"], 0) if r["adaptive_budget"] else
     "not reached", None),
    ("photon ratio", lambda r: r.get("photon_ratio"), 2),
    ("time ratio", lambda r: r.get("time_ratio"), 2),
    ("photon-stage time ratio", lambda r: r.get("photon_stage_time_ratio"), 2),
]  # fmt: skip
ABLATION_HEADERS = ("reference", "adaptive", "filter only (uniform placement)",
                    "placement only (level 0)")  # fmt: skip


def passes_table(sc: dict) -> str:
    """Milliseconds per pass of the reference and the two variants at equal RMSE."""
    geo = sc["geometry_ms"]
    runs = [sc["reference"], sc.get("equal_rmse"), sc.get("equal_rmse_uniform_placement")]
    table = []
    for row, names in PASSES:
        cells = [row]
        for run in runs:
            used = run is not None and any(n in run["stages_ms"] or n in geo for n in names)
            ms = sum(geo.get(n, run["stages_ms"].get(n, 0.0)) for n in names) if used else 0
            cells.append(fmt(ms) if used else "-")
        table.append(cells)
    summary = (
        ("**Total**", lambda r: f"**{fmt(sum(geo.values()) + sum(r['stages_ms'].values()))}**"),
        ("Photon Count (entered the grid)", lambda r: fmt(r["propagated"])),
        ("Marching steps", lambda r: fmt(r["steps"])),
        ("RMSE vs ground truth", lambda r: fmt(r["rmse"], 5)),
    )
    for name, value in summary:
        table.append([name, *(value(run) if run else "–" for run in runs)])
    header = ["Pass", "Reference", "Adaptive", "Adaptive, uniform placement"]
    return report.markdown_table(header, table)


def markdown(result: dict, truth_factor: int) -> str:
    s, m, scenes = result["settings"], result["machine"], result["scenes"]
    lines = [
        f"# Adaptive vs reference pipeline at equal RMSE ({s['grid']}³, {s['width']}×{s['height']})",
        "",
        f"{m['cpu_model']}, {m['cores']} cores, Mitsuba {m['mitsuba']}, Dr.Jit {m['drjit']}, "
        f"{m['date']}, load average at start {m.get('load_average')} (the machine was shared). "
        f"Ground truth: reference pipeline at {truth_factor}× {s['nominal']:,} photons. Times: "
        f"median of {s['runs']} light-change frames in the sweep, of {s.get('final_runs')} at equal "
        "RMSE (all light-dependent stages run, configurations interleaved run by run) after a "
        "warm-up frame. Target RMSE = 1.1 × the reference's at the nominal budget. Adaptive "
        f"settings: {s.get('adaptive', {})}; load average at the end "
        f"{result.get('load_average_end')}.",
        "",
        "## Headline",
        "",
        records_table(
            [
                {
                    **sc,
                    "scene": label,
                    "variant": name,
                    "eq": sc.get(key) or {},
                    "targets": s["targets"],
                }
                for label, sc in scenes.items()
                for key, name in EQUAL
            ],
            HEADLINE_COLUMNS,
        ),  # fmt: skip
        "",
        "Targets: photon ratio ≤ 0.5 (Pfeuti: 0.37–0.46) and time ratio < 1 (Pfeuti: 1.01–1.04).",
        "",
    ]
    for label, sc in scenes.items():
        sweep = [{**r, "variant": v} for v in VARIANTS for r in sc["sweep"][v]]
        lines += [
            f"## {label} ({sc['scene']}): passes in ms (layout of Pfeuti Tables 4.2–4.4)",
            "",
            passes_table(sc),
            "",
            records_table(sweep, SWEEP_COLUMNS),
            "",
        ]
    by_nominal = [
        {**r, "scene": label, "variant": name}
        for label, sc in scenes.items()
        for key, name in (
            ("by_nominal", "adaptive"),
            ("by_nominal_uniform_placement", "uniform p."),
        )
        for r in sc.get(key, [])
    ]
    ablation = [
        [label, fmt(r["budget"]), *(fmt(r[k], 5) for k in ABLATION_COLUMNS)]
        for label, sc in scenes.items()
        for r in sc.get("ablation", [])
    ]
    lines += [
        "## Equal RMSE at every reference budget (interpolated on the sweep)",
        "",
        records_table(by_nominal, BY_NOMINAL_COLUMNS),
        "",
        "## Where the gain comes from (RMSE at equal photon budgets)",
        "",
        report.markdown_table(["scene", "budget", *ABLATION_HEADERS], ablation),
        "",
    ]
    if result.get("analysis"):
        lines += ["## Why", "", result["analysis"], ""]
    lines.append(f"Benchmark wall time {result['elapsed_s']:.0f} s.")
    return "\n".join(lines)


def analysis(result: dict) -> str:
    """A paragraph per scene and variant saying where the time goes, with numbers."""
    extra_passes = ("Pilot Photon Generation", "Pilot Photon Marching", "Photon Distribution",
                    "Photon Generation")  # fmt: skip
    parts = []
    for label, sc in result["scenes"].items():
        ref, fit = sc["reference"], sc["marching_fit"]
        parts.append(
            f"**{label}**: marching costs {fit['fixed_ms']:.0f} ms + "
            f"{fit['ms_per_million_steps']:.0f} ms per million steps (fit over the reference "
            f"sweep); the reference takes {ref['steps'] / ref['propagated']:.1f} steps per photon."
        )
        for key, name in EQUAL:
            eq = sc.get(key)
            if not eq:
                parts.append(f"{name}: the target RMSE is not reached within the sweep.")
                continue
            a, r = eq["passes_ms"], ref["passes_ms"]
            extra = (
                sum(a[k] for k in extra_passes)
                - r["Photon Generation"]
                + a["Filtering"]
                + a["Mipmap Generation (incl. S8)"]
                - r["Smoothing (S8)"]
            )
            saved = fit["ms_per_million_steps"] * (ref["steps"] - eq["steps"]) / 1e6
            parts.append(
                f"{name}: {eq['photon_ratio']:.2f}× the photons at "
                f"{eq['steps_per_photon']:.1f} steps each ({eq['steps_ratio']:.2f}× the steps): "
                f"marching saves ≈ {saved:.0f} ms (measured {r['Photon Marching']:.0f} → "
                f"{a['Photon Marching']:.0f} ms), the extra passes (pilots, pdf, importance "
                f"sampling, mipmaps + filter minus S8) cost {extra:.0f} ms; frame "
                f"{eq['wall_ms']:.0f} vs {ref['wall_ms']:.0f} ms."
            )
    return " ".join(parts)


def plot(result: dict, path: Path) -> None:
    """RMSE against light-change frame time of the three sweeps, per scene."""
    scenes = result["scenes"]
    with report.figure(path, 1, len(scenes), size=(5 * len(scenes), 4), dpi=100) as axes:
        for ax, (label, sc) in zip(axes[0], scenes.items(), strict=True):
            curves = {LABELS[v]: sc["sweep"][v] for v in VARIANTS}
            report.loglog_curves(ax, curves, "wall_ms", "rmse", ("o-", "s-", "^-"))
            ax.axhline(sc["target_rmse"], color="grey", ls=":", label="1.1 × reference RMSE")
            for key, marker in (("equal_rmse", "k*"), ("equal_rmse_uniform_placement", "kP")):
                if sc.get(key):
                    e = sc[key]
                    ax.plot([e["wall_ms"]], [e["rmse"]], marker, ms=11, label=key.replace("_", " "))
            ax.set_title(f"{label} ({sc['scene']})")
            ax.set(xlabel="light-change frame (ms)", ylabel="image RMSE vs ground truth")
            ax.legend(fontsize=8)
