"""Pfeuti 2009's adaptive pipeline against the reference pipeline of the volume method (Sun et
al. 2008) at equal RMSE, per pass in the layout of Pfeuti's Tables 4.2–4.4. Scenes SPHERE, CUBE,
MESH (``glass_sphere_fog``, ``perlin_cube``, ``mesh_in_fog``) at a 128³ grid.

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

import math
import sys
import time
from collections.abc import Sequence

import numpy as np

import report
from accuracy import loglog_between
from adaptive_sweep import (
    VARIANTS,
    ablation,
    ground_truth,
    light_frames,
    marching_fit,
    psnr,
    rmse,
    sweep_row,
)
from adaptive_vs_reference_report import analysis, markdown, plot
from report import load_average, machine_info, results_stem, write_results

NAME = "adaptive_vs_reference"
SCENES = {"SPHERE": "glass_sphere_fog", "CUBE": "perlin_cube", "MESH": "mesh_in_fog"}
RMSE_TOLERANCE = 1.1  # "at equal RMSE (≤ 1.1× the reference's)"
TRUTH_FACTOR = 16
TARGETS = {"photon_ratio": 0.5, "time_ratio": 1.0}
# the adaptive pipeline's defaults recorded with the results
ADAPTIVE_KEYS = (
    "pilot_photons", "background", "delta_weight", "mip_block", "mip_blend", "placement"
)  # fmt: skip
ADAPTIVE_VARIANTS = ("adaptive", "adaptive_uniform_placement")


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def equal_rmse_budget(budgets: Sequence[int], errors: Sequence[float], target: float):
    """The smallest budget whose RMSE reaches ``target``, interpolated log–log between the
    sweep's points (None if no point of the sweep reaches it)."""
    if errors[0] <= target:
        return float(budgets[0])
    return loglog_between(budgets, errors, target)


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


def run_scene(label, scene, args, log=_log) -> dict:
    """Ground truth, the sweep of every variant, the ablation and the equal-RMSE comparison of
    one scene."""
    from photonmap import VolumePipeline

    nominal = args.nominal
    # Pfeuti's adaptive method is single scattering, as is the ground truth's direct march
    pipe = VolumePipeline(scene, grid=args.grid, photons=nominal, scattering="single",
                          width=args.width, height=args.height)  # fmt: skip
    start = time.perf_counter()
    log(f"{label}: ground truth ({TRUTH_FACTOR} × {nominal:,} photons) ...")
    truth = ground_truth(pipe, nominal, TRUTH_FACTOR)
    out = {"scene": scene, "ground_truth_s": time.perf_counter() - start}
    out["sweep"], images = sweep(pipe, args.budgets, args.runs, truth, log)
    # geometry stages (identical for both pipelines) from one full render
    pipe.invalidate()
    pipe.set_params(emission="uniform", photons=nominal)
    pipe.render()
    geometry = ("voxelization", "materials", "gradient", "octree", "march grids")
    out["geometry_ms"] = {k: pipe.timer.ms[k] for k in geometry}
    out["marching_fit"] = marching_fit(out["sweep"]["uniform"])
    out["ablation"] = ablation(pipe, out["sweep"], truth, [nominal // 2, nominal])
    reference = next(r for r in out["sweep"]["uniform"] if r["budget"] == nominal)
    out["target_rmse"] = target = RMSE_TOLERANCE * reference["rmse"]
    out["by_nominal"] = by_nominal(out["sweep"])
    out["by_nominal_uniform_placement"] = by_nominal(out["sweep"], "adaptive_uniform_placement")
    budgets = equal_rmse_budgets(pipe, out["sweep"], args.budgets, truth, target, log)
    # time each variant at its budget interleaved with the reference at the nominal budget
    configs = [("uniform", nominal), *budgets.items()]
    frames = light_frames(pipe, configs, args.final_runs)
    out["reference"] = reference = sweep_row(frames[0], nominal, truth)
    for (variant, budget), frame in zip(configs[1:], frames[1:], strict=True):
        equal = sweep_row(frame, budget, truth)
        equal["psnr_vs_reference_db"] = psnr(frame["image"], images[("uniform", nominal)])
        equal.update(ratios(equal, reference))
        out["equal_rmse" if variant == "adaptive" else "equal_rmse_uniform_placement"] = equal
        log(f"  equal RMSE, {variant}: {budget:,} photons, RMSE {equal['rmse']:.5f} (target "
            f"{target:.5f}), photon ratio {equal['photon_ratio']:.2f}, time ratio "
            f"{equal['time_ratio']:.2f}")  # fmt: skip
    return out


def sweep(pipe, budgets, runs: int, truth, log) -> tuple[dict, dict]:
    """Every variant's light-change frames at every budget: rows per variant and the images."""
    rows, images = {variant: [] for variant in VARIANTS}, {}
    for budget in budgets:
        configs = [(variant, budget) for variant in VARIANTS]
        for (variant, _), frame in zip(configs, light_frames(pipe, configs, runs), strict=True):
            rows[variant].append(sweep_row(frame, budget, truth))
            images[(variant, budget)] = frame["image"]
            log(f"  {variant:27s} {budget:>9,}: RMSE {rows[variant][-1]['rmse']:.5f}, "
                f"{frame['wall_ms']:.0f} ms ({frame['photon_stages_ms']:.0f} photon stages)")  # fmt: skip
    return rows, images


def equal_rmse_budgets(pipe, rows: dict, budgets, truth, target: float, log) -> dict:
    """Each adaptive variant's budget for ``target``: interpolated on the sweep, refined by
    :func:`smallest_budget` with renders (variants that never reach it are left out)."""
    found = {}
    for variant in ADAPTIVE_VARIANTS:
        budget = equal_rmse_budget(budgets, [r["rmse"] for r in rows[variant]], target)
        if budget is None:
            log(f"  {variant} never reaches RMSE {target:.5f} within the sweep")
            continue
        found[variant] = smallest_budget(
            lambda b, v=variant: (
                rmse(light_frames(pipe, [(v, b)], runs=0)[0]["image"], truth) <= target
            ),
            max(int(round(budget)), 2 * pipe.params.pilot_photons),
            next(r["budget"] for r in rows[variant] if r["rmse"] <= target),
        )
    return found


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


# -------------------------------------------------------------------------------------- run
def run(args, log=_log) -> dict:
    """Run the benchmark and return the result dict; with ``args.out_dir`` also write it."""
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
    result["load_average_end"] = load_average()
    result["markdown"] = markdown(result, TRUTH_FACTOR)
    if args.out_dir is not None:
        stem = results_stem(args.out_dir, NAME, args.quick)
        write_results(stem, result, result["markdown"] + "\n")
        plot(result, stem.with_suffix(".png"))
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


def main(argv: Sequence[str] | None = None) -> dict:
    parser = report.arguments(__doc__, "smoke test: tiny grid and budgets")
    parser.add_argument("--runs", type=int, default=3, help="timed frames per sweep configuration")
    parser.add_argument(
        "--final-runs", type=int, default=9, help="timed frames per equal-RMSE configuration"
    )
    parser.add_argument("--grid", type=int, default=128)
    parser.add_argument("--width", type=int, default=480)
    parser.add_argument("--height", type=int, default=360)
    parser.add_argument("--nominal", type=int, default=512**2, help="reference budget N_R")
    parser.add_argument(
        "--budgets",
        type=report.integers,
        default=[2**16, 2**17, 2**18, 2**19, 2**20],
        help="photon sweep",
    )
    parser.add_argument("--scenes", default="SPHERE,CUBE,MESH")
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
