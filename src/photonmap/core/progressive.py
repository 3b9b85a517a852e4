"""Progressive rendering: the loop that runs a progressive pipeline's iterations for a time or
iteration budget, with progress reports, previews and Ctrl-C answered between iterations
(:mod:`.interrupt`), and the radius schedule of progressive density estimation (Knaus & Zwicker
2011: ``r_i = r_1 · i^((α−1)/2)``). The ``sppm`` and ``vcm`` pipelines are :class:`Progressive`."""

from __future__ import annotations

import math
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from . import interrupt
from .arrays import to_jit
from .camera import footprint_radius
from .errors import ParameterError, SceneError
from .params import check_range


def iteration_seeds(seed: int, i: int) -> tuple[int, int]:
    """The two seeds of iteration ``i`` (SPPM's eye and photon passes, VCM's light and camera
    passes), from ``(seed, i)`` alone: an iteration's work is the same whatever ran before."""
    state = np.random.SeedSequence([seed, i]).generate_state(2)
    return int(state[0]), int(state[1])


class Progressive:
    """``run`` and ``render`` for a pipeline with ``step()`` (one iteration), ``image()``,
    ``reset()``, ``iterations``, ``mean_radius`` and the ``iterations`` parameter; the radii
    for one with ``scene``, ``sensor``, the ``radius`` and ``alpha`` parameters and ``_r1``
    (None until the automatic first radius is found)."""

    radius_pixels: float  # the automatic first radius, in pixel footprints

    def finished(self, image: np.ndarray | None) -> mi.TensorXf:
        """The image so far as ``image()`` returns it: black before the first iteration,
        refused when it holds NaN or infinite values."""
        if image is None:
            w, h = self.size
            return dr.zeros(mi.TensorXf, (h, w, 3))
        if not np.all(np.isfinite(image)):
            raise SceneError(
                "the render produced NaN or infinite values; check the scene's textures and "
                "emitters for NaN"
            )
        return to_jit(mi.TensorXf, np.asarray(image, np.float32))

    def initial_radius(self) -> float:
        """``r_1``: the ``radius`` parameter, or :attr:`radius_pixels` footprints of a pixel at
        the median distance of the first surfaces the camera rays meet
        (:func:`~.camera.footprint_radius`)."""
        if self.params.radius > 0:
            return self.params.radius
        if self._r1 is None:
            self._r1 = footprint_radius(self.scene, self.sensor, self.radius_pixels)
        return self._r1

    def radius_at(self, i: int) -> float:
        """``r_i = r_1 · i^((α−1)/2)`` (Knaus & Zwicker 2011; i = 1, 2, …)."""
        return self.initial_radius() * i ** ((self.params.alpha - 1.0) / 2.0)

    def run(self, seconds=None, iterations=None, progress=None, preview=None, preview_every=10.0):
        """Iterate until ``seconds`` have passed or ``iterations`` more have run (whichever comes
        first; one of them is required) and return :meth:`image`. ``progress(iterations,
        elapsed, mean_radius)`` is called after each iteration; ``preview(image)`` every
        ``preview_every`` seconds. An interrupt (Ctrl-C) stops after a whole iteration: the
        image so far stays available through :meth:`image` (the interrupt is raised as
        :class:`~photonmap.core.interrupt.Interrupted`, a ``KeyboardInterrupt``, after the step
        in progress: :mod:`photonmap.core.interrupt`)."""
        if seconds is None and iterations is None:
            raise ParameterError("run() needs a budget: seconds=… or iterations=…")
        if seconds is not None:
            check_range("seconds", seconds, 0, None, "the time budget", lo_open=True)
            if not math.isfinite(seconds):
                raise ParameterError(f"seconds must be finite, got {seconds}: give a time budget")
        if iterations is not None:
            if not isinstance(iterations, int):
                raise ParameterError(f"iterations must be an integer, got {iterations!r}")
            check_range("iterations", iterations, 1, None, "iterations to run")
        start = time.perf_counter()
        last_preview = start
        done = 0
        with interrupt.deferred():  # Ctrl-C is answered between iterations, never inside one
            while True:
                self.step()
                done += 1
                now = time.perf_counter()
                if progress is not None:
                    progress(self.iterations, now - start, self.mean_radius)
                interrupt.check()
                if preview is not None and now - last_preview >= preview_every:
                    preview(self.image())
                    last_preview = now
                if iterations is not None and done >= iterations:
                    break
                if seconds is not None and now - start >= seconds:
                    break
        return self.image()


    def render(self, progress=None) -> mi.TensorXf:
        """Render the ``iterations`` parameter's iterations from scratch (``progress(stage)``
        as the other pipelines: called per iteration with ``"iteration i/n"``)."""
        self.reset()
        n = self.params.iterations

        def report(i, _elapsed, _radius):
            if progress:
                progress(f"iteration {i}/{n}")

        return self.run(iterations=n, progress=report)
