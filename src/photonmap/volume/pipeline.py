"""``VolumePipeline`` — Sun et al. 2008 / Pfeuti 2009 §3.1 as a relightable pipeline.

::

    mesh ─► S1 voxelize ─► S2 materials + blur ─► S3 ∇n ─► S4 octree ─┐
    lights ─► S5 photon generation ────────────────────────────────────┼─► S6/S7 march ─► S8 smooth ─┐
    camera, phase k, table, isosurface ─────────────────────────────────────────────────────────────┴─► S9

The labels S1–S9 name the stages of this diagram (Sun et al. 2008 §4; Pfeuti 2009 §3.1) in the
docstrings of the package. With ``emission="adaptive"`` (Pfeuti 2009 §3.2) S5–S8 become the stages
A1–A7 of :data:`ADAPTIVE_STAGES`: pilot photons (A1 generation, A2 marching, ``pilot.py``), the
photon-plane pdf (A3), importance-sampled photons marched with their weights (A4–A5,
``adaptive.py``), mipmaps (A6) and the level-selecting filter (A7, ``mipmap.py``).

Every stage's result is cached under a key made of exactly the inputs it depends on, so a change
reruns only what it must (the edits of Sun et al. 2008 §6): a camera change reruns S9 only; a light
change S5–S9 (adaptive: A1–A7 and S9); a change of σ_s that keeps κ reruns S9 only; a change of κ
reruns S6–S9 (adaptive: A2–A7 and S9); a change of n reruns S2–S9; new geometry reruns everything.
With multiple scattering (``scattering="multiple"``, the default; our extension of Sun's single
scattering) σ_s and the phase function steer the photons too: a change of σ_s reruns S6–S9, one of
the phase k S6/S7–S9. The stage outputs live in a :class:`~photonmap.core.stages.StageCache`:
``recomputed`` lists the stages the last :meth:`render` ran and ``timer`` their milliseconds (the
rows of Sun et al. Table 1); :meth:`invalidate` forgets stages, :meth:`stage_output` reads one.
``render(progress=f)`` calls ``f(stage)`` as each stage that must run starts (the CLI's progress
bar).

Before allocating anything the pipeline estimates the memory its grids need
(:func:`.params.memory_estimate`) and stops with a :class:`ParameterError` if that exceeds the
available memory or Dr.Jit's 2³² entries per array.
"""

from __future__ import annotations

import dataclasses

import mitsuba as mi
import numpy as np

from ..core.camera import moved_sensor
from ..core.errors import ParameterError, SceneError
from ..core.memory import check_image_memory, check_once
from ..core.params import field_types, parameter_names, updated
from ..core.pipeline import Pipeline
from ..core.scene_info import warn_unmodelled
from ..core.settings import UNBOUNDED, PathSettings, overridden
from ..core.stages import StageCache, cache_key
from .material_stages import fog_boundaries, voxelized_materials
from .materials import MaterialGrids, from_arrays, gradient
from .medium_grid import KAPPA_TOLERANCE
from .octree import build_octree
from .params import (
    ADAPTIVE_STAGES,
    LIGHT_VECTORS,
    STAGES,
    VolumeParams,
    check_grid,
    check_light,
    light_vector,
    memory_estimate,
    updated_medium,
)
from .photon_stages import adaptive_photons, uniform_photons
from .scene import Light, VolumeScene, check_has_fog, from_mitsuba
from .step import MarchGrids, Scattering
from .surface_stages import shading_key, surface_shading, warn_settings
from .view import ViewGrids, ViewSettings, render_view, sensor_key

SHORT_DEPTH = 4  # a file's max_depth up to which the volume method refuses the file
LONG_DEPTH = 32  # and from which it renders it without a word (paths that long carry little)


