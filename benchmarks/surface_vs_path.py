"""Surface photon mapping (Jensen 1996; final gathering, Jensen & Christensen 1998) against
Mitsuba's ``path`` on ``cornell_steinhurst``: time to equal error.

A high-sample ``path`` render is the reference (4096 spp, cached in ``results/cache/``, not in git;
the scene's film uses a box pixel filter, as photonmap does). Both methods are then run at several
budgets; for each run the wall time and the relative RMSE (RMSE / mean of the reference) are
recorded — over the pixels that do not see the light, directly or through the mirror and glass
spheres (:func:`accuracy.light_image_mask`; the whole-image value is kept as ``rel_rmse_full``).
The headline is the time ``path`` needs for the error it reaches in 60 s (interpolated in log-log,
extrapolated with RMSE ∝ t^−½ past the last budget) divided by the time photon mapping needs for
that error (interpolated along its own curve), plus photons traced per second and k = 100 gathers
per second for the hash grid and the kd-tree.

Writes ``results/surface_vs_path.json``, ``.md``, ``.png`` and ``surface_vs_path_photonmap.png``
(``surface_vs_path_quick.*`` with ``--quick``).

    .venv/bin/python benchmarks/surface_vs_path.py [--quick] [--throughput-only]
"""

from __future__ import annotations

import json
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

import report
from accuracy import (
    cached_image,
    light_image_mask,
    loglog_error_at,
    loglog_time_for,
    masked_errors,
    mitsuba_curve,
    render_passes,
)
from photonmap.core.hashgrid import HashGrid
from photonmap.core.image import compare, write_image
from photonmap.core.photon_trace import PhotonRules, trace_photons
from photonmap.core.settings import PathSettings
from photonmap.scenes import SCENES
from photonmap.surface.kdtree import KDTree
from photonmap.surface.pipeline import STAGES, SurfacePipeline
from timing import median, timed

NAME = "surface_vs_path"
PATH_TARGET_S = 60.0
# (global photon paths, caustic photon paths, final-gather rays, spp)
BUDGETS = [
    (50_000, 500_000, 4, 2),
    (100_000, 1_000_000, 4, 4),
    (100_000, 1_000_000, 8, 4),
    (200_000, 2_000_000, 8, 8),
    (400_000, 4_000_000, 16, 8),
]
QUICK_BUDGETS = [(20_000, 100_000, 4, 2), (50_000, 200_000, 4, 4)]


def path_integrator():
    return mi.load_dict({"type": "path", "max_depth": 16})


def reference(scene, size: int, spp: int, cache: Path) -> np.ndarray:
    """``path`` at ``spp`` (passes of 256 spp), cached."""
    return cached_image(
        cache / f"cornell_steinhurst_path_{size}_{spp}spp.exr",
        lambda: render_passes(scene, spp, 256, 1000, path_integrator()),
    )


def errors(image, ref, mask) -> dict:
    """RMSE, relative RMSE and PSNR over the whole image, and the relative RMSE over ``mask``
    (the pixels that do not see the light), which is the headline metric."""
    out = compare(image, ref)
    out["rel_rmse_full"] = out["rel_rmse"]
    out["rel_rmse"] = masked_errors(image, ref, mask)["rel_rmse"]
    return out


def run_photon_mapping(scene, ref, mask, budgets):
    rows, image = [], None
    SurfacePipeline(scene, photons=1000, caustic_photons=1000, fg_rays=1).render()  # compile
    for photons, caustic, fg, spp in budgets:
        pipe = SurfacePipeline(scene, photons=photons, caustic_photons=caustic, fg_rays=fg, spp=spp)
        t, image = timed(lambda p=pipe: np.array(p.render()))
        rows.append(
            {"photons": photons, "caustic_photons": caustic, "fg_rays": fg, "spp": spp,
             "seconds": t, "stages_ms": dict(pipe.timer.ms), **errors(image, ref, mask)}
        )  # fmt: skip
        print(f"pm photons={photons} fg={fg} spp={spp}: {t:.2f} s rel RMSE "
              f"{rows[-1]['rel_rmse']:.4f}", flush=True)  # fmt: skip
    return rows, image


