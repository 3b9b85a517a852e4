"""Light-change frames of the volume method's reference and adaptive pipelines (Sun et al. 2008;
Pfeuti 2009, Ch. 4), as ``adaptive_vs_reference.py`` measures them: the frames, their RMSE
against a ground truth of many more photons, and the per-pass times in the layout of Pfeuti's
Tables 4.2–4.4.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from timing import median, stage_medians

# the pipelines compared: the reference and two adaptive variants (parameters set per frame)
VARIANTS = {
    "uniform": {"emission": "uniform"},
    "adaptive": {"emission": "adaptive", "placement": "importance"},
    "adaptive_uniform_placement": {"emission": "adaptive", "placement": "uniform"},
}
LABELS = {
    "uniform": "reference",
    "adaptive": "adaptive",
    "adaptive_uniform_placement": "adaptive, uniform placement",
}
# rows of Pfeuti Tables 4.2–4.4 → our stages (ours that the thesis does not list are extra rows)
PASSES = (
    ("Voxelization", ("voxelization",)),
    ("Materials + gradient", ("materials", "gradient")),
    ("Octree", ("octree", "march grids")),
    ("Pilot Photon Generation", ("pilot photon generation",)),
    ("Pilot Photon Marching", ("pilot photon marching",)),
    ("Photon Distribution", ("photon distribution",)),
    ("Photon Generation", ("photon generation",)),
    ("Photon Marching", ("photon tracing",)),
    ("Smoothing (S8)", ("smoothing",)),
    ("Mipmap Generation (incl. S8)", ("mipmap generation",)),
    ("Filtering", ("filtering",)),
    ("Copy (view grids)", ("view grids",)),
    ("Viewing Pass", ("viewing",)),
)
# the placement alone: importance photons, every voxel at level 0 (a Δweight no weight reaches)
PLACEMENT_ONLY = {"emission": "adaptive", "placement": "importance", "delta_weight": 1e9}


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    peak = float(np.max(b))
    err = rmse(a, b)
    return 20 * math.log10(peak / err) if err > 0 and peak > 0 else math.inf


def light_stages(emission: str) -> tuple[str, ...]:
    """The stages a light change reruns (all after the octree and the march grids)."""
    from photonmap.volume.params import ADAPTIVE_STAGES, STAGES

    return (ADAPTIVE_STAGES if emission == "adaptive" else STAGES)[5:]


def light_frames(pipe, configs: Sequence[tuple[str, int]], runs: int) -> list[dict]:
    """Light-change frames (every cached stage that depends on the light dropped, then render) of
    each ``(variant, photons)`` config (:data:`VARIANTS`), interleaved run by run so that a load
    change on the shared machine hits every config alike; one untimed warm-up round first. Per
    config: the image, medians and samples."""
    walls = [[] for _ in configs]
    per_stage = [[] for _ in configs]
    images, stats = [None] * len(configs), [None] * len(configs)
    for run in range(runs + 1):
        for k, (variant, photons) in enumerate(configs):
            pipe.set_params(photons=photons, **VARIANTS[variant])
            stages = light_stages(VARIANTS[variant]["emission"])
            pipe.invalidate(stages)
            start = time.perf_counter()
            images[k] = np.array(pipe.render())
            wall = 1e3 * (time.perf_counter() - start)
            stats[k] = dict(pipe.stats)
            if run:  # run 0 warms up (Dr.Jit compilation, and any stage not cached yet)
                assert pipe.recomputed == list(stages), pipe.recomputed
                walls[k].append(wall)
                per_stage[k].append(dict(pipe.timer.ms))
    out = []
    for k in range(len(configs)):
        photon_ms = [
            sum(v for n, v in s.items() if n not in ("view grids", "viewing")) for s in per_stage[k]
        ]
        out.append(
            {
                "image": images[k],
                "wall_ms": median(walls[k]),
                "wall_ms_min": min(walls[k], default=math.nan),
                "photon_stages_ms": median(photon_ms),
                "stages_ms": stage_medians(per_stage[k]),
                "samples_ms": walls[k],
                "stats": stats[k],
            }
        )
    return out


def ground_truth(pipe, photons: int, factor: int) -> np.ndarray:
    """The reference pipeline at ``factor × photons``: ``factor`` batches of ``photons``
    consecutive Halton points (one sequence), C and D averaged, then S8 and S9 as usual."""
    import drjit as dr

    from photonmap.volume import emit, march
    from photonmap.volume.smooth import smooth

    pipe.set_params(emission="uniform", photons=photons, sampler="halton")
    pipe.render()
    s, p = pipe.world, pipe.params
    grids = pipe.stage_output("march grids")
    C = D = None
    for batch in range(factor):
        parts = [emit.emit(light, s.box, photons, "halton", batch * photons) for light in s.lights]
        for part in parts:
            r = march.march(part, grids, march.Marching(p.ds_min, fidelity=p.fidelity), s.box.h)
            C = r.C if C is None else C + r.C
            D = r.D if D is None else D + r.D
        dr.eval(C, D)
    smoothed = smooth(C / factor, D / factor, p.smoothing)
    pipe.set_stage_output("smoothing", smoothed)  # the viewing stages read the averaged grids
    image = np.array(pipe.render())
    assert pipe.recomputed == ["view grids", "viewing"]
    pipe.set_params(sampler="hammersley")
    return image


def pass_table(stages_ms: dict) -> dict:
    """Stage milliseconds summed into the rows of Pfeuti Tables 4.2–4.4."""
    return {row: sum(stages_ms.get(s, 0.0) for s in names) for row, names in PASSES}


def sweep_row(frame: dict, budget: int, truth: np.ndarray) -> dict:
    """What one configuration's frames measured: photons that entered the grid, marching steps,
    RMSE against ``truth``, frame and stage times."""
    stats = frame["stats"]
    return {
        "budget": budget,
        "propagated": int(stats["photons_propagated"]),
        "steps": int(stats["steps"]),
        "rmse": rmse(frame["image"], truth),
        "wall_ms": frame["wall_ms"],
        "wall_ms_min": frame["wall_ms_min"],
        "photon_stages_ms": frame["photon_stages_ms"],
        "stages_ms": frame["stages_ms"],
        "passes_ms": pass_table(frame["stages_ms"]),
        "samples_ms": frame["samples_ms"],
    }


def ablation(pipe, sweep: dict, truth: np.ndarray, budgets: Sequence[int]) -> list:
    """Where the adaptive pipeline's gain comes from, per budget of the sweep: RMSE of the
    reference, the full adaptive pipeline, the filter alone (uniform placement) and the placement
    alone (:data:`PLACEMENT_ONLY`)."""
    from photonmap.volume.params import VolumeParams

    rows = []
    for budget in budgets:
        row = {"budget": budget}
        for variant in VARIANTS:
            found = [r["rmse"] for r in sweep[variant] if r["budget"] == budget]
            row[variant] = found[0] if found else None
        pipe.set_params(photons=budget, **PLACEMENT_ONLY)
        row["placement_only"] = rmse(np.array(pipe.render()), truth)
        rows.append(row)
    pipe.set_params(delta_weight=VolumeParams().delta_weight)
    return rows


def marching_fit(rows: Sequence[dict]) -> dict:
    """Least-squares ``photon tracing ms = F + v · steps`` over the reference sweep: ``F`` ms does
    not shrink with the photon budget, ``v`` is the cost of a million marching steps."""
    steps = np.array([r["steps"] for r in rows], dtype=np.float64) / 1e6
    ms = np.array([r["stages_ms"]["photon tracing"] for r in rows], dtype=np.float64)
    v, fixed = np.polyfit(steps, ms, 1) if len(rows) > 1 else (ms[0] / steps[0], 0.0)
    return {"fixed_ms": float(fixed), "ms_per_million_steps": float(v)}
