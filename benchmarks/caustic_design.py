"""Caustic design: a glass slab's heightmap optimised so that its caustic matches a target image,
with gradients of differentiable photon mapping (``photonmap.render``) against the same
optimisation driven by Mitsuba's ``ptracer`` gradients, at equal compute time, in one run.

The set-up is Mitsuba 3's caustic-design tutorial (``inverse_rendering/caustics_optimization``
of mitsuba-tutorials), built in code by ``examples/caustic_design.py`` (its ``make_scene``,
``Heightmap`` and ``smiley``, loaded from there): a ``directionalarea`` light (a 2×2 rectangle at y = 5
shining down, nearly the sun), a glass slab (ior 1.5, no specular reflection: a flat entry face
at y = 0.2, and an exit face at y = 0 that is an ``n``×``n`` vertex grid displaced along its
normal by the heightmap, clipped to ±0.01), a white diffuse receiver at y = −7, and a
perspective camera at y = −4.65 looking down at the receiver (between slab and receiver, so it
sees the receiver directly: ``ptracer`` connects receiver hits to the camera, glass would block
them). ``max_depth`` 4 (light → entry → exit → receiver → camera). The target
(``smiley`` of the example) is a smiley drawn with NumPy at the render resolution; the loss is the
tutorial's scale-independent L2, ``mean((I / mean(detach(I)) − T / mean(T))²)``.

Both optimisations start from the flat slab and run Adam (``mi.ad.Adam``) on the heightmap, one
render + backward + step per iteration, each with its own learning rate and sample budget:
``ptracer`` with ``--pt-spp`` light paths per pixel (``mi.render(scene, params, seed=step)``),
photon mapping with ``--pm-photons`` photons and kernel radius ``--pm-radius``
(``photonmap.render(scene, params, method="sppm", seed=step)``), and ``--pm-spp`` eye paths per
pixel. A warm-up step of each compiles its kernels first. The two runs are interleaved, step by
step (the one with less compute spent goes next), so that the load of a shared machine falls on
both alike; each step is timed on its own (``dr.sync_thread`` before and after). As in the
tutorial, the learning rates halve late: at half and at three quarters of ``--seconds``. With
``--steps N`` the budget is ``N`` steps each instead of seconds (checkpoints after 1, 2, 4, 8, …
steps; the learning rates halve at the same fractions of ``N``), so that what a run does is
fixed whatever the machine's speed: ``--quick`` runs 24 steps each.
``dr.JitFlag.OptimizeCalls`` is off for the whole run, both methods (Dr.Jit 1.5 loses
derivatives through Mitsuba's shape calls with it on), and restored afterwards.

Progress is measured with the clock stopped: at checkpoints (seconds of compute) the current
heightmap is rendered by Mitsuba's ``ptracer`` at ``--truth-spp`` in two halves of different
seeds, and the *true loss* is ``mean((A − T)(B − T))`` of the two normalised halves (unbiased
for the loss of the noise-free image: the halves' noise is independent). Headline:
``loss_ratio_vs_ptracer_at_equal_time``, ``ptracer``'s true loss over photon mapping's at the
end of ``--seconds`` each (``…_at_equal_steps`` with ``--steps``); also each method's steps,
median step time and the initial loss.

Writes ``results/caustic_design.json``, ``.md``, ``.png`` (true loss against time) and
``caustic_design_images.png`` (target | photon-mapping result | ptracer result, each rendered by
Mitsuba ``ptracer`` at ``--truth-spp``; Mitsuba's ``path`` cannot render this caustic: it would
have to hit a light that shines in one direction only); ``_quick`` with ``--quick``.

    .venv/bin/python benchmarks/caustic_design.py [--quick] [--seconds 120 | --steps N]
"""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

import photonmap  # noqa: F401  (selects the variant, finds libLLVM)
import report
from photonmap.core.image import encode_image
from timing import STEP_MARKS, Budget, median

