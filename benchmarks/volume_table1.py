"""The sweeps of Sun et al. 2008, Table 1, on the volume method: stage times against triangle
count, occupied extent and photon count, beside the paper's (NVIDIA GeForce 8800 Ultra).

Scene: ``mesh_in_fog`` (a glass trefoil-knot mesh in grey fog) at a 128³ grid and 640×480. The
eleven rows of Table 1:

* rows 1–4: 10k / 20k / 40k / 80k triangles at an occupied extent of 103³ voxels, 1024² photons;
* rows 5–8: extents 64³ / 77³ / 90³ / 103³ at 20k triangles, 1024² photons;
* rows 9–11: 256² / 512² / 1024² initial photons at 20k triangles, extent 103³.

Rows 2, 8 and 11 are the same configuration in the paper; it is measured once and shown in all
three. For each configuration: warm-up full renders (JIT compilation; at least two, until one
compiles no kernel), then ``runs`` timed full renders from scratch — the stage cache is cleared so
every stage runs ("all passes are executed for each frame", Pfeuti 2009's protocol) — and the
median of each stage (:mod:`volume_frames`).

Headline (20k triangles, extent 103, 1024² photons): ``light_runs`` light-change frames (the point
light moves by about a voxel each frame with ``set_light``, to a position no earlier run used;
photon generation, tracing, smoothing, view grids and viewing rerun) = "full frame (light change +
view)", and ``view_runs`` view-only frames (``set_camera`` to a slightly different origin; only
viewing reruns). Targets on the 2-core CPU:
full frame ≤ 0.5 s, view-only ≤ 0.25 s. The same two numbers for ``glass_sphere_fog`` go into
``secondary``. A profile of the headline light-change frame (stage shares, Dr.Jit kernels per
stage, photon marching with and without deposition, deposit count; :mod:`volume_profile`) says
what bounds the time.

Column mapping to the paper: its "voxelization" ↔ our voxelization; its "photon tracing" ↔ our
photon generation + photon tracing; its total additionally holds gradient, octree, irradiance
merging and the viewing pass (≈ 68–76 ms together), so it compares with our total of all stages.

Writes ``benchmarks/results/volume_table1.json`` and ``.md`` (``--quick``: ``*_quick.*``) and
prints the markdown. ``python benchmarks/volume_table1.py [--quick] [--runs N] [--rows 1,9,11]``.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import report
from report import RESULTS, load_average, machine_info, results_stem, write_results
from volume_frames import make_pipeline, measure_full, measure_interactive, warm_up_full
from volume_profile import profile as profile_of
from volume_table1_report import markdown

NAME = "volume_table1"
SCENE = "mesh_in_fog"
SECONDARY_SCENE = "glass_sphere_fog"
PAPER_PHOTONS = (256**2, 512**2, 1024**2)
TARGETS_S = {"full_frame_s": 0.5, "view_only_s": 0.25}
QUICK_ROWS = (9, 11)


@dataclasses.dataclass(frozen=True)
class PaperRow:
    """One row of [Sun] Table 1 (times in ms on an NVIDIA GeForce 8800 Ultra)."""

    number: int
    sweep: str
    triangles: int
    extent: int  # occupied voxels per side (of 128)
    photon_index: int  # 0, 1, 2 → 256², 512², 1024² initial photons
    msteps: float
    voxelization_ms: float
    tracing_ms: float
    total_ms: float

    @property
    def photons(self) -> int:
        return PAPER_PHOTONS[self.photon_index]


PAPER_TABLE1 = (
    PaperRow(1, "triangles", 10_000, 103, 2, 3.81, 14.55, 136.85, 225.20),
    PaperRow(2, "triangles", 20_000, 103, 2, 3.81, 24.40, 138.10, 238.15),
    PaperRow(3, "triangles", 40_000, 103, 2, 3.81, 49.90, 134.70, 258.40),
    PaperRow(4, "triangles", 80_000, 103, 2, 3.81, 90.35, 135.75, 299.65),
    PaperRow(5, "extent", 20_000, 64, 2, 1.12, 16.40, 63.55, 148.00),
    PaperRow(6, "extent", 20_000, 77, 2, 1.82, 18.80, 85.20, 175.05),
    PaperRow(7, "extent", 20_000, 90, 2, 2.72, 21.45, 108.60, 201.75),
    PaperRow(8, "extent", 20_000, 103, 2, 3.81, 24.40, 138.10, 238.15),
    PaperRow(9, "photons", 20_000, 103, 0, 0.24, 25.85, 63.40, 159.60),
    PaperRow(10, "photons", 20_000, 103, 1, 0.95, 24.90, 80.10, 175.95),
    PaperRow(11, "photons", 20_000, 103, 2, 3.81, 24.40, 138.10, 238.15),
)
HEADLINE = {"triangles": 20_000, "extent": 103}  # and the largest photon count


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


# -------------------------------------------------------------------------------------- run
def _photon_counts(photons: Sequence[int] | None) -> tuple[int, int, int]:
    """Our counts for the paper's 256², 512², 1024² (positional; the last fills the rest)."""
    photons = list(photons or PAPER_PHOTONS)
    if not 1 <= len(photons) <= 3 or any(int(p) < 1 for p in photons):
        raise ValueError(f"give one to three positive photon counts, got {photons}")
    photons += [photons[-1]] * (3 - len(photons))
    return tuple(int(p) for p in photons)


