"""``photonmap.render`` (defined here, in ``photonmap.api``): one call that renders a Mitsuba
scene with any method, and with ``params`` the differentiable photon-mapping estimate, used as
Mitsuba's own ``mi.render``::

    params = mi.traverse(scene)
    dr.enable_grad(params["slab.vertex_positions"]); params.update()
    image = photonmap.render(scene, params, method="sppm", photons=200_000, seed=i)
    loss = dr.mean(dr.square(image - target), axis=None)
    dr.backward(loss)                      # gradients in dr.grad(params[...])

Without ``params`` the method's Mitsuba plugin renders the scene (``mi.render`` with that
integrator). With ``params`` the image is :class:`~photonmap.sppm.differentiable.
DifferentiablePhotonMapper`'s estimate, attached to every parameter whose gradient is enabled
(forward mode: ``dr.forward(param)`` then ``dr.grad(image)``).
"""

from __future__ import annotations

import dataclasses

import mitsuba as mi

from .core.errors import ParameterError, PhotonmapError
from .core.plugin import PipelineIntegrator
from .sppm.differentiable import DifferentiablePhotonMapper

DIFFERENTIABLE = ("photons", "spp", "radius", "volume_radius", "iterations", "max_depth",
                  "rr_depth", "hide_emitters")  # fmt: skip


def render(
    scene: mi.Scene,
    params: mi.SceneParameters | None = None,
    method: str = "sppm",
    sensor: int | mi.Sensor = 0,
    seed: int = 0,
    **settings,
) -> mi.TensorXf:
    """Render ``scene`` with ``method`` (module docstring); ``settings`` are the method's
    parameters (``photonmap.METHODS[method].params``). With ``params`` (``mi.traverse(scene)``)
    the method must be ``"sppm"``, and ``settings`` are those of the differentiable estimate:
    ``photons`` (per iteration, default 200 000), ``spp`` (eye paths per pixel, 1),
    ``radius`` (0: two pixel footprints), ``volume_radius`` (0: ``radius``), ``iterations``
    (1), ``max_depth``, ``rr_depth``, ``hide_emitters`` (the file's)."""
    if not isinstance(scene, mi.Scene):
        raise ParameterError(
            f"render() takes a loaded mi.Scene, got {type(scene).__name__}; load the file with "
            "mi.load_file(path) first"
        )
    plugins = {s.pipeline_type.method: s.plugin_name for s in PipelineIntegrator.__subclasses__()}
    if method not in plugins:
        raise ParameterError(f"unknown method {method!r}; choose one of {sorted(plugins)}")
    if not isinstance(seed, int) or seed < 0:
        raise ParameterError(f"seed must be a non-negative integer, got {seed!r}")
    if params is None:
        _check_settings(method, settings)
        integrator = mi.load_dict({"type": plugins[method], **settings})
        try:
            return mi.render(scene, sensor=sensor, integrator=integrator, seed=seed)
        except RuntimeError as error:  # Dr.Jit's custom operation wraps the method's own error
            if isinstance(error.__cause__, PhotonmapError):
                raise error.__cause__ from None
            raise
    if not isinstance(params, mi.SceneParameters):
        raise ParameterError(
            f"params must be mi.traverse(scene), got {type(params).__name__}"
        )
    if method != "sppm":
        raise ParameterError(
            f"method {method!r} is not differentiable; gradients come from method='sppm' "
            "(differentiable photon mapping)"
        )
    unknown = sorted(set(settings) - set(DIFFERENTIABLE))
    if unknown:
        raise ParameterError(
            f"unknown setting(s) {unknown} of differentiable rendering; valid: "
            f"{', '.join(DIFFERENTIABLE)}"
        )
    iterations = settings.pop("iterations", 1)
    estimate = DifferentiablePhotonMapper(scene, sensor, **settings)
    return estimate.render(seed, iterations)


def _check_settings(method: str, settings: dict) -> None:
    from . import METHODS

    fields = {f.name for f in dataclasses.fields(METHODS[method].params)}
    unknown = sorted(set(settings) - fields)
    if unknown:
        raise ParameterError(
            f"unknown parameter(s) {unknown} of method {method!r}; valid: {', '.join(sorted(fields))}"
        )

