"""What the volume pipeline reads from a Mitsuba 3 scene (docs/DESIGN.md "Scenes").

A :class:`VolumeScene` is plain data in **world units**; stage S2 converts coefficients to voxel
units (``σ_vox = σ_world · h``). It is built from a Mitsuba scene by :func:`from_mitsuba`:

- every closed shape with a ``dielectric`` BSDF is a :class:`RefractiveObject` (``int_ior/ext_ior``
  → n; its interior ``homogeneous`` medium → σ_s, σ_a);
- every closed shape with a ``null`` or ``thindielectric`` BSDF and an interior medium is a
  :class:`FogVolume`: the fog is inside it and nowhere else;
- the sensor's medium fills the rest of the grid (:attr:`VolumeScene.outside`);
- the grid box is the box grid fitted to the medium-bearing shapes (or an explicit ``grid_bbox``);
- point, spot, directional and area emitters are :class:`Light` s; a ``constant`` or ``envmap``
  emitter is the background and a light too (photons through the grid's faces);
- the perspective sensor is the camera.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.bsdf import shape_box
from ..core.errors import SceneError
from ..core.grid import GridBox
from ..core.scene_info import has_media, warn_unmodelled
from .medium import MediaReader, Medium, read_medium
from .surfaces import Surfaces, digest, unmodelled
from .voxelize import check_closed

LIGHT_KINDS = ("point", "spot", "directional")  # lights set_light can make
EMITTER_KINDS = ("area", "environment")  # lights that are the scene's own Mitsuba emitters


@dataclass
class RefractiveObject:
    """A closed shape filled with a refractive medium of index ``medium.ior``."""

    name: str
    shape: object  # mi.Shape: voxelized by ray-casting parity (stage S1)
    medium: Medium


@dataclass
class FogVolume:
    """A closed shape bounding a medium: a ``null`` or ``thindielectric`` BSDF with an interior
    medium. Index-matched: it does not change n (the pipeline refracts only through ∇n, Sun et al.
    2008 eq 5), and a thin dielectric's reflection is not rendered."""

    name: str
    shape: object  # mi.Shape: voxelized like the refractive objects (stage S1)
    medium: Medium


@dataclass
class Light:
    """A light in world units.

    ``point`` and ``spot``: ``position`` and RGB ``intensity`` (W/sr). A spot light's axis is
    ``direction``; its intensity falls off as Mitsuba's ``spot`` does: 1 within the beam
    (``cos θ ≥ cos_inner``), linearly in the angle θ to 0 at the cutoff ``cos_outer``.
    ``directional``: propagation ``direction`` and RGB ``irradiance`` (W/m² normal to the beam),
    stored in ``intensity``.
    ``area`` and ``environment``: the scene's Mitsuba ``emitter`` itself (an
    area emitter on a sphere, rectangle or mesh; a ``constant`` or ``envmap`` environment), sampled
    by S5 (``emit.py``); ``intensity`` is an RGB factor on its radiance (1: as in the scene) and
    ``fingerprint`` a digest of its parameters and its shape's, so that an edited emitter re-keys
    the cached photon stages.
    """

    kind: str
    intensity: np.ndarray
    position: np.ndarray | None = None
    direction: np.ndarray | None = None
    cos_inner: float = 1.0
    cos_outer: float = 1.0
    emitter: object | None = None  # mi.Emitter of an area / environment light
    shape: object | None = None  # an area emitter's mi.Shape: held here, as the emitter's own
    #                              pointer to it does not keep it alive once the scene is freed
    fingerprint: str = ""


