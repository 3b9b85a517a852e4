"""The ``photon_mapper`` Mitsuba integrator: the surface pipeline behind ``mi.render``.

.. pluginparameters::

 * - photons, caustic_photons, k, max_radius, fg_rays, structure, max_depth, seed, lookup,
     fg_sampling, irradiance_every, spp
   - see :class:`photonmap.surface.pipeline.SurfaceParams`
   - Defaults as there (Steinhurst 2007 Table 7.1; spec seed-001 §2.0, A12).

.. code-block:: python

    import photonmap, mitsuba as mi
    scene = mi.load_file("scene.xml")
    image = mi.render(scene, integrator=mi.load_dict({"type": "photon_mapper", "fg_rays": 64}))

The photon maps are built on the first render of a scene and reused while the scene and the photon
parameters stay the same (Steinhurst §7.2.1: only the camera moves).
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from ..core.params import read_properties, updated
from .pipeline import SurfaceParams, SurfacePipeline


class PhotonMapperIntegrator(mi.SamplingIntegrator):
    """Mitsuba integrator running :class:`~photonmap.surface.pipeline.SurfacePipeline`."""

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.params = read_properties(
            props,
            SurfaceParams,
            "photon_mapper",
            ignore={"samples_per_pass", "hide_emitters", "timeout"},
        )
        updated(SurfaceParams(), self.params, "photon_mapper")
        self.pipeline: SurfacePipeline | None = None
        self._scene = None

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if self.pipeline is None or self._scene is not scene:
            self.pipeline = SurfacePipeline(scene, **self.params)
            self._scene = scene
        seed = int(np.asarray(seed).reshape(-1)[0]) if seed is not None else 0
        self.pipeline.set_params(
            spp=int(spp) if spp else self.params.get("spp", 1),
            seed=seed if seed else self.params.get("seed", 0),
        )
        self.pipeline.set_camera(sensor=sensor)
        return self.pipeline.render()

    def to_string(self):
        return f"PhotonMapperIntegrator[{self.params}]"


def register() -> None:
    mi.register_integrator("photon_mapper", lambda props: PhotonMapperIntegrator(props))
