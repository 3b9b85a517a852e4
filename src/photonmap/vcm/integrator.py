"""The ``vcm`` Mitsuba integrator: the VCM pipeline behind ``mi.render``.

.. pluginparameters::

 * - iterations, spp, radius, alpha, seed, max_depth, rr_depth, mode
   - see :class:`photonmap.vcm.pipeline.VCMParams`
   - ``iterations`` VCM iterations per ``mi.render`` (each ``spp`` light and camera subpaths
     per pixel); ``radius`` 0 = automatic; α = 0.75; ``mode`` ``vcm`` | ``bpt`` | ``ppm`` | ``pt`` |
     ``lt``.

.. code-block:: python

    import photonmap, mitsuba as mi
    scene = mi.load_file("scene.xml")
    image = mi.render(scene, integrator=mi.load_dict({"type": "vcm", "iterations": 256}))

``seed`` of ``mi.render`` reaches the pipeline (its ``spp`` has no meaning here); an edit of the
scene through ``mi.traverse`` rebuilds the pipeline (:mod:`photonmap.core.plugin`).
"""

from __future__ import annotations

import mitsuba as mi

from ..core.plugin import PipelineIntegrator
from .pipeline import VCMParams, VCMPipeline


class VCMIntegrator(PipelineIntegrator):
    """Mitsuba integrator running :class:`~photonmap.vcm.pipeline.VCMPipeline`."""

    pipeline_type, params_type, plugin_name = VCMPipeline, VCMParams, "vcm"
    ignore = {"samples_per_pass", "hide_emitters", "timeout"}  # max_depth, rr_depth are ours


def register() -> None:
    mi.register_integrator("vcm", lambda props: VCMIntegrator(props))
