"""Every method on scenes written as a user writes them, against Mitsuba on the same file.

Each file of ``tests/scenes/`` is rendered by ``photonmap render FILE --method M`` (the command
users run, in a subprocess on this checkout's sources, the methods' defaults unless ``--set`` is
given) for M in volume, surface, screen, sppm, and by Mitsuba with the file's own
``<integrator>`` at a high sample count (the reference; cached under ``results/cache/``). Per
(file, method): the exit status, the ``error:`` line of a refusal or the last line of a crash,
the mean-brightness ratio to the reference, the relative RMSE of 4 × 4-block means
(``photonmap.compare``) and the wall time of the command (Python start-up and imports included;
``cli_startup_s`` is that part alone). A ``mitsuba`` column renders the file with its own
integrator at ``--mitsuba-spp`` samples for scale: the error a short run of the ground truth's own
renderer reaches, and its time.

Writes ``results/<name>.json`` and ``results/<name>.md`` (default name ``user_scenes``).

    nice -n 5 .venv/bin/python benchmarks/user_scenes.py [--scenes a,b] [--methods surface,sppm]
        [--set surface:photons=50000] [--ref-spp 16384] [--name user_scenes_before]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import importlib.util  # noqa: E402

import numpy as np  # noqa: E402

import report  # noqa: E402
import timing  # noqa: E402


def _helpers():
    """``tests/user_scenes.py`` (the corpus and its references), loaded by path: its module name
    is this script's own."""
    path = Path(__file__).resolve().parent.parent / "tests" / "user_scenes.py"
    spec = importlib.util.spec_from_file_location("tests_user_scenes", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


us = _helpers()


def parse_sets(items: list[str]) -> dict[str, dict[str, str]]:
    """``METHOD:KEY=VALUE`` → {method: {key: value}}."""
    out: dict[str, dict[str, str]] = {}
    for item in items:
        method, _, kv = item.partition(":")
        key, eq, value = kv.partition("=")
        if method not in us.METHODS or not eq:
            sys.exit(f"--set expects METHOD:KEY=VALUE with METHOD in {us.METHODS}, got {item!r}")
        out.setdefault(method, {})[key] = value
    return out


def cli_startup() -> float:
    """Seconds ``photonmap --help`` takes: Python start-up and the imports every run pays."""
    code = "import sys; from photonmap.cli import app; sys.argv[0] = 'photonmap'; app()"
    env = {**os.environ, "PYTHONPATH": str(us.REPO / "src")}
    times = []
    for _ in range(2):
        start = time.perf_counter()
        subprocess.run(
            [sys.executable, "-c", code, "--help"],
            cwd=us.REPO,
            env=env,
            capture_output=True,
            check=False,
        )
        times.append(time.perf_counter() - start)
    return min(times)


def status(run: us.Run) -> str:
    if run.returncode == 0:
        return "ok"
    if run.refused:
        return "refused"
    if run.error and run.error.startswith("timeout"):
        return "timeout"
    return "crashed"


def mitsuba_row(path: Path, ref: np.ndarray, spp: int) -> dict:
    """The file's own integrator at ``spp`` (seeds far from the reference's)."""
    import mitsuba as mi

    scene = us.load(path)
    integrator = scene.integrator() or mi.load_dict({"type": "path"})
    mi.render(scene, integrator=integrator, spp=1, seed=10_000)  # compile
    seconds, image = timing.timed(
        lambda: np.array(mi.render(scene, integrator=integrator, spp=spp, seed=10_001))
    )
    return {
        "status": "ok",
        "spp": spp,
        "seconds": seconds,
        **us.errors(np.asarray(image, np.float64)[..., :3], ref),
    }


def run_one(
    path: Path, method: str, ref: np.ndarray, sets: dict, timeout: float, seed: int
) -> dict:
    run = us.render_cli(path, method, sets, seed=seed, timeout=timeout)
    row = {
        "status": status(run),
        "returncode": run.returncode,
        "seconds": run.seconds,
        "sets": sets,
        "seed": seed,
        "warnings": run.warnings,
    }
    if run.image is not None:
        row.update(us.errors(run.image, ref))
    else:
        row["error"] = run.error
        row["stderr_tail"] = run.stderr.splitlines()[-8:]
    return row


def cell(row: dict, notes: list[str]) -> str:
    """``brightness / block error / seconds``, or the kind of failure with a footnote."""
    if row["status"] == "ok" and "block_rel_rmse" in row:
        return f"{row['brightness']:.3f} / {row['block_rel_rmse']:.3f} / {row['seconds']:.1f} s"
    text = row.get("error") or ", ".join(
        f"{k} {v}" for k, v in row.items() if k in ("shape", "ref_shape", "nonfinite")
    )
    text = re.sub(r"\br\d+\b", "rN", text)  # Dr.Jit's register numbers differ run to run
    if text not in notes:
        notes.append(text)
    label = {"ok": "wrong image", "refused": "exit 2", "timeout": "timeout"}.get(
        row["status"], f"crash (exit {row['returncode']})"
    )
    return f"{label} [{notes.index(text) + 1}]"


def _revision(git: dict | None) -> str:
    if not git:
        return "git revision unknown"
    return f"git {git['commit'][:10]}" + (" (uncommitted changes)" if git["dirty"] else "")


def markdown(result: dict) -> str:
    methods = result["methods"]
    notes: list[str] = []
    headers = ["file", "reference", *methods, "mitsuba"]
    rows = []
    for name, entry in result["scenes"].items():
        ref = entry["reference"]
        m = entry.get("mitsuba")
        rows.append(
            [
                name,
                f"{ref['integrator'].replace('Integrator', '')} {ref['spp']} spp",
                *(
                    cell(entry["methods"][k], notes) if k in entry["methods"] else "–"
                    for k in methods
                ),
                f"{m['block_rel_rmse']:.3f} / {m['seconds']:.1f} s ({m['spp']} spp)" if m else "–",
            ]
        )
    info = result["machine"]
    lines = [
        f"# {result['name']}: every method on user-written files vs Mitsuba on the same file",
        "",
        "Cells: mean-brightness ratio to the reference / relative RMSE of 4×4-block means / wall "
        "time of `photonmap render FILE --method M` (start-up included: "
        f"{result['cli_startup_s']:.1f} s alone). Method settings: "
        f"{result['sets'] or 'the defaults'}; seed {result['seed']}. `mitsuba`: the file's "
        "own integrator at a low sample count, its block error and render time.",
        "",
        report.markdown_table(headers, rows, "l" + "l" * (len(headers) - 1)),
        "",
    ]
    lines += [f"[{i + 1}] {text}" for i, text in enumerate(notes)]
    lines += [
        "",
        f"Machine: {info['cpu_model']}, {info['cores_usable']} cores usable, load average "
        f"{info.get('load_average')} at the start and {result['load_average_end']} at the end; "
        f"Mitsuba {info['mitsuba']}, Dr.Jit {info['drjit']}; {_revision(info['git'])}; "
        f"total {result['seconds']:.0f} s.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", help="comma-separated file names (default: all)")
    parser.add_argument("--methods", default=",".join(us.METHODS))
    parser.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        help="METHOD:KEY=VALUE, passed as --set KEY=VALUE (repeatable)",
    )
    parser.add_argument("--ref-spp", type=int, default=16384)
    parser.add_argument("--mitsuba-spp", type=int, default=256)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=300, help="seconds per render")
    parser.add_argument("--name", default="user_scenes")
    parser.add_argument("--out-dir", type=Path, default=report.RESULTS)
    args = parser.parse_args(argv)

    methods = args.methods.split(",")
    sets = parse_sets(args.sets)
    files = us.scene_files()
    if args.scenes:
        wanted = {s.removesuffix(".xml") for s in args.scenes.split(",")}
        files = [f for f in files if f.stem in wanted]
    start = time.perf_counter()
    import photonmap  # noqa: F401  (the variant; machine_info reads it)

    result = {
        "name": args.name,
        "machine": report.machine_info(),
        "cli_startup_s": cli_startup(),
        "methods": methods,
        "sets": sets,
        "seed": args.seed,
        "ref_spp": args.ref_spp,
        "scenes": {},
    }
    for path in files:
        ref, info = us.reference(path, args.ref_spp)
        entry = {
            "file": str(path.relative_to(us.REPO)),
            "key": us.scene_key(path),
            "reference": info,
            "methods": {},
        }
        entry["mitsuba"] = mitsuba_row(path, ref, args.mitsuba_spp)
        for method in methods:
            row = run_one(path, method, ref, sets.get(method, {}), args.timeout, args.seed)
            entry["methods"][method] = row
            what = (
                f"{row['brightness']:.3f} {row['block_rel_rmse']:.3f}"
                if "block_rel_rmse" in row
                else row.get("error")
            )
            print(
                f"{path.stem:26s} {method:8s} {row['status']:8s} {row['seconds']:6.1f} s  {what}",
                flush=True,
            )
        result["scenes"][path.stem] = entry
    result["seconds"] = time.perf_counter() - start
    result["load_average_end"] = report.load_average()
    text = markdown(result)
    return report.publish(args.out_dir / args.name, result, text)


if __name__ == "__main__":
    main()