@dataclass
class VolumeScene:
    """Everything the volume pipeline needs, in world units."""

    box: GridBox
    fog: Medium  # the scene's fog: what ``set_material("fog")`` edits, wherever it is
    lights: list[Light]
    sensor: object  # mi.Sensor (perspective): the camera; S9 asks it for primary rays
    objects: list[RefractiveObject] = field(default_factory=list)
    environment: object | None = None  # mi.Emitter (constant / envmap) seen by escaping rays
    grids: dict | None = None  # {"n", "sigma_s", "kappa"}: NumPy (n, n, n[, 3]), world units;
    #                            given, they bypass voxelization (S1) and material mapping (S2)
    fog_volumes: list[FogVolume] = field(default_factory=list)  # bounded media, in scene order
    outside: Medium | None = None  # fills the grid outside the fog volumes; None: ``fog``
    surfaces: Surfaces | None = None  # the opaque surfaces (surfaces.py); None: there are none

    @property
    def refracted_ior(self) -> float:
        """The index above which a photon has passed through a refractive object (midway between
        the surrounding medium's and the least dense object's), ∞ without objects: such a
        photon's light reaches the surfaces as photons, not along shadow rays."""
        if self.grids is not None or not self.objects:
            return float("inf")
        return 0.5 * (self.surrounding.ior + min(o.medium.ior for o in self.objects))

    @property
    def phase_k(self) -> float | None:
        """Schlick's k of the scattering fog's phase function (the first fog volume that
        scatters, else the fog): what the pipeline uses unless ``phase_k`` is set."""
        media = [v.medium for v in self.fog_volumes] + [self.fog]
        scattering = [m for m in media if np.any(np.asarray(m.sigma_s) > 0)]
        return (scattering or media)[0].phase_k

    @property
    def heterogeneous(self) -> bool:
        """Whether a medium of the scene is heterogeneous (``Medium.field``)."""
        media = [self.surrounding, *(v.medium for v in self.fog_volumes)]
        return any(m.field is not None for m in media + [o.medium for o in self.objects])

    @property
    def surrounding(self) -> Medium:
        """The medium outside every fog volume and object (:attr:`outside`, else :attr:`fog`)."""
        return self.fog if self.outside is None else self.outside

    def replace_medium(self, old: Medium, new: Medium) -> None:
        """Put ``new`` wherever ``old`` is: the fog, the outside and the fog volumes."""
        if self.fog is old:
            self.fog = new
        if self.outside is old:
            self.outside = new
        for volume in self.fog_volumes:
            if volume.medium is old:
                volume.medium = new


# ------------------------------------------------------------------------------------------------
# Reading a Mitsuba scene

MARGIN = 6.0  # voxels left around refractive objects when no fog box bounds the grid (GridBox)
EMITTERS = "point, spot, directional and area emitters, or a constant or envmap environment"


