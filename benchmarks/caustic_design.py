"""Caustic design: a glass surface's heightmap optimised so that its caustic matches a target
image, with gradients of differentiable photon mapping (``photonmap.render``) against the same
optimisation driven by each of Mitsuba's gradients (``ptracer``, ``prb``, ``prb_projective``), at
equal compute time, in one run, on three problems (``examples/caustic_design.py`` builds them:
its ``PROBLEMS``, ``Heightmap`` and ``smiley``, loaded from there):

- ``tutorial`` — Mitsuba 3's caustic-design tutorial (``inverse_rendering/caustics_optimization``
  of mitsuba-tutorials): a ``directionalarea`` light (a 2×2 rectangle at y = 5 shining down,
  nearly the sun), a glass slab (ior 1.5, no specular reflection: a flat entry face at y = 0.2,
  and an exit face at y = 0 that is an ``n``×``n`` vertex grid displaced along its normal by the
  heightmap, clipped to ±0.01), a white diffuse receiver at y = −7, and a perspective camera at
  y = −4.65 looking down at the receiver (between slab and receiver, so it sees the receiver
  directly: ``ptracer`` connects receiver hits to the camera). ``max_depth`` 4. Truth:
  ``ptracer`` (``path`` cannot hit a light that shines in one direction only).
- ``pool`` — a water surface (the heightmap, ``dielectric`` of index 1.33, clipped to ±0.1) over
  a white pool floor one unit below, a 0.3×0.3 area light three units above, the camera two above,
  looking down *through the water*: no light path connects to the camera. ``max_depth`` 4.
  Truth: ``path``.
- ``window`` — the tutorial's slab (heights clipped to ±0.03) under a 0.2×0.2 area light four
  units above it, the floor two below, and the camera looking at the floor through a glass pane
  just in front of it. ``max_depth`` 6. Truth: ``path``.

The target (``smiley`` of the example) is a smiley drawn with NumPy at the render resolution; the
loss is the tutorial's scale-independent L2, ``mean((I / mean(detach(I)) − T / mean(T))²)``.

Every optimisation starts from the flat surface and runs Adam (``mi.ad.Adam``) on the heightmap,
one render + backward + step per iteration, each with its own learning rate and sample budget:
a Mitsuba integrator with ``--mi-spp`` samples per pixel (``mi.render(scene, params,
integrator=..., seed=step)``), photon mapping with ``--pm-photons`` photons, kernel radius
``--pm-radius`` and ``--pm-spp`` eye paths per pixel (``photonmap.render(scene, params,
method="sppm", seed=step)``); each problem has its own defaults (``SETTINGS``). A warm-up step of
each compiles its kernels first; a Mitsuba integrator whose warm-up renders a black image (no
path it samples reaches the light and the camera: ``prb`` under the tutorial's directional light,
``ptracer`` through the water or the window) is not run, and the results say so. The runs of a
problem are interleaved, step by step (the one with less compute spent goes next), so that the
load of a shared machine falls on all alike; each step is timed on its own (``dr.sync_thread``
before and after). As in the tutorial, the learning rates halve late: at half and at three
quarters of ``--seconds``. With ``--steps N`` the budget is ``N`` steps each instead of seconds
(checkpoints after 1, 2, 4, 8, … steps; the learning rates halve at the same fractions of
``N``), so that what a run does is fixed whatever the machine's speed: ``--quick`` runs a few
steps each on small grids. ``dr.JitFlag.OptimizeCalls`` is off for the whole run, every method
(Dr.Jit 1.5 loses derivatives through Mitsuba's shape calls with it on), and restored afterwards.

Progress is measured with the clock stopped: at checkpoints (seconds of compute) the current
heightmap is rendered by the problem's truth integrator at ``truth_spp`` in two halves of
different seeds, and the *true loss* is ``mean((A − T)(B − T))`` of the two normalised halves
(unbiased for the loss of the noise-free image: the halves' noise is independent). Never by
photon mapping itself.

Headline per problem: each method's final true loss, steps and median step time, and
``loss_ratio_vs_best_mitsuba``: the lowest final true loss of the Mitsuba gradients that are
competitors — whose true loss fell by at least 20 % from the start — over photon mapping's.
Where none is a competitor, the ratio is absent and the comparison is photon mapping's final
true loss as a fraction of the start against the fraction ``ptracer`` reaches on the tutorial in
the same run (``…_fraction_of_initial``).

Writes ``results/caustic_design.json``, ``.md``, ``.png`` (true loss against time, one panel a
problem) and ``caustic_design_images_<problem>.png`` (target | photon mapping's result | the best
Mitsuba gradient's result, each rendered by the truth integrator at 4 × ``truth_spp``); ``_quick``
with ``--quick``. ``--fd-check`` instead checks each method's gradient against central
differences on the tutorial's slab and the pool's water surface (``caustic_design_fd.*``).

    .venv/bin/python benchmarks/caustic_design.py [--quick] [--seconds 120 | --steps N]
        [--problems tutorial,pool,window]
    .venv/bin/python benchmarks/caustic_design.py --fd-check
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
MITSUBA = ("ptracer", "prb", "prb_projective")
METHODS = ("photonmap",) + MITSUBA
LABELS = {"photonmap": "photon mapping (photonmap.render)", "ptracer": "Mitsuba ptracer",
          "prb": "Mitsuba prb", "prb_projective": "Mitsuba prb_projective"}  # fmt: skip
DECAYS = (0.5, 0.75)  # the learning rates halve at these fractions of the time budget
CHECKPOINTS = (2, 5, 10, 20, 40, 60, 90, 120, 180, 240)  # seconds of compute
COMPETITOR = 0.8  # a gradient competes if its true loss ends at most this fraction of the start


# ------------------------------------------------------------------------------------ scene
def _example():
    """``examples/caustic_design.py``, which builds the scenes, the heightmap and the target."""
    path = Path(__file__).resolve().parents[1] / "examples" / "caustic_design.py"
    spec = importlib.util.spec_from_file_location("caustic_design_example", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


EXAMPLE = _example()
PROBLEMS, Heightmap = EXAMPLE.PROBLEMS, EXAMPLE.Heightmap

# Per problem: grid and film size, the truth's samples per pixel, photon mapping's and Mitsuba's
# settings (samples per pixel by integrator), full and --quick. The learning rates and radii
# are the example's.
SETTINGS = {
    "tutorial": {"n": 64, "res": 64, "truth_spp": 2048, "photons": 100_000, "pm_spp": 4,
                 "mi_spp": {"ptracer": 32, "prb": 32, "prb_projective": 8}},
    "pool": {"n": 64, "res": 32, "truth_spp": 32768, "photons": 100_000, "pm_spp": 4,
             "mi_spp": {"ptracer": 32, "prb": 64, "prb_projective": 16}},
    "window": {"n": 64, "res": 32, "truth_spp": 32768, "photons": 100_000, "pm_spp": 4,
               "mi_spp": {"ptracer": 32, "prb": 64, "prb_projective": 16}},
}  # fmt: skip
QUICK = {"tutorial": {"n": 16, "res": 32, "truth_spp": 256, "photons": 20_000, "steps": 24,
                      "mi_spp": {"ptracer": 8, "prb": 8, "prb_projective": 2}},
         "pool": {"n": 8, "res": 16, "truth_spp": 512, "photons": 20_000, "steps": 4,
                  "mi_spp": {"ptracer": 4, "prb": 8, "prb_projective": 2}},
         "window": {"n": 8, "res": 16, "truth_spp": 512, "photons": 20_000, "steps": 4,
                    "mi_spp": {"ptracer": 4, "prb": 8, "prb_projective": 2}}}  # fmt: skip


def loss_of(image: mi.TensorXf, target: mi.TensorXf) -> mi.Float:
    """The tutorial's scale-independent L2 loss (``target`` has mean 1). A black image (a few
    samples that found no light) gives the loss of a black image and no gradient, not NaN."""
    mean = dr.maximum(dr.mean(dr.detach(image), axis=None), 1e-30)
    return dr.mean(dr.square(image / mean - target), axis=None)


class Setup:
    """One problem as run here: its scene, heightmap and target at ``n``, ``res``."""

    def __init__(self, name: str, n: int, res: int):
        self.name, self.problem = name, PROBLEMS[name]
        self.scene = self.problem.make(n, res)
        self.heightmap = Heightmap(self.scene, n, self.problem.key, self.problem.clip)
        self.target = EXAMPLE.smiley(res)
        self.max_depth = self.problem.max_depth

    def mitsuba(self, method: str):
        """Mitsuba's integrator ``method`` at the problem's depth (``prb_projective`` without
        indirect silhouette samples, as Mitsuba advises where it finds none)."""
        extra = {"sppi": 0} if method == "prb_projective" else {}
        return mi.load_dict({"type": method, "max_depth": self.max_depth, **extra})

    def truth(self, heights, spp: int, seed: int):
        """The true loss of ``heights`` (module docstring: two halves of ``spp / 2`` by the
        problem's truth integrator) and the mean of the halves (normalised to mean 1)."""
        integrator = self.mitsuba(self.problem.check)
        with dr.suspend_grad():
            self.heightmap.apply(heights)
            halves = []
            for k in range(2):
                image = mi.render(self.scene, integrator=integrator, spp=spp // 2, seed=seed + k)
                halves.append(np.array(image / dr.mean(image, axis=None)))
        t = np.array(self.target)
        loss = float(np.mean((halves[0] - t) * (halves[1] - t)))
        return loss, (halves[0] + halves[1]) / 2


# ------------------------------------------------------------------------------ optimisation
class Run:
    """One method's optimisation: ``step()`` renders with gradients, backpropagates the loss and
    takes an Adam step."""

    def __init__(self, method: str, setup: Setup, settings: dict):
        self.method, self.setup, self.settings = method, setup, settings
        self.opt = mi.ad.Adam(lr=settings["lr"])
        self.opt["heights"] = dr.zeros(mi.Float, dr.width(setup.heightmap.y))
        self.steps = 0
        self.integrator = None if method == "photonmap" else setup.mitsuba(method)

    def render(self, seed: int) -> mi.TensorXf:
        scene, params = self.setup.scene, self.setup.heightmap.params
        if self.integrator is not None:
            return mi.render(scene, params, integrator=self.integrator, seed=seed,
                             spp=self.settings["spp"])  # fmt: skip
        return photonmap.render(scene, params, method="sppm", seed=seed,
                                photons=self.settings["photons"], spp=self.settings["spp"],
                                radius=self.settings["radius"],
                                max_depth=self.setup.max_depth)  # fmt: skip

    def renders_nothing(self, spp: int = 256) -> bool:
        """Whether the flat surface's image at ``spp`` samples per pixel is black: no path the
        integrator samples connects the light and the camera."""
        self.setup.heightmap.apply(self.opt["heights"])
        with dr.suspend_grad():
            image = mi.render(self.setup.scene, integrator=self.integrator, spp=spp, seed=0)
            return float(dr.max(dr.ravel(image.array)).array[0]) <= 0

    def step(self) -> float:
        self.setup.heightmap.apply(self.opt["heights"])
        loss = loss_of(self.render(self.steps), self.setup.target)
        dr.backward(loss)
        self.opt.step()
        dr.eval(self.opt["heights"])
        self.steps += 1
        return loss.array[0]

    def heights(self) -> mi.Float:
        return mi.Float(dr.detach(self.opt["heights"]))


def optimise(runs: dict[str, Run], setup: Setup, budget: Budget, truth_spp: int, decays=()):
    """Run every optimisation of ``runs`` for ``budget`` each (compute seconds or steps),
    interleaved (the one that has used the least goes next, so that a shared machine's load
    falls on all alike); the true loss of each at its checkpoints (clock stopped); each learning
    rate halves when its run has used each fraction ``decays`` of the budget. Returns
    ``{method: result}``."""
    for method, run in runs.items():  # compile each method's kernels; the result is dropped
        Run(method, setup, run.settings).step()
    flat = next(iter(runs.values())).heights()
    initial, _ = setup.truth(flat, truth_spp, 7_000_000)
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
            loss, _ = setup.truth(run.heights(), truth_spp, 8_000_000)
            st["rows"].append({"seconds": st["spent"], "steps": run.steps, "true_loss": loss,
                               "step_loss": float(step_loss)})  # fmt: skip
            print(f"  {setup.name:8s} {method:14s} {st['spent']:7.1f} s  {run.steps:5d} steps  "
                  f"true loss {loss:.4f}", flush=True)  # fmt: skip
    return {m: {"settings": runs[m].settings, "rows": st["rows"], "steps": runs[m].steps,
                "median_step_s": median(st["times"]), "seconds": st["spent"]}
            for m, st in state.items()}  # fmt: skip


# ------------------------------------------------------------------------- gradient check
FD_CHECKS = {"tutorial": ("photonmap", "ptracer"), "pool": ("photonmap", "prb", "prb_projective")}


def fd_check(name: str, methods, seeds: int = 2) -> dict:
    """Each method's directional derivative (AD: ``dr.backward``, then ``<grad, d>``) against
    central finite differences of its own image with the same seed (``eps`` = 0.05 of ``d``), on
    a 16² grid and 32² film, at a smooth bump ``h0`` along a smooth direction ``d`` (both scaled
    to the problem's clip), for a linear loss (``mean(I · w)``, ``w`` a smooth ramp: no noise
    term) and the L2 loss to a fixed image. Mitsuba's integrators render their gradients with a
    seed of their own (``mi.render``'s ``seed_grad``), so for the L2 loss their AD and FD differ
    by the noise covariance too; the linear loss is the clean test. Where the truth is ``path``
    (a light found by chance through the glass) Mitsuba renders 65536 samples per pixel, so that
    its finite differences are not noise."""
    n, res = 16, 32
    setup = Setup(name, n, res)
    scale = setup.problem.clip / 0.01
    y, x = np.mgrid[0:n, 0:n] / (n - 1) * 2 - 1
    h0 = (scale * 0.004 * np.exp(-((x - 0.2) ** 2 + y**2) / 0.2)).ravel().astype(np.float32)
    d = (scale * 0.003 * np.sin(3 * x + 1) * np.cos(2 * y)).ravel().astype(np.float32)
    ramp = np.sin(np.arange(res) / res * 3.0)[None, :, None] * np.ones((res, 1, 3))
    weight = mi.TensorXf(ramp.astype(np.float32))
    fixed = mi.TensorXf(np.random.default_rng(0).uniform(0, 0.5, (res, res, 3)).astype(np.float32))
    losses = {
        "linear": lambda image: dr.mean(image * weight, axis=None),
        "l2": lambda image: dr.mean(dr.square(image - fixed), axis=None),
    }
    spp = 1024 if setup.problem.check == "ptracer" else 65536
    heightmap = setup.heightmap

    def render(method, seed, params):
        if method == "photonmap":
            return photonmap.render(setup.scene, heightmap.params, method="sppm",
                                    photons=400_000, seed=seed, max_depth=setup.max_depth)  # fmt: skip
        return mi.render(setup.scene, params, integrator=setup.mitsuba(method), spp=spp,
                         seed=seed)  # fmt: skip

    out = {}
    for method in methods:
        ad = {k: [] for k in losses}
        fd = {k: [] for k in losses}
        for seed in range(seeds):
            for loss_name, loss in losses.items():
                heights = mi.Float(h0)
                dr.enable_grad(heights)
                heightmap.apply(heights)
                dr.backward(loss(render(method, seed, heightmap.params)))
                ad[loss_name].append(float(dr.sum(dr.grad(heights) * mi.Float(d)).array[0]))
            eps, images = 0.05, []
            with dr.suspend_grad():
                for sign in (1, -1):
                    heightmap.apply(mi.Float(h0 + sign * eps * d))
                    images.append(render(method, seed, None))
            for loss_name, loss in losses.items():
                plus, minus = (float(loss(image).array[0]) for image in images)
                fd[loss_name].append((plus - minus) / (2 * eps))
        for loss_name in losses:
            key = f"{name}_{method}_{loss_name}"
            ratio = float(np.mean(ad[loss_name]) / np.mean(fd[loss_name]))
            out[key] = {"ad": ad[loss_name], "fd": fd[loss_name], "ratio": ratio}
            print(f"  {key:32s} AD/FD {ratio:.3f}", flush=True)
    return out


def fd_markdown(out: dict) -> str:
    rows = [[k, report.fmt(np.mean(v["ad"]) * 1e4, 3), report.fmt(np.mean(v["fd"]) * 1e4, 3),
             report.fmt(v["ratio"], 3)] for k, v in out["fd_check"].items()]  # fmt: skip
    m = out["machine"]
    return "\n".join([f"# {NAME}_fd: gradient check (directional derivative ×1e4)", "",
                      report.markdown_table(["problem_method_loss", "AD", "FD", "AD/FD"], rows),
                      "", f"{m['cpu_model']}, {m['cores']} cores"]) + "\n"  # fmt: skip


# ---------------------------------------------------------------------------------- outputs
def headline(results: dict, skipped: dict, budget: Budget) -> dict:
    """One problem's headline (module docstring)."""
    pm = results["photonmap"]
    initial = pm["rows"][0]["true_loss"]
    out = {"steps_each" if budget.steps else "seconds_each": budget.each,
           "initial_true_loss": initial}  # fmt: skip
    for method, res in results.items():
        out[f"{method}_final_true_loss"] = res["rows"][-1]["true_loss"]
        out[f"{method}_fraction_of_initial"] = res["rows"][-1]["true_loss"] / initial
        out[f"{method}_steps"] = res["steps"]
        out[f"{method}_median_step_s"] = res["median_step_s"]
    competitors = {m: res["rows"][-1]["true_loss"] for m, res in results.items()
                   if m != "photonmap" and res["rows"][-1]["true_loss"] <= COMPETITOR * initial}  # fmt: skip
    out["competitors"] = sorted(competitors, key=competitors.get)
    out["renders_nothing"] = sorted(skipped)
    ratio = None
    if competitors and out["photonmap_final_true_loss"] > 0:
        ratio = min(competitors.values()) / out["photonmap_final_true_loss"]
    out["loss_ratio_vs_best_mitsuba"] = ratio
    return out


def markdown(out: dict) -> str:
    lines = [f"# {NAME}", ""]
    for name, res in out["problems"].items():
        lines += [f"## {name}", "", report.bullets(res["headline"]), ""]
        for method, run in res["methods"].items():
            s = ", ".join(f"{k} {v}" for k, v in run["settings"].items())
            lines += [f"### {LABELS[method]} ({s})", "",
                      report.records_table(run["rows"], [("seconds", "seconds", 1),
                                                         ("steps", "steps", None),
                                                         ("true loss", "true_loss", 4)]), ""]  # fmt: skip
        for method, reason in res["skipped"].items():
            lines += [f"- {LABELS[method]}: {reason}"]
        lines.append("")
    m = out["machine"]
    lines.append(f"load average {m.get('load_average')} (before), {out['load_average_after']} "
                 f"(after); {m['cpu_model']}, {m['cores']} cores")  # fmt: skip
    return "\n".join(lines) + "\n"


def plot(out: dict, path: Path) -> None:
    problems = out["problems"]
    with report.figure(path, cols=len(problems), size=(5 * len(problems), 4)) as axes:
        for ax, (name, res) in zip(axes[0], problems.items(), strict=True):
            for method, run in res["methods"].items():
                rows = run["rows"]
                ax.plot([r["seconds"] for r in rows], [r["true_loss"] for r in rows], "o-",
                        label=f"{LABELS[method]}, {run['steps']} steps")  # fmt: skip
            ax.set_yscale("log")
            ax.set_xlabel("compute seconds (clock stopped at checkpoints)")
            ax.set_ylabel(f"true loss ({PROBLEMS[name].check}, high spp)")
            ax.set_title(f"caustic design: {name}")
            ax.legend(fontsize=7)


def panel(images: list[np.ndarray], path: Path) -> None:
    """The images side by side, 2-pixel white gaps, each scaled by 1/2 of the target's peak."""
    h, w, _ = images[0].shape
    gap = np.ones((h, 2, 3), np.float32) * images[0].max()
    row = np.concatenate(sum(([im, gap] for im in images[:-1]), []) + [images[-1]], 1)
    row = np.clip(row / images[0].max(), 0, 1)
    scale = max(1, 128 // h)
    path.write_bytes(encode_image(np.repeat(np.repeat(row, scale, 0), scale, 1), ".png"))


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "each problem on small grids, a few steps each")
    parser.add_argument("--seconds", type=float, default=120.0, help="compute time per method")
    parser.add_argument("--steps", type=int, default=None,
                        help="a budget of steps per method instead of --seconds")  # fmt: skip
    parser.add_argument("--problems", default=",".join(PROBLEMS))
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--n", type=int, default=None, help="heightmap size (default: the problem's)")
    parser.add_argument("--res", type=int, default=None, help="film size (default: the problem's)")
    parser.add_argument("--pm-photons", type=int, default=None, help="default: the problem's")
    parser.add_argument("--pm-radius", type=float, default=None,
                        help="kernel radius in scene units (default: the problem's)")  # fmt: skip
    parser.add_argument("--pm-spp", type=int, default=None, help="eye paths per pixel")
    parser.add_argument("--pm-lr", type=float, default=None)
    parser.add_argument("--mi-spp", type=int, default=None,
                        help="Mitsuba's samples per pixel (default: the problem's)")  # fmt: skip
    parser.add_argument("--mi-lr", type=float, default=None)
    parser.add_argument("--fd-check", action="store_true",
                        help="instead, check the gradients against finite differences")  # fmt: skip
    args = parser.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    problems = [p for p in args.problems.split(",") if p]
    if unknown := sorted(set(methods) - set(METHODS)):
        raise SystemExit(f"--methods: unknown {unknown}; choose from {', '.join(METHODS)}")
    if unknown := sorted(set(problems) - set(PROBLEMS)):
        raise SystemExit(f"--problems: unknown {unknown}; choose from {', '.join(PROBLEMS)}")
    if "photonmap" not in methods:
        raise SystemExit("--methods must include photonmap (the headline compares against it)")
    if args.steps is not None and args.steps < 1:
        raise SystemExit("--steps must be at least 1")
    flag = dr.flag(dr.JitFlag.OptimizeCalls)
    dr.set_flag(dr.JitFlag.OptimizeCalls, False)  # every method (module docstring)
    try:
        if args.fd_check:
            out = {"machine": report.machine_info(), "fd_check": {}}
            for name, checked in FD_CHECKS.items():
                out["fd_check"].update(fd_check(name, checked))
            stem = report.results_stem(args.out_dir, NAME + "_fd")
            return report.publish(stem, out, fd_markdown(out))
        return run_all(args, methods, problems)
    finally:
        dr.set_flag(dr.JitFlag.OptimizeCalls, flag)


def problem_settings(name: str, args) -> dict:
    """The settings of problem ``name``: :data:`SETTINGS` (:data:`QUICK` over it with
    ``--quick``), the example's learning rate and radius, then the command line's overrides."""
    base = {**SETTINGS[name], **(QUICK[name] if args.quick else {})}
    base.update({k: getattr(args, k) for k in ("n", "res") if getattr(args, k)})
    problem = PROBLEMS[name]
    radius = problem.radius * 64 / base["res"]  # the example's radius is for a 64² film
    pm = {"photons": args.pm_photons or base["photons"], "spp": args.pm_spp or base["pm_spp"],
          "radius": args.pm_radius or radius, "lr": args.pm_lr or problem.lr}  # fmt: skip
    mitsuba = {m: {"spp": args.mi_spp or spp, "lr": args.mi_lr or problem.lr}
               for m, spp in base["mi_spp"].items()}  # fmt: skip
    steps = args.steps or (base["steps"] if args.quick else None)
    return {"n": base["n"], "res": base["res"], "truth_spp": base["truth_spp"], "steps": steps,
            "methods": {"photonmap": pm, **mitsuba}}  # fmt: skip


def run_problem(name: str, args, methods: list[str]) -> tuple[dict, list[np.ndarray]]:
    """Optimise problem ``name`` with every method of ``methods``; its results and its images
    (target, photon mapping's result, the best Mitsuba gradient's result)."""
    settings = problem_settings(name, args)
    setup = Setup(name, settings["n"], settings["res"])
    budget = Budget(settings["steps"], steps=True) if settings["steps"] else Budget(args.seconds)
    runs, skipped = {}, {}
    for method in methods:
        run = Run(method, setup, settings["methods"][method])
        if method != "photonmap" and run.renders_nothing():
            skipped[method] = "renders a black image at 256 spp: no path it samples connects " \
                "the light and the camera"
            continue
        runs[method] = run
    described = {m: r.settings for m, r in runs.items()}
    print(f"{name}: {budget.describe()}, interleaved: {described}; not run: {sorted(skipped)}",
          flush=True)  # fmt: skip
    results = optimise(runs, setup, budget, settings["truth_spp"], DECAYS)
    head = headline(results, skipped, budget)
    images = [np.array(setup.target)]
    finals = [("photonmap", runs["photonmap"])]
    if others := [m for m in runs if m != "photonmap"]:  # the Mitsuba gradient that did best
        best = min(others, key=lambda m: results[m]["rows"][-1]["true_loss"])
        finals.append((best, runs[best]))
    for method, run in finals:
        heights = run.heights()
        _, image = setup.truth(heights, 4 * settings["truth_spp"], 9_000_000)
        images.append(image)
        results[method]["final_heights_abs_max"] = float(dr.max(dr.abs(heights)).array[0])
    head["images"] = ["target"] + [m for m, _ in finals]
    size = {k: settings[k] for k in ("n", "res", "truth_spp")} | {"max_depth": setup.max_depth,
            "truth": setup.problem.check}  # fmt: skip
    return {"headline": head, "size": size, "methods": results, "skipped": skipped}, images


def run_all(args, methods: list[str], problems: list[str]) -> dict:
    machine = report.machine_info()
    stem = report.results_stem(args.out_dir, NAME, args.quick)
    stem.parent.mkdir(parents=True, exist_ok=True)
    out = {"machine": machine, "problems": {}, "optimize_calls": False}
    for name in problems:
        out["problems"][name], images = run_problem(name, args, methods)
        panel(images, stem.with_name(f"{NAME}_images_{name}{stem.name[len(NAME):]}.png"))
    tutorial = out["problems"].get("tutorial", {}).get("headline", {})
    if "ptracer_fraction_of_initial" in tutorial:
        for res in out["problems"].values():
            res["headline"]["tutorial_ptracer_fraction_of_initial"] = tutorial[
                "ptracer_fraction_of_initial"
            ]
    out["load_average_after"] = report.load_average()
    plot(out, stem.with_suffix(".png"))
    return report.publish(stem, out, markdown(out))


if __name__ == "__main__":
    main()
