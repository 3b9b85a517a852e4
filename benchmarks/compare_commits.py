"""A revision against the working tree, interleaved on the same scenes: the guard for every
change to transport.

``REV`` is checked out in a git worktree (``results/cache/worktrees/<sha>``, kept for the next
run); both sides render each scene with ``photonmap render FILE --method M --timings`` in a
subprocess on their own sources (``PYTHONPATH=<side>/src``), in the order REV, tree, REV, tree,
… so that a change of the machine's load falls on both. One untimed render per side first
compiles its kernels. Per side and scene: the wall time of the render (the ``total`` row of
``--timings``, start-up excluded), every stage's milliseconds, the counters ``--timings`` prints
(iterations, photons, ...), and the 4 × 4-block relative RMSE (``photonmap.compare``) against
Mitsuba's own integrator on the file at ``--ref-spp`` (two halves of independent seeds, cached
under ``results/cache/compare/``), the reference's own error subtracted in quadrature
(:func:`accuracy.vs_truth`): near that error the measured one stops falling, and a side that
renders more samples would look no better.

Time to equal error: an estimate's error falls as 1/√t, so the tree needs
``(t_tree · e_tree²) / (t_rev · e_rev²)`` of REV's time to reach the same error (below 1: the
tree is faster). Medians over ``--runs`` seeds (0, 1, …; the same seeds on both sides).

Writes ``results/compare_<name>.json`` and ``.md`` (``--name``, default the revision's short
hash).

    .venv/bin/python benchmarks/compare_commits.py REV [--scenes examples/glass_sphere_plane.xml]
        [--method sppm] [--set iterations=40] [--runs 3] [--ref-spp 4096]
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

import report  # noqa: E402
from accuracy import vs_truth  # noqa: E402

CACHE = report.RESULTS / "cache"
DEFAULT_SCENES = ["examples/glass_sphere_plane.xml"]
ROW = re.compile(r"^[│|]\s*([^│|]+?)\s*[│|]\s*([\d.,]+)\s*[│|]\s*$")
CLI = "import sys; from photonmap.cli import app; sys.argv[0] = 'photonmap'; app()"  # any revision
COUNTER = re.compile(r"([a-z][a-z _]*?) ([\d,]+(?:\.\d+)?)(?:,|$)")


def worktree(rev: str) -> tuple[Path, str]:
    """A checkout of ``rev`` (created once, kept) and its full hash."""
    sha = subprocess.run(["git", "rev-parse", "--verify", f"{rev}^{{commit}}"], cwd=report.REPO,
                         check=True, capture_output=True, text=True).stdout.strip()  # fmt: skip
    path = CACHE / "worktrees" / sha[:12]
    if not (path / "src" / "photonmap").is_dir():
        path.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run(["git", "worktree", "add", "--force", "--detach", str(path), sha],
                       cwd=report.REPO, check=True, capture_output=True)  # fmt: skip
    return path, sha


def parse_timings(stdout: str) -> tuple[dict[str, float], dict[str, float]]:
    """``--timings``' table rows (stage → ms) and its counters line (name → value)."""
    stages, counters = {}, {}
    for line in stdout.splitlines():
        if m := ROW.match(line.strip()):
            stages[m.group(1)] = float(m.group(2).replace(",", ""))
        elif not stages or line.startswith(("┃", "┏", "┡", "└", "│")):
            continue
        else:
            for name, value in COUNTER.findall(line):
                counters[name.strip()] = float(value.replace(",", ""))
    return stages, counters


def render(side: Path, scene: Path, method: str, sets: list[str], seed: int) -> dict:
    """One ``photonmap render`` on ``side``'s sources: its image, stages and counters."""
    import mitsuba as mi

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.exr"
        args = [sys.executable, "-c", CLI, "render", str(scene), "--method", method,
                "-o", str(out), "--seed", str(seed), "--timings"]  # fmt: skip
        for item in sets:
            args += ["--set", item]
        env = {**os.environ, "PYTHONPATH": str(side / "src"), "COLUMNS": "1000"}  # unwrapped
        done = subprocess.run(args, cwd=side, env=env, capture_output=True, text=True,
                              timeout=3600)  # fmt: skip
        if done.returncode != 0 or not out.exists():
            tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
            raise RuntimeError(f"{side.name}: {' '.join(args[2:])} failed: {' | '.join(tail)}")
        image = np.array(mi.Bitmap(str(out)), dtype=np.float64)[..., :3]
    stages, counters = parse_timings(done.stdout)
    return {"image": image, "stages_ms": stages, "counters": counters}


