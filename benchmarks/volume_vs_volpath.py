"""The volume method (Sun et al. 2008) and the surface method's volume photon map (Jensen &
Christensen 1998) against Mitsuba's ``volpath`` on fog: time to equal error.

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
(:class:`~photonmap.SurfacePipeline`, its volume photon map) at rising photon counts and spp.
Every point is rendered once untimed (kernel compilation) and then 3 times with seeds 0, 1, 2,
in rounds over all the points of a scene (a burst of load from other work hits one sample of
several points, not all of one); its time and errors are the medians of the 3. A photonmap time
covers reading the loaded Mitsuba scene, every stage and the image, Dr.Jit's queue drained
(:func:`timing.timed`). Errors: relative RMSE per pixel, and the relative RMSE of 4×4-block
means (noise averages out within a block, a bias does not), over the pixels that do not see the
light directly or through the glass (:func:`light_image_mask`); the whole image's
(:func:`photonmap.compare`) are the ``*_full`` errors.

Headline per scene and method: ``speedup_vs_volpath_at_equal_rmse`` = the time ``volpath`` needs
for the error the method reaches at its lowest-error point (log-log interpolation between the
two ``volpath`` points around it; past its last point, RMSE ∝ t^−½, flagged ``extrapolated``)
divided by the method's time there; the largest such ratio over the method's points is
``max_speedup`` (:mod:`volume_vs_volpath_report`). A method whose error stops falling (less
than 10 % lower over the last doubling or more of its time) has a **bias floor**: the headline
says so, and whether that floor lies above ``volpath``'s lowest measured error (then the method
cannot reach ``volpath``'s long-run error at any budget, and nothing is extrapolated for it).
Every error includes the reference's own noise (independent renders: squared errors add), so
equal raw errors are equal errors against the truth; the ``*_vs_truth`` errors,
√(error² − noise²), show the floors the noise hides, and get headlines of their own.

Writes ``results/volume_vs_volpath.json`` (``headline[scene]``: the speedups per method at the
masked relative RMSE, ``by_error`` for every error, ``bias_floor``, ``notes``; ``scenes[scene]``:
the curves, every sample, the headline's working), ``.md`` and ``.png`` (``_quick`` with
``--quick``).

    .venv/bin/python benchmarks/volume_vs_volpath.py [--quick]
"""

from __future__ import annotations

import json
import time
from functools import partial
from pathlib import Path

import mitsuba as mi
import numpy as np

import photonmap
import report
from accuracy import masked_errors, reference_noise, vs_truth
from photonmap.core.image import read_image, write_image
from timing import median, timed
from volume_vs_volpath_report import (
    KEYS,
    budget_text,
    markdown,
    method_headlines,
    plot,
    scene_headline,
)

NAME = "volume_vs_volpath"
EXAMPLE = report.REPO / "examples" / "fog_box_sphere_light.xml"
SCENES = {
    "ball": "glass ball (n 1.5) in a 4×4×4 box of fog, sphere light "
    "(examples/fog_box_sphere_light.xml)",
    "fog": "the same box of fog without the ball",
}
MAX_DEPTH = 32  # the file's volpath depth
RUNS = 3  # timed renders per point (seeds 0..RUNS-1), medians reported

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
    "volume": [(16, 2**12), (16, 2**14)],  # one grid and spp per method: its kernels serve both
    "surface": [(10_000, 1), (40_000, 1)],
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


def reference(name: str, scene, size, spp: int, cache: Path) -> tuple[list[np.ndarray], dict]:
    """The long ``volpath`` render of scene ``name`` as two independent halves A, B of
    ``spp // 2`` samples per pixel each (cached as EXR in ``cache``, with how each was made
    beside it). Returns both halves (the reference is their mean) and how they were made."""
    halves, info = [], {"spp": spp, "halves": []}
    for half in (1, 2):
        path = cache / f"{NAME}_{name}_{size[0]}x{size[1]}_{spp}spp_{half}.exr"
        made = path.with_suffix(".json")
        if path.exists() and made.exists():
            info["halves"].append({**json.loads(made.read_text()), "cached": str(path)})
        else:
            cache.mkdir(parents=True, exist_ok=True)
            image, done = photonmap.render_reference(
                scene, spp=spp // 2, integrator="volpath", max_depth=MAX_DEPTH, seed=100_000 * half
            )
            write_image(str(path), image)
            report.write_json(made, done)
            info["halves"].append({**done, "rendered": str(path)})
            print(f"  reference half {half}: {spp // 2} spp in {done['seconds']:.1f} s", flush=True)
        halves.append(read_image(str(path)).astype(np.float64))
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


