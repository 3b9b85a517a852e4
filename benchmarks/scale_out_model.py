"""The model of ``scale_out.py``: the throughput of N machines, each like one measured worker,
with the driver handling one block (or frame) at a time; a worker turns out ``b`` iterations in
``b/r + o_w`` seconds, the driver takes ``t_d`` per block, so rate(N) = min(N · b / (b/r + o_w),
b / t_d) and the knee, where the driver saturates, is N* = (b/r + o_w) / t_d.
"""

from __future__ import annotations

from pathlib import Path

import report

BANDWIDTH = 10e9 / 8  # bytes/s of the driver's network link in the model (10 Gbit/s)
MODEL_N = (1, 2, 4, 8, 16, 32, 64)
FILM = (1920, 1080)  # the film-sized image of the model's pessimistic curves


def model(rate_1: float, per_unit_overhead: float, driver_s: float, unit: int, ns=MODEL_N):
    """Throughput of N workers like the measured one (module docstring):
    ``min(N · unit / (unit/rate_1 + overhead), unit / driver_s)``; returns the curve and the
    knee N* where the driver saturates."""
    work = unit / rate_1 + per_unit_overhead
    curve = [min(n * unit / work, unit / driver_s) for n in ns]
    return {"n": list(ns), "throughput": curve, "knee": work / driver_s, "unit": unit}


def curves_of(m: dict, args) -> dict:
    """The model's throughput curves (module docstring) from the measurements ``m``."""
    it0 = m["progressive"][0]["iterations_per_s"]["median"]
    fr0 = m["sequence"][0]["frames_per_s"]["median"]
    driver = m["driver"]
    o_block = m["progressive"][0]["block_round_trip_overhead_s"]["median"]
    t_block = driver["merge_s"]["median"] + driver["store_put_get_s"]["median"]
    t_block += driver["payload_bytes"] / BANDWIDTH
    frame_bytes = args.width * args.height * 3 * 4
    t_frame = m["sequence"][0]["driver_write_s"]["median"] + frame_bytes / BANDWIDTH
    # the same iterations with film-sized sums: every driver cost grows with the pixels
    t_film = t_block * FILM[0] * FILM[1] / (args.width * args.height)
    film, b = f"{FILM[0]}x{FILM[1]} sums", args.block
    return {
        "progressive": {
            f"block {b}": model(it0, o_block, t_block, b),
            f"block {4 * b}": model(it0, o_block, t_block, 4 * b),
            f"{film}, block {b}": model(it0, o_block, t_film, b),
            f"{film}, block {4 * b}": model(it0, o_block, t_film, 4 * b),
        },
        "sequence": {"1 frame/task": model(fr0, 0.0, t_frame, 1)},
    }


def plot(path: Path, curves: dict, measured: dict) -> None:
    """Each kind's modelled throughput against the worker count, with the measured points."""
    kinds = (("progressive", "iterations/s"), ("sequence", "frames/s"))
    with report.figure(path, 1, 2, size=(10, 4)) as axes:
        for ax, (kind, label) in zip(axes[0], kinds, strict=True):
            for name, c in curves[kind].items():
                line = ax.plot(c["n"], c["throughput"], marker=".",
                               label=f"{name} (knee {c['knee']:.0f})")  # fmt: skip
                if c["knee"] <= 64:
                    ax.axvline(c["knee"], color=line[0].get_color(), ls=":", lw=0.8)
            ideal = [n * measured[kind][0] for n in MODEL_N]
            ax.plot(MODEL_N, ideal, "k--", lw=0.8, label="ideal (N × 1 worker)")
            ax.plot([1, 2], measured[kind], "ks", label="measured here")
            ax.set_xlim(0.8, 80)
            ax.set_xscale("log", base=2)
            ax.set_yscale("log")
            ax.set(xlabel="workers (machines like one measured worker)", ylabel=label,
                   title=f"{kind}: model from the measured overheads")  # fmt: skip
            ax.legend(fontsize=7)
