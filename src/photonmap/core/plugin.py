"""The one Mitsuba plugin shell of the four methods (``volume_photon``, ``photon_mapper``,
``ispm``, ``sppm``): read and validate the plugin's properties, keep one pipeline per scene, notice edits
made to the scene through ``mi.traverse`` and render from the sensor Mitsuba asks for.

A subclass names its pipeline, its parameter dataclass and its plugin name::

    class PhotonMapperIntegrator(PipelineIntegrator):
        pipeline_type, params_type, plugin_name = SurfacePipeline, SurfaceParams, "photon_mapper"

Scene edits: before each render the shell fingerprints the parameters of every shape and emitter
of the scene (``mi.traverse``: radiance, BSDF values, vertex positions, media, ...; sensors are
left out, since a camera move is what the pipelines cache for). When the fingerprint changed, the
pipeline re-reads the scene (:meth:`scene_changed`): through its ``reload`` where it declares that
edit (the volume method), else by building the pipeline again. Errors are :class:`photonmap.PhotonmapError`
(``mi.render`` wraps them in a ``RuntimeError`` whose ``__cause__`` is the original error).
"""

from __future__ import annotations

import dataclasses
import hashlib

import mitsuba as mi
import numpy as np

from .params import MITSUBA_BASE, current_names, read_properties, updated
from .scene_info import parameter_values


def scene_fingerprint(scene: mi.Scene) -> str:
    """A digest of the values of every traversable parameter of the scene's shapes and
    emitters (not its sensors)."""
    digest = hashlib.blake2b(digest_size=16)
    for obj in (*scene.shapes(), *scene.emitters()):
        for key, value in parameter_values(obj):
            value = getattr(value, "matrix", value)  # transforms: their matrix
            digest.update(key.encode())
            try:
                data = np.ascontiguousarray(np.asarray(value, dtype=np.float64)).tobytes()
            except (TypeError, ValueError):  # no array form: its text (may differ each time,
                data = repr(value).encode()  # which errs on the side of re-reading the scene)
            digest.update(data)
    return digest.hexdigest()


class PipelineIntegrator(mi.SamplingIntegrator):
    """A Mitsuba integrator that runs a photonmap pipeline. Subclasses set
    :attr:`pipeline_type`, :attr:`params_type`, :attr:`plugin_name` and, for constructor-only
    options, :attr:`extra` (name → type)."""

    pipeline_type: type
    params_type: type
    plugin_name: str
    extra: dict[str, type] = {}
    ignore = MITSUBA_BASE

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        params = read_properties(
            props, self.params_type, self.plugin_name, extra=self.extra, ignore=self.ignore
        )
        self.options = {k: params.pop(k) for k in list(params) if k in self.extra}
        self.params = current_names(self.params_type, params, self.plugin_name)  # warned once
        updated(self.params_type(), self.params, self.plugin_name)
        self.check_options(self.options)
        self.pipeline = None
        self._scene = None  # held, so that a new scene can never reuse its id
        self._fingerprint = None

    def check_options(self, options: dict) -> None:
        """Validate the constructor-only options (:attr:`extra`)."""

    def new_pipeline(self, scene: mi.Scene):
        return self.pipeline_type(scene, **self.options, **self.params)

    def scene_changed(self, scene: mi.Scene) -> None:
        """The scene was edited in place: a pipeline that re-reads an edited scene (its
        ``edits`` hold ``"reload"``) does so, keeping what did not change; another is built
        again."""
        if "reload" in self.pipeline.edits:
            self.pipeline.reload(scene)
        else:
            self.pipeline = self.new_pipeline(scene)

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        fingerprint = scene_fingerprint(scene)
        if self.pipeline is None or self._scene is not scene:
            self.pipeline = self.new_pipeline(scene)
            self._scene = scene
        elif fingerprint != self._fingerprint:
            self.scene_changed(scene)
        self._fingerprint = fingerprint
        fields = {f.name for f in dataclasses.fields(self.params_type)}
        changes = {}
        if "spp" in fields:
            changes["spp"] = int(spp) if spp else self.params.get("spp", self.params_type().spp)
        if "seed" in fields:
            seed = int(np.asarray(seed).reshape(-1)[0]) if seed is not None else 0
            changes["seed"] = seed if seed else self.params.get("seed", 0)
        self.pipeline.set_params(**changes)
        self.pipeline.set_camera(sensor=sensor)
        return self.pipeline.render()

    def to_string(self):
        return f"{type(self).__name__}[{self.options}, {self.params}]"
