"""SPPM against Mitsuba's ``volpath`` on a scene with participating media and no caustics: time to
equal error.

Scene: ``lamp_in_fog`` (examples/lamp_in_fog.xml: a small spherical lamp inside a box of fog
standing on a diffuse floor, a rough-plastic block in the fog; Mitsuba's default gaussian film
filter). SPPM's eye paths run through the fog by volumetric path tracing (equiangular direct light
along each piece, free-flight collisions), its photons light the floor and the block. Reference:
``volpath`` at ``--ref-spp`` in two halves of different seeds (cached in ``results/cache/``), the
halves' difference estimating the reference's own error. ``volpath`` at 4 … 1024 spp (timed
renders) and SPPM (default parameters, one run, errors at checkpoints with the clock stopped).
Errors leave out the pixels that see the lamp (``surface_vs_path.light_image_mask``: its image is
antialiasing noise of the eye samples, the same for every method, and would swamp the rest).

Headline: ``sppm_time_ratio_at_equal_block_rmse`` — the time SPPM needs for the 4×4-block error
that ``volpath`` reaches at ``--target-spp`` (the file's own sample count), divided by the time
``volpath`` needs (log-log interpolation of both curves); the same at 256 and 1024 spp in
``time_ratios``. The goal is at most 2.

Writes ``results/media_vs_volpath.json`` and ``.md``.

    .venv/bin/python benchmarks/media_vs_volpath.py [--quick] [--seconds 60]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import mitsuba as mi  # noqa: E402

import common  # noqa: E402
import photonmap  # noqa: E402,F401
from caustics_vs_path import errors, vs_truth  # noqa: E402
from photonmap.core.image import write_image  # noqa: E402
from photonmap.sppm import SPPMPipeline  # noqa: E402
from surface_vs_path import light_image_mask, loglog_time_for  # noqa: E402

SCENE = common.REPO / "examples" / "lamp_in_fog.xml"
CHECKPOINTS = (0.25, 0.5, 1, 2, 4, 8, 15, 30, 60, 120)


def reference(scene, spp: int, cache: Path, tag: str):
    """The two halves of a ``volpath`` reference at ``spp`` samples per pixel (cached)."""
    halves = []
    for half in (0, 1):
        path = cache / f"media_{tag}_{spp}spp_{half}.exr"
        if not path.exists():
            cache.mkdir(parents=True, exist_ok=True)
            passes = max(1, spp // 2 // 1024)
            image = sum(
                np.array(mi.render(scene, spp=spp // 2 // passes, seed=100_000 * (half + 1) + i))
                for i in range(passes)
            ) / passes
            write_image(str(path), image)
        halves.append(np.array(mi.Bitmap(str(path)), dtype=np.float64)[..., :3])
    return halves


def run_volpath(scene, ref, mask, spps):
    mi.render(scene, spp=1, seed=7)  # compile
    rows = []
    for spp in spps:
        t, image = common.timed(lambda s=spp: np.array(mi.render(scene, spp=s, seed=7)))
        rows.append({"spp": spp, "seconds": t, **errors(image, ref, mask)})
        print(f"  volpath {spp} spp: {t:.2f} s, 4x4 error {rows[-1]['block_rel_rmse']:.4f}",
              flush=True)  # fmt: skip
    return rows


def run_sppm(path: str, ref, mask, seconds: float):
    """One SPPM run (default parameters) of ``seconds`` compute time; errors at checkpoints."""
    pipe = SPPMPipeline(path)
    pipe.run(iterations=2)  # compile every kernel of the run
    pipe.reset()
    rows, spent = [], 0.0
    marks = [c for c in CHECKPOINTS if c < seconds] + [seconds]
    while marks:
        common.sync()
        start = time.perf_counter()
        pipe.step()
        common.sync()
        spent += time.perf_counter() - start
        if spent >= marks[0]:
            while marks and spent >= marks[0]:
                marks.pop(0)
            rows.append({"iterations": pipe.iterations, "seconds": spent,
                         **errors(np.array(pipe.image()), ref, mask)})  # fmt: skip
            print(f"  sppm {pipe.iterations} it: {spent:.1f} s, "
                  f"4x4 error {rows[-1]['block_rel_rmse']:.4f}", flush=True)  # fmt: skip
    return rows, {"stages_ms": dict(pipe.timer.ms), "stats": dict(pipe.stats)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small budgets (a smoke run)")
    ap.add_argument("--seconds", type=float, default=60.0, help="SPPM compute budget")
    ap.add_argument("--ref-spp", type=int, default=32768)
    ap.add_argument("--target-spp", type=int, default=64, help="volpath budget of the headline")
    args = ap.parse_args()
    if args.quick:
        args.seconds, args.ref_spp = 4.0, 2048
    load = os.getloadavg()[0]
    scene = mi.load_file(str(SCENE))
    halves = reference(scene, args.ref_spp, common.RESULTS / "cache", "lamp_in_fog")
    ref = (halves[0] + halves[1]) / 2
    mask = light_image_mask(scene)  # the lamp's own pixels: antialiasing noise, as in caustics
    # each half's error is √2 × the mean's, and the halves' difference √2 × one half's
    ref_err = errors(halves[0], halves[1], mask)["block_rel_rmse"] / 2
    spps = [4, 8, 16] if args.quick else [4, 8, 16, 32, 64, 128, 256, 512, 1024]
    volpath = run_volpath(scene, ref, mask, spps)
    sppm, rates = run_sppm(str(SCENE), ref, mask, args.seconds)
    key = "block_rel_rmse"
    target = next((r[key] for r in volpath if r["spp"] == args.target_spp), volpath[-1][key])
    t_volpath = loglog_time_for(volpath, target, key)
    t_sppm = loglog_time_for(sppm, target, key)
    ratios = {}
    for row in volpath:
        if row["spp"] in (args.target_spp, 256, 1024):
            t = loglog_time_for(sppm, row[key], key)
            ratios[f"{row['spp']} spp"] = None if t is None else t / row["seconds"]
    headline = {
        "target_block_rel_rmse": target,
        "volpath_seconds": t_volpath,
        "sppm_seconds": t_sppm,
        "sppm_time_ratio_at_equal_block_rmse": t_sppm / t_volpath,
        "time_ratios": ratios,
        "goal": "<= 2",
        "reference_block_rel_rmse": ref_err,
        "sppm_final_block_rel_rmse_vs_truth": vs_truth(sppm[-1][key], ref_err),
    }
    machine = common.machine_info()
    load_end = os.getloadavg()[0]
    result = {"headline": headline, "volpath": volpath, "sppm": sppm, "sppm_rates": rates,
              "machine": machine, "load_average": [load, load_end],
              "git": common.git_revision(), "args": vars(args)}  # fmt: skip
    common.write_json(common.RESULTS / "media_vs_volpath.json", result)
    rows = [[f"volpath {r['spp']} spp", common.fmt(r["seconds"], 2), common.fmt(r[key], 4),
             common.fmt(r["brightness"], 3)] for r in volpath]  # fmt: skip
    rows += [[f"sppm {r['iterations']} it", common.fmt(r["seconds"], 2), common.fmt(r[key], 4),
              common.fmt(r["brightness"], 3)] for r in sppm]  # fmt: skip
    table = common.markdown_table(["run", "seconds", "4×4 error", "brightness"], rows)
    text = (f"# SPPM vs volpath on lamp_in_fog\n\nload average {load:.1f} → {load_end:.1f}\n\n"
            f"{table}\n\nvolpath reaches {target:.4f} at {args.target_spp} spp in "
            f"{t_volpath:.2f} s; sppm needs {t_sppm:.2f} s: ratio "
            f"{t_sppm / t_volpath:.2f} (goal ≤ 2); at volpath's errors of "
            + ", ".join(f"{k}: {v:.2f}" for k, v in ratios.items() if v is not None) + "\n")  # fmt: skip
    common.write_text(common.RESULTS / "media_vs_volpath.md", text)
    print(text)


if __name__ == "__main__":
    main()
