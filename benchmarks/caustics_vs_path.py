"""SPPM (Hachisuka & Jensen 2009) against Mitsuba's ``path`` (and the two-pass ``surface``
method) on caustic scenes: time to equal error.

Scenes: ``glass_sphere`` (examples/glass_sphere_plane.xml: a glass ball on a plane under a
spherical area light), ``glass_knot`` (examples/glass_knot_plane.xml: a procedural glass trefoil
knot of 4088 triangles) and ``cornell`` (the built-in ``cornell_steinhurst``: Cornell box with a
glass and a mirror sphere). References: ``path`` at ``--ref-spp`` samples per pixel in two
halves of different seeds, cached in ``results/cache/`` (not in git); the halves' difference
estimates the reference's own error, reported as ``reference_rel_rmse``.

For each scene: ``path`` at 4 … 4096 spp (timed renders), ``sppm`` for ``--seconds`` (one run,
the error measured at checkpoints with the clock stopped), ``surface`` at a few budgets. Errors:
relative RMSE per pixel and of 4×4-pixel block means, over the pixels that do not see a light
directly or through mirrors and glass (:func:`accuracy.light_image_mask`: a light's image is
antialiasing noise of the eye samples, the same for every method); whole-image values are kept.
Headline per scene: ``speedup_vs_path_at_equal_rmse`` = the time ``path`` needs (log-log
interpolation, ``t^-1/2`` past its last budget) for the error ``sppm`` reaches in ``--seconds``,
divided by ``--seconds``; its minimum over scenes; the same against the truth
(``..._vs_truth``: the reference's own error, which both methods' errors contain, subtracted in
quadrature — it compresses the raw ratio once ``sppm`` nears it) and for 4×4 block errors;
photons/s and visible-point gathers/s of the SPPM run.

Writes ``results/caustics_vs_path.json``, ``.md``, ``.png`` (error-vs-time curves) and each
scene's SPPM image ``caustics_<scene>_sppm.png`` (``_quick`` with ``--quick``).

    .venv/bin/python benchmarks/caustics_vs_path.py [--quick] [--seconds 30]
"""

from __future__ import annotations

import time
from pathlib import Path

import mitsuba as mi
import numpy as np

import report
from accuracy import (
    cached_image,
    errors,
    light_image_mask,
    loglog_time_for,
    mitsuba_curve,
    reference_noise,
    render_passes,
    vs_truth,
)
from photonmap.core.image import write_image
from photonmap.scenes import load_scene
from photonmap.sppm import SPPMPipeline
from photonmap.surface.pipeline import SurfacePipeline
from timing import checkpoints, timed

NAME = "caustics_vs_path"
EXAMPLES = report.REPO / "examples"
SCENES = {  # name → (source, full size, quick size)
    "glass_sphere": (str(EXAMPLES / "glass_sphere_plane.xml"), (160, 120), (48, 36)),
    "glass_knot": (str(EXAMPLES / "glass_knot_plane.xml"), (160, 120), (48, 36)),
    "cornell": ("cornell_steinhurst", (128, 128), (40, 40)),
}
MAX_DEPTH = 12
CHECKPOINTS = (1, 2, 4, 8, 15, 30, 60, 120)  # seconds of SPPM compute at which errors are taken
# surface budgets: (global photon paths, caustic photon paths, final-gather rays, spp)
BUDGETS = [(50_000, 300_000, 4, 2), (100_000, 1_000_000, 8, 4), (200_000, 2_000_000, 8, 8)]
QUICK_BUDGETS = [(20_000, 50_000, 2, 1)]
METHODS = ("path", "sppm", "surface")


def load(name: str, size) -> mi.Scene:
    scene, _ = load_scene(SCENES[name][0])
    params = mi.traverse(scene.sensors()[0])
    params["film.size"] = size
    params["film.crop_size"] = size
    params.update()
    return scene


def path_integrator():
    return mi.load_dict({"type": "path", "max_depth": MAX_DEPTH})


def reference(name, scene, size, spp, cache: Path) -> list[np.ndarray]:
    """The two halves of a ``path`` reference at ``spp`` samples per pixel (cached)."""
    return [
        cached_image(
            cache / f"caustics_{name}_{size[0]}x{size[1]}_{spp}spp_{half}.exr",
            lambda h=half: render_passes(
                scene, spp // 2, 512, 100_000 * (h + 1), path_integrator()
            ),
        ).astype(np.float64)
        for half in (0, 1)
    ]