def run(
    grid: int = 128,
    width: int = 640,
    height: int = 480,
    photons: Sequence[int] | None = None,
    rows: Sequence[int] | None = None,
    runs: int = 3,
    out_dir: Path | str | None = RESULTS,
    light_runs: int = 3,
    view_runs: int = 5,
    secondary: bool = True,
    profile: bool = True,
    quick: bool = False,
    log: Callable[[str], None] = _log,
) -> dict:
    """Run the benchmark and return the result dict; with ``out_dir`` also write
    ``volume_table1.json`` and ``.md`` there (``volume_table1_quick.*`` when ``quick``).

    ``photons`` replaces the paper's (256², 512², 1024²) initial photon counts, ``rows`` selects
    rows of Table 1 (1–11; quick: 9 and 11), ``runs`` timed full renders per row (quick: 1),
    ``light_runs``/``view_runs`` the headline's light-change and view-only frames (quick: 1/2).
    """
    import photonmap  # noqa: F401 - selects the Mitsuba variant

    counts = _photon_counts(photons)
    if quick:
        runs, light_runs, view_runs = 1, min(light_runs, 1), min(view_runs, 2)
        rows = rows or QUICK_ROWS
    selected = [r for r in PAPER_TABLE1 if rows is None or r.number in set(rows)]
    if rows is not None and len(selected) != len(set(rows)):
        raise ValueError(f"rows must be numbers 1–{len(PAPER_TABLE1)}, got {list(rows)}")
    if min(runs, light_runs, view_runs) < 1:
        raise ValueError("runs, light_runs and view_runs must be at least 1")
    started = time.perf_counter()
    result: dict = {
        "benchmark": NAME,
        "machine": machine_info(),
        "settings": {
            "scene": SCENE,
            "grid": grid,
            "width": width,
            "height": height,
            "photon_counts": dict(zip(["256^2", "512^2", "1024^2"], counts, strict=True)),
            "runs": runs,
            "light_runs": light_runs,
            "view_runs": view_runs,
            "quick": quick,
            "protocol": (
                "per configuration: untimed warm-up full renders (2 for the first pipeline of the "
                "process, else 1; more until one compiles no Dr.Jit kernel), then `runs` full "
                "renders with the stage cache cleared (every stage runs); medians per stage. "
                "Interactive frames: warm-up frames of the same kind until one compiles nothing "
                "(at most 2), then the timed frames, each with a light position / camera origin "
                "never used before (a random fraction is added, so Dr.Jit's on-disk kernel cache "
                "cannot hide per-move compilation). Frame times are wall-clock of change + "
                "render, Dr.Jit synchronised; kernel history is on to count compilations."
            ),
            "targets_s": TARGETS_S,
        },
    }

    rows, measured = table1_rows(selected, counts, grid, width, height, runs, log)
    result["rows"] = rows
    log(f"headline: {SCENE}, 20k triangles, extent 103, {counts[2]} photons ...")
    pipe, _ = make_pipeline(SCENE, grid, width, height, counts[2], **HEADLINE)
    result["headline"] = headline(pipe, counts[2], grid, width, height, light_runs, view_runs, log)
    if profile:
        log("profile ...")
        full = measured.get((HEADLINE["triangles"], HEADLINE["extent"], counts[2]))
        light_stages = result["headline"]["light_change"]["stages_ms"]
        full_stages = full["stages_ms"] if full else None
        result["profile"] = profile_of(pipe, light_stages, full_stages, 1 if quick else 2)
    del pipe
    if secondary:
        log(f"secondary: {SECONDARY_SCENE}, {counts[2]} photons ...")
        pipe, _ = make_pipeline(SECONDARY_SCENE, grid, width, height, counts[2])
        result["secondary"] = secondary_of(pipe, counts[2], light_runs, view_runs, log)
    result["elapsed_s"] = time.perf_counter() - started
    result["load_average_end"] = load_average()
    result["markdown"] = markdown(result, TARGETS_S)
    if out_dir is not None:
        stem = results_stem(out_dir, NAME, quick)
        result["files"] = {"json": str(stem) + ".json", "markdown": str(stem) + ".md"}
        write_results(stem, result, result["markdown"] + "\n")
    return result