class Target:
    """What a render is compared with: the reference, the mask of :func:`light_image_mask` and
    the reference's noise over it (from the difference of its halves)."""

    def __init__(self, ref: np.ndarray, difference: np.ndarray, mask: np.ndarray):
        self.ref, self.mask = ref, mask
        self.noise = reference_noise(ref, difference, mask)

    def errors(self, image: np.ndarray) -> dict:
        """Masked errors (the headline's), estimates of them against the noise-free image
        (:func:`accuracy.vs_truth`), and the whole image's (:func:`photonmap.compare`:
        ``*_full`` and the mean-brightness ratio)."""
        full = photonmap.compare(image, self.ref)
        out = masked_errors(image, self.ref, self.mask)
        for key in ("rel_rmse", "block_rel_rmse"):
            out[f"{key}_vs_truth"] = vs_truth(out[key], self.noise[key])
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
            seconds, (image, extra) = timed(render, seed)
            load = report.load_average()[0]
            out.append({"seconds": seconds, **target.errors(image), **extra, "load_1min": load})
    rows = {}
    for (method, budget, _), runs in zip(points, samples, strict=True):
        row = {**budget, "seconds": median(r["seconds"] for r in runs)}
        for key in (*KEYS, "brightness"):
            row[key] = median(r[key] for r in runs)
        row["samples"] = runs
        rows.setdefault(method, []).append(row)
        print(f"  {method:8s} {budget_text(method, row):28s} {row['seconds']:7.2f} s  "
              f"rel RMSE {row['rel_rmse']:.4f}  block {row['block_rel_rmse']:.4f}  "
              f"brightness {row['brightness']:.3f}", flush=True)  # fmt: skip
    return rows


def points(scene, config: dict) -> list:
    """``(method, budget, render)`` for every budget of ``config``."""

    def volpath(seed, spp):
        image, _ = photonmap.render_reference(
            scene, spp=spp, integrator="volpath", max_depth=MAX_DEPTH, seed=1000 * seed
        )
        return image, {}

    def volume(seed, grid, photons):
        pipe = photonmap.VolumePipeline(scene, grid=grid, photons=photons, phase_k=0.0,
                                        table=0.0, seed=seed)  # fmt: skip
        return np.array(pipe.render(), dtype=np.float64), {"stages_ms": dict(pipe.timer.ms)}

    def surface(seed, photons, spp):
        pipe = photonmap.SurfacePipeline(scene, photons=photons, caustic_photons=0, fg_rays=4,
                                         spp=spp, max_depth=MAX_DEPTH, seed=seed)  # fmt: skip
        return np.array(pipe.render(), dtype=np.float64), {"stages_ms": dict(pipe.timer.ms)}

    out = [("volpath", {"spp": s}, partial(volpath, spp=s)) for s in config["volpath_spp"]]
    out += [("volume", {"grid": g, "photons": n}, partial(volume, grid=g, photons=n))
            for g, n in config["volume"]]  # fmt: skip
    out += [("surface", {"photons": n, "spp": s}, partial(surface, photons=n, spp=s))
            for n, s in config["surface"]]  # fmt: skip
    return out


# ------------------------------------------------------------------------------------ run
def run_scene(name: str, config: dict, cache: Path) -> dict:
    """The reference, the three curves and their headlines of scene ``name``."""
    size = config["size"]
    scene = mi.load_string(scene_xml(name, *size))
    (a, b), ref_info = reference(name, scene, size, config["reference_spp"], cache)
    target = Target(0.5 * (a + b), a - b, light_image_mask(name, size))
    res = {
        "description": SCENES[name],
        "reference": ref_info,
        "reference_noise": target.noise,
        "masked_pixels": int((~target.mask).sum()),
        **measure(points(scene, config), target),
    }
    res["headline"] = method_headlines(res)
    return res


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "48×36, few budgets (smoke test)")
    parser.add_argument(
        "--scenes", default=",".join(SCENES), help=f"comma-separated subset of {tuple(SCENES)}"
    )
    args = parser.parse_args(argv)
    config = QUICK if args.quick else FULL
    names = [s for s in args.scenes.split(",") if s]
    for s in names:
        if s not in SCENES:
            raise ValueError(f"scenes must be among {', '.join(SCENES)}, got {s!r}")
    machine, start = report.machine_info(), time.perf_counter()
    results = {}
    for name in names:
        print(f"{name}:", flush=True)
        results[name] = run_scene(name, config, args.out_dir / "cache")
    headline = {name: scene_headline(res) for name, res in results.items()}
    result = {
        "machine": machine,
        "command": f"benchmarks/{NAME}.py" + (" --quick" if args.quick else ""),
        "image": list(config["size"]),
        "reference_spp": config["reference_spp"],
        "runs_per_point": RUNS,
        "headline": headline,
        "scenes": results,
        "total_seconds": time.perf_counter() - start,
        "load_average_end": report.load_average(),
    }
    stem = report.results_stem(args.out_dir, NAME, args.quick)
    report.write_results(stem, result, markdown(result, MAX_DEPTH))
    plot(results, stem.with_suffix(".png"))
    print(headline)
    return result


if __name__ == "__main__":
    main()
