"""One method's pipeline behind the viewer: its state (:mod:`.state`), the checks of an update
against it, and applying a change through the pipeline's own setters, so that each change
reruns only the stages it needs (Sun et al. 2008 §6.1–6.2, seed 002; spec seed-000-002 §4.1,
seed-004 §7).

:data:`ADAPTERS` maps a method name to its adapter class; a new method is one line there. An
adapter with ``progressive = True`` keeps refining while nothing changes and restarts on any
change: a pipeline with ``reset()``, ``step()`` and ``image()`` (the ``sppm`` method: one
iteration per step) refines itself; any other renders again with the next seed and averages (the
variance falls as 1/passes). ``sppm`` is offered this way when the package registers it.

Only the render thread (:mod:`.worker`) calls :meth:`Adapter.apply`, :meth:`Adapter.render`,
:meth:`Adapter.refine` and the volume edits; :meth:`Adapter.check` reads nothing the render thread
changes (the state document and parameters captured at start).
"""

from __future__ import annotations

import copy
import dataclasses
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


def _power(rgb) -> tuple[list[float], float]:
    """RGB power → (colour with its largest channel 1, intensity)."""
    rgb = np.asarray(rgb, dtype=np.float64).ravel()
    rgb = np.broadcast_to(rgb, 3) if rgb.size == 1 else rgb[:3]
    peak = float(rgb.max())
    return ((rgb / peak).tolist() if peak > 0 else [1.0, 1.0, 1.0]), peak


def _rgb(light: dict) -> list[float]:
    return (np.asarray(light["color"]) * light["intensity"]).tolist()


class Adapter(ABC):
    """The viewer's handle on one pipeline of :data:`photonmap.METHODS`.

    ``scene`` is a built-in name, an XML path or an ``mi.Scene``; ``overrides`` are method or
    scene parameters (as the CLI's ``--set``); ``size`` overrides the image size."""

    params: tuple[str, ...] = ()  # the method parameters the page offers
    progressive = False

    def __init__(self, method: str, scene, overrides: dict | None = None, size=None):
        self.method = method
        self.pipe = METHODS[method].pipeline(scene, **(overrides or {}))
        if size is not None:
            self.pipe.set_camera(width=int(size[0]), height=int(size[1]))
        self._params0 = self.pipe.params  # a frozen copy: check() reads this, never the pipe
        self._seed0 = getattr(self._params0, "seed", 0)
        self._passes = 0
        self._mean = None
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
            raise ParameterError(f"an update must be a JSON object, got {update!r}")
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
            if "params" in diff:
                self.pipe.set_params(**diff["params"])
                done["params"] = new["params"]
            if "volume" in diff:  # only a VolumeAdapter's check lets it through
                self._set_volume(new["volume"])
                done["volume"] = new["volume"]
        finally:
            self.state = done
            self._passes = 0

    @abstractmethod
    def _set_light(self, index: int, light: dict) -> None:
        """Give light ``index`` of the pipeline the values of ``light`` (its state entry)."""

    @abstractmethod
    def _set_material(self, name: str, material: dict) -> None:
        """Give material ``name`` of the pipeline the values of ``material``."""

    # --------------------------------------------------------------- frames (render thread)
    def render(self, size: tuple[int, int]) -> np.ndarray:
        """The image at ``size`` (width, height): float32 (h, w, 3), linear radiance. A
        progressive adapter restarts its refinement here."""
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
        """The pipeline refines itself (``reset``, ``step``, ``image``)."""
        return all(hasattr(self.pipe, name) for name in ("reset", "step", "image"))

    @property
    def timings(self) -> dict[str, float]:
        """Milliseconds of each stage the last render ran."""
        return dict(self.pipe.timer.ms)

    @property
    def recomputed(self) -> list[str]:
        """The stages the last render ran (the others were reused)."""
        return list(getattr(self.pipe, "recomputed", self.pipe.timer.ms))

    @property
    def stages(self) -> tuple[str, ...]:
        return tuple(self.pipe.stages)