def table1_rows(selected, counts, grid, width, height, runs, log) -> tuple[list, dict]:
    """Our measurement of each selected row beside the paper's, and the measurements by
    configuration (triangles, extent, photons): a configuration is measured once."""
    rows, measured = [], {}
    for row in selected:
        config = (row.triangles, row.extent, counts[row.photon_index])
        if config not in measured:
            log(f"row {row.number}: {row.triangles} triangles, extent {row.extent}, "
                f"{config[2]} photons ...")  # fmt: skip
            pipe, setup_s = make_pipeline(
                SCENE, grid, width, height, config[2], triangles=row.triangles, extent=row.extent
            )
            m = measure_full(pipe, runs)
            measured[config] = {**m, "setup_s": setup_s, "measured_for_row": row.number}
            del pipe
            log(f"  total {m['total_ms']:.0f} ms, tracing {m['stages_ms']['photon tracing']:.0f}"
                f" ms, {m['msteps']:.2f} Msteps")  # fmt: skip
        paper = {
            "photons": row.photons,
            "msteps": row.msteps,
            "voxelization_ms": row.voxelization_ms,
            "photon_tracing_ms": row.tracing_ms,
            "total_ms": row.total_ms,
            "hidden_ms": round(row.total_ms - row.voxelization_ms - row.tracing_ms, 2),
            "ns_per_step": row.tracing_ms / row.msteps,  # ms per Mstep = ns per step
        }
        rows.append({"row": row.number, "sweep": row.sweep, "triangles": row.triangles,
                     "extent": row.extent, "photons": config[2], "paper": paper,
                     "ours": measured[config]})  # fmt: skip
    return rows, measured


def headline(pipe, photons, grid, width, height, light_runs, view_runs, log=_log) -> dict:
    """Light-change and view-only frames of the headline configuration against the targets."""
    warm = warm_up_full(pipe)
    inter = measure_interactive(pipe, light_runs, view_runs)
    log(f"  full frame {inter['full_frame_s']:.2f} s, view only {inter['view_only_s']:.2f} s")
    return {
        "scene": SCENE,
        **HEADLINE,
        "photons": photons,
        "grid": grid,
        "width": width,
        "height": height,
        "full_frame_s": inter["full_frame_s"],
        "view_only_s": inter["view_only_s"],
        "warmup_full_renders": warm,
        "targets_s": TARGETS_S,
        "meets_targets": {k: inter[k] <= v for k, v in TARGETS_S.items()},
        "light_change": inter["light_change"],
        "view_only": inter["view_only"],
        "stats": inter["stats"],
    }


def secondary_of(pipe, photons, light_runs, view_runs, log=_log) -> dict:
    """The headline's two frame times on the secondary scene."""
    warm_up_full(pipe)
    sec = measure_interactive(pipe, light_runs, view_runs)
    log(f"  full frame {sec['full_frame_s']:.2f} s, view only {sec['view_only_s']:.2f} s")
    return {
        "scene": SECONDARY_SCENE,
        "photons": photons,
        "full_frame_s": sec["full_frame_s"],
        "view_only_s": sec["view_only_s"],
        "light_change_stages_ms": sec["light_change"]["stages_ms"],
        "view_only_stages_ms": sec["view_only"]["stages_ms"],
        "stats": sec["stats"],
        "samples": {"light_change": sec["light_change"], "view_only": sec["view_only"]},
    }


# -------------------------------------------------------------------------------------- CLI
def main(argv: Sequence[str] | None = None) -> dict:
    parser = report.arguments(__doc__, "smoke test: 1 run, rows 9 and 11")
    parser.add_argument("--runs", type=int, default=3, help="timed full renders per row")
    parser.add_argument(
        "--rows", type=report.integers, default=None, help="rows of Table 1, e.g. 1,9,11"
    )
    parser.add_argument("--light-runs", type=int, default=3, help="headline light-change frames")
    parser.add_argument("--view-runs", type=int, default=5, help="headline view-only frames")
    parser.add_argument("--grid", type=int, default=128)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument(
        "--photons",
        type=report.integers,
        default=None,
        help="counts for the paper's 256²,512²,1024²",
    )
    parser.add_argument("--no-secondary", action="store_true", help=f"skip {SECONDARY_SCENE}")
    parser.add_argument("--no-profile", action="store_true", help="skip the profile")
    args = parser.parse_args(argv)
    result = run(
        grid=args.grid,
        width=args.width,
        height=args.height,
        photons=args.photons,
        rows=args.rows,
        runs=args.runs,
        out_dir=args.out_dir,
        light_runs=args.light_runs,
        view_runs=args.view_runs,
        secondary=not args.no_secondary,
        profile=not args.no_profile,
        quick=args.quick,
    )
    print(result["markdown"])
    return result


if __name__ == "__main__":
    main()
