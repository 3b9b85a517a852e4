"""The volume and surface methods against Mitsuba's ``volpath`` on fog (issue 11 item 6).

Two scenes: **ball** — ``examples/fog_box_sphere_light.xml``, a glass ball (n = 1.5) in a
4 × 4 × 4 box of grey fog (σ_t 0.25, albedo 0.9, isotropic) under a sphere light of radius 0.2
(fog_box.xml's point light, whose volume caustic through the glass ``volpath`` cannot sample,
with the same power; the tests compare the same file) — and **fog** —
the same file without the ball. For each, a long ``volpath`` render (depth 32, as the file asks)
is the reference (:func:`photonmap.render_reference`, cached in ``results/cache/``, not in git),
made of two independent halves whose difference measures its own noise.

Curves of error against wall time: ``volpath`` at rising spp, the ``volume`` method
(:class:`~photonmap.VolumePipeline`, multiple scattering, isotropic phase ``phase_k=0`` like the
file's medium, no table) at rising grid and photon counts, and the ``surface`` method
(:class:`~photonmap.SurfacePipeline`, its volume photon map; Jensen & Christensen 1998) at rising
photon counts and spp. Every point is rendered once untimed (kernel compilation) and then 3 times
with seeds 0, 1, 2, in rounds over all the points of a scene (a burst of load from other work
hits one sample of several points, not all of one); its time and errors are the medians of the
3. A photonmap time covers reading
the loaded Mitsuba scene, every stage and the image, Dr.Jit's queue drained
(:func:`timing.timed`). Errors: relative RMSE per pixel, and the relative RMSE of 4×4-block
means (noise averages out within a block, a bias does not), over the pixels that do not see the
light directly or through the glass (:func:`light_image_mask`); the whole image's
(:func:`photonmap.compare`) are the ``*_full`` errors.

Headline per scene and method: ``speedup_vs_volpath_at_equal_rmse`` = the time ``volpath`` needs
for the error the method reaches at its lowest-error point (log-log interpolation between the
two ``volpath`` points around it; past its last point, RMSE ∝ t^−½, flagged ``extrapolated``)
divided by the method's time there; the largest such ratio over the method's points is
``max_speedup``. A method whose error stops falling (less than :data:`FLOOR_DROP` lower over the
last doubling or more of its time) has a **bias floor**: the headline says so, and whether that
floor lies above ``volpath``'s lowest measured error (then the method cannot reach ``volpath``'s
long-run error at any budget, and nothing is extrapolated for it). Every error includes the
reference's own noise (independent renders: squared errors add), so equal raw errors are equal
errors against the truth; the ``*_vs_truth`` errors, √(error² − noise²), show the floors the
noise hides, and get headlines of their own.

Writes ``results/volume_vs_volpath.json`` (``headline[scene]``: the speedups per method at the
masked relative RMSE, ``by_error`` for every error, ``bias_floor``, ``notes``; ``scenes[scene]``:
the curves, every sample, the headline's working), ``.md`` and ``.png`` (``_quick`` with
``--quick``).

    .venv/bin/python benchmarks/volume_vs_volpath.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import mitsuba as mi  # noqa: E402

import photonmap  # noqa: E402
import report  # noqa: E402
import timing  # noqa: E402
from photonmap.core.image import block_means, write_image  # noqa: E402

EXAMPLE = report.REPO / "examples" / "fog_box_sphere_light.xml"
SCENES = ("ball", "fog")
METHODS = ("volume", "surface")
MAX_DEPTH = 32  # the file's volpath depth
RUNS = 3  # timed renders per point (seeds 0..RUNS-1), medians reported
KEYS = (  # the errors with headlines; the first is the headline's headline
    "rel_rmse",
    "block_rel_rmse",
    "rel_rmse_vs_truth",
    "block_rel_rmse_vs_truth",
    "rel_rmse_full",
    "block_rel_rmse_full",
)
FLOOR_DROP = 0.1  # the error fell less than this (relative) over the last ≥ 2× of time: a floor

FULL = {
    "size": (160, 120),
    "reference_spp": 4096,
    "volpath_spp": [1, 4, 16, 64, 256, 1024],
    "volume": [(32, 2**14), (48, 2**16), (64, 2**17), (96, 2**18), (128, 2**20)],
    "surface": [(25_000, 1), (100_000, 2), (400_000, 4), (1_000_000, 4)],
}
QUICK = {
    "size": (48, 36),
    "reference_spp": 256,
    "volpath_spp": [1, 4, 16],
    "volume": [(16, 2**12), (24, 2**14)],
    "surface": [(10_000, 1), (40_000, 2)],
}


def scene_xml(name: str, width: int, height: int) -> str:
    """``examples/fog_box_sphere_light.xml`` (fog_box.xml under a sphere light of radius 0.2
    with the point light's power) at ``width`` × ``height``; ``name="fog"`` also drops the
    glass ball."""
    if name not in SCENES:
        raise ValueError(f"scene must be one of {', '.join(SCENES)}, got {name!r}")
    xml = EXAMPLE.read_text()
    xml = xml.replace('value="320"', f'value="{width}"').replace('value="240"', f'value="{height}"')
    if name == "fog":
        start = xml.index('<shape type="sphere" id="ball">')
        end = xml.index("</shape>", start) + len("</shape>")
        xml = xml[:start] + xml[end:]
    return xml


def reference(name: str, scene, size, spp: int, cache: Path) -> tuple[np.ndarray, dict]:
    """The long ``volpath`` render of scene ``name`` as two independent halves A, B of
    ``spp // 2`` samples per pixel each (cached as EXR in ``cache``). Returns both halves (the
    reference is their mean) and how they were made."""
    halves, info = [], {"spp": spp, "halves": []}
    for half in (1, 2):
        path = cache / f"volume_vs_volpath_{name}_{size[0]}x{size[1]}_{spp}spp_{half}.exr"
        made = path.with_suffix(".json")  # how the cached half was rendered
        if path.exists() and made.exists():
            halves.append(np.array(mi.Bitmap(str(path)), dtype=np.float64)[..., :3])
            info["halves"].append({**json.loads(made.read_text()), "cached": str(path)})
            continue
        cache.mkdir(parents=True, exist_ok=True)
        image, done = photonmap.render_reference(
            scene, spp=spp // 2, integrator="volpath", max_depth=MAX_DEPTH, seed=100_000 * half
        )
        write_image(str(path), image)
        report.write_json(path.with_suffix(".json"), done)
        halves.append(image)
        info["halves"].append({**done, "rendered": str(path)})
        print(f"  reference half {half}: {spp // 2} spp in {done['seconds']:.1f} s", flush=True)
    return halves, info


def light_image_mask(name: str, size, spp: int = 16) -> np.ndarray:
    """Pixels that see no emitter, neither directly nor through the glass (refracted or
    reflected), nor next to one that does: Mitsuba's ``path`` on the scene with its medium
    taken out (no diffuse surface is left, so all it renders is the light and its specular
    images). The volume method draws no light sources (Sun et al. 2008 render the fog and the
    objects), and these few pixels of a 318 W/m²/sr source, noisy in every method, would be
    most of every error (85 % of the volume method's squared error in the ball scene), as in
    ``surface_vs_path.py``."""
    from scipy.ndimage import binary_dilation

    xml = scene_xml(name, *size)
    for ref in ('<ref name="interior" id="fog"/>', '<ref name="exterior" id="fog"/>'):
        xml = xml.replace(ref, "")
    integrator = mi.load_dict({"type": "path", "max_depth": MAX_DEPTH})
    seen = np.array(mi.render(mi.load_string(xml), integrator=integrator, spp=spp, seed=3))
    return ~binary_dilation(seen[..., :3].max(-1) > 0.01, iterations=1)


def masked_errors(image: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> dict:
    """Relative RMSE over the pixels of ``mask`` and of the 4×4-block means of the blocks
    entirely in it (relative to the reference's mean there)."""
    mean = float(np.mean(np.abs(ref[mask])))
    d = np.asarray(image, np.float64) - ref
    blocks = block_means(mask[..., None].astype(np.float64))[..., 0] == 1.0
    bd = block_means(d)[blocks]
    return {
        "rel_rmse": float(np.sqrt(np.mean(d[mask] ** 2))) / mean,
        "block_rel_rmse": float(np.sqrt(np.mean(bd**2))) / mean,
    }


def reference_noise(difference: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> dict:
    """The reference's own errors (:func:`masked_errors`), from the difference of its two
    independent halves A, B: Var((A + B)/2) = E[(A − B)²]/4, so (A − B)/2 is its error."""
    return masked_errors(ref + 0.5 * difference, ref, mask)


class Target:
    """What a render is compared with: the reference, the mask of :func:`light_image_mask` and
    the reference's noise over it."""

    def __init__(self, ref: np.ndarray, difference: np.ndarray, mask: np.ndarray):
        self.ref, self.mask = ref, mask
        self.noise = reference_noise(difference, ref, mask)

    def errors(self, image: np.ndarray) -> dict:
        """Masked errors (the headline's), estimates of them against the noise-free image
        (√(error² − noise²): independent renders' variances add), and the whole image's
        (:func:`photonmap.compare`: ``*_full`` and the mean-brightness ratio)."""
        full = photonmap.compare(image, self.ref)
        out = masked_errors(image, self.ref, self.mask)
        for key in ("rel_rmse", "block_rel_rmse"):
            out[f"{key}_vs_truth"] = math.sqrt(max(out[key] ** 2 - self.noise[key] ** 2, 0.0))
            out[f"{key}_full"] = full[key]
        out["brightness"] = full["brightness"]
        return out


def measure(points, target: Target) -> dict[str, list[dict]]:
    """Time and score renders: ``points`` are ``(method, budget, render)`` with ``render(seed)``
    returning ``(image, extra)``. Each is rendered once untimed (kernel compilation), then in
    :data:`RUNS` rounds over all points (seed = round), so that a burst of load from other work
    on the machine hits one sample of several points rather than every sample of one. Returns
    per method the rows: budget, median seconds and errors (:meth:`Target.errors`), and every
    sample with the 1-minute load average after it."""
    for _, _, render in points:
        render(0)
    samples = [[] for _ in points]
    for seed in range(RUNS):
        for (_, _, render), out in zip(points, samples, strict=True):
            seconds, (image, extra) = timing.timed(render, seed)
            load = round(os.getloadavg()[0], 2)
            out.append({"seconds": seconds, **target.errors(image), **extra, "load_1min": load})
    rows = {}
    for (method, budget, _), runs in zip(points, samples, strict=True):
        row = {**budget, "seconds": timing.median(r["seconds"] for r in runs)}
        for key in (*KEYS, "brightness"):
            row[key] = timing.median(r[key] for r in runs)
        row["samples"] = runs
        rows.setdefault(method, []).append(row)
        log(method, budget_text(method, row), row)
    return rows


def volpath_points(scene, spps) -> list:
    def render(seed, spp):
        image, _ = photonmap.render_reference(
            scene, spp=spp, integrator="volpath", max_depth=MAX_DEPTH, seed=1000 * seed
        )
        return image, {}

    return [("volpath", {"spp": spp}, partial(render, spp=spp)) for spp in spps]


def volume_points(scene, budgets) -> list:
    def render(seed, grid, photons):
        pipe = photonmap.VolumePipeline(
            scene, grid=grid, photons=photons, phase_k=0.0, table=0.0, seed=seed
        )
        image = np.array(pipe.render(), dtype=np.float64)
        return image, {"stages_ms": dict(pipe.timer.ms)}

    return [
        ("volume", {"grid": g, "photons": n}, partial(render, grid=g, photons=n))
        for g, n in budgets
    ]


def surface_points(scene, budgets) -> list:
    def render(seed, photons, spp):
        pipe = photonmap.SurfacePipeline(
            scene,
            photons=photons,
            caustic_photons=0,
            fg_rays=4,
            spp=spp,
            max_depth=MAX_DEPTH,
            seed=seed,
        )
        image = np.array(pipe.render(), dtype=np.float64)
        return image, {"stages_ms": dict(pipe.timer.ms)}

    return [
        ("surface", {"photons": n, "spp": spp}, partial(render, photons=n, spp=spp))
        for n, spp in budgets
    ]


def log(method: str, budget: str, row: dict) -> None:
    print(
        f"  {method:8s} {budget:28s} {row['seconds']:7.2f} s  rel RMSE {row['rel_rmse']:.4f}  "
        f"block {row['block_rel_rmse']:.4f}  brightness {row['brightness']:.3f}",
        flush=True,
    )


# ------------------------------------------------------------------------------ curve analysis
def volpath_time_for(rows, error: float, key: str) -> tuple[float | None, str]:
    """Seconds ``volpath`` needs for ``error`` on its (time, error) curve: log-log interpolation
    between the first pair of points that brackets it (``"interpolated"``), RMSE ∝ t^−½ past its
    last point (``"extrapolated"``); ``(None, "volpath_1spp_lower")`` if its cheapest point
    already has a lower error, ``(None, "below_reference_noise")`` for an error of 0 (an error
    against the truth that the reference's noise hides)."""
    t = np.array([r["seconds"] for r in rows], dtype=np.float64)
    e = np.array([r[key] for r in rows], dtype=np.float64)
    order = np.argsort(t)
    t, e = t[order], e[order]
    if error <= 0:
        return None, "below_reference_noise"
    if error >= e[0]:
        return None, "volpath_1spp_lower"
    for i in range(len(t) - 1):
        if e[i] >= error >= e[i + 1]:
            f = math.log(error / e[i]) / math.log(e[i + 1] / e[i])
            return math.exp(math.log(t[i]) + f * math.log(t[i + 1] / t[i])), "interpolated"
    return float(t[-1] * (e[-1] / error) ** 2), "extrapolated"


def floor(rows, key: str) -> dict:
    """Whether a method's error still falls at the end of its curve: ``floor`` is its lowest
    error if the last doubling (or more) of time lowered the error by less than
    :data:`FLOOR_DROP`, else None."""
    t = np.array([r["seconds"] for r in rows], dtype=np.float64)
    e = np.array([r[key] for r in rows], dtype=np.float64)
    last = len(t) - 1
    earlier = [i for i in range(last) if t[last] >= 2 * t[i]]
    falling = True
    if earlier:
        i = earlier[-1]
        falling = bool(e[last] < (1 - FLOOR_DROP) * e[i:last].min())
    return {
        "still_falling": falling,
        "lowest": float(e.min()),
        "floor": None if falling else float(e.min()),
    }


def headline_for(method_rows, volpath_rows, key: str) -> dict:
    """Speedups at equal error (``key``) of one method over ``volpath``: per point, at the
    method's lowest-error point (the headline) and the largest; the bias floor, if any."""
    points = []
    for r in method_rows:
        t_vp, how = volpath_time_for(volpath_rows, r[key], key)
        points.append(
            {
                "error": r[key],
                "seconds": r["seconds"],
                "volpath_seconds": t_vp,
                "volpath_time_is": how,
                "speedup": t_vp / r["seconds"] if t_vp is not None else None,
            }
        )
    best = min(range(len(points)), key=lambda i: points[i]["error"])
    valid = [p for p in points if p["speedup"] is not None]
    status = floor(method_rows, key)
    volpath_lowest = min(r[key] for r in volpath_rows)
    out = {
        "speedup_vs_volpath_at_equal_rmse": points[best]["speedup"],
        "at_error": points[best]["error"],
        "method_seconds": points[best]["seconds"],
        "volpath_seconds_for_that_error": points[best]["volpath_seconds"],
        "volpath_time_is": points[best]["volpath_time_is"],
        "max_speedup": max(p["speedup"] for p in valid) if valid else None,
        "error_still_falling": status["still_falling"],
        "bias_floor": status["floor"],
        "volpath_lowest_error": volpath_lowest,
        "reaches_volpath_lowest_error": status["lowest"] <= volpath_lowest,
        "points": points,
    }
    if status["floor"] is not None and status["floor"] > volpath_lowest:
        out["note"] = (
            f"error stops falling at {status['floor']:.4f}, above volpath's "
            f"{volpath_lowest:.4f} at its largest budget: this method cannot reach volpath's "
            "long-run error; no extrapolation"
        )
    return out


# ----------------------------------------------------------------------------------- output
def plot(results: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(results), figsize=(5 * len(results), 7), squeeze=False)
    for col, (name, res) in enumerate(results.items()):
        for row, (key, label) in enumerate(
            (("rel_rmse", "relative RMSE"), ("block_rel_rmse", "4×4-block relative RMSE"))
        ):
            ax = axes[row][col]
            for method in ("volpath", *METHODS):
                rows = res[method]
                ax.loglog([r["seconds"] for r in rows], [r[key] for r in rows], "o-", label=method)
            ax.axhline(
                res["reference_noise"][key], color="grey", ls="--", lw=0.8, label="reference noise"
            )
            ax.set_xlabel("wall time (s)")
            ax.set_ylabel(label)
            ax.set_title(f"{name}: {label}")
            ax.grid(True, which="both", lw=0.3)
            ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def budget_text(method: str, r: dict) -> str:
    if method == "volpath":
        return f"{r['spp']} spp"
    if method == "volume":
        return f"grid {r['grid']}, {r['photons']:,} photons"
    return f"{r['photons']:,} photons, {r['spp']} spp"


def markdown(result: dict) -> str:
    m = result["machine"]
    lines = [
        "# volume and surface vs Mitsuba volpath on fog (issue 11 item 6)",
        "",
        f"{result['image'][0]}×{result['image'][1]} pixels; reference: volpath "
        f"{result['reference_spp']} spp, depth {MAX_DEPTH}. Times: medians of {RUNS} renders "
        f"(seeds 0–{RUNS - 1}) after a warm-up. {m['cpu_model']}, {m['cores_usable']} usable "
        f"cores; load average {m['load_average']} at the start, "
        f"{result['load_average_end']} at the end; total {result['total_seconds']:.0f} s.",
        "",
        "Command: `" + result["command"] + "`",
        "",
    ]
    for name, res in result["scenes"].items():
        lines += [f"## {name}: {res['description']}", ""]
        rows = [
            [
                method,
                budget_text(method, r),
                report.fmt(r["seconds"], 3),
                report.fmt(r["rel_rmse"], 4),
                report.fmt(r["block_rel_rmse"], 4),
                report.fmt(r["rel_rmse_vs_truth"], 4),
                report.fmt(r["block_rel_rmse_vs_truth"], 4),
                report.fmt(r["rel_rmse_full"], 4),
                report.fmt(r["block_rel_rmse_full"], 4),
                report.fmt(r["brightness"], 3),
            ]
            for method in ("volpath", *METHODS)
            for r in res[method]
        ]
        lines += [
            report.markdown_table(
                [
                    "method",
                    "budget",
                    "seconds",
                    "rel. RMSE",
                    "4×4-block rel. RMSE",
                    "rel. RMSE vs truth",
                    "block vs truth",
                    "rel. RMSE, whole image",
                    "block, whole image",
                    "brightness",
                ],
                rows,
                "llrrrrrrrr",
            ),
            "",
            f"Errors over the pixels that do not see the light ({res['masked_pixels']} masked: "
            "the light and its images in the glass, dilated by 1 pixel) unless `full`. "
            "Reference noise (from its two halves): rel. RMSE "
            f"{res['reference_noise']['rel_rmse']:.4f}, 4×4-block rel. RMSE "
            f"{res['reference_noise']['block_rel_rmse']:.4f}; `*_vs_truth` = √(error² − noise²).",
            "",
        ]
        head = []
        for method in METHODS:
            for key in KEYS:
                h = res["headline"][method][key]
                head.append(
                    [
                        method,
                        key,
                        report.fmt(h["at_error"], 4),
                        report.fmt(h["method_seconds"], 3),
                        report.fmt(h["volpath_seconds_for_that_error"], 2)
                        + (
                            ""
                            if h["volpath_time_is"] == "interpolated"
                            else f" ({h['volpath_time_is']})"
                        ),
                        report.fmt(h["speedup_vs_volpath_at_equal_rmse"], 1),
                        report.fmt(h["max_speedup"], 1),
                        "falling" if h["error_still_falling"] else f"floor {h['bias_floor']:.4f}",
                    ]
                )
                if "note" in h:
                    head[-1][-1] += " — " + h["note"]
        lines += [
            report.markdown_table(
                [
                    "method",
                    "error",
                    "lowest error",
                    "its seconds",
                    "volpath seconds for it",
                    "speedup",
                    "max speedup on curve",
                    "end of curve",
                ],
                head,
                "llrrrrrl",
            ),
            "",
        ]
        h = result["headline"][name]
        lines += [
            "**Headline** (rel. RMSE, light's images masked): "
            + ", ".join(
                f"{method} {report.fmt(v, 1)}× faster than volpath at equal error"
                for method, v in h["speedup_vs_volpath_at_equal_rmse"].items()
            )
            + ".",
            "",
            *[f"- {note}" for note in h["notes"]],
            "",
        ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="48×36, few budgets (smoke test)")
    parser.add_argument("--out-dir", type=Path, default=report.RESULTS)
    parser.add_argument(
        "--scenes", default=",".join(SCENES), help=f"comma-separated subset of {SCENES}"
    )
    args = parser.parse_args(argv)
    config = QUICK if args.quick else FULL
    names = [s for s in args.scenes.split(",") if s]
    for s in names:
        if s not in SCENES:
            raise ValueError(f"scenes must be among {', '.join(SCENES)}, got {s!r}")
    machine = report.machine_info()
    start = time.perf_counter()
    size = config["size"]
    descriptions = {
        "ball": "glass ball (n 1.5) in a 4×4×4 box of fog, sphere light (examples/fog_box_sphere_light.xml)",
        "fog": "the same box of fog without the ball",
    }
    results = {}
    for name in names:
        print(f"{name}:", flush=True)
        scene = mi.load_string(scene_xml(name, *size))
        (a, b), ref_info = reference(
            name, scene, size, config["reference_spp"], args.out_dir / "cache"
        )
        target = Target(0.5 * (a + b), a - b, light_image_mask(name, size))
        res = {
            "description": descriptions[name],
            "reference": ref_info,
            "reference_noise": target.noise,
            "masked_pixels": int((~target.mask).sum()),
        }
        points = (
            volpath_points(scene, config["volpath_spp"])
            + volume_points(scene, config["volume"])
            + surface_points(scene, config["surface"])
        )
        res.update(measure(points, target))
        res["headline"] = {
            method: {key: headline_for(res[method], res["volpath"], key) for key in KEYS}
            for method in METHODS
        }
        results[name] = res
    headline = {
        name: {
            "speedup_vs_volpath_at_equal_rmse": {
                method: res["headline"][method]["rel_rmse"]["speedup_vs_volpath_at_equal_rmse"]
                for method in METHODS
            },
            "by_error": {
                method: {
                    key: res["headline"][method][key]["speedup_vs_volpath_at_equal_rmse"]
                    for key in KEYS
                }
                for method in METHODS
            },
            "bias_floor": {
                method: {key: res["headline"][method][key]["bias_floor"] for key in KEYS}
                for method in METHODS
            },
            "notes": [
                f"{method} {key}: {res['headline'][method][key]['note']}"
                for method in METHODS
                for key in KEYS
                if "note" in res["headline"][method][key]
            ],
        }
        for name, res in results.items()
    }
    suffix = "_quick" if args.quick else ""
    result = {
        "machine": machine,
        "command": "benchmarks/volume_vs_volpath.py" + (" --quick" if args.quick else ""),
        "image": list(size),
        "reference_spp": config["reference_spp"],
        "runs_per_point": RUNS,
        "headline": headline,
        "scenes": results,
        "total_seconds": time.perf_counter() - start,
        "load_average_end": [round(x, 2) for x in os.getloadavg()],
    }
    report.write_json(args.out_dir / f"volume_vs_volpath{suffix}.json", result)
    report.write_text(args.out_dir / f"volume_vs_volpath{suffix}.md", markdown(result))
    plot(results, args.out_dir / f"volume_vs_volpath{suffix}.png")
    print(headline)
    return result


if __name__ == "__main__":
    main()
