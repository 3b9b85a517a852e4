"""Steinhurst 2007's combined importance sampling (Ch. 6, Tables 6.1, 6.2) and irradiance caching
(Ch. 5, Table 5.1) measured on our renders.

**CIS** — the glossy-floor box (``cornell_glossy_floor``, Beckmann α = 0.33 ≈ Phong n = 16, the
lobe for which Steinhurst calls a 4 × 8 table adequate): the final gather of every strategy
(uniform, cosine, BSDF, Jensen, CIS) at several ray counts N against a reference (the mean of a
BSDF and a cosine render at ``--ref-rays``; its own noise, estimated from their difference, is
subtracted in quadrature). All renders share the seed, so direct light and caustics cancel and
the difference is the final gather's error alone. Relative RMSE over the floor's pixels (and over
the diffuse walls); the rays each strategy needs for the error BSDF sampling reaches at
``--target-rays`` come from log-log interpolation of its RMSE(N) curve (slope −½ beyond it).
Headline ``cis_rays_ratio_vs_brdf`` = rays(CIS) / rays(BSDF) on the floor (O25: ¼–⅓).
The cost table evaluates Tables 6.1–6.2's formulas (P = 100, C_J = 32, C_H = 1024, N_FG = 100,
BRDF = 10) beside the printed numbers, and times our table builds and final gathers.

**Irradiance cache** (:mod:`steinhurst_ic`) — the bare Cornell box and the box with two and with
six "bushes": full final gather, Ward's whole-image cache and the tiled cache at ε_max = 0.05 (and
a sweep of ε_max for the tiled cache): R_IC (hit rate), final gathers saved, photon-map gathers
per image (final-gather rays + the tiled cache's one R_avg lookup per hit), the image error
against a high-ray full final gather, the tile-seam ratio (mean step across tile borders /
elsewhere; Fig 5.6's square artifacts at large ε_max). Headline ``ic_gathers_saved`` = gathers
saved by the tiled cache at ε_max = 0.05 on the bare box. The uncached naive column of Table 5.1
is estimated here as the ratio of photon gathers (naive traffic is proportional to them);
``steinhurst_table_5_1.py`` simulates the whole table, every order with and without the cache.

    .venv/bin/python benchmarks/steinhurst_ic_cis.py [--quick]
"""

from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi
import numpy as np

import photonmap  # noqa: F401 - selects the Mitsuba variant
import report
from accuracy import loglog_between, masked_errors, vs_truth
from photonmap.scenes import cornell
from photonmap.surface.cis import sampling_table
from photonmap.surface.pipeline import SurfacePipeline
from report import fmt, markdown_table
from steinhurst_ic import first_hits, ic_markdown, render, run_ic, shape_hits
from timing import median, timed

NAME = "steinhurst_ic_cis"
SAMPLINGS = ("uniform", "cosine", "bsdf", "jensen", "cis")
# Tables 6.1, 6.2 as printed, and their formulas (P photons, C_J / C_H table cells)
COST_DOC = {
    "jensen": ("4C_J", 128, "3P + 3C_J + 7N_FG", 1096),
    "cis": ("4C_J", 128, "3P + C_J(4 + BRDF) + 7N_FG", 1448),
    "pharr": ("96P", 960, "N_B·BRDF + 5N_P + N_FG(BRDF + 5P + 1)", 51850),
    "hey": ("4C_H + 128P", 6256, "P(8+BRDF) + 2C_H + N_B·BRDF + 6N_P + N_FG(BRDF+5P+1)", 55748),
}


def cost_formulas(P=100, C_J=32, C_H=1024, N=100, BRDF=10) -> dict:
    """Tables 6.1 (bytes) and 6.2 (FLOPs) evaluated (N_B = N_P = N/2)."""
    NB = NP = N // 2
    return {
        "jensen": (4 * C_J, 3 * P + 3 * C_J + 7 * N),
        "cis": (4 * C_J, 3 * P + C_J * (4 + BRDF) + 7 * N),
        "pharr": (96 * P, NB * BRDF + 5 * NP + N * (BRDF + 5 * P + 1)),
        "hey": (
            4 * C_H + 128 * P,
            P * (8 + BRDF) + 2 * C_H + NB * BRDF + 6 * NP + N * (BRDF + 5 * P + 1),
        ),
    }


def shape_mask(pipe: SurfacePipeline, name: str) -> np.ndarray:
    """(h, w) pixels whose centre sees the shape with id ``name``."""
    si, w, h = first_hits(pipe)
    shape = next(s for s in pipe.scene.shapes() if s.id() == name)
    return (si.shape == mi.ShapePtr(shape)).numpy().reshape(h, w)


