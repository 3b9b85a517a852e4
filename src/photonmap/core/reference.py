"""Ground truth: the same scene rendered by Mitsuba's own integrators (``path``, ``volpath``,
``ptracer``), in passes that bound memory, for ``photonmap reference`` and the tests.

Each pass renders ``spp_per_pass`` samples per pixel with its own seed; the image is the mean of
the passes, so any number of samples fits in memory (a pass holds about
:data:`BYTES_PER_SAMPLE` bytes per sample in flight). A time budget stops after the pass that
crosses it.

The path-length settings are the scene file's own (:class:`.settings.PathSettings`: ``max_depth``,
``rr_depth`` and ``hide_emitters`` of its ``<integrator>``, also inside an ``aov`` or ``moment``
wrapper), so that the reference is Mitsuba's image of the file; arguments override them.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import drjit as dr
import mitsuba as mi
import numpy as np

from . import interrupt
from .errors import ParameterError
from .scene_info import has_media
from .settings import PathSettings

INTEGRATORS = ("path", "volpath", "ptracer")
BYTES_PER_SAMPLE = 200  # Mitsuba's wavefront path tracing on the LLVM backend, rough upper bound
PASS_MEMORY = 2 << 30  # bytes one pass may hold in flight
FIRST_PASS_SPP = 4


def default_integrator(scene: mi.Scene) -> str:
    """``volpath`` for a scene with participating media, else ``path``."""
    return "volpath" if has_media(scene) else "path"


def spp_per_pass(pixels: int, spp: int, memory: int | None = None) -> int:
    """Samples per pixel of one pass: all of ``spp`` if they fit in ``memory`` bytes (default
    :data:`PASS_MEMORY`), else fewer."""
    memory = PASS_MEMORY if memory is None else memory
    return int(max(1, min(spp, memory // max(BYTES_PER_SAMPLE * pixels, 1))))


def render_reference(
    scene: mi.Scene,
    spp: int = 1024,
    integrator: str | None = None,
    max_depth: int | None = None,
    time_limit: float | None = None,
    seed: int = 0,
    sensor: int = 0,
    progress: Callable[[int, int], None] | None = None,
    source=None,
    rr_depth: int | None = None,
    hide_emitters: bool | None = None,
) -> tuple[np.ndarray, dict]:
    """Mitsuba's ``integrator`` (default :func:`default_integrator`) on ``scene`` at ``spp``
    samples per pixel, or fewer if ``time_limit`` seconds run out first (at least one pass; the
    last pass may overrun the limit by about a tenth of it).
    ``max_depth`` as Mitsuba counts it (-1: unbounded; 2: direct light only), ``rr_depth`` and
    ``hide_emitters``: None takes the scene's own (its ``<integrator>``; ``source``, the XML file
    it was loaded from, if any, supplies what a wrapper integrator hides). Returns the image
    (height, width, 3) as float64 and ``{"spp", "seconds", "integrator", "passes", "max_depth",
    "rr_depth", "hide_emitters"}``; ``progress(samples_done, spp)`` is called after each pass."""
    own = PathSettings.of(scene, source=source)
    max_depth = own.max_depth if max_depth is None else max_depth
    rr_depth = own.rr_depth if rr_depth is None else rr_depth
    hide_emitters = own.hide_emitters if hide_emitters is None else bool(hide_emitters)
    integrator = integrator or default_integrator(scene)
    if integrator not in INTEGRATORS:
        raise ParameterError(
            f"integrator must be one of {', '.join(INTEGRATORS)}, got {integrator!r}"
        )
    if isinstance(spp, bool) or not isinstance(spp, int) or spp < 1:
        raise ParameterError(f"spp must be an integer >= 1, got {spp!r}")
    if time_limit is not None and not time_limit > 0:
        raise ParameterError(f"the time limit must be > 0 seconds, got {time_limit!r}")
    if max_depth < -1 or max_depth == 0:
        raise ParameterError(f"max_depth must be -1 (unbounded) or >= 1, got {max_depth}")
    if isinstance(rr_depth, bool) or not isinstance(rr_depth, int) or rr_depth < 1:
        raise ParameterError(f"rr_depth must be an integer >= 1, got {rr_depth!r}")
    if not scene.sensors():
        raise ParameterError("the scene has no sensor (camera) to render from")
    props = {
        "type": integrator,
        "max_depth": int(max_depth),
        "rr_depth": int(rr_depth),
        "hide_emitters": hide_emitters,
    }
    method = mi.load_dict(props)
    size = scene.sensors()[sensor].film().crop_size()
    per_pass = spp_per_pass(int(size[0]) * int(size[1]), spp)
    # with a time limit, passes are sized from the measured time per sample to take about a
    # tenth of the budget each (the first one renders FIRST_PASS_SPP samples)
    n = min(per_pass, FIRST_PASS_SPP) if time_limit is not None else per_pass
    total, done, passes = None, 0, 0
    start = time.perf_counter()
    while done < spp:
        n = min(n, spp - done)
        with interrupt.held():  # Mitsuba's own SIGINT handler is not signal-safe
            image = mi.render(scene, integrator=method, sensor=sensor, spp=n, seed=seed + passes)
            image = np.array(image, dtype=np.float64)[..., :3]
        dr.sync_thread()
        total = image * n if total is None else total + image * n
        done += n
        passes += 1
        if progress is not None:
            progress(done, spp)
        elapsed = time.perf_counter() - start
        if time_limit is not None:
            if elapsed >= time_limit:
                break
            rate = done / max(elapsed, 1e-6)  # samples per pixel per second
            n = int(max(1, min(per_pass, rate * min(time_limit / 10, time_limit - elapsed))))
    seconds = time.perf_counter() - start
    return total / done, {
        "spp": done, "seconds": seconds, "integrator": integrator, "passes": passes,
        "max_depth": int(max_depth), "rr_depth": int(rr_depth), "hide_emitters": hide_emitters,
    }  # fmt: skip
