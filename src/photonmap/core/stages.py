"""The keyed stage cache every pipeline keeps its stage outputs in (DESIGN.md "Data flow").

A stage's output is stored under its name with a key made of exactly the inputs it depends on;
asking again with an equal key returns the stored output, any other key recomputes it. So a
camera move reruns only the stages whose keys hold the camera, and so on, without a dirty flag
per input (the rerun rules of Sun et al. 2008 §6 and Yao 2011 Ch. 3: a camera move keeps the
photons, a light move keeps the geometry).

>>> cache = StageCache(StageTimer())
>>> grids = cache.stage("march", key=(light_key, photons), compute=lambda: march(...))
>>> cache.recomputed        # the stages the last frame ran
>>> cache.invalidate("march")   # the next frame reruns it (benchmarks time whole frames so)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable

import numpy as np

from .errors import ParameterError
from .timer import StageTimer


def cache_key(value):
    """A hashable key for parameters made of arrays, lists, dataclasses and scalars; other
    objects (Mitsuba shapes, sensors) count by identity."""
    if isinstance(value, np.ndarray):
        return (value.shape, value.tobytes())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return tuple(cache_key(getattr(value, f.name)) for f in dataclasses.fields(value))
    if isinstance(value, list | tuple):
        return tuple(cache_key(v) for v in value)
    if isinstance(value, float | int | str | bool) or value is None:
        return value
    return id(value)


class StageCache:
    """Stage outputs by name, each with the key it was computed under.

    ``timer`` records each computed stage's milliseconds; ``progress`` (set per frame by the
    pipeline) is called with a stage's name as it starts; cached stages are skipped silently."""

    def __init__(self, timer: StageTimer | None = None):
        self.timer = timer if timer is not None else StageTimer()
        self.recomputed: list[str] = []
        self.progress: Callable[[str], None] | None = None
        self._entries: dict[str, tuple] = {}

    def new_frame(self, progress: Callable[[str], None] | None = None) -> None:
        """Start a frame: reset the timer and :attr:`recomputed`, report stages to ``progress``."""
        self.timer.reset()
        self.recomputed = []
        self.progress = progress

    def stage(self, name: str, key, compute: Callable[[], object], timed: bool = True):
        """The output of stage ``name`` for ``key``: the stored one if its key equals ``key``,
        else ``compute()`` (timed, reported, stored). ``timed=False``: an intermediate kept with
        the stages' outputs but computed inside the stage that asks for it (its time counts
        there, and it is not reported)."""
        hit = self._entries.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        value = self.run(name, compute) if timed else compute()
        self._entries[name] = (key, value)
        return value

    def run(self, name: str, compute: Callable[[], object]):
        """``compute()`` as stage ``name``, timed and reported but not stored: a stage that runs
        anew each time (an iteration of a progressive method). Its milliseconds add up over the
        frame; :attr:`recomputed` lists it once."""
        if self.progress is not None:
            self.progress(name)
        with self.timer(name):
            value = compute()
        if name not in self.recomputed:
            self.recomputed.append(name)
        return value

    def get(self, name: str, default=None):
        """The stored output of stage ``name`` (whatever its key), or ``default``."""
        hit = self._entries.get(name)
        return default if hit is None else hit[1]

    def key(self, name: str, default=None):
        """The key stage ``name`` was last computed under, or ``default``."""
        hit = self._entries.get(name)
        return default if hit is None else hit[0]

    def invalidate(self, names: str | Iterable[str] | None = None, keep: Iterable[str] = ()) -> None:
        """Forget the outputs of ``names`` (all stages when None, except those in ``keep``): the
        next frame recomputes them."""
        if names is None:
            names = [n for n in self._entries if n not in set(keep)]
        elif isinstance(names, str):
            names = [names]
        for name in list(names):
            self._entries.pop(name, None)

    def __contains__(self, name: str) -> bool:
        return name in self._entries


class StagedPipeline:
    """The stage-cache interface of a pipeline holding a :class:`StageCache` in ``cache`` and
    its stage names in ``stages``: per-stage timings, the stages the last frame ran, forgetting
    stages, and reading a stage's output."""

    cache: StageCache
    stages: tuple[str, ...]

    @property
    def timer(self) -> StageTimer:
        """Milliseconds of each stage the last ``render`` ran."""
        return self.cache.timer

    @timer.setter
    def timer(self, timer: StageTimer) -> None:
        self.cache.timer = timer

    @property
    def recomputed(self) -> list[str]:
        """The stages the last ``render`` ran, in order (the others were reused)."""
        return self.cache.recomputed

    def invalidate(self, names: str | Iterable[str] | None = None) -> None:
        """Forget the cached output of the stages ``names`` (all when None): the next
        ``render`` recomputes them. The other stages keep their outputs while their own inputs
        are unchanged, so to time a whole frame invalidate every stage (the benchmarks do)."""
        if names is not None:
            for name in [names] if isinstance(names, str) else names:
                self._check_stage(name)
        self.cache.invalidate(names)

    def stage_output(self, name: str):
        """The cached output of stage ``name`` (one of :attr:`stages`) from the last render."""
        self._check_stage(name)
        if name not in self.cache:
            raise ParameterError(f"stage {name!r} has not run yet: call render() first")
        return self.cache.get(name)

    def _check_stage(self, name: str) -> None:
        if name not in self.stages:
            raise ParameterError(f"no stage {name!r}; the stages are {', '.join(self.stages)}")
