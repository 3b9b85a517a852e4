"""SPPM (Hachisuka & Jensen 2009) against Mitsuba's ``volpath`` on a scene with participating
media and no caustics: time to equal error.

Scene: ``lamp_in_fog`` (examples/lamp_in_fog.xml: a small spherical lamp inside a box of fog
standing on a diffuse floor, a rough-plastic block in the fog; Mitsuba's default gaussian film
filter). SPPM's eye paths run through the fog by volumetric path tracing (equiangular direct light
along each piece, free-flight collisions), its photons light the floor and the block. Reference:
``volpath`` at ``--ref-spp`` in two halves of different seeds (cached in ``results/cache/``), the
halves' difference estimating the reference's own error. ``volpath`` at 4 … 1024 spp (timed
renders) and SPPM (default parameters, errors at checkpoints with the clock stopped), both
``--runs`` times, interleaved.
Errors leave out the pixels that see the lamp (:func:`accuracy.light_image_mask`: its image is
antialiasing noise of the eye samples, the same for every method, and would swamp the rest).

Headline: ``sppm_time_ratio_at_equal_block_rmse`` — the time SPPM needs for the 4×4-block error
that ``volpath`` reaches at ``--target-spp`` (the file's own sample count), divided by the time
``volpath`` needs (log-log interpolation of both curves); the same at 256 and 1024 spp in
``time_ratios``. The goal is at most 2. The headline and the tables are those of the run with
the median ratio; ``runs`` holds every run's ratio.

Writes ``results/media_vs_volpath.json`` and ``.md`` (``_quick`` with ``--quick``).

    .venv/bin/python benchmarks/media_vs_volpath.py [--quick] [--seconds 60]
"""

from __future__ import annotations

import os
from pathlib import Path

import mitsuba as mi
import numpy as np

import report
from accuracy import (
    cached_image,
    errors,
    light_image_mask,
    loglog_time_for,
    masked_errors,
    mitsuba_curve,
    render_passes,
    vs_truth,
)
from photonmap.sppm import SPPMPipeline
from timing import Budget, checkpoints

NAME = "media_vs_volpath"
SCENE = report.REPO / "examples" / "lamp_in_fog.xml"
CHECKPOINTS = (0.25, 0.5, 1, 2, 4, 8, 15, 30, 60, 120)
KEY = "block_rel_rmse"


