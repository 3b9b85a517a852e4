"""SPPM against Mitsuba's ``path`` (and the two-pass ``surface`` method) on caustic scenes
(issue 12 item 5).

Scenes: ``glass_sphere`` (examples/glass_sphere_plane.xml: a glass ball on a plane under a
spherical area light), ``glass_knot`` (examples/glass_knot_plane.xml: a procedural glass trefoil
knot of 4088 triangles) and ``cornell`` (the built-in ``cornell_steinhurst``: Cornell box with a
glass and a mirror sphere). References: ``path`` at ``--ref-spp`` samples per pixel in two
halves of different seeds, cached in ``results/cache/`` (not in git); the halves' difference
estimates the reference's own error, reported as ``reference_rel_rmse``.

For each scene: ``path`` at 4 … 1024 spp (timed renders), ``sppm`` for ``--seconds`` (one run,
the error measured at checkpoints with the clock stopped), ``surface`` at a few budgets. Errors:
relative RMSE per pixel and of 4×4-pixel block means, over the pixels that do not see a light
directly or through mirrors and glass (``surface_vs_path.light_image_mask``: a light's image is
antialiasing noise of the eye samples, the same for every method); whole-image values are kept.
Headline per scene: ``speedup_vs_path_at_equal_rmse`` = the time ``path`` needs (log-log
interpolation, ``t^-1/2`` past its last budget) for the error ``sppm`` reaches in ``--seconds``,
divided by ``--seconds``; its minimum over scenes; the same against the truth
(``..._vs_truth``: the reference's own error, which both methods' errors contain, subtracted in
quadrature — it compresses the raw ratio once ``sppm`` nears it) and for 4×4 block errors;
photons/s and visible-point gathers/s of the SPPM run.

Writes ``results/caustics_vs_path.json``, ``.md`` and ``.png`` (error-vs-time curves).

    .venv/bin/python benchmarks/caustics_vs_path.py [--quick] [--seconds 30]
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
from photonmap.core.image import block_means, write_image  # noqa: E402
from photonmap.scenes import load_scene  # noqa: E402
from photonmap.sppm import SPPMPipeline  # noqa: E402
from photonmap.surface.pipeline import SurfacePipeline  # noqa: E402
from surface_vs_path import light_image_mask, loglog_time_for  # noqa: E402

EXAMPLES = common.REPO / "examples"
SCENES = {  # name → (source, full size, quick size)
    "glass_sphere": (str(EXAMPLES / "glass_sphere_plane.xml"), (160, 120), (48, 36)),
    "glass_knot": (str(EXAMPLES / "glass_knot_plane.xml"), (160, 120), (48, 36)),
    "cornell": ("cornell_steinhurst", (128, 128), (40, 40)),
}
MAX_DEPTH = 12
CHECKPOINTS = (1, 2, 4, 8, 15, 30, 60, 120)  # seconds of SPPM compute at which errors are taken


def load(name: str, size) -> mi.Scene:
    source = SCENES[name][0]
    scene, _ = load_scene(source)
    params = mi.traverse(scene.sensors()[0])
    params["film.size"] = size
    params["film.crop_size"] = size
    params.update()
    return scene


def reference(name, scene, size, spp, cache: Path):
    """The two halves of a ``path`` reference at ``spp`` samples per pixel (cached)."""
    halves = []
    for half in (0, 1):
        path = cache / f"caustics_{name}_{size[0]}x{size[1]}_{spp}spp_{half}.exr"
        if not path.exists():
            cache.mkdir(parents=True, exist_ok=True)
            integrator = mi.load_dict({"type": "path", "max_depth": MAX_DEPTH})
            passes = max(1, spp // 2 // 512)
            image = sum(
                np.array(
                    mi.render(scene, integrator=integrator, spp=spp // 2 // passes,
                              seed=100_000 * (half + 1) + i)
                )  # fmt: skip
                for i in range(passes)
            ) / passes
            write_image(str(path), image)
        halves.append(np.array(mi.Bitmap(str(path)), dtype=np.float64)[..., :3])
    return halves


def errors(image, ref, mask) -> dict:
    """Relative RMSE per pixel and of 4×4 block means over ``mask`` (and over all pixels)."""
    image = np.asarray(image, np.float64)
    mean = ref[mask].mean()
    block_mask = block_means(mask[..., None].astype(float))[..., 0] == 1
    d_blocks = block_means(image) - block_means(ref)
    return {
        "rel_rmse": float(np.sqrt(np.mean((image - ref)[mask] ** 2)) / mean),
        "block_rel_rmse": float(np.sqrt(np.mean(d_blocks[block_mask] ** 2)) / mean),
        "rel_rmse_full": float(np.sqrt(np.mean((image - ref) ** 2)) / ref.mean()),
        "brightness": float(image[mask].mean() / mean),
    }


def vs_truth(rel_rmse: float, reference_rel_rmse: float) -> float:
    """The relative RMSE against the truth, estimated: the reference's own (independent) error
    adds in quadrature, E|x − ref|² = |x − truth|² + E|ref − truth|², so it is subtracted."""
    return float(np.sqrt(max(rel_rmse**2 - reference_rel_rmse**2, 0.0)))


def run_path(scene, ref, mask, spps):
    integrator = mi.load_dict({"type": "path", "max_depth": MAX_DEPTH})
    mi.render(scene, integrator=integrator, spp=1, seed=7)  # compile
    rows = []
    for spp in spps:
        t, image = common.timed(
            lambda s=spp: np.array(mi.render(scene, integrator=integrator, spp=s, seed=7))
        )
        rows.append({"spp": spp, "seconds": t, **errors(image, ref, mask)})
        print(f"  path {spp} spp: {t:.2f} s, rel RMSE {rows[-1]['rel_rmse']:.4f}", flush=True)
    return rows


def run_sppm(scene, ref, mask, seconds: float, photons: int):
    """One SPPM run of ``seconds`` compute time; errors at the checkpoints (clock stopped)."""
    SPPMPipeline(scene, photons_per_iteration=1000).run(iterations=2)  # compile
    pipe = SPPMPipeline(scene, photons_per_iteration=photons, max_depth=MAX_DEPTH)
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
            image = np.array(pipe.image())
            rows.append(
                {"iterations": pipe.iterations, "seconds": spent,
                 "mean_radius": pipe.mean_radius, **errors(image, ref, mask)}
            )  # fmt: skip
            print(
                f"  sppm {pipe.iterations} it: {spent:.1f} s, rel RMSE {rows[-1]['rel_rmse']:.4f}",
                flush=True,
            )
    ms = pipe.timer.ms
    stats = dict(pipe.stats)
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


def run_surface(scene, ref, mask, budgets):
    SurfacePipeline(scene, photons=1000, caustic_photons=1000, fg_rays=1).render()  # compile
    rows = []
    for photons, caustic, fg, spp in budgets:
        pipe = SurfacePipeline(
            scene, photons=photons, caustic_photons=caustic, fg_rays=fg, spp=spp,
            max_depth=MAX_DEPTH,
        )  # fmt: skip
        t, image = common.timed(lambda p=pipe: np.array(p.render()))
        rows.append(
            {"photons": photons, "caustic_photons": caustic, "fg_rays": fg, "spp": spp,
             "seconds": t, **errors(image, ref, mask)}
        )  # fmt: skip
        print(f"  surface {photons}/{caustic}/{fg}/{spp}: {t:.2f} s, "
              f"rel RMSE {rows[-1]['rel_rmse']:.4f}", flush=True)  # fmt: skip
    return rows


def plot(results: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(4.5 * len(results), 3.8), squeeze=False)
    for ax, (name, res) in zip(axes[0], results.items(), strict=True):
        for key, label in (("path", "Mitsuba path"), ("sppm", "sppm"), ("surface", "surface")):
            rows = res[key]
            ax.loglog([r["seconds"] for r in rows], [r["rel_rmse"] for r in rows], "o-",
                      label=label)  # fmt: skip
        ax.axhline(res["reference_rel_rmse"], color="grey", lw=0.6, ls=":", label="reference")
        ax.set_title(name)
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel("relative RMSE")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny images and budgets (smoke)")
    parser.add_argument("--seconds", type=float, default=30.0, help="SPPM compute time")
    parser.add_argument("--photons", type=int, default=100_000, help="SPPM photons/iteration")
    parser.add_argument("--ref-spp", type=int, default=16384, help="path reference spp")
    parser.add_argument("--scenes", default=",".join(SCENES), help="comma-separated subset")
    parser.add_argument("--out-dir", type=Path, default=common.RESULTS)
    args = parser.parse_args(argv)
    seconds = 3.0 if args.quick else args.seconds
    ref_spp = 512 if args.quick else args.ref_spp
    spps = [4, 16, 64] if args.quick else [4, 16, 64, 256, 1024, 4096]
    budgets = (
        [(20_000, 50_000, 2, 1)]
        if args.quick
        else [(50_000, 300_000, 4, 2), (100_000, 1_000_000, 8, 4), (200_000, 2_000_000, 8, 8)]
    )
    results, started = {}, time.perf_counter()
    for name in args.scenes.split(","):
        size = SCENES[name][2 if args.quick else 1]
        print(f"{name} {size[0]}x{size[1]}", flush=True)
        scene = load(name, size)
        a, b = reference(name, scene, size, ref_spp, args.out_dir / "cache")
        ref = (a + b) / 2
        mask = light_image_mask(scene)
        ref_error = float(np.sqrt(np.mean((a - b)[mask] ** 2) / 4) / ref[mask].mean())
        path_rows = run_path(scene, ref, mask, spps)
        sppm_rows, rates, image = run_sppm(scene, ref, mask, seconds, args.photons)
        surface_rows = run_surface(scene, ref, mask, budgets)
        for row in path_rows + sppm_rows + surface_rows:
            row["rel_rmse_vs_truth"] = vs_truth(row["rel_rmse"], ref_error)
        final = sppm_rows[-1]
        t_path = loglog_time_for(path_rows, final["rel_rmse"])
        t_truth = loglog_time_for(path_rows, final["rel_rmse_vs_truth"], "rel_rmse_vs_truth")
        t_path_blocks = loglog_time_for(path_rows, final["block_rel_rmse"], "block_rel_rmse")
        t_surface = loglog_time_for(surface_rows, final["rel_rmse"])
        results[name] = {
            "image": list(size),
            "reference_spp": ref_spp,
            "reference_rel_rmse": ref_error,
            "headline": {
                "sppm_rel_rmse": final["rel_rmse"],
                "path_seconds_for_that_error": t_path,
                "speedup_vs_path_at_equal_rmse": t_path / final["seconds"] if t_path else None,
                "speedup_vs_path_at_equal_rmse_vs_truth": (
                    t_truth / final["seconds"] if t_truth else None
                ),
                "speedup_vs_path_at_equal_block_rmse": (
                    t_path_blocks / final["seconds"] if t_path_blocks else None
                ),
                "surface_seconds_for_that_error": t_surface,
                "photons_per_s": rates["photons_per_s"],
                "gathers_per_s": rates["gathers_per_s"],
                "aimed_fraction_on_specular": rates["aimed_fraction_on_specular"],
            },
            "path": path_rows,
            "sppm": sppm_rows,
            "sppm_rates": rates,
            "surface": surface_rows,
            "load_average_after": [round(x, 2) for x in os.getloadavg()],
        }
        write_image(str(args.out_dir / f"caustics_{name}_sppm{'_quick' if args.quick else ''}.png"),
                    image)  # fmt: skip
    speedups = [r["headline"]["speedup_vs_path_at_equal_rmse"] for r in results.values()]
    headline = {
        "sppm_seconds": seconds,
        "speedup_vs_path_at_equal_rmse": {
            n: r["headline"]["speedup_vs_path_at_equal_rmse"] for n, r in results.items()
        },
        "min_speedup_vs_path_at_equal_rmse": min(
            (s for s in speedups if s is not None), default=None
        ),
        "speedup_vs_path_at_equal_rmse_vs_truth": {
            n: r["headline"]["speedup_vs_path_at_equal_rmse_vs_truth"] for n, r in results.items()
        },
        "speedup_vs_path_at_equal_block_rmse": {
            n: r["headline"]["speedup_vs_path_at_equal_block_rmse"] for n, r in results.items()
        },
        "photons_per_s": {n: r["headline"]["photons_per_s"] for n, r in results.items()},
        "gathers_per_s": {n: r["headline"]["gathers_per_s"] for n, r in results.items()},
        "runtime_s": time.perf_counter() - started,
    }
    out = {"machine": common.machine_info(), "headline": headline, "scenes": results,
           "sppm_photons_per_iteration": args.photons}  # fmt: skip
    stem = "caustics_vs_path_quick" if args.quick else "caustics_vs_path"
    common.write_json(args.out_dir / f"{stem}.json", out)
    plot(results, args.out_dir / f"{stem}.png")
    table = common.markdown_table(
        ["scene", "method", "budget", "seconds", "rel. RMSE", "4×4 block rel. RMSE"],
        [
            [name, method, budget(method, r), common.fmt(r["seconds"], 2),
             common.fmt(r["rel_rmse"], 4), common.fmt(r["block_rel_rmse"], 4)]
            for name, res in results.items()
            for method in ("path", "sppm", "surface")
            for r in res[method]
        ],  # fmt: skip
    )
    summary = "\n".join(f"- {k}: {v}" for k, v in headline.items())
    refs = "\n".join(
        f"- {n}: reference {r['reference_spp']} spp, its own rel. RMSE "
        f"{r['reference_rel_rmse']:.4f}; load after {r['load_average_after']}"
        for n, r in results.items()
    )
    common.write_text(args.out_dir / f"{stem}.md", table + "\n\n" + summary + "\n\n" + refs + "\n")
    print(table)
    print(summary)
    print(refs)
    return out


def budget(method: str, row: dict) -> str:
    if method == "path":
        return f"{row['spp']} spp"
    if method == "sppm":
        return f"{row['iterations']} iterations, r {row['mean_radius']:.3g}"
    return (f"{row['photons']:,} + {row['caustic_photons']:,} paths, {row['fg_rays']} FG, "
            f"{row['spp']} spp")  # fmt: skip


if __name__ == "__main__":
    main()
