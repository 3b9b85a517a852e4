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

The integrator keeps one :class:`VolumePipeline` per scene, so rendering again from another sensor
reuses the photon grids (Sun et al. 2008 §3: a camera change reruns only the viewing pass).
"""

from __future__ import annotations

import dataclasses

import mitsuba as mi

from .pipeline import VolumeParams, VolumePipeline

_FIELDS = {f.name: f.type for f in dataclasses.fields(VolumeParams)}


class VolumePhotonIntegrator(mi.SamplingIntegrator):
    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.grid = int(props.get("grid", 128))
        defaults = VolumeParams()
        self.params = {}
        for name in _FIELDS:
            if props.has_property(name):
                value = props[name]
                self.params[name] = type(getattr(defaults, name))(value)
        self._pipelines: dict[int, VolumePipeline] = {}

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        pipe = self._pipelines.get(id(scene))
        if pipe is None:
            pipe = VolumePipeline(scene, grid=self.grid, **self.params)
            self._pipelines = {id(scene): pipe}
        if spp:
            pipe.set_params(spp=int(spp))
        pipe.set_params(seed=int(seed) if seed else pipe.params.seed)
        pipe.set_camera(sensor=sensor)
        return pipe.render()

    def to_string(self):
        return f"VolumePhotonIntegrator[grid={self.grid}, {self.params}]"


def register() -> None:
    mi.register_integrator("volume_photon", lambda props: VolumePhotonIntegrator(props))
