"""The viewer's handle on the volume pipeline (Sun et al. 2008 §6.1–6.2; Pfeuti 2009):
lights, the refractive objects' and the fog's media, photons and emission, a sequence of
simulation volumes (§6.2.3) and volume painting (§6.2.1)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.errors import ParameterError
from . import state as st
from .adapters import Adapter, light_power, light_rgb


class VolumeAdapter(Adapter):
    """The volume pipeline (Sun et al. 2008, Pfeuti 2009): lights, the refractive objects' and
    the fog's media, photons and emission, plus a sequence of volumes (``frames``: arrays
    ``n``, ``sigma_s``, ``kappa`` with a leading frame axis; Sun §6.2.3) and volume painting
    (:meth:`paint`; Sun §6.2.1)."""

    params = ("photons", "emission")
    preview_divisors = {"photons": 16}

    def __init__(self, method, scene, overrides=None, size=None, frames=None):
        super().__init__(method, scene, overrides, size)
        self.frames = None if frames is None else self._check_frames(frames)
        self._own = None  # the scene's own material grids (world units), read when first needed
        if self.frames is not None:
            self.state["volume"] = {"frame": -1}

    @property
    def sensor(self):
        return self.pipe.sensor

    @property
    def centre(self):
        return self.pipe.world.box.center

    def _lights(self):
        out = []
        for light in self.pipe.world.lights:
            color, intensity = light_power(light.intensity)
            entry = {"kind": light.kind, "color": color, "intensity": intensity}
            if light.position is not None:
                entry["position"] = np.asarray(light.position, float).tolist()
            out.append(entry)
        return out

    def _materials(self):
        s = self.pipe.world
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

        old = self.pipe.world.lights[index]
        position = light.get("position")
        check_light(dataclasses.replace(
            old, intensity=np.asarray(light_rgb(light)),
            position=None if position is None else np.asarray(position),
        ))  # fmt: skip

    def _check_material(self, name, material):
        from ..volume.params import updated_medium
        from ..volume.scene import Medium

        updated_medium(Medium(ior=material.get("ior", 1.0)), None, material["sigma_s"],
                       material["sigma_a"], name)  # fmt: skip

    def _set_light(self, index, light):
        changes = {"intensity": light_rgb(light)}
        if "position" in light:
            changes["position"] = light["position"]
        self.pipe.set_light(index, **changes)

    def _set_material(self, name, material):
        self.pipe.set_material(name, **material)

    # ---------------------------------------------------------- sequences and painting
    def _check_frames(self, frames) -> dict[str, np.ndarray]:
        n = self.pipe.world.box.n
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

    def render(self, size, preview=False):
        image = super().render(size, preview)
        if self._own is None and self.pipe.world.grids is None:
            mats, h = self.pipe.cache.get("materials"), self.pipe.world.box.h
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
            self.pipe.world.grids = None  # back to the scene's own materials (S1/S2)
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
        box = self.pipe.world.box
        grids = self.pipe.world.grids or self.own_grids()
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
        raise ParameterError(f"stroke.field must be 'sigma_s' or 'n', got {st.shown(field)}")
    return {
        "field": field,
        "center": st.vector("stroke.center", stroke["center"]),
        "radius": st.number("stroke.radius", stroke["radius"], 0, lo_open=True),
        "amount": st.number("stroke.amount", stroke["amount"]),
    }
