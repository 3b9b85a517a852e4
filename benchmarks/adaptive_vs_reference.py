"""Benchmark: Pfeuti's adaptive pipeline against the reference pipeline at equal RMSE (issue 5).

Spec seed-000-002 §5.7 oracle 33 and §3.2 (Pfeuti Tables 4.2–4.4). Scenes SPHERE, CUBE, MESH
(``glass_sphere_fog``, ``perlin_cube``, ``mesh_in_fog``) at a 128³ grid.

* **Ground truth**: the reference pipeline with 16× the nominal photon count ``N_R`` (512² =
  262144, Pfeuti's reference, §4.3), marched in 16 batches of ``N_R`` consecutive points of one
  Halton sequence (memory), the C and D sums averaged, then smoothed and viewed as usual.
* **Sweep**: for each photon budget, both pipelines render light-change frames — every stage that
  depends on the light runs (reference S5–S9, adaptive A1–A7 + S9; the geometry stages are the
  same for both and cached) — after one warm-up frame; wall time = median of ``runs`` frames
  (``final_runs`` at equal RMSE);
  RMSE of the linear-radiance image against the ground truth. Photon counts are the photons that
  entered the grid (pilots included), as in Pfeuti's tables.
* **Variants**: ``adaptive`` is the pipeline's default (photons placed by the pilot pdf, Pfeuti
  A4); ``adaptive_uniform_placement`` places the reference's photons and lets the pilot pdf steer
  only the reconstruction filter (``placement="uniform"``).
* **Equal RMSE**: the target is ``1.1 × RMSE(reference at N_R)``; each adaptive variant's budget
  reaching it is interpolated log–log on the sweep (refined by a geometric bisection if the
  interpolated budget falls short, :func:`smallest_budget`), then rendered and timed at that
  budget, interleaved with the reference at ``N_R``, to report the per-pass times in the layout
  of Pfeuti Tables 4.2–4.4. ``headline[scene]`` = photon and time ratios of the default variant
  against the reference at ``N_R`` (``headline[scene]["uniform_placement"]``: the other
  variant's); the targets are ≤ 0.5 and < 1. ``by_nominal`` repeats the comparison for every
  reference budget of the sweep, interpolated log–log on the sweep alone (no extra run; the
  ground truth stays 16 × N_R).
* **Ablation** at ``N_R/2`` and ``N_R``: the RMSE of the filter alone (uniform placement) and of
  the placement alone (importance photons, every voxel at level 0), beside the full pipeline's.
* **Marching cost**: the photon-tracing stage of the reference sweep is fitted as ``F + v·steps``
  — ``F`` (the accumulator's allocation, reduction and conversion) does not shrink with fewer
  photons, which bounds what a smaller budget can save.

Writes ``benchmarks/results/adaptive_vs_reference.{json,md,png}`` (``--quick``: ``*_quick.*``)
and prints the markdown. ``python benchmarks/adaptive_vs_reference.py [--quick] [--runs N]
[--final-runs N]``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from report import RESULTS, fmt, machine_info, markdown_table, write_json, write_text
from timing import median, stage_medians

NAME = "adaptive_vs_reference"
SCENES = {"SPHERE": "glass_sphere_fog", "CUBE": "perlin_cube", "MESH": "mesh_in_fog"}
RMSE_TOLERANCE = 1.1  # "at equal RMSE (≤ 1.1× the reference's)"
TRUTH_FACTOR = 16
TARGETS = {"photon_ratio": 0.5, "time_ratio": 1.0}
# the adaptive pipeline's defaults recorded with the results
ADAPTIVE_KEYS = (
    "pilot_photons", "background", "delta_weight", "mip_block", "mip_blend", "placement"
)  # fmt: skip
# the pipelines compared: the reference and two adaptive variants (parameters set per frame)
VARIANTS = {
    "uniform": {"emission": "uniform"},
    "adaptive": {"emission": "adaptive", "placement": "importance"},
    "adaptive_uniform_placement": {"emission": "adaptive", "placement": "uniform"},
}
ADAPTIVE_VARIANTS = ("adaptive", "adaptive_uniform_placement")
LABELS = {
    "uniform": "reference",
    "adaptive": "adaptive",
    "adaptive_uniform_placement": "adaptive, uniform placement",
}
# rows of Pfeuti Tables 4.2–4.4 → our stages (ours that the thesis does not list are extra rows)
PASSES = (
    ("Voxelization", ("voxelization",)),
    ("Materials + gradient", ("materials", "gradient")),
    ("Octree", ("octree", "march grids")),
    ("Pilot Photon Generation", ("pilot photon generation",)),
    ("Pilot Photon Marching", ("pilot photon marching",)),
    ("Photon Distribution", ("photon distribution",)),
    ("Photon Generation", ("photon generation",)),
    ("Photon Marching", ("photon tracing",)),
    ("Smoothing (S8)", ("smoothing",)),
    ("Mipmap Generation (incl. S8)", ("mipmap generation",)),
    ("Filtering", ("filtering",)),
    ("Copy (view grids)", ("view grids",)),
    ("Viewing Pass", ("viewing",)),
)


def light_stages(emission: str) -> tuple[str, ...]:
    """The stages a light change reruns (all after the octree and the march grids)."""
    from photonmap.volume.params import ADAPTIVE_STAGES, STAGES

    return (ADAPTIVE_STAGES if emission == "adaptive" else STAGES)[5:]


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    peak = float(np.max(b))
    err = rmse(a, b)
    return 20 * math.log10(peak / err) if err > 0 and peak > 0 else math.inf


def light_frames(pipe, configs: Sequence[tuple[str, int]], runs: int) -> list[dict]:
    """Light-change frames (every cached stage that depends on the light dropped, then render) of
    each ``(variant, photons)`` config (:data:`VARIANTS`), interleaved run by run so that a load
    change on the shared machine hits every config alike; one untimed warm-up round first. Per
    config: the image, medians and samples."""
    walls = [[] for _ in configs]
    per_stage = [[] for _ in configs]
    images, stats = [None] * len(configs), [None] * len(configs)
    for run in range(runs + 1):
        for k, (variant, photons) in enumerate(configs):
            pipe.set_params(photons=photons, **VARIANTS[variant])
            stages = light_stages(VARIANTS[variant]["emission"])
            pipe.invalidate(stages)
            start = time.perf_counter()
            images[k] = np.array(pipe.render())
            wall = 1e3 * (time.perf_counter() - start)
            stats[k] = dict(pipe.stats)
            if run:  # run 0 warms up (Dr.Jit compilation, and any stage not cached yet)
                assert pipe.recomputed == list(stages), pipe.recomputed
                walls[k].append(wall)
                per_stage[k].append(dict(pipe.timer.ms))
    out = []
    for k in range(len(configs)):
        photon_ms = [
            sum(v for n, v in s.items() if n not in ("view grids", "viewing")) for s in per_stage[k]
        ]
        out.append(
            {
                "image": images[k],
                "wall_ms": median(walls[k]),
                "wall_ms_min": min(walls[k], default=math.nan),
                "photon_stages_ms": median(photon_ms),
                "stages_ms": stage_medians(per_stage[k]),
                "samples_ms": walls[k],
                "stats": stats[k],
            }
        )
    return out


def ground_truth(pipe, photons: int, factor: int) -> np.ndarray:
    """The reference pipeline at ``factor × photons``: ``factor`` batches of ``photons``
    consecutive Halton points (one sequence), C and D averaged, then S8 and S9 as usual."""
    import drjit as dr

    from photonmap.volume import emit, march
    from photonmap.volume.smooth import smooth

    pipe.set_params(emission="uniform", photons=photons, sampler="halton")
    pipe.render()
    s, p = pipe.scene, pipe.params
    grids = pipe.stage_output("march grids")
    C = D = None
    for batch in range(factor):
        parts = [emit.emit(light, s.box, photons, "halton", batch * photons) for light in s.lights]
        for part in parts:
            r = march.march(part, grids, ds_min=p.ds_min, fidelity=p.fidelity, voxel_size=s.box.h)
            C = r.C if C is None else C + r.C
            D = r.D if D is None else D + r.D
        dr.eval(C, D)
    smoothed = smooth(C / factor, D / factor, p.smoothing)
    pipe.set_stage_output("smoothing", smoothed)  # the viewing stages read the averaged grids
    image = np.array(pipe.render())
    assert pipe.recomputed == ["view grids", "viewing"]
    pipe.set_params(sampler="hammersley")
    return image


def equal_rmse_budget(budgets: Sequence[int], errors: Sequence[float], target: float):
    """The smallest budget whose RMSE reaches ``target``, interpolated log–log between the
    sweep's points (None if no point of the sweep reaches it)."""
    for i, (budget, error) in enumerate(zip(budgets, errors, strict=True)):
        if error <= target:
            if i == 0:
                return float(budget)
            b0, e0 = budgets[i - 1], errors[i - 1]
            t = math.log(e0 / target) / math.log(e0 / error)
            return float(math.exp(math.log(b0) + t * math.log(budget / b0)))
    return None


