"""The headline, tables and plot of ``volume_vs_volpath.py``: how much sooner each method reaches
an error than Mitsuba's ``volpath`` does, read off the (time, error) curves, whether its error
stops falling (a bias floor), and the markdown and plot of the curves.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import report
from accuracy import curve, loglog_between

METHODS = ("volume", "surface")
KEYS = (  # the errors with headlines; the first is the headline's headline
    "rel_rmse",
    "block_rel_rmse",
    "rel_rmse_vs_truth",
    "block_rel_rmse_vs_truth",
    "rel_rmse_full",
    "block_rel_rmse_full",
)
FLOOR_DROP = 0.1  # the error fell less than this (relative) over the last ≥ 2× of time: a floor


# ----------------------------------------------------------------------------------- headline
def volpath_time_for(rows, error: float, key: str) -> tuple[float | None, str]:
    """Seconds ``volpath`` needs for ``error`` on its (time, error) curve: log-log interpolation
    between the first pair of points that brackets it (``"interpolated"``), RMSE ∝ t^−½ past its
    last point (``"extrapolated"``); ``(None, "volpath_1spp_lower")`` if its cheapest point
    already has a lower error, ``(None, "below_reference_noise")`` for an error of 0 (an error
    against the truth that the reference's noise hides)."""
    t, e = curve(rows, key)
    if error <= 0:
        return None, "below_reference_noise"
    if error >= e[0]:
        return None, "volpath_1spp_lower"
    found = loglog_between(t, e, error)
    if found is not None:
        return found, "interpolated"
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
    lowest = float(e.min())
    return {"still_falling": falling, "lowest": lowest, "floor": None if falling else lowest}


def headline_for(method_rows, volpath_rows, key: str) -> dict:
    """Speedups at equal error (``key``) of one method over ``volpath``: per point, at the
    method's lowest-error point (the headline) and the largest; the bias floor, if any."""
    points = []
    for r in method_rows:
        t_vp, how = volpath_time_for(volpath_rows, r[key], key)
        speedup = t_vp / r["seconds"] if t_vp is not None else None
        points.append({"error": r[key], "seconds": r["seconds"], "volpath_seconds": t_vp,
                       "volpath_time_is": how, "speedup": speedup})  # fmt: skip
    best = points[min(range(len(points)), key=lambda i: points[i]["error"])]
    valid = [p["speedup"] for p in points if p["speedup"] is not None]
    status = floor(method_rows, key)
    volpath_lowest = min(r[key] for r in volpath_rows)
    out = {
        "speedup_vs_volpath_at_equal_rmse": best["speedup"],
        "at_error": best["error"],
        "method_seconds": best["seconds"],
        "volpath_seconds_for_that_error": best["volpath_seconds"],
        "volpath_time_is": best["volpath_time_is"],
        "max_speedup": max(valid) if valid else None,
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


def method_headlines(res: dict) -> dict:
    """:func:`headline_for` of every method and error of one scene's curves."""
    return {m: {k: headline_for(res[m], res["volpath"], k) for k in KEYS} for m in METHODS}


def scene_headline(res: dict) -> dict:
    """The speedups of one scene at every error, its bias floors and notes."""
    h = res["headline"]
    return {
        "speedup_vs_volpath_at_equal_rmse": {
            m: h[m]["rel_rmse"]["speedup_vs_volpath_at_equal_rmse"] for m in METHODS
        },
        "by_error": {
            m: {k: h[m][k]["speedup_vs_volpath_at_equal_rmse"] for k in KEYS} for m in METHODS
        },
        "bias_floor": {m: {k: h[m][k]["bias_floor"] for k in KEYS} for m in METHODS},
        "notes": [
            f"{m} {k}: {h[m][k]['note']}" for m in METHODS for k in KEYS if "note" in h[m][k]
        ],
    }


# ------------------------------------------------------------------------------------ output
def budget_text(method: str, r: dict) -> str:
    if method == "volpath":
        return f"{r['spp']} spp"
    if method == "volume":
        return f"grid {r['grid']}, {r['photons']:,} photons"
    return f"{r['photons']:,} photons, {r['spp']} spp"


CURVE_COLUMNS = [
    ("method", "method", None),
    ("budget", lambda r: budget_text(r["method"], r), None),
    ("seconds", "seconds", 3),
    ("rel. RMSE", "rel_rmse", 4),
    ("4×4-block rel. RMSE", "block_rel_rmse", 4),
    ("rel. RMSE vs truth", "rel_rmse_vs_truth", 4),
    ("block vs truth", "block_rel_rmse_vs_truth", 4),
    ("rel. RMSE, whole image", "rel_rmse_full", 4),
    ("block, whole image", "block_rel_rmse_full", 4),
    ("brightness", "brightness", 3),
]


def _volpath_seconds(h: dict) -> str:
    how = h["volpath_time_is"]
    return report.fmt(h["volpath_seconds_for_that_error"], 2) + (
        "" if how == "interpolated" else f" ({how})"
    )


def _end_of_curve(h: dict) -> str:
    text = "falling" if h["error_still_falling"] else f"floor {h['bias_floor']:.4f}"
    return text + (" — " + h["note"] if "note" in h else "")


HEADLINE_COLUMNS = [
    ("method", "method", None),
    ("error", "error", None),
    ("lowest error", "at_error", 4),
    ("its seconds", "method_seconds", 3),
    ("volpath seconds for it", _volpath_seconds, None),
    ("speedup", "speedup_vs_volpath_at_equal_rmse", 1),
    ("max speedup on curve", "max_speedup", 1),
    ("end of curve", _end_of_curve, None),
]


def markdown(result: dict, max_depth: int) -> str:
    m, runs = result["machine"], result["runs_per_point"]
    lines = [
        "# volume and surface vs Mitsuba volpath on fog",
        "",
        f"{result['image'][0]}×{result['image'][1]} pixels; reference: volpath "
        f"{result['reference_spp']} spp, depth {max_depth}. Times: medians of {runs} renders "
        f"(seeds 0–{runs - 1}) after a warm-up. {m['cpu_model']}, {m['cores_usable']} usable "
        f"cores; load average {m['load_average']} at the start, "
        f"{result['load_average_end']} at the end; total {result['total_seconds']:.0f} s.",
        "",
        "Command: `" + result["command"] + "`",
        "",
    ]
    for name, res in result["scenes"].items():
        curves = [{"method": k, **r} for k in ("volpath", *METHODS) for r in res[k]]
        heads = [{"method": k, "error": e, **res["headline"][k][e]} for k in METHODS for e in KEYS]
        noise, h = res["reference_noise"], result["headline"][name]
        speedups = ", ".join(
            f"{method} {report.fmt(v, 1)}× faster than volpath at equal error"
            for method, v in h["speedup_vs_volpath_at_equal_rmse"].items()
        )
        lines += [
            f"## {name}: {res['description']}",
            "",
            report.records_table(curves, CURVE_COLUMNS, "llrrrrrrrr"),
            "",
            f"Errors over the pixels that do not see the light ({res['masked_pixels']} masked: "
            "the light and its images in the glass, dilated by 1 pixel) unless `full`. "
            f"Reference noise (from its two halves): rel. RMSE {noise['rel_rmse']:.4f}, 4×4-block "
            f"rel. RMSE {noise['block_rel_rmse']:.4f}; `*_vs_truth` = √(error² − noise²).",
            "",
            report.records_table(heads, HEADLINE_COLUMNS, "llrrrrrl"),
            "",
            f"**Headline** (rel. RMSE, light's images masked): {speedups}.",
            "",
            *[f"- {note}" for note in h["notes"]],
            "",
        ]
    return "\n".join(lines) + "\n"


def plot(results: dict, path: Path) -> None:
    """Error against time of every method, per scene (columns) and error (rows)."""
    errors = (("rel_rmse", "relative RMSE"), ("block_rel_rmse", "4×4-block relative RMSE"))
    with report.figure(path, 2, len(results), size=(5 * len(results), 7)) as axes:
        for col, (name, res) in enumerate(results.items()):
            for row, (key, label) in enumerate(errors):
                ax = axes[row][col]
                report.loglog_curves(ax, {k: res[k] for k in ("volpath", *METHODS)}, "seconds", key)
                ax.axhline(res["reference_noise"][key], color="grey", ls="--", lw=0.8,
                           label="reference noise")  # fmt: skip
                ax.set(xlabel="wall time (s)", ylabel=label, title=f"{name}: {label}")
                ax.grid(True, which="both", lw=0.3)
                ax.legend()