# ------------------------------------------------------------------------------------ volume
class VolumeAdapter(Adapter):
    """The volume pipeline (Sun et al. 2008, Pfeuti 2009): lights, the refractive objects' and
    the fog's media, photons and emission, plus a sequence of volumes (``frames``: arrays
    ``n``, ``sigma_s``, ``kappa`` with a leading frame axis; Sun §6.2.3) and volume painting
    (:meth:`paint`; Sun §6.2.1)."""

    params = ("photons", "emission")

    def __init__(self, method, scene, overrides=None, size=None, frames=None):
        super().__init__(method, scene, overrides, size)
        self.frames = None if frames is None else self._check_frames(frames)
        self._own = None  # the scene's own material grids (world units), read when first needed
        if self.frames is not None:
            self.state["volume"] = {"frame": -1}

    @property
    def sensor(self):
        return self.pipe.scene.sensor

    @property
    def centre(self):
        return self.pipe.scene.box.center

    def _lights(self):
        out = []
        for light in self.pipe.scene.lights:
            color, intensity = _power(light.intensity)
            entry = {"kind": light.kind, "color": color, "intensity": intensity}
            if light.position is not None:
                entry["position"] = np.asarray(light.position, float).tolist()
            out.append(entry)
        return out

    def _materials(self):
        s = self.pipe.scene
        out = {
            o.name: {
                "ior": float(o.medium.ior),
                "sigma_s": np.asarray(o.medium.sigma_s, float).tolist(),
                "sigma_a": np.asarray(o.medium.sigma_a, float).tolist(),
            }
            for o in s.objects
        }
        out["fog"] = {
            "sigma_s": np.asarray(s.fog.sigma_s, float).tolist(),
            "sigma_a": np.asarray(s.fog.sigma_a, float).tolist(),
        }
        return out

    def _check_light(self, index, light):
        from ..volume.params import check_light

        old = self.pipe.scene.lights[index]
        position = light.get("position")
        check_light(dataclasses.replace(
            old, intensity=np.asarray(_rgb(light)),
            position=None if position is None else np.asarray(position),
        ))  # fmt: skip

    def _check_material(self, name, material):
        from ..volume.params import updated_medium
        from ..volume.scene import Medium

        updated_medium(Medium(ior=material.get("ior", 1.0)), None, material["sigma_s"],
                       material["sigma_a"], name)  # fmt: skip

    def _set_light(self, index, light):
        changes = {"intensity": _rgb(light)}
        if "position" in light:
            changes["position"] = light["position"]
        self.pipe.set_light(index, **changes)

    def _set_material(self, name, material):
        self.pipe.set_material(name, **material)

    # ---------------------------------------------------------- sequences and painting
    def _check_frames(self, frames) -> dict[str, np.ndarray]:
        n = self.pipe.scene.box.n
        keys = {"n", "sigma_s", "kappa"}
        arrays = {k: np.asarray(frames[k], dtype=np.float32) for k in frames if k in keys}
        if not arrays or set(frames) - keys:
            raise ParameterError(
                f"a volume sequence holds arrays n, sigma_s and/or kappa with a leading frame "
                f"axis, shape (F, {n}, {n}, {n}) or (F, {n}, {n}, {n}, 3); got {sorted(frames)}"
            )
        counts = {len(a) for a in arrays.values()}
        for key, a in arrays.items():
            if a.ndim not in (4, 5) or a.shape[1:4] != (n, n, n) or len(counts) != 1:
                raise ParameterError(
                    f"volume sequence array {key!r} has shape {a.shape}; expected (F, {n}, {n}, "
                    f"{n}[, 3]) with the same F for every array (the grid is {n}³: set grid={n} "
                    "or resample the data)"
                )
        return arrays

    @property
    def frame_count(self) -> int:
        return 0 if self.frames is None else len(next(iter(self.frames.values())))

    def _check_volume(self, state, update):
        if self.frames is None:
            raise ParameterError("no volume sequence: start the viewer with --volumes FILE.npz")
        st.check_keys("volume", st.as_object("volume", update), ("frame",))
        frame = st.number("volume.frame", update.get("frame", -1), -1, self.frame_count - 1,
                          integer=True)  # fmt: skip
        return {"frame": frame}

    def own_grids(self) -> dict[str, np.ndarray]:
        """The scene's own material grids (world units; S1/S2), kept from the first render."""
        if self._own is None:
            raise ParameterError("render once before painting or playing volumes")
        return self._own

    def render(self, size):
        image = super().render(size)
        if self._own is None and self.pipe.scene.grids is None:
            mats, h = self.pipe.cache.get("materials"), self.pipe.scene.box.h
            self._own = {
                "n": np.asarray(mats.ior)[..., 0],
                "sigma_s": np.asarray(mats.sigma_s) / h,
                "kappa": np.asarray(mats.kappa) / h,
            }
        return image

    def _grids_of(self, frame: int) -> dict[str, np.ndarray] | None:
        """Frame ``frame`` of the sequence; arrays it lacks are the scene's own, and a σ_s
        without κ keeps the scene's absorption (κ = σ_s + σ_a)."""
        if frame < 0:
            return None
        own = self.own_grids()
        grids = {**own, **{k: a[frame] for k, a in self.frames.items()}}
        if "sigma_s" in self.frames and "kappa" not in self.frames:
            absorb = np.maximum(_rgb_grid(own["kappa"]) - _rgb_grid(own["sigma_s"]), 0)
            grids["kappa"] = _rgb_grid(grids["sigma_s"]) + absorb
        return grids

    def _set_volume(self, volume):
        grids = self._grids_of(volume["frame"])
        if grids is None:
            self.pipe.scene.grids = None  # back to the scene's own materials (S1/S2)
        else:
            self.pipe.set_volume(**grids)

    def reset_volume(self) -> None:
        """Undo the painting: the current sequence frame, or the scene's own materials."""
        self._set_volume(self.state.get("volume", {"frame": -1}))
        self._passes = 0

    def paint(self, stroke: dict) -> None:
        """Add a Gaussian brush (Sun §6.2.1: a precomputed pattern, scaled and weighted) of
        ``amount`` at ``center`` (world units) with standard deviation ``radius`` to σ_s (κ
        follows: σ_a is kept) or to n; the result is clamped to σ_s >= 0 and n >= 1."""
        box = self.pipe.scene.box
        grids = self.pipe.scene.grids or self.own_grids()
        grids = {k: np.array(v, dtype=np.float32) for k, v in grids.items()}
        c = box.to_voxel(stroke["center"])
        r = stroke["radius"] / box.h
        lo = np.clip(np.floor(c - 3 * r).astype(int), 0, box.n)
        hi = np.clip(np.ceil(c + 3 * r).astype(int) + 1, 0, box.n)
        if np.any(hi <= lo):
            return  # the brush lies outside the grid
        axes = [np.arange(lo[a], hi[a]) + 0.5 - c[a] for a in range(3)]  # x, y, z
        z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
        blob = stroke["amount"] * np.exp(-0.5 * (x * x + y * y + z * z) / (r * r))
        region = (slice(lo[2], hi[2]), slice(lo[1], hi[1]), slice(lo[0], hi[0]))
        if stroke["field"] == "n":
            grids["n"][region] = np.maximum(grids["n"][region] + blob, 1.0)
        else:
            s = _rgb_grid(grids["sigma_s"])
            k = _rgb_grid(grids["kappa"])
            absorb = k[region] - s[region]
            s[region] = np.maximum(s[region] + blob[..., None], 0.0)
            k[region] = s[region] + absorb
            grids["sigma_s"], grids["kappa"] = s, k
        self.pipe.set_volume(**grids)
        self._passes = 0