def _loglog(xs, ys, x):
    """``y(x)`` interpolated log–log between the points of a sorted sweep (clamped)."""
    return float(np.exp(np.interp(math.log(x), np.log(xs), np.log(ys))))


def by_nominal(sweep: dict, variant: str = "adaptive") -> list:
    """Photon and time ratios at equal RMSE (≤ 1.1×) of an adaptive variant for every reference
    budget of the sweep, from the sweep alone."""
    adaptive = sweep[variant]
    budgets = [r["budget"] for r in adaptive]
    out = []
    for ref in sweep["uniform"]:
        target = RMSE_TOLERANCE * ref["rmse"]
        budget = equal_rmse_budget(budgets, [r["rmse"] for r in adaptive], target)
        row = {"reference_budget": ref["budget"], "target_rmse": target, "adaptive_budget": budget}
        if budget is not None:
            entered = _loglog(budgets, [r["propagated"] for r in adaptive], budget)
            row["photon_ratio"] = entered / ref["propagated"]
            row["time_ratio"] = (
                _loglog(budgets, [r["wall_ms"] for r in adaptive], budget) / ref["wall_ms"]
            )
            row["photon_stage_time_ratio"] = (
                _loglog(budgets, [r["photon_stages_ms"] for r in adaptive], budget)
                / ref["photon_stages_ms"]
            )
        out.append(row)
    return out