def rays_for(curve: list[tuple[int, float]], target: float) -> float:
    """Rays at which a RMSE(N) curve reaches ``target`` (log-log interpolation; slope −½ past
    its ends)."""
    n = [c[0] for c in curve]
    e = [max(c[1], 1e-12) for c in curve]
    if target >= e[0]:
        return n[0] * (e[0] / target) ** 2
    if target <= e[-1]:
        return n[-1] * (e[-1] / target) ** 2
    return loglog_between(n, e, target)


def cis_scenes(size: int) -> dict:
    """Fig 6.14's box — the ceiling light replaced by a white disk that a spot light aims at, so
    all light is indirect — with the glossy floor, and Fig 7.5's glossy floor under the ceiling
    light; the floor's lobe is Beckmann α = 0.33 (≈ Phong n = 16) in both."""
    glossy = cornell.cornell_glossy_floor(size, size, roughness=0.33)
    spot = cornell.cornell_spot_indirect(size, size)
    spot["floor"]["bsdf"] = glossy["floor"]["bsdf"]
    return {
        "spot-lit disk, glossy floor (Fig 6.14)": spot,
        "ceiling light, glossy floor (Fig 7.5)": glossy,
    }


def run_cis(scene: dict, photons: int, rays: list[int], ref_rays: int, target_rays: int) -> dict:
    """Every strategy's final gather at each of ``rays`` against a ``ref_rays`` reference, over
    the floor and over the diffuse surfaces, and the rays each needs for BSDF sampling's error
    at ``target_rays``."""
    pipe = SurfacePipeline(scene, photons=photons, caustic_photons=0, emitter_spp=0)
    floor = shape_mask(pipe, "floor")
    masks = {"floor": floor, "diffuse surfaces": shape_hits(pipe).reshape(floor.shape) & ~floor}
    ref_a, _ = render(pipe, fg_sampling="bsdf", fg_rays=ref_rays)
    ref_b, _ = render(pipe, fg_sampling="cosine", fg_rays=ref_rays)
    ref = 0.5 * (ref_a + ref_b)
    # the reference's own error, (A − B)/2, relative to its mean over each mask
    noise = {k: masked_errors(ref_a, ref, m)["rel_rmse"] for k, m in masks.items()}
    curves: dict = {k: {s: [] for s in SAMPLINGS} for k in masks}
    times: dict = {s: {} for s in SAMPLINGS}
    for sampling in SAMPLINGS:
        for n in rays:
            image, ms = render(pipe, fg_sampling=sampling, fg_rays=n)
            times[sampling][n] = ms
            for key, mask in masks.items():
                error = vs_truth(masked_errors(image, ref, mask)["rel_rmse"], noise[key])
                curves[key][sampling].append((n, error))
    equal = {}
    for key in masks:
        target = dict(curves[key]["bsdf"])[target_rays]
        needed = {s: rays_for(curves[key][s], target) for s in SAMPLINGS}
        equal[key] = {
            "target_rel_rmse": target,
            "rays": needed,
            "ratio_vs_bsdf": {s: needed[s] / needed["bsdf"] for s in SAMPLINGS},
        }
    return {
        "photons": photons,
        "reference_rays": ref_rays,
        "reference_rel_noise": noise,
        "pixels": {k: int(m.sum()) for k, m in masks.items()},
        "rel_rmse": {k: {s: c for s, c in v.items()} for k, v in curves.items()},
        "final_gather_ms": times,
        "equal_rmse": equal,
        "table_build": table_build_times(pipe),
    }


def table_build_times(pipe: SurfacePipeline, runs: int = 3) -> dict:
    """Median wall time per query of the Jensen and CIS tables at the image's hits (k = 100)."""
    si, _, _ = first_hits(pipe)
    gmap = pipe.photon_maps()[0]
    radius = pipe.radii()[1]
    out = {}
    for method in ("jensen", "cis"):
        seconds = median(
            timed(sampling_table, method, gmap, si, si.is_valid(), 100, radius)[0]
            for _ in range(runs)
        )
        out[method] = {"us_per_query": 1e6 * seconds / dr.width(si.p)}
    return out