def _rgb_grid(a: np.ndarray) -> np.ndarray:
    return a if a.ndim == 4 else np.repeat(a[..., None], 3, axis=-1)


def check_stroke(stroke) -> dict:
    """A brush stroke ``{"field": "sigma_s" | "n", "center": [x, y, z], "radius": r > 0,
    "amount": a}`` (world units), checked."""
    st.check_keys("stroke", st.as_object("stroke", stroke), ("field", "center", "radius", "amount"))
    missing = {"center", "radius", "amount"} - set(stroke)
    if missing:
        raise ParameterError(f"a stroke needs {', '.join(sorted(missing))}")
    field = stroke.get("field", "sigma_s")
    if field not in ("sigma_s", "n"):
        raise ParameterError(f"stroke.field must be 'sigma_s' or 'n', got {field!r}")
    return {
        "field": field,
        "center": st.vector("stroke.center", stroke["center"]),
        "radius": st.number("stroke.radius", stroke["radius"], 0, lo_open=True),
        "amount": st.number("stroke.amount", stroke["amount"]),
    }


# ------------------------------------------------------------------------ Mitsuba scenes
class MitsubaAdapter(Adapter):
    """Pipelines that render a Mitsuba scene directly (screen, surface): the refractive index
    of each ``dielectric`` (its ``eta``) is a material."""

    def _dielectrics(self) -> dict[str, mi.BSDF]:
        out = {}
        for number, shape in enumerate(self.pipe.scene.shapes()):
            bsdf = shape.bsdf()
            if bsdf is not None and "eta" in mi.traverse(bsdf).keys():
                out[shape.id() or f"shape {number}"] = bsdf
        return out

    def _materials(self):
        return {
            name: {"ior": float(np.array(mi.traverse(b)["eta"]).ravel()[0])}
            for name, b in self._dielectrics().items()
        }

    def _set_eta(self, name: str, material: dict) -> None:
        params = mi.traverse(self._dielectrics()[name])
        params["eta"] = float(material["ior"])
        params.update()


