"""The ``ispm`` Mitsuba integrator: the screen pipeline (Yao 2011) behind ``mi.render``.

.. pluginparameters::

 * - bounces, photons, radius, splat, compression, subsample, shadows, isg_samples,
     light_size, glossy, seed
   - see :class:`photonmap.screen.pipeline.ScreenParams`
   - Defaults as there (Yao 2011 Tables 1–2 where given).

.. code-block:: python

    import photonmap, mitsuba as mi
    scene = mi.load_dict(photonmap.scenes.SCENES["cornell_ispm"].build())
    image = mi.render(scene, integrator=mi.load_dict({"type": "ispm", "subsample": 8}))

The integrator keeps the :class:`ScreenPipeline` of the scene it rendered last, so rendering again
from another sensor reuses the light G-buffer and the photons (a camera move keeps the
photons); an edit of the scene through ``mi.traverse`` rebuilds it (:mod:`photonmap.core.plugin`).
One primary ray per pixel centre: the ``spp`` of ``mi.render`` is ignored; its ``seed`` seeds the
fixed random map.
"""

from __future__ import annotations

import mitsuba as mi

from ..core.plugin import PipelineIntegrator
from .pipeline import ScreenParams, ScreenPipeline


class ISPMIntegrator(PipelineIntegrator):
    """Mitsuba integrator running :class:`~photonmap.screen.pipeline.ScreenPipeline`."""

    pipeline_type, params_type, plugin_name = ScreenPipeline, ScreenParams, "ispm"


def register() -> None:
    mi.register_integrator("ispm", lambda props: ISPMIntegrator(props))