def throughput(scene, photons: int, queries: int, runs: int = 3) -> dict:
    """Photon paths traced per second and k = 100 gathers per second of the hash grid and the
    kd-tree at ``queries`` of the photons' own positions (medians of ``runs``)."""

    def trace(count):
        return trace_photons(scene, count, PhotonRules.of(scene, PathSettings(9, 3))).records

    trace(10_000)
    t_trace = median(timed(trace, photons)[0] for _ in range(runs))
    records = trace(photons)
    index = dr.arange(mi.UInt32, 0, records.count, max(1, records.count // queries))
    q = dr.gather(mi.Point3f, records.position, index)
    n = dr.gather(mi.Vector3f, records.normal, index)
    out = {"photon_paths": photons, "records": records.count, "photons_per_s": photons / t_trace}
    for name, cls in (("hash", HashGrid), ("kdtree", KDTree)):
        structure = cls(records.position)

        def gather(s=structure):
            found = s.knn(q, k=100, max_radius=0.1, query_normal=n, normals=records.normal,
                          directions=records.direction)  # fmt: skip
            dr.eval(found.index, found.count, found.radius2)  # timed only if evaluated
            return found

        gather()
        t = median(timed(gather)[0] for _ in range(runs))
        out[f"gathers_per_s_{name}"] = dr.width(q.x) / t
    return out


def update_throughput(scene, path: Path) -> dict:
    """Re-measure :func:`throughput` and store it in the result JSON at ``path``."""
    result = json.loads(path.read_text())
    rates = throughput(scene, 1_000_000, 65536)
    result["throughput"] = rates
    for key in ("photons_per_s", "gathers_per_s_hash", "gathers_per_s_kdtree"):
        result["headline"][key] = rates[key]
    report.write_json(path, result)
    print(rates)
    return result


def headline(path_rows, pm_rows, rates) -> dict:
    error_60 = loglog_error_at(path_rows, PATH_TARGET_S)
    t_pm = loglog_time_for(pm_rows, error_60)
    full_60 = loglog_error_at(path_rows, PATH_TARGET_S, "rel_rmse_full")
    t_pm_full = loglog_time_for(pm_rows, full_60, "rel_rmse_full")
    t_path_full = loglog_time_for(path_rows, full_60, "rel_rmse_full")
    t_path = loglog_time_for(path_rows, error_60)
    return {
        "path_rel_rmse_at_60s": error_60,
        "path_seconds_for_that_error": t_path,
        "photon_mapping_seconds_for_that_error": t_pm,
        "speedup_vs_path_at_equal_rmse": (t_path / t_pm) if t_pm else None,
        "whole_image": {  # the same with the light and its specular images counted
            "path_rel_rmse_at_60s": full_60,
            "photon_mapping_seconds_for_that_error": t_pm_full,
            "speedup_vs_path_at_equal_rmse": t_path_full / t_pm_full if t_pm_full else None,
        },
        **{k: rates[k] for k in ("photons_per_s", "gathers_per_s_hash", "gathers_per_s_kdtree")},
    }


def budget_text(r: dict) -> str:
    if "photons" not in r:
        return f"{r['spp']} spp"
    return (
        f"{r['photons']:,} + {r['caustic_photons']:,} paths, {r['fg_rays']} FG rays, {r['spp']} spp"
    )


def markdown(result: dict) -> str:
    """The curves, the photon-mapping stages and the headline."""
    table = report.records_table(
        result["path"] + result["photon_mapping"],
        [
            ("method", lambda r: "photon mapping" if "photons" in r else "path", None),
            ("budget", budget_text, None),
            ("seconds", "seconds", 2),
            ("rel. RMSE (light's images masked)", "rel_rmse", 4),
            ("rel. RMSE (all)", "rel_rmse_full", 4),
        ],
    )
    stages = report.records_table(
        result["photon_mapping"],
        [("photon mapping budget", lambda r: f"{r['photons']:,} / {r['fg_rays']} FG / "
          f"{r['spp']} spp", None)]
        + [(s, lambda r, s=s: r["stages_ms"].get(s, 0.0), 0) for s in STAGES],
    )  # fmt: skip

    def cell(v):
        if isinstance(v, dict):
            return ", ".join(f"{k} {cell(x)}" for k, x in v.items())
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    summary = report.bullets({k: cell(v) for k, v in result["headline"].items()})
    return table + "\n\nPer-stage ms:\n\n" + stages + "\n\n" + summary + "\n"


def plot(result: dict, path: Path) -> None:
    curves = {"Mitsuba path": result["path"], "photon mapping": result["photon_mapping"]}
    with report.figure(path, dpi=120) as axes:
        ax = axes[0][0]
        report.loglog_curves(ax, curves, "seconds", "rel_rmse")
        ax.axvline(PATH_TARGET_S, color="grey", lw=0.5)
        ax.set(xlabel="wall time (s)", ylabel="relative RMSE vs reference")
        ax.set_title(f"cornell_steinhurst, {result['image'][0]}×{result['image'][1]}")
        ax.legend()


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "64×64, few budgets (smoke test)")
    parser.add_argument(
        "--throughput-only",
        action="store_true",
        help="re-measure photons/s and gathers/s into an existing result JSON",
    )
    args = parser.parse_args(argv)
    size = 64 if args.quick else 512
    scene = mi.load_dict(SCENES["cornell_steinhurst"].build(width=size, height=size))
    if args.throughput_only:
        return update_throughput(scene, args.out_dir / f"{NAME}.json")
    ref_spp = 256 if args.quick else 4096
    ref = reference(scene, size, ref_spp, args.out_dir / "cache")
    mask = light_image_mask(scene)
    spps = [1, 4, 16] if args.quick else [1, 4, 16, 64, 256]
    path_rows = mitsuba_curve(scene, spps, lambda im: errors(im, ref, mask), path_integrator())
    pm_rows, last = run_photon_mapping(scene, ref, mask, QUICK_BUDGETS if args.quick else BUDGETS)
    rates = throughput(scene, 100_000 if args.quick else 1_000_000, 4096 if args.quick else 65536)
    result = {
        "machine": report.machine_info(),
        "image": [size, size],
        "reference_spp": ref_spp,
        "headline": headline(path_rows, pm_rows, rates),
        "path": path_rows,
        "photon_mapping": pm_rows,
        "throughput": rates,
    }
    stem = report.results_stem(args.out_dir, NAME, args.quick)
    text = markdown(result)
    write_image(str(stem) + "_photonmap.png", last)
    plot(result, stem.with_suffix(".png"))
    return report.publish(stem, result, text)


if __name__ == "__main__":
    main()
