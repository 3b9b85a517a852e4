"""The ``volume_photon`` Mitsuba integrator: the volume pipeline behind ``mi.render``.

.. pluginparameters::

 * - grid
   - |int|
   - Voxel resolution N of the N³ grid. (Default: 128)
 * - photons, sampler, seed, eps, eps2, ds_min, ds_max, supersample, phase_k, table,
     iso_reflect, iso_ior, ior_noise, sigma_s_noise, noise_scale, fidelity, smoothing, blur_all
   - see :class:`photonmap.volume.pipeline.VolumeParams`
   - Defaults as there (spec seed-000-002 §1 and §6).

.. code-block:: python

    import photonmap, mitsuba as mi
    scene = mi.load_file("scene.xml")
    image = mi.render(scene, integrator=mi.load_dict({"type": "volume_photon", "photons": 262144}))

The integrator keeps the :class:`VolumePipeline` of the scene it rendered last and re-reads that
scene's lights, media and sensor on every render, so rendering again from another sensor reuses
the photon grids (Sun et al. 2008 §3: a camera change reruns only the viewing pass), and parameters
changed through ``mi.traverse`` take effect with the reruns they need. In-place edits of a mesh's
vertices are not detected: use :meth:`VolumePipeline.set_geometry` or a new integrator.
Errors are :class:`photonmap.PhotonmapError` (``mi.render`` wraps them in a ``RuntimeError`` whose
``__cause__`` is the original error).
"""

from __future__ import annotations

import dataclasses

import mitsuba as mi
import numpy as np

from ..core.params import read_properties
from .pipeline import VolumeParams, VolumePipeline, check_grid

_DEFAULTS = VolumeParams()


class VolumePhotonIntegrator(mi.SamplingIntegrator):
    """Mitsuba integrator running :class:`~photonmap.volume.pipeline.VolumePipeline`."""

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.params = read_properties(props, VolumeParams, "volume_photon", extra={"grid": int})
        self.grid = self.params.pop("grid", 128)
        check_grid(self.grid)
        dataclasses.replace(_DEFAULTS, **self.params).validate()
        self.pipeline: VolumePipeline | None = None
        self._scene = None  # held, so that a new scene can never reuse its id

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if self.pipeline is None or self._scene is not scene:
            self.pipeline = VolumePipeline(scene, grid=self.grid, **self.params)
            self._scene = scene
        else:
            self.pipeline.reload(scene)
        pipe = self.pipeline
        seed = int(np.asarray(seed).reshape(-1)[0]) if seed is not None else 0
        pipe.set_params(
            spp=int(spp) if spp else self.params.get("spp", _DEFAULTS.spp),
            seed=seed if seed else self.params.get("seed", _DEFAULTS.seed),
        )
        pipe.set_camera(sensor=sensor)
        return pipe.render()

    def to_string(self):
        return f"VolumePhotonIntegrator[grid={self.grid}, {self.params}]"


def register() -> None:
    mi.register_integrator("volume_photon", lambda props: VolumePhotonIntegrator(props))
