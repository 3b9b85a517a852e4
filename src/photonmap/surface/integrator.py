"""The ``photon_mapper`` Mitsuba integrator: the surface pipeline behind ``mi.render``.

.. pluginparameters::

 * - photons, caustic_photons, k, radius, fg_rays, structure, max_depth, seed, lookup,
     fg_sampling, irradiance_cache, ic_error, irradiance_every, spp, emitter_spp, light_samples,
     volume_k, volume_radius, rr_depth, hide_emitters
   - see :class:`photonmap.surface.params.SurfaceParams`
   - Defaults as there (Steinhurst 2007 Table 7.1).

.. code-block:: python

    import photonmap, mitsuba as mi
    scene = mi.load_file("scene.xml")
    image = mi.render(scene, integrator=mi.load_dict({"type": "photon_mapper", "fg_rays": 64}))

The photon maps are built on the first render of a scene and reused while only the camera moves
(Steinhurst §7.2.1); an edit of the scene through ``mi.traverse`` rebuilds them
(:mod:`photonmap.core.plugin`). ``spp`` and ``seed`` of ``mi.render`` reach the pipeline.
"""

from __future__ import annotations

import mitsuba as mi

from ..core.plugin import PipelineIntegrator
from .params import SurfaceParams
from .pipeline import SurfacePipeline


class PhotonMapperIntegrator(PipelineIntegrator):
    """Mitsuba integrator running :class:`~photonmap.surface.pipeline.SurfacePipeline`."""

    pipeline_type, params_type, plugin_name = SurfacePipeline, SurfaceParams, "photon_mapper"
    ignore = {"samples_per_pass", "hide_emitters", "timeout"}  # max_depth is a SurfaceParams field


def register() -> None:
    mi.register_integrator("photon_mapper", lambda props: PhotonMapperIntegrator(props))
