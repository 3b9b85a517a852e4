"""The text report of ``photonmap analyze bandwidth`` (Steinhurst 2007 Table 3.1, Figs 3.5, 3.9,
4.1): validates the options, traces the scene's final gathers once and prints one row per gather
order, or the curves of a sweep."""

from __future__ import annotations

from dataclasses import dataclass

from ..core import interrupt
from ..core.errors import ParameterError
from ..core.image import check_output
from ..surface.gather_batch import ORDERS, OrderParams
from .bandwidth import SWEEP_ORDERS, SWEEPS, WAYS, bandwidth_table, plot_sweep, sweep
from .cache import parse_size
from .stream import cropped_scene, photons_per_line, trace_final_gathers
from .structures import STRUCTURES, structure_trace


def _crop(text: str | None, size: int):
    if text is None:
        return None
    try:
        x, y, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise ParameterError(f"--crop expects X,Y,W,H (four integers), got {text!r}") from None
    return (x, y), (w, h)


@dataclass
class CacheModel:
    """What ``photonmap analyze bandwidth`` measures the traffic under: the gather ``orders``
    (None: all, or the sweep's), the ``cache`` and ``line`` sizes (``parse_size``), the ``tile``
    edge in pixels, the photon map's layout (``structure``, :data:`.structures.STRUCTURES`,
    Ch. 4), and a ``sweep`` (tile | cache | line: curves instead of a table, drawn to ``plot``)."""

    orders: list[str] | None = None
    cache: str = "128K"
    line: str = "128"
    tile: int = 16
    structure: str = "kdtree"
    sweep: str | None = None
    plot: str | None = None


def bandwidth_report(scene, builtin, params: dict, size: int, crop, model: CacheModel) -> str:
    """The report text of ``scene`` (``builtin``: the built-in it names, traced at ``size``²,
    cropped to ``crop``; ``params``: typed surface-method and scene parameters) under
    ``model``."""
    cache_bytes, line_bytes = parse_size(model.cache), parse_size(model.line)
    structure, sweep_kind, plot, tile = model.structure, model.sweep, model.plot, model.tile
    orders = _checked(model.orders, cache_bytes, line_bytes, structure, sweep_kind, plot)
    order_params = OrderParams(tile=tile)
    order_params.validate()
    target, surface = _target(scene, builtin, params, size, _crop(crop, size))
    trace = trace_final_gathers(target, **surface)
    interrupt.check()
    head = (
        f"{scene}: {len(trace.batch):,} final gathers, {trace.visits:,} kd-tree node visits "
        f"({trace.visits / max(len(trace.batch), 1):.0f} per gather), {trace.photons:,} photons; "
        f"uncached naive (20 B per node): {trace.uncached_bytes() / 1e6:,.1f} MB"
    )
    if structure != "kdtree":  # the same gathers on a line-organised structure (Ch. 4)
        trace = structure_trace(trace, structure)
        head += (
            f"\non the {structure}: {trace.footprint_lines(line_bytes):,} lines of "
            f"{line_bytes} B; uncached (records read at 128 B lines): "
            f"{trace.uncached_bytes() / 1e6:,.1f} MB"
        )
    if sweep_kind is None:
        rows = bandwidth_table(trace, orders, cache_bytes, line_bytes, order_params, WAYS)
        return _table_text(head, rows, cache_bytes, line_bytes, tile)
    xs, curves = sweep(trace, sweep_kind, orders, cache_bytes, line_bytes, order_params)
    xlabel, _ = SWEEPS[sweep_kind]
    lines = [
        head,
        f"MB per image against {xlabel}",
        f"{'order':<22}" + "".join(f"{x:>9}" for x in xs),
    ]
    for o, ys in curves.items():
        lines.append(f"{o:<22}" + "".join(f"{y / 1e6:>9.2f}" for y in ys))
    if plot:
        plot_sweep(curves, xs, xlabel, plot, f"{scene}: photon-map traffic", trace.uncached_bytes())
        lines.append(f"wrote {plot}")
    return "\n".join(lines)


def _checked(orders, cache_bytes: int, line_bytes: int, structure, sweep_kind, plot) -> list:
    """The gather orders to report (all, or the sweep's, when none are given), after checking
    the options; a bad one raises a :class:`ParameterError` that names it."""
    photons_per_line(line_bytes)
    if structure not in STRUCTURES:
        raise ParameterError(f"--structure must be one of {', '.join(STRUCTURES)}")
    if cache_bytes < line_bytes:
        raise ParameterError(f"the cache ({cache_bytes} B) is smaller than one line")
    orders = list(orders or (SWEEP_ORDERS if sweep_kind else ORDERS))
    for o in orders:
        if o not in ORDERS:
            raise ParameterError(f"unknown --order {o!r}; choose from {', '.join(ORDERS)}")
    if sweep_kind is not None and sweep_kind not in SWEEPS:
        raise ParameterError(f"--sweep must be one of {', '.join(SWEEPS)}, got {sweep_kind!r}")
    if plot is not None and (sweep_kind is None or not plot.lower().endswith(".png")):
        raise ParameterError("--plot needs --sweep and a .png path")
    if plot is not None:
        check_output(plot, (".png",))
    return orders


def _target(scene, builtin, params: dict, size: int, window) -> tuple:
    """``(scene, surface-method parameters)`` to trace: a built-in at ``size``² (cropped to
    ``window``) with its own parameters taken out of ``params``, or the given scene."""
    scene_params = {k: v for k, v in params.items() if builtin and k in builtin.params}
    surface = {k: v for k, v in params.items() if k not in scene_params}
    if builtin is not None:
        offset, extent = window or ((0, 0), (size, size))
        return cropped_scene(builtin.name, size, offset, extent, **scene_params), surface
    if window is not None:
        raise ParameterError("--crop applies to built-in scenes only")
    return scene, surface


def _table_text(head: str, rows: list, cache_bytes: int, line_bytes: int, tile: int) -> str:
    """The report of one cache: a row per gather order."""
    lines = [
        head,
        f"cache {cache_bytes // 1024} KB fully associative LRU, {line_bytes} B lines, "
        f"{tile}x{tile} tiles",
        f"{'order':<22}{'misses':>12}{'MB':>10}{'vs uncached':>13}{'8-way/full':>12}",
    ]
    for r in rows:
        lines.append(
            f"{r['order']:<22}{r['misses']:>12,}{r['bytes'] / 1e6:>10.2f}"
            f"{r['reduction_vs_uncached']:>12.1f}x{r['set_associative_ratio']:>12.2f}"
        )
    return "\n".join(lines)