def run_sppm(scene, score, seconds: float, photons: int):
    """One SPPM run of ``seconds`` compute time; errors at the checkpoints (clock stopped)."""
    SPPMPipeline(scene, photons=1000).run(iterations=2)  # compile
    pipe = SPPMPipeline(scene, photons=photons, max_depth=MAX_DEPTH)
    rows = []
    for spent in checkpoints(pipe.step, seconds, CHECKPOINTS):
        image = np.array(pipe.image())
        rows.append({"iterations": pipe.iterations, "seconds": spent,
                     "mean_radius": pipe.mean_radius, **score(image)})  # fmt: skip
        print(f"  sppm {pipe.iterations} it: {spent:.1f} s, rel RMSE {rows[-1]['rel_rmse']:.4f}",
              flush=True)  # fmt: skip
    ms, stats = pipe.timer.ms, dict(pipe.stats)
    rates = {
        "photons_per_s": stats["photons"] / (ms["photon pass"] / 1e3),
        "gathers_per_s": stats["gathers"] / (ms["gather"] / 1e3),
        "eye_paths_per_s": stats["gathers"] / (ms["eye pass"] / 1e3),
        "aimed_fraction_on_specular": (
            stats["aimed_on_specular"] / stats["aimed_photons"] if stats["aimed_photons"] else None
        ),
        "stages_ms": dict(ms),
        "stats": stats,
    }
    return rows, rates, image


def run_surface(scene, score, budgets):
    SurfacePipeline(scene, photons=1000, caustic_photons=1000, fg_rays=1).render()  # compile
    rows = []
    for photons, caustic, fg, spp in budgets:
        pipe = SurfacePipeline(scene, photons=photons, caustic_photons=caustic, fg_rays=fg,
                               spp=spp, max_depth=MAX_DEPTH)  # fmt: skip
        t, image = timed(lambda p=pipe: np.array(p.render()))
        rows.append({"photons": photons, "caustic_photons": caustic, "fg_rays": fg, "spp": spp,
                     "seconds": t, **score(image)})  # fmt: skip
        print(f"  surface {photons}/{caustic}/{fg}/{spp}: {t:.2f} s, "
              f"rel RMSE {rows[-1]['rel_rmse']:.4f}", flush=True)  # fmt: skip
    return rows


def scene_result(name: str, size, args, ref_spp: int, seconds: float) -> tuple[dict, np.ndarray]:
    """The three curves of one scene, its headline and SPPM's last image."""
    scene = load(name, size)
    a, b = reference(name, scene, size, ref_spp, args.out_dir / "cache")
    ref = (a + b) / 2
    mask = light_image_mask(scene)
    ref_error = reference_noise(ref, a - b, mask)["rel_rmse"]

    def score(image):
        return errors(image, ref, mask)

    path_rows = mitsuba_curve(scene, args.spps, score, path_integrator())
    sppm_rows, rates, image = run_sppm(scene, score, seconds, args.photons)
    surface_rows = run_surface(scene, score, args.budgets)
    for row in path_rows + sppm_rows + surface_rows:
        row["rel_rmse_vs_truth"] = vs_truth(row["rel_rmse"], ref_error)
    final = sppm_rows[-1]

    def speedup(key: str):
        t = loglog_time_for(path_rows, final[key], key)
        return t / final["seconds"] if t else None

    t_path = loglog_time_for(path_rows, final["rel_rmse"])
    return {
        "image": list(size),
        "reference_spp": ref_spp,
        "reference_rel_rmse": ref_error,
        "headline": {
            "sppm_rel_rmse": final["rel_rmse"],
            "path_seconds_for_that_error": t_path,
            "speedup_vs_path_at_equal_rmse": t_path / final["seconds"] if t_path else None,
            "speedup_vs_path_at_equal_rmse_vs_truth": speedup("rel_rmse_vs_truth"),
            "speedup_vs_path_at_equal_block_rmse": speedup("block_rel_rmse"),
            "surface_seconds_for_that_error": loglog_time_for(surface_rows, final["rel_rmse"]),
            **{k: rates[k] for k in ("photons_per_s", "gathers_per_s")},
            "aimed_fraction_on_specular": rates["aimed_fraction_on_specular"],
        },
        "path": path_rows,
        "sppm": sppm_rows,
        "sppm_rates": rates,
        "surface": surface_rows,
        "load_average_after": report.load_average(),
    }, image


