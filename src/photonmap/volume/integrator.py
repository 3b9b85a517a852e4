"""The ``volume_photon`` Mitsuba integrator: the volume pipeline behind ``mi.render``.

.. pluginparameters::

 * - grid
   - |int|
   - Voxels N along the grid box's longest side (a box grid). (Default: 128)
 * - photons, sampler, seed, eps, eps2, ds_min, ds_max, supersample, phase_k, table,
     iso_reflect, iso_ior, ior_noise, sigma_s_noise, noise_scale, fidelity, smoothing, blur_all,
     spp, emission and the adaptive-emission keys
   - see :class:`photonmap.volume.pipeline.VolumeParams`
   - Defaults as there (Sun et al. 2008 and Pfeuti 2009 where they give them).

.. code-block:: python

    import photonmap, mitsuba as mi
    scene = mi.load_file("scene.xml")
    image = mi.render(scene, integrator=mi.load_dict({"type": "volume_photon", "photons": 262144}))

The integrator keeps the :class:`VolumePipeline` of the scene it rendered last, so rendering again
from another sensor reuses the photon grids (Sun et al. 2008 §3: a camera change reruns only the
viewing pass); when the scene was edited through ``mi.traverse`` (:mod:`photonmap.core.plugin`)
the pipeline re-reads its lights, media and sensor and reruns the stages the edit needs. In-place
edits of a mesh's vertices are seen as an edit but the voxel grids are keyed by the shape: use
:meth:`VolumePipeline.set_geometry` or a new integrator.
"""

from __future__ import annotations

import mitsuba as mi

from ..core.plugin import PipelineIntegrator
from .params import VolumeParams
from .pipeline import VolumePipeline


class VolumePhotonIntegrator(PipelineIntegrator):
    """Mitsuba integrator running :class:`~photonmap.volume.pipeline.VolumePipeline`."""

    pipeline_type, params_type, plugin_name = VolumePipeline, VolumeParams, "volume_photon"


def register() -> None:
    mi.register_integrator("volume_photon", lambda props: VolumePhotonIntegrator(props))
