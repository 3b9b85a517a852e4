"""The ``sppm`` Mitsuba integrator: the SPPM pipeline behind ``mi.render``.

.. pluginparameters::

 * - iterations, photons, radius, alpha, seed, max_depth, rr_depth, mode, aim,
     volume_radius
   - see :class:`photonmap.sppm.pipeline.SPPMParams`
   - ``iterations`` SPPM iterations per ``mi.render`` (each one eye path per pixel and
     ``photons`` photon paths); ``radius`` 0 = automatic; α = 2/3;
     ``mode`` ``sppm`` | ``memoryless``.

.. code-block:: python

    import photonmap, mitsuba as mi
    scene = mi.load_file("scene.xml")
    image = mi.render(scene, integrator=mi.load_dict({"type": "sppm", "iterations": 256}))

``seed`` of ``mi.render`` reaches the pipeline (its ``spp`` has no meaning here: one eye path per
pixel and iteration); an edit of the scene through ``mi.traverse`` rebuilds the pipeline
(:mod:`photonmap.core.plugin`).
"""

from __future__ import annotations

import mitsuba as mi

from ..core.plugin import PipelineIntegrator
from .pipeline import SPPMParams, SPPMPipeline


class SPPMIntegrator(PipelineIntegrator):
    """Mitsuba integrator running :class:`~photonmap.sppm.pipeline.SPPMPipeline`."""

    pipeline_type, params_type, plugin_name = SPPMPipeline, SPPMParams, "sppm"
    ignore = {"samples_per_pass", "hide_emitters", "timeout"}  # max_depth, rr_depth are ours


def register() -> None:
    mi.register_integrator("sppm", lambda props: SPPMIntegrator(props))
