"""One method's pipeline behind the viewer: its state (:mod:`.state`), the checks of an update
against it, and applying a change through the pipeline's own setters, so that each change reruns
only the stages it needs (Sun et al. 2008 §6.1–6.2; Yao 2011 Ch. 3). The adapters are in
:mod:`.volume_adapter` and :mod:`.mitsuba_adapters`; :data:`.methods.ADAPTERS` maps a method name to
its adapter (a new method is one line there).

During a drag (``preview`` frames, :mod:`.worker`) a change that makes the pipeline trace its
photons again (a light, a material, a parameter, the volume) is rendered with a reduced photon
budget: each parameter of :attr:`Adapter.preview_divisors` divided (the volume method's photons
by 16, the screen method's ``photons`` by 16), so that the preview costs
about 1/16 of the photon tracing that dominates a light move (Sun et al. 2008 §6: the preview
while the user drags, the converged image when they stop). The next full-size
frame restores the user's budget, so it is the render of the full settings; the state keeps the
user's values throughout. A camera-only drag keeps whatever photons the pipeline holds.

An adapter with ``progressive = True`` keeps refining while nothing changes and restarts on any
change: a pipeline with ``reset()``, ``step()`` and ``image()`` (the ``sppm`` method: one
iteration per step) refines itself; any other renders again with the next seed and averages (the
variance falls as 1/passes). ``sppm`` is offered this way when the package registers it.

Only the render thread (:mod:`.worker`) calls :meth:`Adapter.apply`, :meth:`Adapter.render`,
:meth:`Adapter.refine` and the volume edits; :meth:`Adapter.check` reads nothing the render thread
changes (the state document and parameters captured at start; the pipeline's memory estimate,
``check_memory``, reads only what the pipeline fixed when it was built).
"""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod

import mitsuba as mi
import numpy as np

from .. import METHODS
from ..core.camera import scene_bounds
from ..core.errors import ParameterError
from ..core.image import as_rgb
from ..core.params import updated
from . import state as st

MAX_PASSES = 64  # progressive refinement stops here (the image no longer changes visibly)


def _camera_state(sensor, centre) -> dict:
    """Origin, target (the point of the view axis nearest ``centre``), horizontal fov, size."""
    m = np.array(sensor.world_transform().matrix, dtype=np.float64)[..., 0]
    origin, forward = m[:3, 3], m[:3, 2]
    distance = max(float(np.dot(np.asarray(centre) - origin, forward)), 1e-3)
    size = sensor.film().size()
    return {
        "origin": origin.tolist(),
        "target": (origin + distance * forward).tolist(),
        "fov": float(np.array(mi.traverse(sensor)["x_fov"]).ravel()[0]),
        "width": int(size[0]),
        "height": int(size[1]),
    }


def light_power(rgb) -> tuple[list[float], float]:
    """RGB power → (colour with its largest channel 1, intensity)."""
    rgb = np.asarray(rgb, dtype=np.float64).ravel()
    rgb = np.broadcast_to(rgb, 3) if rgb.size == 1 else rgb[:3]
    peak = float(rgb.max())
    return ((rgb / peak).tolist() if peak > 0 else [1.0, 1.0, 1.0]), peak


def light_rgb(light: dict) -> list[float]:
    """A light's RGB power: its colour times its intensity."""
    return (np.asarray(light["color"]) * light["intensity"]).tolist()