def markdown(result: dict) -> str:
    lines = ["# Steinhurst Ch. 5–6: irradiance caching and combined importance sampling", ""]
    lines.append(
        f"load average {result['machine'].get('load_average')}; command `{result['command']}`"
    )
    for scene, cis in result["cis"].items():
        lines += ["", f"## O25: final-gather rays for equal RMSE — {scene}", ""]
        for key, eq in cis["equal_rmse"].items():
            rows = [
                [s, fmt(eq["rays"][s], 1), fmt(eq["ratio_vs_bsdf"][s], 3),
                 ", ".join(f"{n}: {e:.4f}" for n, e in cis["rel_rmse"][key][s])]
                for s in SAMPLINGS
            ]  # fmt: skip
            lines += [
                f"**{key}** (target rel. RMSE {eq['target_rel_rmse']:.4f} = BSDF sampling "
                f"at {result['target_rays']} rays; {cis['pixels'][key]} pixels)",
                "",
                markdown_table(["sampling", "rays needed", "× BSDF", "rel. RMSE at each N"], rows),
                "",
            ]
    formulas = result["costs"]["evaluated"]
    costs = [[m, d[0], f"{formulas[m][0]} / {d[1]}", d[2], f"{formulas[m][1]} / {d[3]}"]
             for m, d in COST_DOC.items()]  # fmt: skip
    tb = next(iter(result["cis"].values()))["table_build"]
    lines += [
        "## Tables 6.1–6.2: storage and computation per final gather",
        "",
        markdown_table(
            ["method", "storage", "bytes (ours / doc)", "FLOPs", "FLOPs (ours / doc)"], costs
        ),  # fmt: skip
        "",
        "Measured table builds (k = 100 photons, this CPU): "
        f"Jensen {tb['jensen']['us_per_query']:.2f} µs/query, "
        f"CIS {tb['cis']['us_per_query']:.2f} µs/query.",
        *ic_markdown(result["irradiance_cache"]),
    ]
    return "\n".join(lines)


# image sides, photon paths, final-gather rays, ε_max of the tiled and of Ward's cache
FULL = dict(cis_size=128, ic_size=256, photons=200_000, rays=[4, 8, 16, 32, 64], ref_rays=1024,
            target=32, ic_rays=32, ic_ref_rays=512, errors=[0.025, 0.05, 0.1, 0.3],
            # Ward's image-wide cache enumerates every pixel pair within ε_max·R: at 256² and
            # ε_max = 0.3 that is ~10⁸ pairs, so the baseline runs at the practical values only
            ward=[0.025, 0.05, 0.1])  # fmt: skip
QUICK = dict(cis_size=24, ic_size=32, photons=10_000, rays=[4, 8], ref_rays=32, target=8,
             ic_rays=8, ic_ref_rays=32, errors=[0.05, 0.3], ward=[0.05, 0.3])  # fmt: skip


def headline(cis: dict, ic: dict) -> dict:
    """CIS's rays against BSDF sampling's on the floor, the tiled cache's savings at ε_max 0.05
    on the bare box."""
    spot, ceiling = (c["equal_rmse"]["floor"]["ratio_vs_bsdf"] for c in cis.values())
    bare = next(
        r for r in ic["rows"]
        if r["scene"] == "bare box" and r["mode"] == "tiled" and r["ic_error"] == 0.05
    )  # fmt: skip
    return {
        "cis_rays_ratio_vs_brdf": spot["cis"],
        "jensen_rays_ratio_vs_brdf": spot["jensen"],
        "cis_rays_ratio_vs_brdf_ceiling_light": ceiling["cis"],
        "ic_gathers_saved": bare["gathers_saved"],
        "ic_hit_rate": bare["hit_rate"],
        "ic_knn_final_gather_speedup": ic["knn_wall_time"]["speedup"],
    }


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "tiny images (smoke test)")
    parser.add_argument("--size", type=int, default=None, help="image side (default 128 / 256)")
    args = parser.parse_args(argv)
    c = dict(QUICK if args.quick else FULL)
    if args.size:
        c["cis_size"] = c["ic_size"] = args.size
    cis = {
        name: run_cis(scene, c["photons"], c["rays"], c["ref_rays"], c["target"])
        for name, scene in cis_scenes(c["cis_size"]).items()
    }
    ic = run_ic(c["ic_size"], c["photons"], c["ic_rays"], c["ic_ref_rays"], c["errors"], c["ward"])
    result = {
        "machine": report.machine_info(),
        "load_average": list(os.getloadavg()),
        "command": f"benchmarks/{NAME}.py" + (" --quick" if args.quick else ""),
        "target_rays": c["target"],
        "headline": headline(cis, ic),
        "cis_image": [c["cis_size"]] * 2,
        "cis": cis,
        "costs": {"doc": COST_DOC, "evaluated": cost_formulas()},
        "irradiance_cache": ic,
    }
    text = markdown(result)
    return report.publish(report.results_stem(args.out_dir, NAME, args.quick), result, text)


if __name__ == "__main__":
    main()
