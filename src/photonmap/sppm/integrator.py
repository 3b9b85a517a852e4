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

**Derivatives** (``mi.render(scene, params, integrator=...)`` with gradients enabled on some
``params``): the primal image is the pipeline's; ``render_forward`` and ``render_backward``
differentiate :class:`~photonmap.sppm.differentiable.DifferentiablePhotonMapper`'s estimate
(Mitsuba's split of the primal and the differential phase, with its decorrelated ``seed_grad``):
``spp_grad`` (or ``spp``; at least 1) memoryless iterations of ``photons`` photon paths each,
at ``radius`` (0: two pixel footprints), with the plugin's path settings.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.plugin import PipelineIntegrator
from .differentiable import DifferentiablePhotonMapper
from .pipeline import SPPMParams, SPPMPipeline


class SPPMIntegrator(PipelineIntegrator):
    """Mitsuba integrator running :class:`~photonmap.sppm.pipeline.SPPMPipeline`."""

    pipeline_type, params_type, plugin_name = SPPMPipeline, SPPMParams, "sppm"
    ignore = {"samples_per_pass", "hide_emitters", "timeout"}  # max_depth, rr_depth are ours

    def differentiable(self, scene, sensor) -> DifferentiablePhotonMapper:
        """The differentiable estimate with this plugin's settings."""
        p = SPPMParams(**self.params)
        return DifferentiablePhotonMapper(
            scene, sensor, photons=p.photons, radius=p.radius, volume_radius=p.volume_radius,
            max_depth=p.max_depth, rr_depth=p.rr_depth, hide_emitters=p.hide_emitters,
        )  # fmt: skip

    def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
        with dr.resume_grad():
            image = self.differentiable(scene, sensor).render(_seed(seed), max(int(spp), 1))
            dr.forward_to(image)
            return dr.grad(image)

    def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
        with dr.resume_grad():
            image = self.differentiable(scene, sensor).render(_seed(seed), max(int(spp), 1))
            dr.backward_from(image * grad_in)


def _seed(seed) -> int:
    """``mi.render``'s seed (an int or a one-element ``UInt32``) as an int."""
    return int(dr.ravel(mi.UInt32(seed))[0]) if not isinstance(seed, int) else seed


def register() -> None:
    mi.register_integrator("sppm", lambda props: SPPMIntegrator(props))
