"""Rendering on a Ray cluster: memoryless progressive passes split into blocks of
iterations across worker actors (:mod:`.progressive`), and frame sequences with one task per frame
(:mod:`.sequence`). Ray is an optional dependency (``pip install 'photonmap[cluster]'``); it is
imported only when a cluster is started or joined.

Modules: :mod:`.connect` (start or join Ray, place the actors), :mod:`.workers` (the actors),
:mod:`.schedule` (tasks to actors, rescheduling after a worker dies), :mod:`.frames` (frame
specs), :mod:`.job` (rebuilding the driver's pipeline on a worker).
"""

from .connect import ClusterError, cluster, probe
from .frames import Frame, FrameSpec, FrameSpecError, load_frames, parse_frames
from .job import SceneJob, build_pipeline
from .progressive import ProgressiveResult, render_progressive
from .sequence import render_sequence

__all__ = [
    "ClusterError",
    "Frame",
    "FrameSpec",
    "FrameSpecError",
    "ProgressiveResult",
    "SceneJob",
    "build_pipeline",
    "cluster",
    "load_frames",
    "parse_frames",
    "probe",
    "render_progressive",
    "render_sequence",
]