def pass_table(stages_ms: dict) -> dict:
    return {row: sum(stages_ms.get(s, 0.0) for s in names) for row, names in PASSES}


def run_scene(label, scene, args, log=_log) -> dict:
    from photonmap import VolumePipeline

    size = {"width": args.width, "height": args.height}
    nominal = args.nominal
    # Pfeuti's adaptive method is single scattering, as is the ground truth's direct march
    pipe = VolumePipeline(scene, grid=args.grid, photons=nominal, scattering="single", **size)
    start = time.perf_counter()
    log(f"{label}: ground truth ({TRUTH_FACTOR} × {nominal:,} photons) ...")
    truth = ground_truth(pipe, nominal, TRUTH_FACTOR)
    images = {}
    out = {"scene": scene, "ground_truth_s": time.perf_counter() - start}
    out["sweep"] = {variant: [] for variant in VARIANTS}
    for budget in args.budgets:
        configs = [(variant, budget) for variant in VARIANTS]
        for (variant, _), frame in zip(
            configs, light_frames(pipe, configs, args.runs), strict=True
        ):
            out["sweep"][variant].append(_row(frame, budget, truth))
            images[(variant, budget)] = frame["image"]
            log(
                f"  {variant:27s} {budget:>9,}: RMSE {out['sweep'][variant][-1]['rmse']:.5f}, "
                f"{frame['wall_ms']:.0f} ms ({frame['photon_stages_ms']:.0f} photon stages)"
            )
    # geometry stages (identical for both pipelines) from one full render
    pipe.invalidate()
    pipe.set_params(emission="uniform", photons=nominal)
    pipe.render()
    out["geometry_ms"] = {
        k: pipe.timer.ms[k]
        for k in ("voxelization", "materials", "gradient", "octree", "march grids")
    }
    out["marching_fit"] = marching_fit(out["sweep"]["uniform"])
    out["ablation"] = ablation(pipe, out["sweep"], truth, [nominal // 2, nominal])
    reference = next(r for r in out["sweep"]["uniform"] if r["budget"] == nominal)
    target = RMSE_TOLERANCE * reference["rmse"]
    out["target_rmse"] = target
    out["by_nominal"] = by_nominal(out["sweep"])
    out["by_nominal_uniform_placement"] = by_nominal(out["sweep"], "adaptive_uniform_placement")
    budgets = {}
    for variant in ADAPTIVE_VARIANTS:
        budget = equal_rmse_budget(args.budgets, [r["rmse"] for r in out["sweep"][variant]], target)
        if budget is None:
            log(f"  {variant} never reaches RMSE {target:.5f} within the sweep")
            continue
        budget = max(int(round(budget)), 2 * pipe.params.pilot_photons)
        budgets[variant] = smallest_budget(
            lambda b, v=variant: (
                rmse(light_frames(pipe, [(v, b)], runs=0)[0]["image"], truth) <= target
            ),
            budget,
            next(r["budget"] for r in out["sweep"][variant] if r["rmse"] <= target),
        )
    # time each variant at its budget interleaved with the reference at the nominal budget
    configs = [("uniform", nominal), *budgets.items()]
    frames = light_frames(pipe, configs, args.final_runs)
    out["reference"] = reference = _row(frames[0], nominal, truth)
    for (variant, budget), frame in zip(configs[1:], frames[1:], strict=True):
        equal = _row(frame, budget, truth)
        equal["psnr_vs_reference_db"] = psnr(frame["image"], images[("uniform", nominal)])
        equal.update(ratios(equal, reference))
        out["equal_rmse" if variant == "adaptive" else "equal_rmse_uniform_placement"] = equal
        log(
            f"  equal RMSE, {variant}: {budget:,} photons, RMSE {equal['rmse']:.5f} (target "
            f"{target:.5f}), photon ratio {equal['photon_ratio']:.2f}, time ratio "
            f"{equal['time_ratio']:.2f}"
        )
    return out


def smallest_budget(reaches, guess: int, known: int, probes: int = 6) -> int:
    """A budget near the smallest that ``reaches`` the target RMSE: ``guess`` (the log–log
    interpolation) if it does, else a geometric bisection between ``guess`` and ``known`` (a sweep
    budget that does) over ``probes`` renders. RMSE is not exactly monotone in the budget (the
    point sets change), so this is the smallest budget found, not a proven minimum."""
    if guess >= known or reaches(guess):
        return min(guess, known)
    lo, hi = guess, known
    for _ in range(probes):
        mid = int(round(math.sqrt(lo * hi)))
        if mid in (lo, hi):
            break
        if reaches(mid):
            hi = mid
        else:
            lo = mid
    return hi


ABLATION_COLUMNS = ("uniform", "adaptive", "adaptive_uniform_placement", "placement_only")
PLACEMENT_ONLY = {"emission": "adaptive", "placement": "importance", "delta_weight": 1e9}


def ablation(pipe, sweep: dict, truth: np.ndarray, budgets: Sequence[int]) -> list:
    """Where the adaptive pipeline's gain comes from, per budget of the sweep: RMSE of the
    reference, the full adaptive pipeline, the filter alone (uniform placement) and the placement
    alone (importance photons, every voxel at level 0 — a Δweight no weight reaches)."""
    from photonmap.volume.params import VolumeParams

    rows = []
    for budget in budgets:
        row = {"budget": budget}
        for variant in VARIANTS:
            found = [r["rmse"] for r in sweep[variant] if r["budget"] == budget]
            row[variant] = found[0] if found else None
        pipe.set_params(photons=budget, **PLACEMENT_ONLY)
        row["placement_only"] = rmse(np.array(pipe.render()), truth)
        rows.append(row)
    pipe.set_params(delta_weight=VolumeParams().delta_weight)
    return rows


def ratios(equal: dict, reference: dict) -> dict:
    """Photon, time, photon-stage time and step ratios of an equal-RMSE run to the reference."""
    return {
        "photon_ratio": equal["propagated"] / reference["propagated"],
        "time_ratio": equal["wall_ms"] / reference["wall_ms"],
        "time_ratio_min": equal["wall_ms_min"] / reference["wall_ms_min"],
        "photon_stage_time_ratio": equal["photon_stages_ms"] / reference["photon_stages_ms"],
        "steps_ratio": equal["steps"] / reference["steps"],  # marching work, load-independent
        "steps_per_photon": equal["steps"] / equal["propagated"],
    }


def marching_fit(rows: Sequence[dict]) -> dict:
    """Least-squares ``photon tracing ms = F + v · steps`` over the reference sweep: ``F`` ms does
    not shrink with the photon budget, ``v`` is the cost of a million marching steps."""
    steps = np.array([r["steps"] for r in rows], dtype=np.float64) / 1e6
    ms = np.array([r["stages_ms"]["photon tracing"] for r in rows], dtype=np.float64)
    v, fixed = np.polyfit(steps, ms, 1) if len(rows) > 1 else (ms[0] / steps[0], 0.0)
    return {"fixed_ms": float(fixed), "ms_per_million_steps": float(v)}


def _row(frame: dict, budget: int, truth: np.ndarray) -> dict:
    stats = frame["stats"]
    return {
        "budget": budget,
        "propagated": int(stats["photons_propagated"]),
        "steps": int(stats["steps"]),
        "rmse": rmse(frame["image"], truth),
        "wall_ms": frame["wall_ms"],
        "wall_ms_min": frame["wall_ms_min"],
        "photon_stages_ms": frame["photon_stages_ms"],
        "stages_ms": frame["stages_ms"],
        "passes_ms": pass_table(frame["stages_ms"]),
        "samples_ms": frame["samples_ms"],
    }


# ----------------------------------------------------------------------------------- report
def markdown(result: dict) -> str:
    s, m = result["settings"], result["machine"]
    lines = [
        f"# Adaptive vs reference pipeline at equal RMSE ({s['grid']}³, {s['width']}×{s['height']})",
        "",
        f"{m['cpu_model']}, {m['cores']} cores, Mitsuba {m['mitsuba']}, Dr.Jit {m['drjit']}, "
        f"{m['date']}, load average at start {m.get('load_average')} (the machine was shared). "
        f"Ground truth: reference pipeline at {TRUTH_FACTOR}× {s['nominal']:,} photons. Times: "
        f"median of {s['runs']} light-change frames in the sweep, of {s.get('final_runs')} at equal "
        "RMSE (all light-dependent stages run, configurations interleaved run by run) after a "
        "warm-up frame. Target RMSE = 1.1 × the reference's at the nominal budget. Adaptive "
        f"settings: {s.get('adaptive', {})}; load average at the end "
        f"{result.get('load_average_end')}.",
        "",
        "## Headline",
        "",
    ]
    rows = []
    for label, sc in result["scenes"].items():
        for key, name in (
            ("equal_rmse", "adaptive"),
            ("equal_rmse_uniform_placement", "uniform placement"),
        ):
            eq = sc.get(key) or {}
            met = eq and eq["photon_ratio"] <= TARGETS["photon_ratio"] and eq["time_ratio"] < 1
            rows.append(
                [
                    label,
                    name,
                    fmt(sc["reference"]["propagated"]),
                    fmt(sc["reference"]["rmse"], 5),
                    fmt(sc["target_rmse"], 5),
                    fmt(eq.get("propagated")) if eq else "not reached",
                    fmt(eq.get("rmse"), 5) if eq else "–",
                    fmt(eq.get("photon_ratio"), 2),
                    fmt(eq.get("time_ratio"), 2),
                    fmt(eq.get("photon_stage_time_ratio"), 2),
                    fmt(eq.get("time_ratio_min"), 2),
                    "yes" if met else "no",
                ]
            )
    lines += [
        markdown_table(
            [
                "scene",
                "variant",
                "ref photons",
                "ref RMSE",
                "target RMSE",
                "adaptive photons",
                "adaptive RMSE",
                "photon ratio",
                "time ratio",
                "photon-stage time ratio",
                "time ratio (min of runs)",
                "targets met",
            ],
            rows,
        ),
        "",
        "Targets: photon ratio ≤ 0.5 (Pfeuti: 0.37–0.46) and time ratio < 1 (Pfeuti: 1.01–1.04).",
        "",
    ]
    for label, sc in result["scenes"].items():
        lines += [f"## {label} ({sc['scene']}): passes in ms (layout of Pfeuti Tables 4.2–4.4)", ""]
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
            (
                "**Total**",
                lambda r, g=geo: f"**{fmt(sum(g.values()) + sum(r['stages_ms'].values()))}**",
            ),
            ("Photon Count (entered the grid)", lambda r: fmt(r["propagated"])),
            ("Marching steps", lambda r: fmt(r["steps"])),
            ("RMSE vs ground truth", lambda r: fmt(r["rmse"], 5)),
        )
        for name, value in summary:
            table.append([name, *(value(run) if run else "–" for run in runs)])
        header = ["Pass", "Reference", "Adaptive", "Adaptive, uniform placement"]
        lines += [markdown_table(header, table), ""]
        sweep = []
        for variant in VARIANTS:
            for r in sc["sweep"][variant]:
                sweep.append(
                    [
                        LABELS[variant],
                        fmt(r["budget"]),
                        fmt(r["propagated"]),
                        fmt(r["rmse"], 5),
                        fmt(r["wall_ms"]),
                        fmt(r["photon_stages_ms"]),
                        fmt(r["steps"] / max(r["propagated"], 1), 1),
                    ]
                )
        lines += [
            markdown_table(
                [
                    "pipeline",
                    "budget",
                    "entered",
                    "RMSE",
                    "frame ms",
                    "photon stages ms",
                    "steps/photon",
                ],
                sweep,
            ),
            "",
        ]
    rows = []
    for label, sc in result["scenes"].items():
        for key, name in (
            ("by_nominal", "adaptive"),
            ("by_nominal_uniform_placement", "uniform p."),
        ):
            for r in sc.get(key, []):
                rows.append(
                    [
                        label,
                        name,
                        fmt(r["reference_budget"]),
                        fmt(r["adaptive_budget"], 0) if r["adaptive_budget"] else "not reached",
                        fmt(r.get("photon_ratio"), 2),
                        fmt(r.get("time_ratio"), 2),
                        fmt(r.get("photon_stage_time_ratio"), 2),
                    ]
                )
    lines += [
        "## Equal RMSE at every reference budget (interpolated on the sweep)",
        "",
        markdown_table(
            [
                "scene",
                "variant",
                "reference budget",
                "adaptive budget",
                "photon ratio",
                "time ratio",
                "photon-stage time ratio",
            ],
            rows,
        ),  # fmt: skip
        "",
    ]
    rows = [
        [label, fmt(r["budget"]), *(fmt(r[k], 5) for k in ABLATION_COLUMNS)]
        for label, sc in result["scenes"].items()
        for r in sc.get("ablation", [])
    ]
    lines += [
        "## Where the gain comes from (RMSE at equal photon budgets)",
        "",
        markdown_table(
            [
                "scene",
                "budget",
                "reference",
                "adaptive",
                "filter only (uniform placement)",
                "placement only (level 0)",
            ],
            rows,
        ),  # fmt: skip
        "",
    ]
    if result.get("analysis"):
        lines += ["## Why", "", result["analysis"], ""]
    lines.append(f"Benchmark wall time {result['elapsed_s']:.0f} s.")
    return "\n".join(lines)


def analysis(result: dict) -> str:
    """A paragraph per scene and variant saying where the time goes, with numbers."""
    parts = []
    for label, sc in result["scenes"].items():
        ref = sc["reference"]
        fit = sc["marching_fit"]
        parts.append(
            f"**{label}**: marching costs {fit['fixed_ms']:.0f} ms + "
            f"{fit['ms_per_million_steps']:.0f} ms per million steps (fit over the reference "
            f"sweep); the reference takes {ref['steps'] / ref['propagated']:.1f} steps per photon."
        )
        for key, name in (
            ("equal_rmse", "adaptive"),
            ("equal_rmse_uniform_placement", "uniform placement"),
        ):
            eq = sc.get(key)
            if not eq:
                parts.append(f"{name}: the target RMSE is not reached within the sweep.")
                continue
            a, r = eq["passes_ms"], ref["passes_ms"]
            extra = (
                sum(
                    a[k]
                    for k in (
                        "Pilot Photon Generation",
                        "Pilot Photon Marching",
                        "Photon Distribution",
                        "Photon Generation",
                    )
                )
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = result["scenes"]
    fig, axes = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 4), squeeze=False)
    for ax, (label, sc) in zip(axes[0], scenes.items(), strict=True):
        for variant, style in zip(VARIANTS, ("o-", "s-", "^-"), strict=True):
            rows = sc["sweep"][variant]
            ax.loglog([r["wall_ms"] for r in rows], [r["rmse"] for r in rows], style,
                      label=LABELS[variant])  # fmt: skip
        ax.axhline(sc["target_rmse"], color="grey", ls=":", label="1.1 × reference RMSE")
        for key, marker in (("equal_rmse", "k*"), ("equal_rmse_uniform_placement", "kP")):
            if sc.get(key):
                e = sc[key]
                ax.plot(
                    [e["wall_ms"]], [e["rmse"]], marker, ms=11, label=f"{key.replace('_', ' ')}"
                )
        ax.set_title(f"{label} ({sc['scene']})")
        ax.set_xlabel("light-change frame (ms)")
        ax.set_ylabel("image RMSE vs ground truth")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# -------------------------------------------------------------------------------------- run