def check_depth(settings: PathSettings) -> None:
    """The volume method renders paths of any length — its radiance grid is the steady state of
    the photons' transport, refracted continuously — so a file's finite ``max_depth`` is not
    honoured: refuse where it is at most :data:`SHORT_DEPTH` (most of the image would be light
    the file leaves out), warn below :data:`LONG_DEPTH`."""
    depth = settings.max_depth
    if depth == UNBOUNDED or depth >= LONG_DEPTH:
        return
    if depth <= SHORT_DEPTH:
        raise SceneError(
            f"the scene's integrator says max_depth {depth}; the volume method renders paths of "
            "any length: render this scene with --method sppm (or surface)"
        )
    warn_unmodelled(
        "volume", [f"the file's max_depth {depth} (it renders paths of any length)"],
        "--method sppm honours it",
    )  # fmt: skip


class VolumePipeline(Pipeline):
    """Voxel photon tracing through refractive participating media, relightable.

    ``scene`` is a Mitsuba scene (``mi.Scene``), a scene dict, an XML path or a built-in name
    (``photonmap scenes``). ``grid`` is the voxel count N along the longest side of the box grid
    (N_x × N_y × N_z cubic voxels fitted to the media, ``scene.box.dims``). Keyword arguments
    are :class:`VolumeParams` fields; a built-in scene's own defaults apply first, and for a
    built-in the keywords of its ``build`` (``width``, ``height``, ``ior``, ...) pass through.
    Any unknown keyword raises a :class:`ParameterError` listing the valid ones.

    >>> pipe = VolumePipeline("glass_sphere_fog", grid=64, photons=256**2, width=320, height=240)
    >>> image = pipe.render()               # mi.TensorXf (height, width, 3), linear radiance
    >>> pipe.set_camera(origin=[0.5, 0.8, 2.5], target=[0.5, 0.4, 0.5])
    >>> image = pipe.render()               # reruns only the viewing pass
    """

    method, params_type = "volume", VolumeParams
    edits = frozenset({"camera", "params", "light", "material", "volume", "reload"})
    world: VolumeScene  # what the method reads of ``scene``, in world units (:mod:`.scene`)

    def __init__(self, scene, **params):
        from ..scenes import SCENES, load_scene

        valid = parameter_names(VolumeParams)
        scene_params = {k: v for k, v in params.items() if k not in valid}
        builtin = SCENES.get(scene) if isinstance(scene, str) else None
        if scene_params:
            accepted = set(builtin.params) if builtin else set()
            unknown = sorted(set(scene_params) - accepted)
            if unknown:
                also = f"; scene {scene!r} also accepts {', '.join(sorted(accepted))}"
                raise ParameterError(
                    f"unknown volume parameter(s) {', '.join(unknown)}; valid: "
                    f"{', '.join(sorted(field_types(VolumeParams)))}{also if builtin else ''}"
                )
        self.scene, defaults = load_scene(scene, **scene_params)
        own = {**defaults, **{k: v for k, v in params.items() if k in valid}}
        new = updated(VolumeParams(), own, "volume")  # a bad value is named before the scene
        check_has_fog(self.scene, scene)
        self.file_settings = PathSettings.of(self.scene, scene)
        check_depth(self.file_settings)
        self.cache = StageCache()
        self._warned: set[str] = set()
        self.stats: dict[str, float] = {}
        self._geometry_version = 0
        self._apply(new)

    @property
    def sensor(self) -> mi.Sensor:
        """The camera (the volume scene's: the viewing pass asks it for primary rays)."""
        return self.world.sensor

    @sensor.setter
    def sensor(self, sensor: mi.Sensor) -> None:
        self.world.sensor = sensor

    def reload(self, scene: mi.Scene) -> None:
        """Re-read lights, media, sensor and shapes from ``scene`` (a Mitsuba scene, possibly
        edited through ``mi.traverse``); cached stages whose inputs did not change are kept.
        Grids given by :meth:`set_volume` stay."""
        check_has_fog(scene, scene)
        new = from_mitsuba(scene, grid=self.params.grid, grid_bbox=self.params.grid_bbox)
        new.grids = self.world.grids
        self.scene, self.world = scene, new

    # ------------------------------------------------------------------ changes
    def set_params(self, **params) -> None:
        """Change pipeline parameters (:class:`VolumeParams` fields). ``grid`` and ``grid_bbox``
        are fixed once the pipeline is built (its volume scene is voxelized for them)."""
        self._apply(updated(self.params, params, "volume"))

    def _apply(self, new: VolumeParams) -> None:
        """Take the validated parameters ``new``; the first time, build the volume scene."""
        world = getattr(self, "world", None)
        if world is None:  # building: the volume scene in the grid box of these parameters
            world = from_mitsuba(self.scene, grid=new.grid, grid_bbox=new.grid_bbox)
        elif (new.grid, new.grid_bbox) != (self.params.grid, self.params.grid_bbox):
            raise ParameterError(
                "grid and grid_bbox are fixed when the volume pipeline is built (its scene is "
                "voxelized for them); build a new pipeline with the new values"
            )
        photons = new.photons * len(world.lights)
        check_grid(new.grid, len(world.objects), photons, dims=world.box.dims)
        self.params, self.world = new, world

    def check_memory(self, params: VolumeParams | None = None, size=None) -> int:
        """Raise a :class:`ParameterError` when ``params`` (default: the pipeline's) at ``size``
        (width, height; default: the camera's) would need more memory than is available: the
        grids and photons (:func:`.params.check_grid`), the viewing pass's samples
        (:func:`~photonmap.core.memory.check_image_memory`). Returns the estimate in bytes."""
        p = params or self.params
        w, h = size or self.size
        box, objects = self.world.box, len(self.world.objects)
        photons = p.photons * len(self.world.lights)
        check_grid(box.n, objects, photons, dims=box.dims)
        return memory_estimate(box.dims, objects, photons)[0] + check_image_memory(
            "volume", w, h, p.spp
        )

    def set_camera(
        self, origin=None, target=None, up=(0, 1, 0), fov=None, width=None, height=None, sensor=None
    ) -> None:
        """Move the camera (reruns S9 only). Pass a Mitsuba ``sensor``, or any of ``origin``,
        ``target``, ``up``, ``fov`` (horizontal, degrees), ``width``, ``height``; the rest is kept."""
        if sensor is None:
            sensor = moved_sensor(
                self.world.sensor, self.world.box.center, origin, target, up, fov, width, height
            )
        self.world.sensor = sensor

    def set_light(self, index: int = 0, **changes) -> None:
        """Change light ``index`` (fields of :class:`~.scene.Light`: position, direction, intensity,
        kind, cos_inner, cos_outer). Reruns S5–S9."""
        if not 0 <= index < len(self.world.lights):
            raise ParameterError(
                f"no light {index}; the scene has {len(self.world.lights)} "
                f"(valid indices 0..{len(self.world.lights) - 1})"
            )
        light = self.world.lights[index]
        fields = {f.name for f in dataclasses.fields(Light)}
        unknown = sorted(set(changes) - fields)
        if unknown:
            raise ParameterError(f"unknown light field(s) {unknown}; valid: {sorted(fields)}")
        changes = {
            k: (light_vector(k, v) if k in LIGHT_VECTORS and v is not None else v)
            for k, v in changes.items()
        }
        new = dataclasses.replace(light, **changes)
        check_light(new)
        self.world.lights[index] = new

    def set_material(self, name: str | None = None, ior=None, sigma_s=None, sigma_a=None) -> None:
        """Change the medium of the refractive object ``name`` (all objects if None), of the fog
        volume ``name`` (a ``null``-BSDF shape's interior), or with ``"fog"`` of the fog wherever
        it is (:attr:`~.scene.VolumeScene.fog`). World units. Changing only σ_s while keeping
        κ = σ_s + σ_a reruns S9 alone; κ reruns S6–S9; n reruns S2–S9."""
        s = self.world
        if name == "fog":
            s.replace_medium(s.fog, updated_medium(s.fog, ior, sigma_s, sigma_a, "fog"))
            return
        volumes = [v for v in s.fog_volumes if name is not None and v.name == name]
        if volumes and ior is not None:
            raise ParameterError(
                f"fog volume {name!r} is index-matched (its boundary does not refract): change "
                "its sigma_s and sigma_a only"
            )
        for volume in volumes:
            volume.medium = updated_medium(volume.medium, None, sigma_s, sigma_a, name)
        targets = [o for o in s.objects if name in (None, o.name)]
        if not targets and not volumes:
            raise ParameterError(
                f"no refractive object {name!r}; objects: {[o.name for o in s.objects]}, fog "
                f"volumes: {[v.name for v in s.fog_volumes]} or 'fog'"
            )
        for obj in targets:
            obj.medium = updated_medium(obj.medium, ior, sigma_s, sigma_a, obj.name)

    def set_volume(self, n=None, sigma_s=None, kappa=None) -> None:
        """Supply material grids directly (simulation data, painting; Sun §6.2): NumPy arrays of
        shape ``scene.box.shape`` (N_z, N_y, N_x) or (N_z, N_y, N_x, 3) indexed [z, y, x], world
        units. Bypasses S1/S2."""
        grids = dict(self.world.grids or {})
        for key, value in (("n", n), ("sigma_s", sigma_s), ("kappa", kappa)):
            if value is not None:
                try:
                    grids[key] = np.array(value, dtype=np.float32)  # a copy: later edits re-key
                except (TypeError, ValueError):
                    raise ParameterError(
                        f"set_volume: {key} must be a numeric array of shape (N_z, N_y, N_x) or "
                        f"(N_z, N_y, N_x, 3), got {type(value).__name__}"
                    ) from None
        missing = {"n", "sigma_s", "kappa"} - set(grids)
        if missing:
            raise ParameterError(
                f"set_volume needs n, sigma_s and kappa the first time; missing {sorted(missing)}"
            )
        from_arrays(grids, self.world.box)  # validates
        self.world.grids = grids

    def set_geometry(self, name: str, shape) -> None:
        """Replace the shape of refractive object ``name`` (a deformed mesh). Reruns S1–S9."""
        for obj in self.world.objects:
            if obj.name == name:
                obj.shape = shape
                self._geometry_version += 1
                return
        raise ParameterError(f"no refractive object {name!r}")

    # ------------------------------------------------------------------ stages
    def set_stage_output(self, name: str, value) -> None:
        """Replace the cached output of stage ``name`` (computed before) by ``value``, keeping
        its key, and forget the stages after it, so that the next :meth:`render` reruns those
        from ``value`` (benchmarks: a reference whose C, D average several photon batches)."""
        self.stage_output(name)  # checks the name
        key = self.cache.key(name)
        later = self.stages[self.stages.index(name) :]
        self.cache.invalidate(later)
        self.cache.stage(name, key, lambda: value)

    def _materials(self) -> tuple[MaterialGrids, tuple, tuple, tuple]:
        """S1 + S2 (cached; :func:`.material_stages.voxelized_materials`)."""
        return voxelized_materials(self.cache, self.world, self.params, self._geometry_version)

    def render(self, progress=None) -> mi.TensorXf:
        """Run (or reuse) every stage and return the image (height, width, 3), linear radiance.

        ``progress``, if given, is called with the name of each stage (one of :data:`STAGES`) as
        it starts; cached stages are skipped silently.
        """
        check_once(self, self.params, self.size, self.check_memory)
        self.cache.new_frame(progress)
        try:
            return self._render()
        finally:
            self.cache.progress = None

    def _render(self) -> mi.TensorXf:
        s, p = self.world, self.params
        paper = p.fidelity == "paper"

        mats, ior_key, kappa_key, sigma_key = self._materials()
        grad = self.cache.stage("gradient", ior_key, lambda: gradient(mats.ior))
        # a heterogeneous medium's κ varies within its shape: nodes split there too
        varying = s.grids is None and s.heterogeneous
        octree_key = (ior_key, p.eps, p.eps2, p.ds_max, kappa_key if varying else None)
        octree = self.cache.stage(
            "octree",
            octree_key,
            lambda: build_octree(
                mats.ior,
                p.eps,
                p.eps2,
                p.ds_max,
                kappa=mats.kappa if varying else None,
                eps_kappa=KAPPA_TOLERANCE,
                boundaries=fog_boundaries(self.cache, s),
            ),
        )
        phase_k = self.phase_k
        # multiple scattering: σ_s and the phase function steer the photons too (scatter.py)
        scatter = Scattering(phase_k, p.seed) if p.scattering == "multiple" else None
        scatter_key = None if scatter is None else (sigma_key, cache_key(scatter))
        march_grids = self.cache.stage(
            "march grids",
            (octree_key, kappa_key, None if scatter is None else sigma_key),
            lambda: MarchGrids.build(
                mats.ior,
                grad,
                mats.kappa,
                octree.level,
                octree.step_limit,
                sigma_s=None if scatter is None else mats.sigma_s,
            ),
        )

        warn_settings(s, p, self._warned)
        photons = adaptive_photons if p.emission == "adaptive" else uniform_photons
        C, D, smooth_key, on_surfaces, self.stats = photons(
            self.cache, s, p, march_grids, (octree_key, kappa_key), scatter, scatter_key
        )
        surf = s.surfaces
        view_grids = self.cache.stage(
            "view grids",
            (smooth_key, ior_key, kappa_key, sigma_key, surf is not None),
            lambda: ViewGrids.build(
                mats.ior, grad, mats.kappa, mats.sigma_s, C, D, shadows=surf is not None
            ),
        )
        shading = surface_shading(s, p, on_surfaces, view_grids)
        settings = ViewSettings(
            phase_k=phase_k,
            table=(p.table,) * 3,
            iso_ior=self._iso_ior(mats),
            iso_reflect=p.iso_reflect,
            paper=paper,
            spp=p.spp,
            seed=p.seed,
            hide_emitters=overridden(self.file_settings, hide_emitters=p.hide_emitters).hide_emitters,
        )
        image = self.cache.stage(
            "viewing",
            (
                cache_key(settings),
                sensor_key(s.sensor),
                id(s.environment),
                view_grids is not None and id(view_grids),
                shading_key(s, p, shading),
            ),
            lambda: render_view(view_grids, s.box, s.sensor, s.environment, settings, shading),
        )
        if not np.all(np.isfinite(np.asarray(image))):
            raise SceneError("the render produced NaN or infinite values; please report this scene")
        return image

    @property
    def phase_k(self) -> float:
        """Schlick's k in use: the ``phase_k`` parameter, else the fog's own phase function
        (:attr:`VolumeScene.phase_k`: isotropic 0, Henyey–Greenstein g → 1.55 g − 0.55 g³)."""
        if self.params.phase_k is not None:
            return self.params.phase_k
        k = self.world.phase_k
        if k is None:
            raise SceneError(
                "the fog's phase function is neither isotropic nor Henyey–Greenstein ('hg'), "
                "which the volume pipeline models: set phase_k (Schlick's k) explicitly"
            )
        return k

    @property
    def stages(self) -> tuple[str, ...]:
        """The stage names of the current emission, in the order :meth:`render` runs them."""
        return ADAPTIVE_STAGES if self.params.emission == "adaptive" else STAGES

    def _iso_ior(self, mats: MaterialGrids) -> float | None:
        p, s = self.params, self.world
        if p.iso_reflect <= 0 or s.environment is None:
            return None
        if p.iso_ior > 0:
            return p.iso_ior
        if not s.objects:
            return None
        return 0.5 * (s.surrounding.ior + max(o.medium.ior for o in s.objects))

    @property
    def grids(self) -> dict[str, np.ndarray]:
        """The cached intermediate grids of the last render, as NumPy arrays (for inspection)."""
        out = {}
        for name in self.stages:  # not what is left over from the other emission
            value = self.cache.get(name)
            if value is None:
                continue
            if isinstance(value, MaterialGrids):
                out.update(
                    ior=np.asarray(value.ior),
                    sigma_s=np.asarray(value.sigma_s),
                    kappa=np.asarray(value.kappa),
                )
            elif name in ("smoothing", "filtering"):
                out.update(C=np.asarray(value[0]), D=np.asarray(value[1]))
                if name == "filtering":
                    out["mip_level"] = np.asarray(value[2]).reshape(value[0].shape[:3])
            elif name == "photon distribution":
                out["pdf"] = np.stack([sampler.pdf for sampler in value])
            elif name == "gradient":
                out["grad"] = np.asarray(value)
            elif name == "octree":
                out.update(level=np.asarray(value.level), step_limit=np.asarray(value.step_limit))
        return out