class Adapter(ABC):
    """The viewer's handle on one pipeline of :data:`photonmap.METHODS`.

    ``scene`` is a built-in name, an XML path or an ``mi.Scene``; ``overrides`` are method or
    scene parameters (as the CLI's ``--set``); ``size`` overrides the image size."""

    params: tuple[str, ...] = ()  # the method parameters the page offers
    progressive = False
    # method parameter → divisor during a drag, for the parameters setting the photon count
    preview_divisors: dict[str, int] = {}

    def __init__(self, method: str, scene, overrides: dict | None = None, size=None):
        self.method = method
        self.pipe = METHODS[method].pipeline(scene, **(overrides or {}))
        if size is not None:
            self.pipe.check_memory(size=(int(size[0]), int(size[1])))
            self.pipe.set_camera(width=int(size[0]), height=int(size[1]))
        self._params0 = self.pipe.params  # a frozen copy: check() reads this, never the pipe
        self._seed0 = getattr(self._params0, "seed", 0)
        self._passes = 0
        self._mean = None
        self._drafting = False  # a change since the last full frame needs new photons
        self.reduced: dict = {}  # the reduced budget of the last render ({}: the user's)
        self.state = {
            "camera": _camera_state(self.sensor, self.centre),
            "lights": self._lights(),
            "materials": self._materials(),
            "params": {k: getattr(self.pipe.params, k) for k in self.params},
        }

    # --------------------------------------------------------------- what the method shows
    @property
    def sensor(self):
        return self.pipe.sensor

    @property
    def centre(self):
        return scene_bounds(self.pipe.scene)[0]

    @abstractmethod
    def _lights(self) -> list[dict]:
        """The state entries of the pipeline's lights."""

    @abstractmethod
    def _materials(self) -> dict[str, dict]:
        """The state entries of the pipeline's materials, by name."""

    # --------------------------------------------------------------- checks (any thread)
    def check(self, state: dict, update: dict) -> dict:
        """``state`` after ``update``, or a :class:`ParameterError` naming the first bad value."""
        if not isinstance(update, dict):
            raise ParameterError(f"an update must be a JSON object, got {st.shown(update)}")
        allowed = (*st.SECTIONS, *st.READ_ONLY, "preview")
        unknown = sorted(set(update) - set(allowed))
        if unknown:
            raise ParameterError(
                f"unknown key(s) {', '.join(unknown)}; an update may hold "
                f"{', '.join(k for k in st.SECTIONS if k in state)} and preview"
            )
        new = dict(state)
        if "camera" in update:
            new["camera"] = st.check_camera(state["camera"], update["camera"])
        if "lights" in update:
            lights = list(state["lights"])
            for i, changes in st.light_changes(update["lights"], len(lights)).items():
                lights[i] = st.check_light(i, lights[i], changes)
                self._check_light(i, lights[i])
            new["lights"] = lights
        if "materials" in update:
            materials = dict(state["materials"])
            for name, changes in st.as_object("materials", update["materials"]).items():
                if name not in materials:
                    raise ParameterError(
                        f"no material {name!r}; materials: {', '.join(materials) or 'none'}"
                    )
                materials[name] = st.check_material(name, materials[name], changes)
                self._check_material(name, materials[name])
            new["materials"] = materials
        if "params" in update:
            st.check_keys("params", st.as_object("params", update["params"]), self.params)
            params = {**state["params"], **update["params"]}
            updated(self._params0, params, self.method)  # the method's own validation
            new["params"] = params
        if "volume" in update:
            new["volume"] = self._check_volume(state, update["volume"])
        cam, old = new["camera"], state["camera"]
        resized = (cam["width"], cam["height"]) != (old["width"], old["height"])
        if "params" in update or resized:  # the method's memory estimate (not for a mere move)
            params = updated(self._params0, new["params"], self.method)
            self.pipe.check_memory(params, (cam["width"], cam["height"]))
        return new

    def _check_light(self, index: int, light: dict) -> None:  # noqa: B027 (a hook: none)
        """The method's own checks of a light (beyond :func:`.state.check_light`)."""

    def _check_material(self, name: str, material: dict) -> None:  # noqa: B027 (a hook)
        """The method's own checks of a material (beyond :func:`.state.check_material`)."""

    def _check_volume(self, state: dict, update) -> dict:
        raise ParameterError(f"the {self.method} method has no volume to play or paint")

    # --------------------------------------------------------------- changes (render thread)
    def apply(self, diff: dict, new: dict) -> None:
        """Push the changes ``diff`` (a :func:`.state.changes` of the applied state) into the
        pipeline; ``new`` is the whole state they lead to. If a setter fails, :attr:`state`
        holds what the pipeline took before it."""
        done = copy.deepcopy(self.state)
        try:
            if "camera" in diff:
                c = new["camera"]
                self.pipe.set_camera(
                    origin=c["origin"], target=c["target"], fov=c["fov"],
                    width=c["width"], height=c["height"],
                )  # fmt: skip
                done["camera"] = new["camera"]
            for index in diff.get("lights", {}):
                self._set_light(index, new["lights"][index])
                done["lights"][index] = new["lights"][index]
            for name in diff.get("materials", {}):
                self._set_material(name, new["materials"][name])
                done["materials"][name] = new["materials"][name]
            if "params" in diff:  # all of them: a preview's reduced budget is replaced too
                self.pipe.set_params(**new["params"])
                done["params"] = new["params"]
            if "volume" in diff:  # only a VolumeAdapter's check lets it through
                self._set_volume(new["volume"])
                done["volume"] = new["volume"]
        finally:
            self.state = done
            self._passes = 0
            self._drafting = self._drafting or any(k != "camera" for k in diff)

    @abstractmethod
    def _set_light(self, index: int, light: dict) -> None:
        """Give light ``index`` of the pipeline the values of ``light`` (its state entry)."""

    @abstractmethod
    def _set_material(self, name: str, material: dict) -> None:
        """Give material ``name`` of the pipeline the values of ``material``."""

    # --------------------------------------------------------------- frames (render thread)
    def render(self, size: tuple[int, int], preview: bool = False) -> np.ndarray:
        """The image at ``size`` (width, height): float32 (h, w, 3), linear radiance. A
        ``preview`` after a change that needs new photons traces the reduced budget (the module
        docstring); any other frame the user's. A progressive adapter restarts here."""
        self._set_budget(preview and self._drafting)
        if not preview:
            self._drafting = False
        film = tuple(int(c) for c in self.sensor.film().size())
        if film != tuple(size):
            self.pipe.set_camera(width=int(size[0]), height=int(size[1]))
        if self.progressive and self._steps:
            self._passes = 0
            self.pipe.reset()
            self.pipe.step()
            self._mean = as_rgb(self.pipe.image())
            return self._mean
        if self.progressive and self._passes:
            self._passes = 0
            self.pipe.set_params(seed=self._seed0)
        self._mean = as_rgb(self.pipe.render())
        return self._mean

    def _set_budget(self, reduce: bool) -> None:
        """Give the pipeline the user's photon budget, or (``reduce``) each of
        :attr:`preview_divisors` divided; a reduced budget the method refuses (e.g. adaptive
        emission's photons below its pilots) stays the user's. Sets :attr:`reduced`."""
        user = {k: self.state["params"][k] for k in self.preview_divisors
                if k in self.state["params"]}  # fmt: skip
        divisors = self.preview_divisors if reduce else {}
        reduced = {k: max(1, v // divisors[k]) for k, v in user.items() if k in divisors and v > 1}
        try:
            updated(self.pipe.params, reduced, self.method)
        except ParameterError:
            reduced = {}
        want = {**user, **reduced}
        changed = {k: v for k, v in want.items() if getattr(self.pipe.params, k) != v}
        if changed:
            self.pipe.set_params(**changed)
        self.reduced = reduced

    def refine(self) -> np.ndarray | None:
        """A progressive adapter's next pass folded into the image (None when done)."""
        if not self.progressive or self._mean is None or self._passes >= MAX_PASSES:
            return None
        self._passes += 1
        if self._steps:
            self.pipe.step()
            self._mean = as_rgb(self.pipe.image())
            return self._mean
        self.pipe.set_params(seed=(self._seed0 + self._passes) % 2**32)
        image = as_rgb(self.pipe.render())
        self._mean = self._mean + (image - self._mean) / (self._passes + 1)
        return self._mean

    @property
    def passes(self) -> int:
        """The passes in the current image (1 unless progressive)."""
        return self._passes + 1

    @property
    def _steps(self) -> bool:
        """The pipeline refines itself (a progressive method: ``reset``, ``step``, ``image``)."""
        return self.pipe.progressive

    @property
    def timings(self) -> dict[str, float]:
        """Milliseconds of each stage the last render ran."""
        return dict(self.pipe.timer.ms)

    @property
    def recomputed(self) -> list[str]:
        """The stages the last render ran (the others were reused)."""
        return list(self.pipe.recomputed)

    @property
    def stages(self) -> tuple[str, ...]:
        return tuple(self.pipe.stages)


def progressive(adapter: type[Adapter], params: tuple[str, ...] | None = None) -> type[Adapter]:
    """``adapter`` refining while idle and restarting on change (:meth:`Adapter.refine`),
    offering the method parameters ``params`` (default: the adapter's)."""
    attrs = {"progressive": True, "params": adapter.params if params is None else params}
    return type(f"Progressive{adapter.__name__}", (adapter,), attrs)