def run(args, log=_log) -> dict:
    import photonmap  # noqa: F401 - selects the Mitsuba variant
    from photonmap.volume.params import VolumeParams

    started = time.perf_counter()
    result: dict = {
        "benchmark": NAME,
        "machine": machine_info(),
        "settings": {
            "grid": args.grid,
            "width": args.width,
            "height": args.height,
            "nominal": args.nominal,
            "budgets": list(args.budgets),
            "runs": args.runs,
            "final_runs": args.final_runs,
            "truth_factor": TRUTH_FACTOR,
            "rmse_tolerance": RMSE_TOLERANCE,
            "targets": TARGETS,
            "quick": args.quick,
            "adaptive": {k: getattr(VolumeParams(), k) for k in ADAPTIVE_KEYS},
        },
        "scenes": {},
        "headline": {},
    }
    for label in args.scenes:
        sc = run_scene(label, SCENES[label], args, log)
        result["scenes"][label] = sc
        result["headline"][label] = {
            **headline(sc.get("equal_rmse")),
            "uniform_placement": headline(sc.get("equal_rmse_uniform_placement")),
        }
    result["analysis"] = analysis(result)
    result["elapsed_s"] = time.perf_counter() - started
    result["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    result["markdown"] = markdown(result)
    if args.out_dir is not None:
        stem = Path(args.out_dir) / (NAME + ("_quick" if args.quick else ""))
        write_text(stem.with_suffix(".md"), result["markdown"] + "\n")
        plot(result, stem.with_suffix(".png"))
        write_json(stem.with_suffix(".json"), result)
    return result


def headline(equal: dict | None) -> dict:
    """Photon and time ratio at equal RMSE and whether both targets are met."""
    if equal is None:
        return {"photon_ratio": None, "time_ratio": None, "meets_targets": False}
    return {
        "photon_ratio": equal["photon_ratio"],
        "time_ratio": equal["time_ratio"],
        "meets_targets": equal["photon_ratio"] <= TARGETS["photon_ratio"]
        and equal["time_ratio"] < TARGETS["time_ratio"],
    }


def _ints(text: str) -> list[int]:
    return [int(float(x)) for x in text.replace(" ", "").split(",") if x]


def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smoke test: tiny grid and budgets")
    parser.add_argument("--runs", type=int, default=3, help="timed frames per sweep configuration")
    parser.add_argument(
        "--final-runs", type=int, default=9, help="timed frames per equal-RMSE configuration"
    )
    parser.add_argument("--grid", type=int, default=128)
    parser.add_argument("--width", type=int, default=480)
    parser.add_argument("--height", type=int, default=360)
    parser.add_argument("--nominal", type=int, default=512**2, help="reference budget N_R")
    parser.add_argument(
        "--budgets", type=_ints, default=[2**16, 2**17, 2**18, 2**19, 2**20], help="photon sweep"
    )
    parser.add_argument("--scenes", default="SPHERE,CUBE,MESH")
    parser.add_argument("--out-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    args.scenes = [s.strip().upper() for s in args.scenes.split(",") if s.strip()]
    if args.quick:
        args.grid, args.width, args.height, args.runs, args.final_runs = 32, 48, 36, 1, 1
        args.nominal, args.budgets = 2**14, [2**12 * 3, 2**13, 2**14]
    args.budgets = sorted({*args.budgets, args.nominal})
    result = run(args)
    print(result["markdown"])
    return result


if __name__ == "__main__":
    main()
