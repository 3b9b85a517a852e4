"""``VCMPipeline`` — vertex connection and merging (Georgiev, Křivánek, Davidovič & Slusallek 2012;
Hachisuka, Pantaleoni & Jensen 2012's unified path sampling is the same estimator).

Iteration ``i`` (1-based) traces ``spp`` light subpaths per pixel (:mod:`.light`: their
vertices stored, each connected to the camera), puts the vertices in a hash grid, and traces
``spp`` camera subpaths per pixel, each of which at each vertex adds the emission met, next-event
estimation, connections to its light subpath and merges with the light vertices within ``r_i``,
every technique weighted by the balance heuristic (:mod:`.camera`, :mod:`.mis`). The image is
the mean of the iterations' images; the merging radius shrinks as
``r_i = r_1 · i^((α−1)/2) / √spp`` (α = 0.75, SmallVCM's default), which makes the merges consistent
(Knaus & Zwicker 2011) while the other techniques are unbiased. An iteration's random numbers
come from ``(seed, i)`` alone, and memory is one iteration's whatever their number.

``radius = 0`` picks ``r_1``: :data:`RADIUS_PIXELS` pixel footprints at the median distance of the
surfaces the camera sees (:func:`~photonmap.core.camera.footprint_radius`).

``mode`` picks the techniques (:mod:`.mis`: ``vcm``, ``bpt``, ``ppm``, ``pt``, ``lt``); every
mode converges to the same image, so they check each other.

**The scene file's settings**: ``max_depth``, ``rr_depth`` and ``hide_emitters`` default to the
file's ``<integrator>`` with Mitsuba's meaning (a path of at most ``max_depth`` segments).
Refused, each in one line naming ``sppm``: participating media, environment and directional
lights (area, point and spot lights are supported), sensors other than ``perspective``, and the
``hair`` BSDF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from ..core.arrays import to_numpy
from ..core.emission import checked_powers
from ..core.errors import SceneError
from ..core.film_filter import filter_image
from ..core.memory import check_memory, check_once
from ..core.params import check_choice, check_fields, check_range, updated
from ..core.photon_trace import CHUNK
from ..core.pipeline import Pipeline
from ..core.progressive import Progressive, iteration_seeds
from ..core.scene_info import check_gathered_bsdfs, refuse_media
from ..core.settings import PathSettings, check_path_params, overridden
from ..core.stages import StageCache
from .camera import MergeGrid, camera_pass
from .light import Emitters, light_pass
from .mis import MODES, Techniques

STAGES = ("light pass", "camera pass")
WAVEFRONT = 2**17  # automatic spp: about this many subpaths of each kind per iteration
MAX_SPP = 64
# automatic initial radius, in pixel footprints at the median eye distance (core.camera's
# footprint_radius, as sppm): 1, smaller than sppm's 4, because merging is one technique of
# several under MIS (connections carry the light they sample well) and has no per-pixel shrink
RADIUS_PIXELS = 1.0
ALPHA = 0.75


@dataclass
class VCMParams:
    """Parameters of the VCM pipeline (the ``vcm`` plugin and ``--set`` keys)."""

    iterations: int = 64  # iterations of render() (run() takes its own budget)
    spp: int = 0  # camera subpaths per pixel and iteration (as many light subpaths); 0 = automatic
    radius: float = 0.0  # initial merging radius r_1 in scene units; 0 = automatic
    alpha: float = ALPHA  # radius reduction: r_i = r_1 i^((α−1)/2) / √spp, α in (0, 1)
    seed: int = 0
    max_depth: int = 0  # longest path in segments (Mitsuba's); 0 = the scene's, -1 = unbounded
    rr_depth: int = 0  # depth where Russian roulette starts; 0 = the scene's
    hide_emitters: str = "scene"  # hide emitters seen directly: scene | true | false
    mode: str = "vcm"  # vcm | bpt | ppm | pt | lt (the techniques used)

    def validate(self) -> None:
        check_fields(self)
        check_range("iterations", self.iterations, 1, None, "VCM iterations of render()")
        check_range("spp", self.spp, 0, MAX_SPP, "camera subpaths per pixel; 0 = automatic")
        check_range("radius", self.radius, 0, None, "the initial merging radius; 0 = automatic")
        check_range("alpha", self.alpha, 0, 1, "the radius reduction α (0.75 is usual)", True,
                    True)  # fmt: skip
        check_path_params(self)
        check_choice("mode", self.mode, MODES, "the techniques: vcm, bpt, ppm, pt or lt")


def auto_spp(width: int, height: int) -> int:
    """The automatic ``spp`` (:attr:`VCMPipeline.spp`)."""
    return int(np.clip(round(WAVEFRONT / (width * height)), 1, 16))


SUPPORTED_EMITTERS = ("AreaLight", "PointLight", "SpotLight")
HINT = "render this scene with --method sppm"


def check_scene(scene: mi.Scene, sensor: mi.Sensor) -> None:
    """Refuse what the light and camera subpaths cannot start from or pass through (module
    docstring), in one line each."""
    refuse_media(scene, "vcm")
    for emitter in scene.emitters():
        kind = emitter.class_name()
        if kind not in SUPPORTED_EMITTERS:
            name = f" '{emitter.id()}'" if emitter.id() else ""
            raise SceneError(
                f"the vcm method starts light subpaths on area, point and spot lights only, not "
                f"on the scene's {kind}{name}: {HINT}"
            )
    kind = str(sensor).split("[")[0]
    if kind != "PerspectiveCamera":
        raise SceneError(
            f"the vcm method connects light subpaths to a pinhole camera (perspective); the "
            f"scene's sensor is a {kind}: {HINT}"
        )
    check_gathered_bsdfs(scene, "vcm")


BYTES_PER_PATH = 900  # per camera and light subpath pair: their loop states
SLOT_BYTES = 330  # per light subpath and slot of a chunk: the vertex slot and its compaction
VERTEX_BYTES = 400  # per vertex kept: the vertex, its sorted copy and the hash grid's


class VCMPipeline(Progressive, Pipeline):
    """Vertex connection and merging of a Mitsuba scene (name, XML path, dict or ``mi.Scene``).

    >>> pipe = VCMPipeline("examples/glass_sphere_plane.xml")
    >>> pipe.run(seconds=30)            # or: iterations=…, or pipe.step() in a loop
    >>> image = pipe.image()            # mi.TensorXf (height, width, 3)
    """

    method, params_type, stages = "vcm", VCMParams, STAGES
    progressive, radius_pixels = True, RADIUS_PIXELS

    def __init__(self, scene, **params):
        from ..scenes import load_with_sensor

        self.cache = StageCache()
        self.scene, self.sensor, own = load_with_sensor(scene, VCMParams, params)
        check_scene(self.scene, self.sensor)
        checked_powers(self.scene, 0)  # no light, a light that emits nothing, NaN
        self.emitters = Emitters.of(self.scene)
        self.file_settings = PathSettings.of(self.scene, scene)
        self.params = VCMParams()
        self._r1 = None
        self.set_params(**own)

    # ------------------------------------------------------------------------- settings
    def set_params(self, **params) -> None:
        """Change parameters (:class:`VCMParams` fields); the progressive state restarts."""
        new = updated(self.params, params, "vcm")
        self.check_memory(new)
        self.params = new
        self.reset()

    def set_camera(self, *args, **kwargs) -> None:
        super().set_camera(*args, **kwargs)
        check_scene(self.scene, self.sensor)
        self._r1 = None
        self.reset()

    @property
    def settings(self) -> PathSettings:
        p = self.params
        return overridden(self.file_settings, p.max_depth, p.rr_depth, p.hide_emitters)

    def check_memory(self, params: VCMParams | None = None, size=None) -> int:
        """Refuse settings that would not fit in memory (one iteration: the subpaths' state, a
        chunk's vertex slots and the vertices kept, about 4 per light subpath); return the
        estimate in bytes. On ``mi.cornell_box()`` at 256² with ``spp=4`` (262k subpaths of each
        kind, 3.1–3.2 vertices kept per light subpath) it is 1285 MB against a measured peak
        of 1060 MB (``max_depth`` 8) and 1278 MB (unbounded) above the process's start."""
        w, h = size or self.size
        paths = w * h * ((params or self.params).spp or auto_spp(w, h))
        parts = {
            "subpaths": paths * BYTES_PER_PATH,
            "light vertex slots": paths * CHUNK * SLOT_BYTES,
            "light vertices": paths * 4 * VERTEX_BYTES,
        }
        entries = {"subpaths × CHUNK vertex slots": paths * CHUNK}
        return check_memory("vcm", parts, "lower spp or the image size", entries)

    # ------------------------------------------------------------------------- iterations
    def radius_at(self, i: int) -> float:
        """``r_1 · i^((α−1)/2) / √spp``: a merge over ``spp`` light subpaths per pixel within
        a disk ``spp`` times smaller finds as many as SmallVCM's over one, so ``η_VCM = π r² N_L``
        — the weight of merging against connecting — and the merges' blur are those of one
        subpath per pixel (measured on ``mi.cornell_box()`` at 16 per pixel, 15 s: 4×4-block
        error 0.057 with ``r_i`` alone, 0.050 with SmallVCM's schedule at equal subpaths
        ``r_1 (i·spp)^((α−1)/2)``, 0.041 with this one; one subpath per pixel: 0.042)."""
        return super().radius_at(i) / math.sqrt(self.spp)

    @property
    def mean_radius(self) -> float:
        return self.radius_at(max(self.iterations, 1))

    @property
    def spp(self) -> int:
        """Camera subpaths per pixel and iteration (and light subpaths as many): ``spp``, or
        automatically about :data:`WAVEFRONT` of each per iteration, 1 to 16 per pixel (a
        wavefront that size spends little of its time in the per-iteration work: the loops'
        tracing, the sort of the light vertices, the hash grid)."""
        return self.params.spp or auto_spp(*self.size)

    def techniques(self, i: int) -> Techniques:
        w, h = self.size
        return Techniques(self.params.mode, w * h * self.spp, self.radius_at(i), self.spp)

    def reset(self) -> None:
        self._total = None
        self.iterations = 0
        self.stats = {"light_paths": 0, "camera_paths": 0, "light_vertices": 0}
        self.cache.new_frame()

    def iteration_image(self, i: int) -> np.ndarray:
        """Iteration ``i``'s image (H×W×3 float64): the camera subpaths' radiance and the light
        tracing splats (filtered by the film's filter, :func:`~.film_filter.filter_image`)."""
        check_once(self, self.params, self.size, self.check_memory)
        tech = self.techniques(i)
        light_seed, camera_seed = iteration_seeds(self.params.seed, i)
        settings = self.settings
        w, h = self.size
        run = self.cache.run
        light = None
        if tech.light_pass:
            light = run("light pass", lambda: light_pass(
                self.scene, self.sensor, light_seed, settings, tech, self.emitters
            ))  # fmt: skip
        vertices = light.vertices if light is not None and light.vertices.count else None
        radiance = run("camera pass", lambda: camera_pass(
            self.scene, self.sensor, camera_seed, settings, tech, vertices,
            MergeGrid.build(vertices, tech.radius) if tech.merge and vertices else None,
            self.emitters,
        ))  # fmt: skip
        image = to_numpy(radiance).astype(np.float64).T.reshape(h, w, 3)
        if light is not None and tech.light_tracing:
            image += filter_image(light.image, self.sensor.film())
        if vertices is not None:
            self.stats["light_vertices"] += vertices.count
        if light is not None:
            self.stats["light_paths"] += light.paths
        self.stats["camera_paths"] += w * h * tech.spp
        return image

    def step(self) -> None:
        """Run the next iteration and fold it into the image."""
        i = self.iterations + 1
        image = self.iteration_image(i)
        total = image if self._total is None else self._total + image
        self._total, self.iterations = total, i  # one assignment: Ctrl-C keeps a whole iteration

    def image(self) -> mi.TensorXf:
        """The mean of the iterations' images so far, ``(height, width, 3)``."""
        return self.finished(None if self._total is None else self._total / self.iterations)