def from_mitsuba(scene: mi.Scene, grid: int = 128, grid_bbox=None) -> VolumeScene:
    """Read what the volume pipeline needs from a loaded Mitsuba scene (world units).

    - **Refractive objects**: closed shapes (a sphere or a watertight mesh) with a ``dielectric``
      BSDF. ``medium.ior`` is Mitsuba's relative index ``int_ior / ext_ior`` (the BSDF keeps only
      this ratio; the ray equation is unchanged when n is scaled, so the fog has n = 1). The
      interior medium (none: clear glass, σ = 0) gives the object's σ_s and σ_a.
    - **Fog volumes**: closed shapes with a ``null`` or ``thindielectric`` BSDF
      and an interior medium, several allowed, each with its own medium; the medium is inside the
      shape only (S1 voxelizes it, S2 maps its coverage to σ_s and κ). They are index-matched (n
      unchanged); a thin dielectric's reflection is left to the surface methods.
    - **Outside** the fog volumes the grid holds the sensor's medium; else the exterior medium of
      the refractive objects when no fog volume bounds it (it is then taken to fill the grid, with
      a warning); else vacuum. An object's exterior medium that is the interior of a fog volume is
      fog only inside that volume.
    - **Media** are read as Mitsuba defines them: ``homogeneous`` with ``sigma_t``, ``albedo``
      and ``scale`` (RGB): ``σ_s = scale·albedo·σ_t``, ``σ_a = scale·σ_t − σ_s``;
      ``heterogeneous`` (grid volumes) kept as Mitsuba media and evaluated per voxel by S2
      (``medium_grid.py``).
    - **Fog** (:attr:`VolumeScene.fog`, the medium ``set_material("fog")`` edits): the exterior
      medium of the refractive objects, else the sensor's medium, else the interior medium of the
      first fog volume, else vacuum.
    - **Grid box** (a box grid: ``n_x × n_y × n_z`` cubic voxels with ``grid``
      of them along the longest side, :meth:`GridBox.fitted`): around ``grid_bbox = (min, max)``
      if given, else around the fog volumes with no margin when they enclose every refractive
      object (the fog box is the domain), else around all medium-bearing shapes with ``MARGIN``
      voxels.
    - **Lights** (anywhere): point, spot (``cutoff_angle`` → ``cos_outer``,
      ``beam_width`` → ``cos_inner``), directional, and area emitters (kept as Mitsuba emitters,
      sampled on their surface by S5); a ``constant``/``envmap`` emitter is the ``environment``
      (the background of the viewing pass) and also a light whose photons enter through the
      grid's faces.
    - **Camera**: the first sensor, which must be ``perspective``.

    - **Opaque surfaces** (every other shape, emitters' shapes included: ``surfaces.py``) stop
      photons and camera rays; the viewing pass shades them (``shading.py``) and follows their
      mirror lobes (``view.py``). What it does not render of them — partial transparency — is
      named in a :class:`~photonmap.PhotonmapWarning`.

    Raises :class:`SceneError` saying what to fix for anything the pipeline cannot render.
    """
    sensor = _camera(scene)
    media = MediaReader(scene.bbox())
    objects, fog_volumes, exteriors = _medium_shapes(scene, media)
    if not objects and not fog_volumes:
        raise SceneError(
            "the scene has no refractive or medium-bearing shape, which the volume method's grid "
            "is fitted to: render it with --method sppm (or surface), or give a closed shape a "
            "'dielectric' BSDF, or a 'null' BSDF with an interior 'homogeneous' medium (the fog)"
        )
    fog, outside = _fog(sensor, exteriors, fog_volumes, media)
    box = _grid_box(objects, [v.shape for v in fog_volumes], grid, grid_bbox)
    lights, environment = _lights(scene, box.center)
    warn_unmodelled("volume", unmodelled(scene.shapes()), SURFACE_HINT)
    return VolumeScene(
        box,
        fog,
        lights,
        sensor,
        objects,
        environment,
        fog_volumes=fog_volumes,
        outside=outside,
        surfaces=Surfaces.of(scene, box),
    )


def _medium_shapes(scene: mi.Scene, media: MediaReader) -> tuple[list, list, list]:
    """The scene's refractive objects, its fog volumes and the ``(id, medium)`` outside each
    refractive object that has an exterior medium (:func:`from_mitsuba`)."""
    objects, fog_volumes, exteriors = [], [], []
    for number, shape in enumerate(scene.shapes()):
        bsdf = shape.bsdf()
        kind = bsdf.class_name() if bsdf is not None else "none"
        if kind == "SmoothDielectric":
            objects.append(_refractive_object(shape, bsdf, media))
            if shape.exterior_medium() is not None:
                exteriors.append((shape.id(), shape.exterior_medium()))
        elif kind == "RoughDielectric":
            raise SceneError(
                f"{_shape_name(shape, number)} has a {kind} BSDF; the volume pipeline refracts "
                "only through smooth 'dielectric' objects: change its BSDF type to 'dielectric', "
                "or render the scene with --method sppm (or surface)"
            )
        elif kind in ("Null", "ThinDielectric") and shape.interior_medium() is not None:
            name = shape.id() or f"{shape.class_name()} {len(fog_volumes)} (no id)"
            check_closed(shape, name)
            medium = media.read(shape.interior_medium(), f"the fog inside '{name}'", shape_box(shape))
            fog_volumes.append(FogVolume(name, shape, medium))
    return objects, fog_volumes, exteriors