def headline(results: dict, seconds: float, started: float) -> dict:
    def per_scene(key: str) -> dict:
        return {n: r["headline"][key] for n, r in results.items()}

    speedups = per_scene("speedup_vs_path_at_equal_rmse")
    return {
        "sppm_seconds": seconds,
        "speedup_vs_path_at_equal_rmse": speedups,
        "min_speedup_vs_path_at_equal_rmse": min(
            (s for s in speedups.values() if s is not None), default=None
        ),
        "speedup_vs_path_at_equal_rmse_vs_truth": per_scene(
            "speedup_vs_path_at_equal_rmse_vs_truth"
        ),
        "speedup_vs_path_at_equal_block_rmse": per_scene("speedup_vs_path_at_equal_block_rmse"),
        "photons_per_s": per_scene("photons_per_s"),
        "gathers_per_s": per_scene("gathers_per_s"),
        "runtime_s": time.perf_counter() - started,
    }


def budget_text(method: str, row: dict) -> str:
    if method == "path":
        return f"{row['spp']} spp"
    if method == "sppm":
        return f"{row['iterations']} iterations, r {row['mean_radius']:.3g}"
    return (f"{row['photons']:,} + {row['caustic_photons']:,} paths, {row['fg_rays']} FG, "
            f"{row['spp']} spp")  # fmt: skip


def markdown(out: dict) -> str:
    records = [
        {"scene": name, "method": method, **r}
        for name, res in out["scenes"].items()
        for method in METHODS
        for r in res[method]
    ]
    table = report.records_table(
        records,
        [
            ("scene", "scene", None),
            ("method", "method", None),
            ("budget", lambda r: budget_text(r["method"], r), None),
            ("seconds", "seconds", 2),
            ("rel. RMSE", "rel_rmse", 4),
            ("4×4 block rel. RMSE", "block_rel_rmse", 4),
        ],
    )
    refs = "\n".join(
        f"- {n}: reference {r['reference_spp']} spp, its own rel. RMSE "
        f"{r['reference_rel_rmse']:.4f}; load after {r['load_average_after']}"
        for n, r in out["scenes"].items()
    )
    return table + "\n\n" + report.bullets(out["headline"]) + "\n\n" + refs + "\n"


def plot(results: dict, path: Path) -> None:
    with report.figure(path, 1, len(results), size=(4.5 * len(results), 3.8)) as axes:
        for ax, (name, res) in zip(axes[0], results.items(), strict=True):
            curves = {"Mitsuba path": res["path"], "sppm": res["sppm"], "surface": res["surface"]}
            report.loglog_curves(ax, curves, "seconds", "rel_rmse")
            ax.axhline(res["reference_rel_rmse"], color="grey", lw=0.6, ls=":", label="reference")
            ax.set(title=name, xlabel="wall time (s)", ylabel="relative RMSE")
            ax.legend(fontsize=8)


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "tiny images and budgets (smoke)")
    parser.add_argument("--seconds", type=float, default=30.0, help="SPPM compute time")
    parser.add_argument("--photons", type=int, default=100_000, help="SPPM photons/iteration")
    parser.add_argument("--ref-spp", type=int, default=16384, help="path reference spp")
    parser.add_argument("--scenes", default=",".join(SCENES), help="comma-separated subset")
    args = parser.parse_args(argv)
    seconds = 3.0 if args.quick else args.seconds
    ref_spp = 512 if args.quick else args.ref_spp
    args.spps = [4, 16, 64] if args.quick else [4, 16, 64, 256, 1024, 4096]
    args.budgets = QUICK_BUDGETS if args.quick else BUDGETS
    results, started = {}, time.perf_counter()
    for name in args.scenes.split(","):
        size = SCENES[name][2 if args.quick else 1]
        print(f"{name} {size[0]}x{size[1]}", flush=True)
        results[name], image = scene_result(name, size, args, ref_spp, seconds)
        sppm_image = report.results_stem(args.out_dir, f"caustics_{name}_sppm", args.quick)
        write_image(str(sppm_image.with_suffix(".png")), image)
    out = {"machine": report.machine_info(), "headline": headline(results, seconds, started),
           "scenes": results, "sppm_photons_per_iteration": args.photons}  # fmt: skip
    stem = report.results_stem(args.out_dir, NAME, args.quick)
    text = markdown(out)
    plot(results, stem.with_suffix(".png"))
    return report.publish(stem, out, text)


if __name__ == "__main__":
    main()