def reference(scene, spp: int, cache: Path, tag: str) -> list[np.ndarray]:
    """The two halves of a ``volpath`` reference at ``spp`` samples per pixel (cached)."""
    return [
        cached_image(
            cache / f"media_{tag}_{spp}spp_{half}.exr",
            lambda h=half: render_passes(scene, spp // 2, 1024, 100_000 * (h + 1)),
        ).astype(np.float64)
        for half in (0, 1)
    ]


def run_sppm(path: str, score, seconds: float):
    """One SPPM run (default parameters) of ``seconds`` compute time; errors at checkpoints."""
    pipe = SPPMPipeline(path)
    pipe.run(iterations=2)  # compile every kernel of the run
    pipe.reset()
    rows = []
    for spent in checkpoints(pipe.step, Budget(seconds), CHECKPOINTS):
        rows.append({"iterations": pipe.iterations, "seconds": spent,
                     **score(np.array(pipe.image()))})  # fmt: skip
        print(f"  sppm {pipe.iterations} it: {spent:.1f} s, "
              f"4x4 error {rows[-1][KEY]:.4f}", flush=True)  # fmt: skip
    return rows, {"stages_ms": dict(pipe.timer.ms), "stats": dict(pipe.stats)}


def headline(volpath: list, sppm: list, target_spp: int, ref_err: float) -> dict:
    """SPPM's time over volpath's for volpath's error at ``target_spp`` (and 256, 1024 spp)."""
    target = next((r[KEY] for r in volpath if r["spp"] == target_spp), volpath[-1][KEY])
    t_volpath = loglog_time_for(volpath, target, KEY)
    t_sppm = loglog_time_for(sppm, target, KEY)
    ratios = {}
    for row in volpath:
        if row["spp"] in (target_spp, 256, 1024):
            t = loglog_time_for(sppm, row[KEY], KEY)
            ratios[f"{row['spp']} spp"] = None if t is None else t / row["seconds"]
    return {
        "target_block_rel_rmse": target,
        "volpath_seconds": t_volpath,
        "sppm_seconds": t_sppm,
        "sppm_time_ratio_at_equal_block_rmse": t_sppm / t_volpath,
        "time_ratios": ratios,
        "goal": "<= 2",
        "reference_block_rel_rmse": ref_err,
        "sppm_final_block_rel_rmse_vs_truth": vs_truth(sppm[-1][KEY], ref_err),
    }


def markdown(result: dict) -> str:
    h, (load, load_end) = result["headline"], result["load_average"]
    records = [{**r, "run": f"volpath {r['spp']} spp"} for r in result["volpath"]]
    records += [{**r, "run": f"sppm {r['iterations']} it"} for r in result["sppm"]]
    table = report.records_table(
        records,
        [("run", "run", None), ("seconds", "seconds", 2), ("4×4 error", KEY, 4),
         ("brightness", "brightness", 3)],
    )  # fmt: skip
    ratios = ", ".join(f"{k}: {v:.2f}" for k, v in h["time_ratios"].items() if v is not None)
    return (
        f"# SPPM vs volpath on lamp_in_fog\n\nload average {load:.1f} → {load_end:.1f}\n\n"
        f"{table}\n\nvolpath reaches {h['target_block_rel_rmse']:.4f} at "
        f"{result['args']['target_spp']} spp in {h['volpath_seconds']:.2f} s; sppm needs "
        f"{h['sppm_seconds']:.2f} s: ratio {h['sppm_time_ratio_at_equal_block_rmse']:.2f} "
        f"(goal ≤ 2); at volpath's errors of {ratios}. The run of the median ratio of "
        f"{len(h['runs'])}: {', '.join(f'{r:.2f}' for r in h['runs'])}\n"
    )


def main(argv=None) -> dict:
    ap = report.arguments(__doc__, "small budgets (a smoke run)")
    ap.add_argument("--seconds", type=float, default=60.0, help="SPPM compute budget")
    ap.add_argument("--ref-spp", type=int, default=32768)
    ap.add_argument("--target-spp", type=int, default=64, help="volpath budget of the headline")
    ap.add_argument("--runs", type=int, default=3, help="volpath and SPPM runs (median)")
    args = ap.parse_args(argv)
    if args.quick:
        args.seconds, args.ref_spp, args.runs = 4.0, 2048, 1
    load = os.getloadavg()[0]
    scene = mi.load_file(str(SCENE))
    a, b = reference(scene, args.ref_spp, args.out_dir / "cache", "lamp_in_fog")
    ref = (a + b) / 2
    mask = light_image_mask(scene)  # the lamp's own pixels: antialiasing noise, as in caustics
    # each half's error is √2 × the mean's, and the halves' difference √2 × one half's
    ref_err = masked_errors(a, b, mask)[KEY] / 2

    def score(image):
        return errors(image, ref, mask)

    spps = [4, 8, 16] if args.quick else [4, 8, 16, 32, 64, 128, 256, 512, 1024]
    runs = []
    for _ in range(args.runs):  # interleaved: a load change on the shared machine hits both
        volpath = mitsuba_curve(scene, spps, score, label="volpath")
        sppm, rates = run_sppm(str(SCENE), score, args.seconds)
        runs.append((headline(volpath, sppm, args.target_spp, ref_err), volpath, sppm, rates))
    ratio = "sppm_time_ratio_at_equal_block_rmse"
    runs.sort(key=lambda run: run[0][ratio])
    head, volpath, sppm, rates = runs[len(runs) // 2]
    result = {
        "headline": {**head, "runs": [run[0][ratio] for run in runs]},
        "volpath": volpath,
        "sppm": sppm,
        "sppm_rates": rates,
        "machine": report.machine_info(),
        "load_average": [load, os.getloadavg()[0]],
        "git": report.git_revision(),
        "args": {k: v for k, v in vars(args).items() if k != "out_dir"},
    }
    text = markdown(result)
    return report.publish(report.results_stem(args.out_dir, NAME, args.quick), result, text)


if __name__ == "__main__":
    main()