SURFACE_HINT = "--method sppm renders every BSDF (Python: photonmap.SPPMPipeline)"


def _shape_name(shape, number: int) -> str:
    return (
        f"shape '{shape.id()}'" if shape.id() else f"shape number {number} ({shape.class_name()})"
    )


def _rgb(value) -> np.ndarray:
    """A Mitsuba spectrum value (uniform or RGB, width 1) as a float64 RGB NumPy array."""
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    return np.repeat(a, 3) if a.size == 1 else a[:3]


def _np3(v) -> np.ndarray:
    return np.asarray(v, dtype=np.float64).reshape(-1)[:3]


def _camera(scene: mi.Scene):
    sensors = scene.sensors()
    if not sensors:
        raise SceneError("the scene has no sensor: add a 'perspective' sensor (the camera)")
    sensor = sensors[0]
    if sensor.class_name() != "PerspectiveCamera":
        raise SceneError(
            f"the sensor is a {sensor.class_name()}; the volume pipeline's viewing pass needs a "
            "pinhole camera: use a 'perspective' sensor"
        )
    return sensor


def _refractive_object(shape, bsdf, media: MediaReader) -> RefractiveObject:
    name = shape.id()
    check_closed(shape, name)
    eta = float(np.asarray(mi.traverse(bsdf)["eta"]).reshape(-1)[0])
    if not np.isfinite(eta) or eta < 1.0:
        raise SceneError(
            f"object '{name}' has relative index n = int_ior/ext_ior = {eta:g}; the volume "
            "pipeline needs a finite n >= 1 (an object optically denser than the fog): fix its "
            "int_ior/ext_ior"
        )
    medium = read_medium(shape.interior_medium(), f"the interior medium of '{name}'", shape_box(shape))
    medium.ior = eta
    return RefractiveObject(name, shape, medium)


def _fog(sensor, exteriors, fog_volumes, media: MediaReader) -> tuple[Medium, Medium | None]:
    """(the fog, the medium outside the fog volumes: None when there is none, the fog filling
    the grid); see :func:`from_mitsuba`."""
    bounded = [v.shape.interior_medium() for v in fog_volumes]
    camera = sensor.get_medium()
    unbounded = [(name, m) for name, m in exteriors if all(m is not b for b in bounded)]
    if any(m is not unbounded[0][1] for _, m in unbounded):
        raise SceneError(
            "the refractive objects have different exterior media and no 'null'-BSDF shape bounds "
            "them; the volume pipeline fills the space outside the fog shapes with one medium: "
            "give every dielectric shape the same 'exterior' medium, or put each medium inside a "
            "closed 'null'-BSDF shape (its 'interior')"
        )
    if unbounded and camera is not None and unbounded[0][1] is not camera:
        raise SceneError(
            f"the exterior medium of '{unbounded[0][0]}' is neither the sensor's medium nor inside "
            "a 'null'-BSDF shape: make it the sensor's medium, or the interior medium of a closed "
            "'null'-BSDF shape around the object"
        )
    outside = camera
    if outside is None and unbounded:
        outside = unbounded[0][1]
        if fog_volumes:
            warnings.warn(
                f"the exterior medium of '{unbounded[0][0]}' is bounded by no shape and the sensor "
                "is not in it: the volume pipeline fills the grid outside the fog shapes with it. "
                "Make it the interior medium of a closed 'null'-BSDF shape or the sensor's medium",
                stacklevel=3,
            )
    candidates = [*(m for _, m in exteriors), camera, *bounded]
    first = next((m for m in candidates if m is not None), None)
    fog = media.read(first, "the fog (exterior medium)")
    if not fog_volumes:
        return fog, None
    return fog, media.read(outside, "the fog outside the fog shapes (exterior medium)")