def reference(scene: Path, spp: int) -> tuple[np.ndarray, float]:
    """Mitsuba's image of the file with its own integrator at ``spp``, in two halves of
    independent seeds (cached), and its own 4 × 4-block error (:func:`accuracy.reference_noise`:
    the halves' difference over two is distributed as the mean's error)."""
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    halves = []
    for half in (0, 1):
        path = CACHE / "compare" / f"{scene.stem}-{spp}spp-half{half}.exr"
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            loaded = mi.load_file(str(scene))
            total, done = None, 0
            while done < spp // 2:
                n = min(256, spp // 2 - done)
                seed = half * spp + done
                image = np.array(mi.render(loaded, spp=n, seed=seed), np.float64)[..., :3] * n
                total = image if total is None else total + image
                done += n
            mi.Bitmap((total / done).astype(np.float32)).write(str(path))
        halves.append(np.array(mi.Bitmap(str(path)), dtype=np.float64)[..., :3])
    ref = (halves[0] + halves[1]) / 2
    return ref, error(ref + 0.5 * (halves[0] - halves[1]), ref)


def error(image: np.ndarray, ref: np.ndarray) -> float:
    from photonmap import compare

    return float(compare(image, ref)["block_rel_rmse"])


def summary(runs: list[dict]) -> dict:
    """Medians of a side's timed runs."""
    stages = {k: statistics.median(r["stages_ms"].get(k, 0.0) for r in runs)
              for k in runs[0]["stages_ms"]}  # fmt: skip
    counters = {k: statistics.median(r["counters"].get(k, 0.0) for r in runs)
                for k in runs[0]["counters"]}  # fmt: skip
    return {
        "seconds": stages.get("total", 0.0) / 1e3,
        "error": statistics.median(r["error"] for r in runs),
        "stages_ms": stages,
        "counters": counters,
        "runs": [{k: v for k, v in r.items() if k != "image"} for r in runs],
    }


def time_to_equal_error(rev: dict, tree: dict) -> float:
    """The share of ``rev``'s time the tree needs to reach ``rev``'s error (error ∝ 1/√t)."""
    return (tree["seconds"] * tree["error"] ** 2) / (rev["seconds"] * rev["error"] ** 2)


def markdown(result: dict) -> str:
    rev, lines = result["rev"][:10], []
    sets = " ".join(result["sets"]) or "defaults"
    lines.append(f"# `{rev}` against the working tree ({result['method']}, {sets}, "
                 f"medians of {result['runs']} runs)\n")  # fmt: skip
    rows = []
    for name, scene in result["scenes"].items():
        a, b = scene["rev"], scene["tree"]
        for label, side in ((rev, a), ("tree", b)):
            stages = ", ".join(f"{k} {v:.0f}" for k, v in side["stages_ms"].items() if k != "total")
            rows.append([name, label, f"{side['seconds']:.2f}", f"{side['error']:.4f}", stages])
        rows.append([name, "tree / rev", f"{b['seconds'] / a['seconds']:.2f}×",
                     f"{b['error'] / a['error']:.2f}×",
                     f"time to equal error {scene['time_to_equal_error']:.2f}×"])  # fmt: skip
    lines.append(report.markdown_table(["scene", "side", "seconds", "4×4 error", "stages (ms)"],
                                       rows))  # fmt: skip
    for name, scene in result["scenes"].items():
        lines.append(f"\n{name}: the reference's own 4×4 error {scene['reference_error']:.4f}, "
                     "subtracted in quadrature from each error above")  # fmt: skip
    lines.append(f"\nload average at the end: {result['load_average_end']}")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("rev")
    parser.add_argument("--scenes", default=",".join(DEFAULT_SCENES))
    parser.add_argument("--method", default="sppm")
    parser.add_argument("--set", dest="sets", action="append", default=[])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--ref-spp", type=int, default=4096)
    parser.add_argument("--name")
    parser.add_argument("--out-dir", default=str(report.RESULTS))
    args = parser.parse_args(argv)
    old, sha = worktree(args.rev)
    sides = {"rev": old, "tree": report.REPO}
    result = {"name": "compare_commits", "machine": report.machine_info(), "rev": sha,
              "method": args.method, "sets": args.sets, "runs": args.runs, "scenes": {}}  # fmt: skip
    for scene in [report.REPO / s for s in args.scenes.split(",")]:
        ref, ref_error = reference(scene, args.ref_spp)
        for path in sides.values():  # compile each side's kernels
            render(path, scene, args.method, args.sets, seed=0)
        runs: dict[str, list] = {"rev": [], "tree": []}
        for seed in range(args.runs):
            for label, path in sides.items():
                run = render(path, scene, args.method, args.sets, seed)
                run["measured_error"] = error(run.pop("image"), ref)
                run["error"] = vs_truth(run["measured_error"], ref_error)
                runs[label].append(run)
                print(f"{scene.name} {label:4} seed {seed}: {run['stages_ms'].get('total', 0):8.0f} "
                      f"ms, error {run['error']:.4f}", flush=True)  # fmt: skip
        a, b = summary(runs["rev"]), summary(runs["tree"])
        ratio = time_to_equal_error(a, b)
        result["scenes"][scene.stem] = {"rev": a, "tree": b, "time_to_equal_error": ratio,
                                        "reference_error": ref_error}  # fmt: skip
    result["load_average_end"] = report.load_average()
    stem = Path(args.out_dir) / f"compare_{args.name or sha[:10]}"
    text = markdown(result)
    report.write_results(stem, result, text)
    print(text)
    return result


if __name__ == "__main__":
    main()
