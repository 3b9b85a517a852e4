"""The ``ispm`` Mitsuba integrator: the screen pipeline (Yao 2011) behind ``mi.render``.

.. pluginparameters::

 * - bounces, light_res, radius, splat, compression, subsample, shadows, isg_samples,
     light_size, glossy, seed
   - see :class:`photonmap.screen.pipeline.ScreenParams`
   - Defaults as there (spec seed-004 §4.2).

.. code-block:: python

    import photonmap, mitsuba as mi
    scene = mi.load_dict(photonmap.scenes.SCENES["cornell_ispm"].build())
    image = mi.render(scene, integrator=mi.load_dict({"type": "ispm", "subsample": 8}))

The integrator keeps the :class:`ScreenPipeline` of the scene it rendered last, so rendering again
from another sensor reuses the light G-buffer and the photons (spec §7: a camera move keeps the
photons). One primary ray per pixel centre: the ``spp`` of ``mi.render`` is ignored. Errors are
:class:`photonmap.PhotonmapError` (``mi.render`` wraps them in a ``RuntimeError`` whose
``__cause__`` is the original error).
"""

from __future__ import annotations

import dataclasses

import mitsuba as mi

from ..core.params import read_properties
from .pipeline import ScreenParams, ScreenPipeline


class ISPMIntegrator(mi.SamplingIntegrator):
    """Mitsuba integrator running :class:`~photonmap.screen.pipeline.ScreenPipeline`."""

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.params = read_properties(props, ScreenParams, "ispm")
        dataclasses.replace(ScreenParams(), **self.params).validate()
        self.pipeline: ScreenPipeline | None = None
        self._scene = None  # held, so that a new scene can never reuse its id

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if self.pipeline is None or self._scene is not scene:
            self.pipeline = ScreenPipeline(scene, **self.params)
            self._scene = scene
        self.pipeline.set_camera(sensor=sensor)
        return self.pipeline.render()

    def to_string(self):
        return f"ISPMIntegrator[{self.params}]"


def register() -> None:
    mi.register_integrator("ispm", lambda props: ISPMIntegrator(props))
