"""Distributed sequences: one task per frame, frames written as they finish.

>>> spec = load_frames("orbit.json")
>>> job = SceneJob("glass_sphere_fog", "volume", {"grid": 64}, width=160, height=120)
>>> for frame, paths, info in render_sequence(job, spec.frames, ["out/%04d.png"], workers=2):
...     print(frame, paths, info["seconds"])

Each worker keeps its pipeline between the frames it renders (:class:`~.job.FrameState`), so a
camera path reruns only the viewing stages there and a light path keeps the voxel grids. A
frame is written by the driver as soon as it arrives, in whatever order frames finish; the files
of finished frames stay if the run is interrupted or a worker dies (its frames are rendered
again elsewhere, :mod:`.schedule`).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator, Sequence

import numpy as np

from ..core.image import check_output, write_image
from .connect import cluster, import_ray, spawn
from .frames import Frame, check_pattern, frame_path
from .job import SceneJob
from .schedule import run_tasks
from .workers import FrameWorker


def check_outputs(patterns: Sequence[str]) -> None:
    """Each pattern has one frame-number field and a writable .png/.exr path (before any work)."""
    for pattern in patterns:
        check_pattern(pattern)
        check_output(frame_path(pattern, 0))


def render_sequence(
    job: SceneJob,
    frames: Sequence[Frame],
    patterns: Sequence[str],
    workers: int | None = None,
    address: str | None = None,
    skip_existing: bool = False,
) -> Iterator[tuple[int, list[str], dict]]:
    """Render ``frames`` of ``job`` on Ray workers and write each to every output pattern as it
    arrives; yield ``(frame index, paths written, worker info)``. ``skip_existing`` leaves out
    frames whose files all exist (resuming an interrupted sequence)."""
    check_outputs(patterns)
    todo = [
        f
        for f in frames
        if not (skip_existing and all(os.path.exists(frame_path(p, f.index)) for p in patterns))
    ]
    if not todo:
        return
    ray = import_ray()
    with cluster(workers, address) as place:
        place = dataclasses.replace(place, workers=min(place.workers, len(todo)))
        tasks = [(f.index, (f,)) for f in todo]
        with spawn(ray, FrameWorker, place, job) as actors:
            for index, (image, info) in run_tasks(ray, actors, "render", tasks, label="frame"):
                image = np.array(image)  # writable: Ray hands out read-only views of its store
                paths = [write_image(frame_path(p, index), image) for p in patterns]
                yield index, paths, info
