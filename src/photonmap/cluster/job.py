"""What a worker needs to rebuild the driver's pipeline: a picklable :class:`SceneJob` (scene name
or path, method, parameters, image size), :func:`build_pipeline`, and :class:`FrameState`, which
applies a frame's camera, light and parameters to a pipeline so that the result depends on the
frame alone, not on the frames that worker rendered before.

A scene file is read by path on every worker: on a multi-machine cluster it (and the meshes and
textures it names) must lie at the same path on each node (a shared file system, or Ray's
``runtime_env={"working_dir": ...}``; docs/cluster.md).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

from ..core import interrupt
from ..core.errors import ParameterError, PhotonmapError, SceneError
from ..core.params import parameter_names
from .frames import Frame, FrameSpecError


@dataclass(frozen=True)
class SceneJob:
    """A scene and how to render it: ``params`` are the method's fields, ``scene_params`` a
    built-in's own parameters or an XML file's ``$name`` values; ``width``/``height`` resize the
    camera (None: the scene's)."""

    scene: str
    method: str
    params: dict = field(default_factory=dict)
    scene_params: dict = field(default_factory=dict)
    width: int | None = None
    height: int | None = None

    def with_scene_params(self, scene_params: dict) -> SceneJob:
        return dataclasses.replace(self, scene_params={**self.scene_params, **scene_params})


def build_pipeline(job: SceneJob):
    """The pipeline of ``job``, its camera resized to ``job.width × job.height`` (one of them
    alone keeps the scene's aspect ratio)."""
    from .. import METHODS
    from ..scenes import SCENES, load_scene

    if job.method not in METHODS:
        raise ParameterError(f"unknown method {job.method!r}; available: {', '.join(METHODS)}")
    pipeline = METHODS[job.method].pipeline
    if job.scene in SCENES:
        pipe = pipeline(job.scene, **job.params, **job.scene_params)
    elif os.path.isfile(job.scene):
        mi_scene, _ = load_scene(job.scene, **job.scene_params)
        pipe = pipeline(mi_scene, **job.params)
    else:
        raise SceneError(
            f"scene {job.scene!r} is neither a built-in nor a file on this node "
            f"({os.uname().nodename}); on a cluster every node needs the scene at the same path"
        )
    if job.width or job.height:
        w0, h0 = (int(c) for c in pipe.sensor.film().size())
        width = job.width or max(1, round(job.height * w0 / h0))
        height = job.height or max(1, round(job.width * h0 / w0))
        if (width, height) != (w0, h0):
            pipe.set_camera(width=width, height=height)
    return pipe


def split_set(job: SceneJob, values: dict) -> tuple[dict, dict]:
    """A frame's ``set`` values → (method parameters, scene parameters); an unknown key is a
    :class:`FrameSpecError` listing the valid ones."""
    from .. import METHODS
    from ..scenes import SCENES

    fields = parameter_names(METHODS[job.method].params)
    if job.scene in SCENES:
        scene_keys = set(SCENES[job.scene].params) - {"width", "height"}
    else:
        with open(job.scene, errors="replace") as f:
            text = f.read()
        scene_keys = {k for k in values if f"${k}" in text}
    unknown = sorted(set(values) - fields - scene_keys)
    if unknown:
        raise FrameSpecError(
            f"unknown set key(s) {', '.join(unknown)} for the {job.method} method; valid: "
            f"{', '.join(sorted(fields))}"
            + (f"; scene parameters: {', '.join(sorted(scene_keys))}" if scene_keys else "")
        )
    return (
        {k: v for k, v in values.items() if k in fields},
        {k: v for k, v in values.items() if k not in fields},
    )


class FrameState:
    """A pipeline that renders frames in any order: before each frame the camera is reset to the
    job's (then moved as the frame says), the frame's parameters are set (every frame gives the
    same keys), and a frame whose scene parameters differ from the current pipeline's rebuilds
    it. Stages whose inputs
    are unchanged stay cached (a camera path reruns only the viewing stages; a light path keeps
    the volume method's voxel grids and octree)."""

    def __init__(self, job: SceneJob):
        self.job = job
        self.pipe = None
        self._scene_key = None
        self._sensor = None

    def apply(self, frame: Frame):
        """Set the pipeline up for ``frame``; return it."""
        params, scene_params = split_set(self.job, frame.set)
        key = tuple(sorted(scene_params.items()))
        if self.pipe is None or key != self._scene_key:
            self.pipe = build_pipeline(self.job.with_scene_params(scene_params))
            self._scene_key = key
            self._sensor = self.pipe.sensor
        pipe = self.pipe
        if params:  # every frame sets the same keys (frames.py), so none needs undoing
            pipe.set_params(**params)
        if frame.camera:  # a camera given without a target keeps aiming where the job's did
            pipe.set_camera(sensor=self._sensor)
            pipe.set_camera(**frame.camera)
        if frame.light:
            if "light" not in pipe.edits:
                raise FrameSpecError(
                    f"the {self.job.method} method cannot move lights (no set_light); move a "
                    "light with a scene parameter instead (an XML file's $name in 'set')"
                )
            pipe.set_light(**frame.light)
        return pipe


def check_frames(job: SceneJob, frames) -> None:
    """Apply every frame to one pipeline here, in order, and check its memory estimate at the
    job's image size: before the first frame starts, a bad value anywhere (a type, a length, a
    range, more memory than is available) is one error naming its frame."""
    from .schedule import named

    state = FrameState(job)
    for frame in frames:
        interrupt.check()
        try:
            state.apply(frame).check_memory()
        except PhotonmapError as exc:
            raise named(exc, f"frame {frame.index}") from None
        except (TypeError, ValueError) as exc:
            raise FrameSpecError(
                f"frame {frame.index}: its settings cannot be applied ({exc})"
            ) from None