class ScreenAdapter(MitsubaAdapter):
    """The screen pipeline (Yao 2011): its one light, dielectrics' n, photon count
    (``light_res``² × ``bounces``) and the indirect light's subsampling."""

    params = ("light_res", "bounces", "subsample")

    def _lights(self):
        light = self.pipe.light
        key = "intensity.value" if light.kind != "area" else "radiance.value"
        color, intensity = _power(np.array(mi.traverse(light.emitter)[key]))
        entry = {"kind": light.kind, "color": color, "intensity": intensity}
        if light.kind != "area":
            entry["position"] = np.asarray(light.position, float).tolist()
        return [entry]

    def _set_light(self, index, light):
        self.pipe.set_light(position=light.get("position"), intensity=_rgb(light))

    def _set_material(self, name, material):
        self._set_eta(name, material)
        self.pipe.invalidate()  # the glass reaches every stage (eye, light and photon paths)


class SurfaceAdapter(MitsubaAdapter):
    """The surface pipeline (Steinhurst 2007, after Jensen): point, spot and area lights'
    power, point and spot positions, dielectrics' n, photon counts. A light or material change
    retraces the photon maps (the pipeline is rebuilt on the edited scene); a camera move keeps
    them."""

    params = ("photons", "caustic_photons")

    def _emitters(self) -> list:
        kinds = ("PointLight", "SpotLight", "AreaLight")
        return [e for e in self.pipe.scene.emitters() if e.class_name() in kinds]

    def _lights(self):
        out = []
        for e in self._emitters():
            params = mi.traverse(e)
            key = "radiance.value" if e.class_name() == "AreaLight" else "intensity.value"
            color, intensity = _power(np.array(params[key]))
            entry = {"kind": e.class_name()[:-5].lower(), "color": color, "intensity": intensity}
            if e.class_name() == "PointLight":
                entry["position"] = np.array(params["position"], float).ravel().tolist()
            elif e.class_name() == "SpotLight":
                m = np.array(params["to_world"].matrix, float)
                entry["position"] = m[:3, 3].ravel().tolist()
            out.append(entry)
        return out

    def _set_light(self, index, light):
        emitter = self._emitters()[index]
        params = mi.traverse(emitter)
        area = emitter.class_name() == "AreaLight"
        params["radiance.value" if area else "intensity.value"] = mi.Color3f(*_rgb(light))
        if emitter.class_name() == "PointLight":
            params["position"] = mi.Point3f(*light["position"])
        elif emitter.class_name() == "SpotLight":
            m = np.array(params["to_world"].matrix, dtype=np.float64)[..., 0]
            m[:3, 3] = light["position"]
            params["to_world"] = mi.ScalarTransform4f(m)
        params.update()
        self._rebuild()

    def _set_material(self, name, material):
        self._set_eta(name, material)
        self._rebuild()

    def _rebuild(self) -> None:
        """A new pipeline on the edited scene, from the current camera: the photon maps are
        traced again (the surface pipeline keys them by its parameters only)."""
        sensor = self.pipe.sensor
        params = dataclasses.asdict(self.pipe.params)
        self.pipe = type(self.pipe)(self.pipe.scene, **params)
        self.pipe.set_camera(sensor=sensor)


def progressive(adapter: type[Adapter], params: tuple[str, ...] | None = None) -> type[Adapter]:
    """``adapter`` refining while idle and restarting on change (:meth:`Adapter.refine`),
    offering the method parameters ``params`` (default: the adapter's)."""
    attrs = {"progressive": True, "params": adapter.params if params is None else params}
    return type(f"Progressive{adapter.__name__}", (adapter,), attrs)


ADAPTERS: dict[str, type[Adapter]] = {
    "volume": VolumeAdapter,
    "screen": ScreenAdapter,
    "surface": SurfaceAdapter,
}
if "sppm" in METHODS:  # stochastic progressive photon mapping: refine, restart on any change
    ADAPTERS["sppm"] = progressive(SurfaceAdapter, ("photons_per_iteration", "alpha"))
