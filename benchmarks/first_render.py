"""The first render on a new machine: ``make demo``'s command on an empty Dr.Jit kernel cache
against the same command once the cache holds its kernels, per stage, with the kernels each
stage compiled.

Each run is a fresh process (as a user's ``photonmap render`` is) running the command's own code
(``photonmap.cli``'s ``render``, from this checkout's ``src/``) with ``DRJIT_CACHE_DIR`` set: a
new empty folder for the *cold* run, the folder that cold run filled for the *warm* run after it.
Kernel history is on in both (Dr.Jit's ``JitFlag.KernelHistory``), and every pipeline's stage
timer records the kernels each stage launched: a kernel counts as compiled when it was neither in
memory nor on disk. Per run:
the seconds of ``import photonmap`` (which starts Dr.Jit and compiles one kernel), of the command
(scene loading, pipeline set-up, the render, writing the images) and of the render itself (the
sum of its stage times, what ``--timings`` prints), the stages' milliseconds, kernels compiled
and milliseconds spent compiling them. ``--rounds`` cold/warm pairs, interleaved; medians.

Headline: ``cold_over_warm_render``, the median cold render time over the median warm one (goal
≤ 1.25), ``cold_over_warm_command`` the same for the whole command, and the kernels the cold
render compiled.

Writes ``results/first_render.json`` and ``.md`` (``_quick`` with ``--quick``: one round of a
64-pixel-wide render).

    .venv/bin/python benchmarks/first_render.py [--quick] [--rounds 3]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import report
from timing import median

NAME = "first_render"
COMMAND = ["render", "glass_sphere_fog", "--timings"]  # make demo's, with -o added per run
HERE = Path(__file__).resolve().parent

CHILD = r"""
import json, sys, time
start = time.perf_counter()
import photonmap
import_s = time.perf_counter() - start
import drjit as dr
sys.path.insert(0, sys.argv[1])
from timing import profiling_timer
import photonmap.core.stages as stages

timers = []


class Recording(profiling_timer(stages.StageTimer)):
    def __init__(self):
        super().__init__()
        timers.append(self)


stages.StageTimer = Recording  # every pipeline's stage cache makes its timer from this name
dr.set_flag(dr.JitFlag.KernelHistory, True)
from photonmap.cli import app

start = time.perf_counter()
app(sys.argv[2:], standalone_mode=False)
command_s = time.perf_counter() - start
timer = timers[-1]
stages_out = {}
for stage, ms in timer.ms.items():
    compiled = [k for k in timer.kernels.get(stage, []) if k.get("compiled")]
    stages_out[stage] = {"ms": ms, "kernels_compiled": len(compiled),
                         "compile_ms": sum(k.get("codegen_time_ms", 0.0)
                                           + k.get("backend_time_ms", 0.0) for k in compiled)}
print("RESULT " + json.dumps({"import_s": import_s, "command_s": command_s,
                              "render_s": timer.total / 1e3, "stages": stages_out}))
"""


def run(cache: str, width: int | None, out_dir: str) -> dict:
    """One fresh process rendering with the kernel cache ``cache``; its measurements plus the
    process's wall time and the number of kernels it added to the cache."""
    env = {**os.environ, "DRJIT_CACHE_DIR": cache, "PYTHONPATH": str(HERE.parent / "src")}
    args = [*COMMAND, "-o", os.path.join(out_dir, "demo.png"), "-o",
            os.path.join(out_dir, "demo.exr")]  # fmt: skip
    if width:
        args += ["--width", str(width)]
    before = len(os.listdir(cache))
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", CHILD, str(HERE), *args], env=env,
                          capture_output=True, text=True, check=False)  # fmt: skip
    wall = time.perf_counter() - start
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"the render failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    result = json.loads(lines[-1][len("RESULT "):])
    result.update(process_s=wall, kernels_cached=len(os.listdir(cache)) - before,
                  load_1min=report.load_average()[0])  # fmt: skip
    return result


def summary(runs: list[dict]) -> dict:
    """Medians over ``runs`` of every number, per stage too."""
    out = {k: median(r[k] for r in runs)
           for k in ("import_s", "command_s", "render_s", "process_s", "kernels_cached")}
    stages = {}
    for stage in runs[0]["stages"]:
        stages[stage] = {k: median(r["stages"][stage][k] for r in runs)
                         for k in ("ms", "kernels_compiled", "compile_ms")}  # fmt: skip
    out["stages"] = stages
    return out


def markdown(out: dict) -> str:
    cold, warm = out["cold"], out["warm"]
    rows = [[stage, report.fmt(s["ms"], 0), report.fmt(warm["stages"][stage]["ms"], 0),
             report.fmt(s["ms"] / max(warm["stages"][stage]["ms"], 1e-9), 2),
             int(s["kernels_compiled"]), report.fmt(s["compile_ms"], 0),
             int(warm["stages"][stage]["kernels_compiled"])]
            for stage, s in cold["stages"].items()]  # fmt: skip
    for key, label in (("render_s", "render (sum of stages)"), ("import_s", "import photonmap"),
                       ("command_s", "command"), ("process_s", "process")):  # fmt: skip
        rows.append([label, report.fmt(1e3 * cold[key], 0), report.fmt(1e3 * warm[key], 0),
                     report.fmt(cold[key] / warm[key], 2), "", "", ""])  # fmt: skip
    head = ["stage", "cold ms", "warm ms", "cold/warm", "kernels compiled (cold)",
            "compile ms (cold)", "kernels compiled (warm)"]  # fmt: skip
    m = out["machine"]
    return (f"# {NAME}\n\n`photonmap {' '.join(out['command'])}`, medians of {out['rounds']} "
            f"cold/warm rounds\n\n{report.bullets(out['headline'])}\n\n"
            f"{report.markdown_table(head, rows)}\n\nload average {m.get('load_average')} "
            f"(before), {out['load_average_after']} (after); {m['cpu_model']}, {m['cores']} "
            "cores\n")  # fmt: skip


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "one round at 64 pixels wide (smoke)")
    parser.add_argument("--rounds", type=int, default=3, help="cold/warm pairs")
    args = parser.parse_args(argv)
    rounds, width = (1, 64) if args.quick else (args.rounds, None)
    machine = report.machine_info()
    cold, warm = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(rounds):
            cache = os.path.join(tmp, f"cache{k}")
            os.makedirs(cache)
            cold.append(run(cache, width, tmp))
            warm.append(run(cache, width, tmp))
            print(f"  round {k + 1}: render cold {cold[-1]['render_s']:.2f} s, warm "
                  f"{warm[-1]['render_s']:.2f} s; kernels compiled cold "
                  f"{cold[-1]['kernels_cached']}", flush=True)  # fmt: skip
    c, w = summary(cold), summary(warm)
    headline = {
        "cold_over_warm_render": c["render_s"] / w["render_s"],
        "cold_over_warm_command": c["command_s"] / w["command_s"],
        "cold_render_s": c["render_s"],
        "warm_render_s": w["render_s"],
        "kernels_compiled_cold": c["kernels_cached"],
        "kernels_compiled_cold_render": sum(s["kernels_compiled"] for s in c["stages"].values()),
    }
    out = {"machine": machine, "command": [*COMMAND] + (["--width", str(width)] if width else []),
           "rounds": rounds, "headline": headline, "cold": c, "warm": w,
           "runs": {"cold": cold, "warm": warm}, "load_average_after": report.load_average()}  # fmt: skip
    stem = report.results_stem(args.out_dir, NAME, args.quick)
    return report.publish(stem, out, markdown(out))


if __name__ == "__main__":
    main()