def _grid_box(objects, fog_shapes, grid: int, grid_bbox) -> GridBox:
    if grid_bbox is not None:
        lo, hi = (_np3(v) for v in grid_bbox)
        return GridBox.fitted(lo, hi, grid, margin=0.0)

    def union(shapes):
        lo = np.min([_np3(shape_box(s).min) for s in shapes], axis=0)
        hi = np.max([_np3(shape_box(s).max) for s in shapes], axis=0)
        return lo, hi

    if fog_shapes:
        lo, hi = union(fog_shapes)
        inside = all(
            np.all(_np3(shape_box(o.shape).min) >= lo) and np.all(_np3(shape_box(o.shape).max) <= hi)
            for o in objects
        )
        if inside:
            return GridBox.fitted(lo, hi, grid, margin=0.0)
    lo, hi = union([o.shape for o in objects] + fog_shapes)
    return GridBox.fitted(lo, hi, grid, margin=MARGIN)


def _probe(emitter, ref) -> tuple[np.ndarray, np.ndarray, float]:
    """Sample a delta emitter from ``ref``: (direction to it, I/dist² or irradiance, dist)."""
    it = dr.zeros(mi.Interaction3f)
    it.p = mi.Point3f(*(float(c) for c in ref))
    ds, spec = emitter.sample_direction(it, mi.Point2f(0.5, 0.5))
    return _np3(ds.d), _rgb(spec), float(np.asarray(ds.dist).reshape(-1)[0])


def _lights(scene, center) -> tuple[list[Light], object]:
    lights, environment = [], None
    for emitter in scene.emitters():
        kind, name = emitter.class_name(), emitter.id()
        if emitter.is_environment():
            environment = emitter
            key = digest(emitter)
            lights.append(Light("environment", np.ones(3), emitter=emitter, fingerprint=key))
        elif kind == "PointLight":
            position = _np3(mi.traverse(emitter)["position"])
            _, spec, dist = _probe(emitter, position - [0.0, 1.0, 0.0])
            lights.append(Light("point", spec * dist**2, position=position))
        elif kind == "SpotLight":
            m = np.asarray(emitter.world_transform().matrix, dtype=np.float64).reshape(4, 4)
            position, axis = m[:3, 3], m[:3, 2] / np.linalg.norm(m[:3, 2])
            _, spec, dist = _probe(emitter, position + axis)
            params = mi.traverse(emitter)
            cos_outer, cos_inner = (
                float(np.cos(np.radians(_np3(params[key])[0])))
                for key in ("cutoff_angle", "beam_width")
            )
            lights.append(
                Light(
                    "spot",
                    spec * dist**2,
                    position=position,
                    direction=axis,
                    cos_inner=cos_inner,
                    cos_outer=cos_outer,
                )
            )
        elif kind == "DirectionalEmitter":
            to_light, irradiance, _ = _probe(emitter, center)
            lights.append(Light("directional", irradiance, direction=-to_light))
        elif kind == "AreaLight":
            shape = emitter.get_shape()
            key = digest(emitter, shape)
            lights.append(Light("area", np.ones(3), emitter=emitter, shape=shape, fingerprint=key))
        else:
            raise SceneError(
                f"emitter '{name}' is a {kind}, which the volume pipeline cannot use; it supports "
                f"{EMITTERS}"
            )
    if not lights:
        raise SceneError(f"the scene has no light: add one of the {EMITTERS}")
    return lights, environment


def check_has_fog(mi_scene: mi.Scene, source) -> None:
    """Raise :class:`SceneError` unless ``mi_scene`` holds a participating medium: the volume
    method renders single scattering in fog (Sun et al. 2008) and would write a black image of a
    scene without; the message names the method to use."""
    if has_media(mi_scene):
        return
    what = f"scene {source!r}" if isinstance(source, str) else "the scene"
    raise SceneError(
        f"{what} has no fog (no participating medium), so the volume method would render it "
        "black: render it with --method surface (Python: photonmap.SurfacePipeline), or give "
        "it fog (a 'homogeneous' medium as the exterior of its dielectric shapes, the sensor's "
        "medium, or the interior of a 'null'-BSDF shape)"
    )
