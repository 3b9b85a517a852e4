"""The one shape of every method's pipeline, and all that the command line, the viewer, the
cluster and the Mitsuba plugins use of a method.

Each method (``volume``, ``surface``, ``screen``, ``sppm``) is a :class:`Pipeline`: it holds the
Mitsuba ``scene`` and the current ``sensor``, its validated parameters ``params`` (an instance of
its ``params_type``, which holds every setting), its stage names ``stages`` and a
:class:`~.stages.StageCache` (a camera move reruns only the stages whose inputs hold the
camera), and it declares the edits it supports in ``edits`` rather than being probed for them:

=============  ==========================================================================
edit           method
=============  ==========================================================================
``camera``     :meth:`set_camera` (every method)
``params``     :meth:`set_params` (every method)
``light``      ``set_light(...)``: move, re-aim or rescale a light
``material``   ``set_material(...)``: a refractive object's index, a medium's σ_s and σ_a
``volume``     ``set_volume(...)``: the voxel grids themselves
``reload``     ``reload(scene)``: re-read an ``mi.Scene`` edited through ``mi.traverse``,
               keeping what did not change (the others are built again)
=============  ==========================================================================

A ``progressive`` pipeline refines its image by iterations: ``reset()``, ``step()``,
``image()`` and ``run(seconds=…, iterations=…)``; its :meth:`render` runs the ``iterations``
parameter's worth from scratch.

>>> pipe = METHODS["sppm"].pipeline("examples/cornell_box.xml", photons=100_000)
>>> pipe.set_camera(width=320, height=240)
>>> image = pipe.render()
>>> "light" in pipe.edits, pipe.progressive
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import mitsuba as mi

from .camera import MovableCamera
from .stages import StageCache, StagedPipeline

EDITS = ("camera", "params", "light", "material", "volume", "reload")


class Pipeline(MovableCamera, StagedPipeline, ABC):
    """A method's pipeline (module docstring). Subclasses set :attr:`method`,
    :attr:`params_type`, :attr:`stages`, :attr:`edits` and :attr:`progressive`, and keep
    ``scene``, ``sensor``, ``params``, ``cache`` and ``stats``."""

    method: str
    params_type: type
    edits: frozenset[str] = frozenset({"camera", "params"})
    progressive: bool = False

    scene: mi.Scene
    params: object
    cache: StageCache
    stats: dict[str, float]

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        unknown = set(cls.edits) - set(EDITS)
        if unknown:
            raise TypeError(f"{cls.__name__} declares unknown edits {sorted(unknown)}")

    @abstractmethod
    def render(self, progress=None) -> mi.TensorXf:
        """The image from the current camera, ``(height, width, 3)`` linear radiance;
        ``progress(stage)`` is called as each stage that must run starts."""

    @abstractmethod
    def set_params(self, **params) -> None:
        """Change parameters (fields of :attr:`params_type`); invalid values raise a
        :class:`~.errors.ParameterError` and leave the pipeline as it was."""

    @abstractmethod
    def check_memory(self, params=None, size=None) -> int:
        """Raise a :class:`~.errors.ParameterError` when ``params`` (default: the pipeline's)
        at ``size`` (width, height; default: the camera's) would not fit in memory; return the
        estimate in bytes."""

    @property
    def size(self) -> tuple[int, int]:
        """The image size (width, height): the film's crop window."""
        w, h = (int(c) for c in self.sensor.film().crop_size())
        return w, h