NAME = "caustic_design"
METHODS = ("photonmap", "ptracer")
LABELS = {"photonmap": "photon mapping (photonmap.render)", "ptracer": "Mitsuba ptracer"}
DECAYS = (0.5, 0.75)  # the learning rates halve at these fractions of the time budget
CHECKPOINTS = (2, 5, 10, 20, 40, 60, 90, 120, 180, 240)  # seconds of compute
QUICK_STEPS = 24  # --quick: steps per method


# ------------------------------------------------------------------------------------ scene
def _example():
    """``examples/caustic_design.py``, which builds the scene, the heightmap and the target."""
    path = Path(__file__).resolve().parents[1] / "examples" / "caustic_design.py"
    spec = importlib.util.spec_from_file_location("caustic_design_example", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


EXAMPLE = _example()
make_scene, Heightmap, MAX_DEPTH = EXAMPLE.make_scene, EXAMPLE.Heightmap, EXAMPLE.MAX_DEPTH


def loss_of(image: mi.TensorXf, target: mi.TensorXf) -> mi.Float:
    """The tutorial's scale-independent L2 loss (``target`` has mean 1)."""
    return dr.mean(dr.square(image / dr.mean(dr.detach(image), axis=None) - target), axis=None)


# ------------------------------------------------------------------------------ optimisation
class Run:
    """One method's optimisation: ``step()`` renders with gradients, backpropagates the loss and
    takes an Adam step."""

    def __init__(self, method: str, scene: mi.Scene, heightmap: Heightmap, target, settings):
        self.method, self.scene, self.heightmap, self.target = method, scene, heightmap, target
        self.settings = settings
        self.opt = mi.ad.Adam(lr=settings["lr"])
        self.opt["heights"] = dr.zeros(mi.Float, dr.width(heightmap.y))
        self.steps = 0
        self.ptracer = mi.load_dict({"type": "ptracer", "max_depth": MAX_DEPTH})

    def render(self, seed: int) -> mi.TensorXf:
        params = self.heightmap.params
        if self.method == "ptracer":
            return mi.render(self.scene, params, integrator=self.ptracer, seed=seed,
                             spp=self.settings["spp"])  # fmt: skip
        return photonmap.render(self.scene, params, method="sppm", seed=seed,
                                photons=self.settings["photons"], spp=self.settings["spp"],
                                radius=self.settings["radius"], max_depth=MAX_DEPTH)  # fmt: skip

    def step(self) -> float:
        self.heightmap.apply(self.opt["heights"])
        loss = loss_of(self.render(self.steps), self.target)
        dr.backward(loss)
        self.opt.step()
        dr.eval(self.opt["heights"])
        self.steps += 1
        return loss.array[0]

    def heights(self) -> mi.Float:
        return mi.Float(dr.detach(self.opt["heights"]))


def truth(scene: mi.Scene, heightmap: Heightmap, heights, target, spp: int, seed: int):
    """The true loss of ``heights`` (module docstring: two ``ptracer`` halves of ``spp / 2``)
    and the mean of the halves (the image, normalised to mean 1)."""
    integrator = mi.load_dict({"type": "ptracer", "max_depth": MAX_DEPTH})
    with dr.suspend_grad():
        heightmap.apply(heights)
        halves = []
        for k in range(2):
            image = mi.render(scene, integrator=integrator, spp=spp // 2, seed=seed + k)
            halves.append(np.array(image / dr.mean(image, axis=None)))
    t = np.array(target)
    loss = float(np.mean((halves[0] - t) * (halves[1] - t)))
    return loss, (halves[0] + halves[1]) / 2


def optimise(
    runs: dict[str, Run], scene, heightmap, target, budget: Budget, truth_spp: int, decays=()
):
    """Run every optimisation of ``runs`` for ``budget`` each (compute seconds or steps),
    interleaved (the one that has used the least goes next, so that a shared machine's load
    falls on all alike); the true loss of each at its checkpoints (clock stopped); each learning
    rate halves when its run has used each fraction ``decays`` of the budget. Returns
    ``{method: result}``."""
    for method, run in runs.items():  # compile each method's kernels; the result is dropped
        Run(method, scene, heightmap, target, run.settings).step()
    initial, _ = truth(scene, heightmap, next(iter(runs.values())).heights(), target,
                       truth_spp, 7_000_000)  # fmt: skip
    state = {m: {"spent": 0.0, "times": [], "marks": budget.marks(CHECKPOINTS, STEP_MARKS),
                 "rows": [{"seconds": 0.0, "steps": 0, "true_loss": initial, "step_loss": None}],
                 "decays": [f * budget.each for f in decays]}
             for m in runs}  # fmt: skip

    def used(m: str) -> float:
        return runs[m].steps if budget.steps else state[m]["spent"]

    while any(st["marks"] for st in state.values()):
        method = min((m for m in runs if state[m]["marks"]), key=used)
        run, st = runs[method], state[method]
        dr.sync_thread()
        start = time.perf_counter()
        step_loss = run.step()
        dr.sync_thread()
        st["times"].append(time.perf_counter() - start)
        st["spent"] += st["times"][-1]
        while st["decays"] and used(method) >= st["decays"][0]:  # as the tutorial does, late
            st["decays"].pop(0)
            run.opt.set_learning_rate(0.5 * run.opt.learning_rate())
        if used(method) >= st["marks"][0]:
            while st["marks"] and used(method) >= st["marks"][0]:
                st["marks"].pop(0)
            loss, _ = truth(scene, heightmap, run.heights(), target, truth_spp, 8_000_000)
            st["rows"].append({"seconds": st["spent"], "steps": run.steps, "true_loss": loss,
                               "step_loss": float(step_loss)})  # fmt: skip
            print(f"  {method:9s} {st['spent']:7.1f} s  {run.steps:5d} steps  true loss "
                  f"{loss:.4f}", flush=True)  # fmt: skip
    return {m: {"settings": runs[m].settings, "rows": st["rows"], "steps": runs[m].steps,
                "median_step_s": median(st["times"]), "seconds": st["spent"]}
            for m, st in state.items()}  # fmt: skip


# ------------------------------------------------------------------------- gradient check
def fd_check(seeds: int = 2) -> dict:
    """Each method's directional derivative (AD: ``dr.backward``, then ``<grad, d>``) against
    central finite differences with the same seed (``eps`` = 0.05 of ``d``), on a 16² grid and
    32² film, at a smooth bump ``h0`` along a smooth direction ``d``, for a linear loss
    (``mean(I · w)``, ``w`` a smooth ramp: no noise term) and the L2 loss to a fixed image.
    ``ptracer`` renders its gradient with a seed of its own (``mi.render``'s ``seed_grad``), so
    for the L2 loss its AD and FD differ by the noise covariance too; the linear loss is the
    clean test."""
    n, res = 16, 32
    scene = make_scene(n, res)
    heightmap = Heightmap(scene, n)
    y, x = np.mgrid[0:n, 0:n] / (n - 1) * 2 - 1
    h0 = (0.004 * np.exp(-((x - 0.2) ** 2 + y**2) / 0.2)).ravel().astype(np.float32)
    d = (0.003 * np.sin(3 * x + 1) * np.cos(2 * y)).ravel().astype(np.float32)
    ramp = np.sin(np.arange(res) / res * 3.0)[None, :, None] * np.ones((res, 1, 3))
    weight = mi.TensorXf(ramp.astype(np.float32))
    fixed = mi.TensorXf(np.random.default_rng(0).uniform(0, 0.5, (res, res, 3)).astype(np.float32))
    losses = {
        "linear": lambda image: dr.mean(image * weight, axis=None),
        "l2": lambda image: dr.mean(dr.square(image - fixed), axis=None),
    }
    ptracer = mi.load_dict({"type": "ptracer", "max_depth": MAX_DEPTH})

    def render(method, seed, params):
        if method == "ptracer":
            return mi.render(scene, params, integrator=ptracer, spp=1024, seed=seed)
        return photonmap.render(scene, heightmap.params, method="sppm", photons=400_000,
                                seed=seed, max_depth=MAX_DEPTH)  # fmt: skip

    out = {}
    for method in METHODS:
        for name, loss in losses.items():
            ad, fd = [], []
            for seed in range(seeds):
                heights = mi.Float(h0)
                dr.enable_grad(heights)
                heightmap.apply(heights)
                dr.backward(loss(render(method, seed, heightmap.params)))
                ad.append(float(dr.sum(dr.grad(heights) * mi.Float(d)).array[0]))
                eps, values = 0.05, []
                with dr.suspend_grad():
                    for sign in (1, -1):
                        heightmap.apply(mi.Float(h0 + sign * eps * d))
                        values.append(float(loss(render(method, seed, None)).array[0]))
                fd.append((values[0] - values[1]) / (2 * eps))
            out[f"{method}_{name}"] = {
                "ad": ad,
                "fd": fd,
                "ratio": float(np.mean(ad) / np.mean(fd)),
            }
            print(
                f"  {method:9s} {name:6s} AD/FD {out[f'{method}_{name}']['ratio']:.3f}", flush=True
            )
    return out


# ---------------------------------------------------------------------------------- outputs
def headline(results: dict, budget: Budget) -> dict:
    pm, pt = results.get("photonmap"), results.get("ptracer")
    out = {"steps_each" if budget.steps else "seconds_each": budget.each}
    for method, res in results.items():
        out[f"{method}_final_true_loss"] = res["rows"][-1]["true_loss"]
        out[f"{method}_steps"] = res["steps"]
        out[f"{method}_median_step_s"] = res["median_step_s"]
    out["initial_true_loss"] = next(iter(results.values()))["rows"][0]["true_loss"]
    ratio = None
    if pm and pt and pm["rows"][-1]["true_loss"] > 0:
        ratio = pt["rows"][-1]["true_loss"] / pm["rows"][-1]["true_loss"]
    out[f"loss_ratio_vs_ptracer_at_equal_{'steps' if budget.steps else 'time'}"] = ratio
    return out


def markdown(out: dict) -> str:
    lines = [f"# {NAME}", "", report.bullets(out["headline"]), ""]
    for method, res in out["methods"].items():
        s = ", ".join(f"{k} {v}" for k, v in res["settings"].items())
        lines += [f"## {LABELS[method]} ({s})", "",
                  report.records_table(res["rows"], [("seconds", "seconds", 1),
                                                     ("steps", "steps", None),
                                                     ("true loss", "true_loss", 4)]), ""]  # fmt: skip
    if "fd_check" in out:
        rows = [[k, report.fmt(np.mean(v["ad"]) * 1e4, 3), report.fmt(np.mean(v["fd"]) * 1e4, 3),
                 report.fmt(v["ratio"], 3)] for k, v in out["fd_check"].items()]  # fmt: skip
        lines += ["## gradient check (directional derivative ×1e4)", "",
                  report.markdown_table(["method_loss", "AD", "FD", "AD/FD"], rows), ""]  # fmt: skip
    m = out["machine"]
    lines.append(f"load average {m.get('load_average')} (before), {out['load_average_after']} "
                 f"(after); {m['cpu_model']}, {m['cores']} cores")  # fmt: skip
    return "\n".join(lines) + "\n"


def plot(out: dict, path: Path) -> None:
    with report.figure(path, size=(6, 4)) as axes:
        ax = axes[0][0]
        for method, res in out["methods"].items():
            rows = res["rows"]
            ax.plot([r["seconds"] for r in rows], [r["true_loss"] for r in rows], "o-",
                    label=f"{LABELS[method]}, {res['steps']} steps")  # fmt: skip
        ax.set_yscale("log")
        ax.set_xlabel("compute seconds (clock stopped at checkpoints)")
        ax.set_ylabel("true loss (ptracer, high spp)")
        ax.set_title("caustic design: loss against time")
        ax.legend()


def panel(images: list[np.ndarray], path: Path) -> None:
    """The images side by side, 2-pixel white gaps, each scaled by 1/2 of the target's peak."""
    h, w, _ = images[0].shape
    gap = np.ones((h, 2, 3), np.float32) * images[0].max()
    row = np.concatenate(sum(([im, gap] for im in images[:-1]), []) + [images[-1]], 1)
    row = np.clip(row / images[0].max(), 0, 1)
    path.write_bytes(encode_image(np.repeat(np.repeat(row, 2, 0), 2, 1), ".png"))


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, f"16×16 heightmap, 32² images, {QUICK_STEPS} steps each")
    parser.add_argument("--seconds", type=float, default=120.0, help="compute time per method")
    parser.add_argument("--steps", type=int, default=None,
                        help="a budget of steps per method instead of --seconds")  # fmt: skip
    parser.add_argument("--n", type=int, default=64, help="heightmap (exit-face grid) size")
    parser.add_argument("--res", type=int, default=64, help="render resolution (square)")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--pm-photons", type=int, default=100_000)
    parser.add_argument("--pm-radius", type=float, default=0.034,
                        help="kernel radius (scene units; a pixel is 0.03 on the receiver)")  # fmt: skip
    parser.add_argument("--pm-spp", type=int, default=4, help="eye paths per pixel")
    parser.add_argument("--pm-lr", type=float, default=3e-4)
    parser.add_argument("--pt-spp", type=int, default=32)
    parser.add_argument("--pt-lr", type=float, default=3e-4)
    parser.add_argument("--truth-spp", type=int, default=2048)
    parser.add_argument("--fd-check", action="store_true",
                        help="also check both methods' gradients against finite differences")  # fmt: skip
    args = parser.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    if unknown := sorted(set(methods) - set(METHODS)):
        raise SystemExit(f"--methods: unknown {unknown}; choose from {', '.join(METHODS)}")
    if args.steps is not None and args.steps < 1:
        raise SystemExit("--steps must be at least 1")
    if args.quick:
        args.steps, args.n, args.res, args.truth_spp = QUICK_STEPS, 16, 32, 256
        args.pm_photons, args.pm_radius, args.pt_spp = 20_000, 0.07, 8
    flag = dr.flag(dr.JitFlag.OptimizeCalls)
    dr.set_flag(dr.JitFlag.OptimizeCalls, False)  # both methods (module docstring)
    try:
        return run_all(args, methods)
    finally:
        dr.set_flag(dr.JitFlag.OptimizeCalls, flag)


def run_all(args, methods: list[str]) -> dict:
    machine = report.machine_info()
    scene = make_scene(args.n, args.res)
    heightmap = Heightmap(scene, args.n)
    target = EXAMPLE.smiley(args.res)
    settings = {
        "photonmap": {
            "photons": args.pm_photons,
            "spp": args.pm_spp,
            "radius": args.pm_radius,
            "lr": args.pm_lr,
        },
        "ptracer": {"spp": args.pt_spp, "lr": args.pt_lr},
    }
    runs = {m: Run(m, scene, heightmap, target, settings[m]) for m in METHODS if m in methods}
    budget = Budget(args.steps, steps=True) if args.steps else Budget(args.seconds)
    print(f"{budget.describe()}, interleaved: {settings}", flush=True)
    results = optimise(runs, scene, heightmap, target, budget, args.truth_spp, DECAYS)
    images = [np.array(target)]
    for method, run in runs.items():
        heights = run.heights()
        _, image = truth(scene, heightmap, heights, target, 4 * args.truth_spp, 9_000_000)
        images.append(image)
        results[method]["final_heights_abs_max"] = float(dr.max(dr.abs(heights)).array[0])
    out = {"machine": machine, "headline": headline(results, budget),
           "size": {"heightmap": args.n, "render": args.res, "truth_spp": args.truth_spp,
                    "max_depth": MAX_DEPTH},
           "methods": results, "load_average_after": report.load_average(),
           "optimize_calls": False}  # fmt: skip
    if args.fd_check:
        print("gradient check (AD / central finite differences)", flush=True)
        out["fd_check"] = fd_check()
    stem = report.results_stem(args.out_dir, NAME, args.quick)
    stem.parent.mkdir(parents=True, exist_ok=True)
    plot(out, stem.with_suffix(".png"))
    panel(images, stem.with_name(stem.name.replace(NAME, NAME + "_images")).with_suffix(".png"))
    return report.publish(stem, out, markdown(out))


if __name__ == "__main__":
    main()
