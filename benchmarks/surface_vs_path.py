"""Surface photon mapping against Mitsuba's ``path`` on ``cornell_steinhurst`` (issue 3 item 7).

A high-sample ``path`` render is the reference (4096 spp, cached in ``results/cache/``, not in git;
the scene's film uses a box pixel filter, as photonmap does). Both methods are then run at several
budgets; for each run the wall time and the relative RMSE (RMSE / mean of the reference) are
recorded — over the pixels that do not see the light, directly or through the mirror and glass
spheres (:func:`light_image_mask`; the whole-image value is kept as ``rel_rmse_full``). The
headline is the time ``path`` needs for the error it reaches in 60 s (interpolated in log-log,
extrapolated with RMSE ∝ t^−½ past the last budget) divided by the time photon mapping needs for
that error (interpolated along its own curve), plus photons traced per second and k = 100 gathers
per second for the hash grid and the kd-tree.

Writes ``results/surface_vs_path.json``, ``.md`` and ``surface_vs_path.png``.

    .venv/bin/python benchmarks/surface_vs_path.py [--quick]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

import common  # noqa: E402
import photonmap  # noqa: E402,F401
from photonmap.core.camera import pixel_rays  # noqa: E402
from photonmap.core.eye_trace import trace_eye_paths  # noqa: E402
from photonmap.core.hashgrid import HashGrid  # noqa: E402
from photonmap.core.image import compare, write_image  # noqa: E402
from photonmap.core.media import broadcast  # noqa: E402
from photonmap.core.photon_trace import trace_photons  # noqa: E402
from photonmap.core.sampling import rng  # noqa: E402
from photonmap.core.scene_info import SceneTraits  # noqa: E402
from photonmap.core.settings import PathSettings  # noqa: E402
from photonmap.scenes import SCENES  # noqa: E402
from photonmap.surface.kdtree import KDTree  # noqa: E402
from photonmap.surface.pipeline import STAGES, SurfacePipeline  # noqa: E402

PATH_TARGET_S = 60.0


def reference(scene, size: int, spp: int, cache: Path) -> np.ndarray:
    path = cache / f"cornell_steinhurst_path_{size}_{spp}spp.exr"
    if path.exists():
        return np.array(mi.Bitmap(str(path)), dtype=np.float32)[..., :3]
    cache.mkdir(parents=True, exist_ok=True)
    integrator = mi.load_dict({"type": "path", "max_depth": 16})
    image = None
    passes = max(1, spp // 256)
    for i in range(passes):  # 256 spp a pass keeps the wavefront in memory
        part = np.array(mi.render(scene, integrator=integrator, spp=spp // passes, seed=1000 + i))
        image = part if image is None else image + part
    image /= passes
    write_image(str(path), image)
    return image


def errors(image, ref, mask) -> dict:
    """RMSE, relative RMSE and PSNR over the whole image, and the relative RMSE over ``mask``
    (the pixels that do not see the light), which is the headline metric."""
    out = compare(image, ref)
    d = (np.asarray(image, np.float64) - ref)[mask]
    out["rel_rmse_full"] = out["rel_rmse"]
    out["rel_rmse"] = float(np.sqrt(np.mean(d**2)) / np.mean(ref[mask]))
    return out


def light_image_mask(scene, spp: int = 64) -> np.ndarray:
    """Pixels that see no emitter, neither directly nor through mirrors and glass, nor next to
    one that does. Those pixels are the light's images: an 18 W/m²/sr source a few pixels wide
    whose edges both methods antialias with the same pixel jitter (photon mapping follows the
    same specular eye paths as ``path``), so their noise says nothing about the light transport
    being compared and at low sample counts it swamps every other error in the image."""
    from scipy.ndimage import binary_dilation

    sensor = scene.sensors()[0]
    w, h = (int(c) for c in sensor.film().crop_size())
    lanes = w * h * spp
    gen = rng(lanes, 12345, 0)
    pixel = dr.arange(mi.UInt32, lanes) // spp
    ray, weight = pixel_rays(sensor, pixel, mi.Point2f(gen.next_float32(), gen.next_float32()))
    emitted = trace_eye_paths(
        scene, ray, weight, broadcast(None, lanes), gen, PathSettings(16), SceneTraits.of(scene),
        media_mode="transmit",
    ).radiance
    seen = np.array(dr.block_reduce(dr.ReduceOp.Add, dr.max(emitted), spp)).reshape(h, w) / spp
    return ~binary_dilation(seen > 0.01, iterations=1)


def run_path(scene, ref, mask, spps):
    integrator = mi.load_dict({"type": "path", "max_depth": 16})
    rows = []
    for spp in spps:
        mi.render(scene, integrator=integrator, spp=1, seed=7)  # warm-up (compile)
        t, image = common.timed(
            lambda s=spp: np.array(mi.render(scene, integrator=integrator, spp=s, seed=7))
        )
        rows.append({"spp": spp, "seconds": t, **errors(image, ref, mask)})
        print(f"path spp={spp}: {t:.2f} s rel RMSE {rows[-1]['rel_rmse']:.4f}", flush=True)
    return rows


def run_photon_mapping(scene, ref, mask, budgets):
    rows = []
    SurfacePipeline(scene, photons=1000, caustic_photons=1000, fg_rays=1).render()  # compile
    last = None
    for photons, caustic, fg, spp in budgets:
        pipe = SurfacePipeline(scene, photons=photons, caustic_photons=caustic, fg_rays=fg, spp=spp)
        t, image = common.timed(lambda p=pipe: np.array(p.render()))
        rows.append(
            {
                "photons": photons,
                "caustic_photons": caustic,
                "fg_rays": fg,
                "spp": spp,
                "seconds": t,
                "stages_ms": dict(pipe.timer.ms),
                **errors(image, ref, mask),
            }
        )
        print(
            f"pm photons={photons} fg={fg} spp={spp}: {t:.2f} s rel RMSE "
            f"{rows[-1]['rel_rmse']:.4f}",
            flush=True,
        )
        last = image
    return rows, last


def loglog_time_for(rows, error, key="rel_rmse"):
    """Time at which a (time, error) curve reaches ``error``: log-log interpolation, RMSE ∝ t^−½
    past the end; None if the curve never gets there."""
    t = np.array([r["seconds"] for r in rows])
    e = np.array([r[key] for r in rows])
    order = np.argsort(t)
    t, e = t[order], e[order]
    for i in range(len(t) - 1):
        if e[i] >= error >= e[i + 1]:
            f = (math.log(error) - math.log(e[i])) / (math.log(e[i + 1]) - math.log(e[i]))
            return math.exp(math.log(t[i]) + f * (math.log(t[i + 1]) - math.log(t[i])))
    if error <= e[-1]:
        return t[-1] * (e[-1] / error) ** 2
    return t[0] * (e[0] / error) ** 2 if error > e[0] else None


def loglog_error_at(rows, seconds, key="rel_rmse"):
    t = np.array([r["seconds"] for r in rows])
    e = np.array([r[key] for r in rows])
    order = np.argsort(t)
    t, e = t[order], e[order]
    if seconds >= t[-1]:
        return e[-1] * math.sqrt(t[-1] / seconds)
    return float(np.exp(np.interp(np.log(seconds), np.log(t), np.log(e))))


def throughput(scene, photons: int, queries: int, runs: int = 3) -> dict:
    def trace(count):
        return trace_photons(scene, count, PathSettings(9, 3)).records

    trace(10_000)
    t_trace = common.median(common.timed(trace, photons)[0] for _ in range(runs))
    records = trace(photons)
    q = dr.gather(
        mi.Point3f,
        records.position,
        dr.arange(mi.UInt32, 0, records.count, max(1, records.count // queries)),
    )
    n = dr.gather(
        mi.Vector3f,
        records.normal,
        dr.arange(mi.UInt32, 0, records.count, max(1, records.count // queries)),
    )
    out = {"photon_paths": photons, "records": records.count, "photons_per_s": photons / t_trace}
    for name, cls in (("hash", HashGrid), ("kdtree", KDTree)):
        structure = cls(records.position)

        def gather(s=structure):
            found = s.knn(
                q,
                k=100,
                max_radius=0.1,
                query_normal=n,
                normals=records.normal,
                directions=records.direction,
            )
            dr.eval(found.index, found.count, found.radius2)  # timed only if evaluated
            return found

        gather()
        t = common.median(common.timed(gather)[0] for _ in range(runs))
        out[f"gathers_per_s_{name}"] = dr.width(q.x) / t
    return out


def update_throughput(scene, path: Path) -> dict:
    """Re-measure :func:`throughput` and store it in the result JSON at ``path``."""
    import json

    result = json.loads(path.read_text())
    rates = throughput(scene, 1_000_000, 65536)
    result["throughput"] = rates
    for key in ("photons_per_s", "gathers_per_s_hash", "gathers_per_s_kdtree"):
        result["headline"][key] = rates[key]
    common.write_json(path, result)
    print(rates)
    return result


def plot(path_rows, pm_rows, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for rows, label in ((path_rows, "Mitsuba path"), (pm_rows, "photon mapping")):
        ax.loglog([r["seconds"] for r in rows], [r["rel_rmse"] for r in rows], "o-", label=label)
    ax.axvline(PATH_TARGET_S, color="grey", lw=0.5)
    ax.set_xlabel("wall time (s)")
    ax.set_ylabel("relative RMSE vs reference")
    ax.set_title("cornell_steinhurst, 512×512")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=120)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="64×64, few budgets (smoke test)")
    parser.add_argument("--out-dir", type=Path, default=common.RESULTS)
    parser.add_argument(
        "--throughput-only",
        action="store_true",
        help="re-measure photons/s and gathers/s into an existing result JSON",
    )
    args = parser.parse_args(argv)
    size = 64 if args.quick else 512
    scene = mi.load_dict(SCENES["cornell_steinhurst"].build(width=size, height=size))
    if args.throughput_only:
        return update_throughput(scene, args.out_dir / "surface_vs_path.json")
    ref_spp = 256 if args.quick else 4096
    ref = reference(scene, size, ref_spp, args.out_dir / "cache")
    spps = [1, 4, 16] if args.quick else [1, 4, 16, 64, 256]
    budgets = (  # (global photon paths, caustic photon paths, final-gather rays, spp)
        [(20_000, 100_000, 4, 2), (50_000, 200_000, 4, 4)]
        if args.quick
        else [
            (50_000, 500_000, 4, 2),
            (100_000, 1_000_000, 4, 4),
            (100_000, 1_000_000, 8, 4),
            (200_000, 2_000_000, 8, 8),
            (400_000, 4_000_000, 16, 8),
        ]
    )
    mask = light_image_mask(scene)
    path_rows = run_path(scene, ref, mask, spps)
    pm_rows, last = run_photon_mapping(scene, ref, mask, budgets)
    error_60 = loglog_error_at(path_rows, PATH_TARGET_S)
    t_path = loglog_time_for(path_rows, error_60)
    t_pm = loglog_time_for(pm_rows, error_60)
    full_60 = loglog_error_at(path_rows, PATH_TARGET_S, "rel_rmse_full")
    t_pm_full = loglog_time_for(pm_rows, full_60, "rel_rmse_full")
    rates = throughput(scene, 100_000 if args.quick else 1_000_000, 4096 if args.quick else 65536)
    headline = {
        "path_rel_rmse_at_60s": error_60,
        "path_seconds_for_that_error": t_path,
        "photon_mapping_seconds_for_that_error": t_pm,
        "speedup_vs_path_at_equal_rmse": (t_path / t_pm) if t_pm else None,
        "whole_image": {  # the same with the light and its specular images counted
            "path_rel_rmse_at_60s": full_60,
            "photon_mapping_seconds_for_that_error": t_pm_full,
            "speedup_vs_path_at_equal_rmse": (
                loglog_time_for(path_rows, full_60, "rel_rmse_full") / t_pm_full
                if t_pm_full
                else None
            ),
        },
        "photons_per_s": rates["photons_per_s"],
        "gathers_per_s_hash": rates["gathers_per_s_hash"],
        "gathers_per_s_kdtree": rates["gathers_per_s_kdtree"],
    }
    name = "surface_vs_path_quick" if args.quick else "surface_vs_path"
    result = {
        "machine": common.machine_info(),
        "image": [size, size],
        "reference_spp": ref_spp,
        "headline": headline,
        "path": path_rows,
        "photon_mapping": pm_rows,
        "throughput": rates,
    }
    common.write_json(args.out_dir / f"{name}.json", result)
    write_image(str(args.out_dir / f"{name}_photonmap.png"), last)
    plot(path_rows, pm_rows, args.out_dir / f"{name}.png")
    table = common.markdown_table(
        ["method", "budget", "seconds", "rel. RMSE (light's images masked)", "rel. RMSE (all)"],
        [
            [
                "path",
                f"{r['spp']} spp",
                common.fmt(r["seconds"], 2),
                common.fmt(r["rel_rmse"], 4),
                common.fmt(r["rel_rmse_full"], 4),
            ]
            for r in path_rows
        ]
        + [
            [
                "photon mapping",
                f"{r['photons']:,} + {r['caustic_photons']:,} paths, {r['fg_rays']} FG rays, "
                f"{r['spp']} spp",
                common.fmt(r["seconds"], 2),
                common.fmt(r["rel_rmse"], 4),
                common.fmt(r["rel_rmse_full"], 4),
            ]
            for r in pm_rows
        ],
    )
    stages = common.markdown_table(
        ["photon mapping budget", *STAGES],
        [
            [f"{r['photons']:,} / {r['fg_rays']} FG / {r['spp']} spp"]
            + [common.fmt(r["stages_ms"].get(stage, 0.0), 0) for stage in STAGES]
            for r in pm_rows
        ],
    )

    def cell(v):
        if isinstance(v, dict):
            return ", ".join(f"{k} {cell(x)}" for k, x in v.items())
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    summary = "\n".join(f"- {k}: {cell(v)}" for k, v in headline.items())
    common.write_text(
        args.out_dir / f"{name}.md",
        table + "\n\nPer-stage ms:\n\n" + stages + "\n\n" + summary + "\n",
    )
    print(table)
    print(summary)
    return result


if __name__ == "__main__":
    main()
