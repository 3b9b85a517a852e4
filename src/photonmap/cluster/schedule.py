"""Handing tasks to worker actors and getting the results back as they finish, surviving workers
that die.

Each worker holds at most ``depth`` tasks (one running, the next queued, so it never waits for
the driver). A task whose worker crashed is retried by Ray on the restarted actor
(``max_task_retries``); if the actor is gone for good (killed, restarts used up, its node lost)
the task goes back to the front of the queue and runs on another worker. Results carry the
task's key, so where a task ran never changes what it returns.
"""

from __future__ import annotations

import copy
import re
from collections import deque
from collections.abc import Iterable, Iterator

from ..core import interrupt
from ..core.errors import PhotonmapError
from .connect import ClusterError

WAIT = 0.25  # seconds between looks at Ctrl-C while waiting for results
ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def one_line(exc: BaseException) -> str:
    """An exception as one plain line: its type and the first line of its message (a remote
    traceback and its colour codes left out)."""
    lines = [ANSI.sub("", line).strip() for line in str(exc).splitlines()]
    first = next((line for line in lines if line), "")
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def named(exc: PhotonmapError, what: str) -> PhotonmapError:
    """``exc`` (same class, same exit status) with its message prefixed by ``what``."""
    new = copy.copy(exc)
    new.args = (f"{what}: {exc}",)
    return new


def run_tasks(ray, actors: list, method: str, tasks: Iterable, depth: int = 2,
              label: str = "task") -> Iterator[tuple]:  # fmt: skip
    """Yield ``(key, result)`` for each ``(key, args)`` of ``tasks`` as its result arrives:
    ``actors[i].<method>.remote(*args)``. ``tasks`` is consumed lazily (a generator may stop
    yielding when a time budget is spent). Raises the worker's own :class:`PhotonmapError` (bad
    input is not retried) or a :class:`ClusterError` for any other failure of a task, one line
    naming it (``f"{label} {key}"``), or a :class:`ClusterError` when no worker is left. Ctrl-C
    (:mod:`photonmap.core.interrupt`) is answered while waiting: :class:`Interrupted`."""
    fresh = iter(tasks)
    retry: deque = deque()  # tasks whose worker died, run first
    alive = list(actors)
    load = {id(a): 0 for a in alive}
    flight: dict = {}  # ObjectRef → (task, actor)
    try:
        while True:
            for actor in alive:
                while load[id(actor)] < depth:
                    task = retry.popleft() if retry else next(fresh, None)
                    if task is None:
                        break
                    flight[getattr(actor, method).remote(*task[1])] = (task, actor)
                    load[id(actor)] += 1
            if not flight:
                if alive or not (retry or next(fresh, None) is not None):
                    return  # everything ran
                raise ClusterError(
                    "every worker died and work is left undone (a worker process was killed, "
                    "ran out of memory or crashed repeatedly)"
                )
            ready = []
            while not ready:
                interrupt.check()
                ready, _ = ray.wait(list(flight), num_returns=1, timeout=WAIT)
            (ref,) = ready
            task, actor = flight.pop(ref)
            load[id(actor)] -= 1
            try:
                result = ray.get(ref)
            except ray.exceptions.RayActorError as exc:
                if isinstance(exc, ray.exceptions.ActorDiedError) and actor in alive:
                    alive.remove(actor)
                retry.append(task)
                continue
            except ray.exceptions.RayTaskError as exc:
                cause = getattr(exc, "cause", None)
                if isinstance(cause, PhotonmapError):
                    raise named(cause, f"{label} {task[0]}") from None
                raise ClusterError(
                    f"{label} {task[0]}: the worker failed: {one_line(cause or exc)}"
                ) from None
            yield task[0], result
    finally:
        for ref in flight:  # an interrupted driver leaves no work behind
            try:
                ray.cancel(ref)
            except Exception:  # noqa: BLE001 - the task may have finished meanwhile
                pass
