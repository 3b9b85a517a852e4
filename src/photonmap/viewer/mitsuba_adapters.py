"""The viewer's handles on the pipelines that render a Mitsuba scene directly: screen (Yao 2011)
and surface (Steinhurst 2007, after Jensen); each dielectric's n is a material."""

from __future__ import annotations

import dataclasses

import mitsuba as mi
import numpy as np

from .adapters import Adapter, light_power, light_rgb


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
    (``photons`` × ``bounces``) and the indirect light's subsampling."""

    params = ("photons", "bounces", "subsample")
    preview_divisors = {"photons": 16}  # a light G-buffer a quarter as wide: 1/16

    def _lights(self):
        light = self.pipe.light
        key = "intensity.value" if light.kind != "area" else "radiance.value"
        color, intensity = light_power(np.array(mi.traverse(light.emitter)[key]))
        entry = {"kind": light.kind, "color": color, "intensity": intensity}
        if light.kind != "area":
            entry["position"] = np.asarray(light.position, float).tolist()
        return [entry]

    def _set_light(self, index, light):
        self.pipe.set_light(position=light.get("position"), intensity=light_rgb(light))

    def _set_material(self, name, material):
        self._set_eta(name, material)
        self.pipe.invalidate()  # the glass reaches every stage (eye, light and photon paths)


class SurfaceAdapter(MitsubaAdapter):
    """The surface pipeline (Steinhurst 2007, after Jensen): point, spot and area lights'
    power, point and spot positions, dielectrics' n, photon counts. A light or material change
    retraces the photon maps (the pipeline is rebuilt on the edited scene); a camera move keeps
    them."""

    params = ("photons", "caustic_photons")
    preview_divisors = {"photons": 16, "caustic_photons": 16}

    def _emitters(self) -> list:
        kinds = ("PointLight", "SpotLight", "AreaLight")
        return [e for e in self.pipe.scene.emitters() if e.class_name() in kinds]

    def _lights(self):
        out = []
        for e in self._emitters():
            params = mi.traverse(e)
            key = "radiance.value" if e.class_name() == "AreaLight" else "intensity.value"
            color, intensity = light_power(np.array(params[key]))
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
        params["radiance.value" if area else "intensity.value"] = mi.Color3f(*light_rgb(light))
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
