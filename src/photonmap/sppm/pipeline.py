"""``SPPMPipeline`` — stochastic progressive photon mapping (Hachisuka & Jensen 2009) and its
memoryless variant (Knaus & Zwicker 2011).

One iteration ``i`` (1-based) is an eye pass (:mod:`.visible`: ``spp`` visible points per pixel
and the direct term ``L_d``), a photon pass (:mod:`.photons`: ``photons`` paths)
and a gather at the visible points (:mod:`.gather`: a pixel's photon count and flux are the means
over its visible points, so one iteration with ``spp`` points is one SPPM pass whose estimate
has less variance). Its random numbers come from ``(seed, i)`` alone,
so an iteration's work is the same whatever ran before, and memory is one iteration's plus the
per-pixel state, whatever the number of iterations.

- ``mode="sppm"``: per-pixel radius ``R_j``, photon count ``N_j`` and flux ``τ_j``, updated after
  each iteration (α: the fraction of new photons kept).
- ``mode="memoryless"``: one radius ``r_i = r_1 · i^((α−1)/2)`` for all pixels; iteration ``i``
  is an ordinary photon-mapping image and the result their mean. Iterations are independent:
  :meth:`SPPMPipeline.render_block` renders any range of them as a :class:`BlockSums`, and
  blocks from anywhere merge into the same image (the basis of distributed rendering).

``radius = 0`` picks ``r_1`` automatically: :data:`RADIUS_PIXELS` pixel footprints at the median
distance of the surfaces the camera sees; in ``sppm`` mode the first iteration then shrinks each
pixel's radius to hold about :data:`FIRST_PHOTONS` photons (:meth:`.gather.PixelState.updated`:
small radii where photons are dense, in caustics), and path-traced eye paths, which read the
caustic photons with one radius, take at most the disk that holds about :data:`CAUSTIC_PHOTONS`
of them (:meth:`SPPMPipeline.initial_radius`). A given ``radius`` is every pixel's start.

**Path tracing with caustic photons** (``transport``; Jensen 1996's split of the light into
what path tracing samples well and the caustics, used progressively): with ``"paths"`` the eye
paths are path tracing throughout, as Mitsuba's ``path`` and ``volpath`` (:mod:`.visible`:
next-event estimation and BSDF samples under MIS, on through media) and the photon pass traces
the caustic photons alone (:mod:`.photons`: light that reached a surface or a medium through
mirrors and glass only, which no eye path finds; no photon pass without delta lobes), read at
every vertex of the eye paths: on surfaces within the iteration's global radius ``r_i``, in the
media within ``ρ_i = ρ_1 · i^((α−1)/3)`` (Knaus & Zwicker 2011's rule for 3-D estimates: the
variance of one estimate grows as ``1/ρ³``). The iterations are then memoryless in both modes.
``ρ_1``: ``volume_radius``, or the sphere that holds about :data:`FIRST_PHOTONS` of iteration 1's
caustic volume photons (at most :data:`VOLUME_RADIUS` × the scene diagonal). ``"auto"`` (the
default) path traces the scenes with participating media (visible points hold no medium) and
those without mirrors and glass: there no photon carries light that path tracing does not find,
and the method is exactly path tracing. ``"photons"``, and ``"auto"`` in every other scene:
visible points and photons, which measure as fast or faster on most such scenes (15 s each at
160 × 120, 100k photons, two seeds, 4×4-block error against Mitsuba references: the Cornell box
with a glass sphere 0.022 against ``"paths"``' 0.022–0.024, the glass knot 0.014–0.015 against
0.015–0.020, Veach's lamp in a reflector 0.023–0.028 against 0.10–0.13; but the glass sphere
over a plane 0.022–0.025 against 0.011–0.014).

**The scene file's settings**: ``max_depth``, ``rr_depth`` and ``hide_emitters`` default to the
file's ``<integrator>`` (:class:`~photonmap.core.settings.PathSettings`), with Mitsuba's meaning;
a photon counts at a visible point where the two paths together fit ``max_depth``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.bsdf import has_delta_lobes
from ..core.camera import scene_bounds
from ..core.emission import checked_powers
from ..core.errors import ParameterError
from ..core.eye_rules import Caustics, EyeRules
from ..core.media import emitter_media
from ..core.memory import check_once
from ..core.params import Renamed, check_choice, check_fields, check_range, updated
from ..core.photon_trace import PhotonRules
from ..core.pipeline import Pipeline
from ..core.progressive import Progressive, iteration_seeds
from ..core.scene_info import SceneTraits, check_gathered_bsdfs, warn_disagreeing_media
from ..core.settings import PathSettings, check_path_params, overridden
from ..core.stages import StageCache
from ..core.volume_map import VolumeMap, density_radius
from . import memory
from .gather import Gathered, PhotonGrid, PixelState, gather, iteration_image
from .photons import photon_pass
from .visible import eye_pass, mirror_pixels

MODES = ("sppm", "memoryless")
TRANSPORTS = ("auto", "photons", "paths")
STAGES = ("photon pass", "eye pass", "gather")
# automatic initial radius, in pixel footprints at the median eye distance (core.camera's
# footprint_radius, as vcm and the differentiable estimate): 4, larger than theirs, because the
# first iteration shrinks it per pixel to FIRST_PHOTONS photons, and photon mapping is the only
# technique that reads the photons (VCM's connections carry most light and merge in 1)
RADIUS_PIXELS = 4.0
FIRST_PHOTONS = 32.0  # sppm: after iteration 1 a pixel's disk holds about this many photons
VOLUME_RADIUS = 0.1  # automatic first volume radius ρ_1, × the scene diagonal
# path tracing with caustic photons: the automatic r_1 holds about this many of them (at most the
# footprint rule's). The glass sphere in the Cornell box (transport "paths", 128², 8 s, 4×4 error
# against path, same seed): 32, 128, 512 photons gave 0.052, 0.045, 0.049 at 452, 255, 348 ms an
# iteration (smaller disks, finer hash cells: slower); RADIUS_PIXELS footprints 0.097, 1529 ms
CAUSTIC_PHOTONS = 128
MAX_SPP = 64  # eye paths per pixel and iteration at most
AUTO_SPP = 16  # ... and at most when automatic
# automatic eye paths per iteration where the iteration is path tracing alone (no photon pass):
# an iteration's fixed cost (tracing the loop in Python, kernel launches) is then paid per 2^18
# paths. Samples per second, medians of 5 interleaved runs of equal samples (100k photons, which
# gave 5–6 paths per pixel): mi.cornell_box() at 128² (16 per pixel) +11 %, the diffuse room
# (14) +3 %
PATH_LANES = 2**18


@dataclass
class SPPMParams:
    """Parameters of the SPPM pipeline (the ``sppm`` plugin and ``--set`` keys)."""

    RENAMED: ClassVar[dict[str, Renamed]] = {"photons_per_iteration": Renamed("photons", int)}

    iterations: int = 64  # iterations of render() (run() takes its own budget)
    photons: int = 200_000  # photon paths traced per iteration (M)
    spp: int = 0  # eye paths per pixel and iteration; 0 = automatic (1; path tracing up to 16)
    radius: float = 0.0  # initial gather radius r_1 in scene units; 0 = automatic
    alpha: float = 2.0 / 3.0  # fraction of new photons kept (SPPM α), in (0, 1)
    seed: int = 0
    max_depth: int = 0  # longest path in segments (Mitsuba's); 0 = the scene's, -1 = unbounded
    rr_depth: int = 0  # depth where Russian roulette starts; 0 = the scene's
    hide_emitters: str = "scene"  # hide emitters seen directly: scene | true | false
    mode: str = "sppm"  # "sppm" (per-pixel radii) | "memoryless" (Knaus & Zwicker 2011)
    aim: float = 0.5  # fraction of the area lights' photons aimed at specular shapes (0 = none)
    volume_radius: float = 0.0  # scenes with media: first volume radius ρ_1; 0 = automatic
    transport: str = "auto"  # "photons" (visible points) | "paths" (path tracing) | "auto"

    def validate(self) -> None:
        """Types (:func:`~photonmap.core.params.check_fields`), then ranges and choices."""
        check_fields(self)
        check_range("iterations", self.iterations, 1, None, "SPPM iterations of render()")
        check_range("photons", self.photons, 1, None, "photon paths traced per iteration")
        check_range("spp", self.spp, 0, MAX_SPP, "eye paths per pixel and iteration; 0 = automatic")
        check_range("radius", self.radius, 0, None, "the initial gather radius; 0 = automatic")
        check_range("alpha", self.alpha, 0, 1, "SPPM's α (2/3 is usual)", True, True)
        check_path_params(self)
        check_range("aim", self.aim, 0, 1, "fraction of photons aimed at specular shapes",
                    hi_open=True)
        check_choice("mode", self.mode, MODES, "progressive per-pixel radii or memoryless")
        check_range("volume_radius", self.volume_radius, 0, None, "the first volume radius; 0 = auto")
        check_choice("transport", self.transport, TRANSPORTS,
                     "visible points and photons, or path tracing with caustic photons")


@dataclass
class BlockSums:
    """The sum of the images of memoryless iterations ``first … first + iterations − 1``:
    ``total`` (float64, H×W×3) and ``iterations``. Blocks of disjoint ranges merge by addition."""

    total: np.ndarray
    iterations: int

    def merge(self, other: BlockSums) -> BlockSums:
        if self.total.shape != other.total.shape:
            raise ParameterError(
                f"cannot merge blocks of different image sizes {self.total.shape[:2]} and "
                f"{other.total.shape[:2]}"
            )
        return BlockSums(self.total + other.total, self.iterations + other.iterations)

    def image(self) -> np.ndarray:
        """The mean of the iteration images (float32 H×W×3)."""
        if self.iterations < 1:
            raise ParameterError("an empty block (0 iterations) has no image")
        return (self.total / self.iterations).astype(np.float32)


class SPPMPipeline(Progressive, Pipeline):
    """Progressive photon mapping of a Mitsuba scene (name, XML path, dict or ``mi.Scene``).

    >>> pipe = SPPMPipeline("examples/glass_sphere_plane.xml", photons=100_000)
    >>> pipe.run(seconds=30)            # or: iterations=…, or pipe.step() in a loop
    >>> image = pipe.image()            # mi.TensorXf (height, width, 3)
    """

    method, params_type, stages = "sppm", SPPMParams, STAGES
    progressive, radius_pixels = True, RADIUS_PIXELS

    def __init__(self, scene, **params):
        from ..scenes import load_with_sensor

        self.cache = StageCache()  # its stages run anew each iteration (StageCache.run)
        self.scene, self.sensor, own = load_with_sensor(scene, SPPMParams, params)
        self.traits = SceneTraits.of(self.scene)
        if self.traits.media:
            warn_disagreeing_media(self.scene, "sppm")
        self.file_settings = PathSettings.of(self.scene, scene)
        self.emitter_media = emitter_media(self.scene)
        check_gathered_bsdfs(self.scene, "sppm")
        self.emitter_powers = checked_powers(self.scene, 0)
        self.delta_lobes = has_delta_lobes(self.scene)  # caustics possible
        self.params = SPPMParams()
        self.set_params(**own)
        self.stats: dict[str, float] = {}
        self._r1 = None
        self._rho1 = None  # the automatic first volume radius, once found
        self._r1_caustic = None  # the automatic r_1 of path-traced eye paths' caustic photons
        self.reset()

    def set_params(self, **params) -> None:
        """Change parameters (:class:`SPPMParams` fields); the progressive state restarts.
        Settings that would not fit in memory are refused (:meth:`check_memory`)."""
        new = updated(self.params, params, "sppm")
        if self.traits.media and new.transport == "photons":
            raise ParameterError(
                "transport='photons' cannot render participating media: their light is carried "
                "by path-traced eye paths; use transport='auto' (or 'paths')"
            )
        self.check_memory(new)
        self.params = new
        self._r1 = self._rho1 = self._r1_caustic = None
        self.reset()

    def set_camera(self, *args, **kwargs) -> None:
        super().set_camera(*args, **kwargs)
        self._r1 = self._r1_caustic = None
        self.reset()

    def check_memory(self, params: SPPMParams | None = None, size=None) -> int:
        """Raise a :class:`ParameterError` when ``params`` (default: the pipeline's) at ``size``
        (width, height; default: the camera's) would need more memory than is available
        (:mod:`.memory`); return the estimate in bytes."""
        p = params or self.params
        w, h = size or self.size
        depth = overridden(self.file_settings, p.max_depth, p.rr_depth, p.hide_emitters).max_depth
        return memory.check(p, w, h, depth, self.spp_for(p, w, h), self.traits.media)

    @property
    def settings(self) -> PathSettings:
        """The path-length settings: the file's, with this pipeline's parameters applied."""
        p = self.params
        return overridden(self.file_settings, p.max_depth, p.rr_depth, p.hide_emitters)

    def reset(self) -> None:
        """Forget all iterations (the next :meth:`step` is iteration 1)."""
        self._state = None  # PixelState (sppm) or BlockSums (memoryless)
        self._mirrors = None  # the pixels that may show a light in mirrors and glass, once found
        self.iterations = 0
        self.stats = {
            "photons": 0, "photon_records": 0, "gathers": 0, "aimed_photons": 0,
            "aimed_on_specular": 0.0, "volume_photons": 0, "photon_rays": 0, "eye_rays": 0,
        }  # fmt: skip
        self.cache.new_frame()

    @property
    def memoryless(self) -> bool:
        """Whether the iterations are memoryless: ``mode``, or path-traced eye paths, which read
        the caustic photons at every vertex with one radius per iteration."""
        return self.params.mode == "memoryless" or self.path_traced

    @property
    def path_traced(self) -> bool:
        """Whether the eye paths are path tracing that reads the caustic photons (module
        docstring, :meth:`traces_paths`)."""
        return self.traces_paths(self.params)

    def traces_paths(self, p: SPPMParams) -> bool:
        """Path tracing under ``p``: ``transport="paths"``, and ``"auto"`` in a scene with media
        or without mirrors and glass (where no caustic photon exists: no photon pass at all)."""
        return p.transport == "paths" or p.transport == "auto" and (
            self.traits.media or not self.delta_lobes
        )

    @property
    def eye_spp(self) -> int:
        """Eye paths per pixel and iteration under the pipeline's parameters (:meth:`spp_for`)."""
        return self.spp_for(self.params, *self.size)

    def spp_for(self, p: SPPMParams, w: int, h: int) -> int:
        """Eye paths per pixel and iteration under ``p`` at ``w`` × ``h``: ``spp``, or
        automatically one — and where the eye paths are path tracing, which carries the light
        itself, about as many eye paths as photon paths (pbrt's balance of SPPM's two passes), or
        :data:`PATH_LANES` where no photon is traced; 1 to :data:`AUTO_SPP`."""
        if p.spp:
            return p.spp
        if not self.traces_paths(p):
            return 1
        lanes = p.photons if self.delta_lobes else PATH_LANES
        return int(np.clip(round(lanes / (w * h)), 1, AUTO_SPP))

    # ------------------------------------------------------------------------- radii
    @property
    def mean_radius(self) -> float:
        """The current mean gather radius (per-pixel radii: their mean)."""
        if self.memoryless:
            return self.radius_at(max(self.iterations, 1))
        if self._state is None:
            return self.initial_radius()
        return float(dr.mean(self._state.radius, axis=None)[0])

    # ------------------------------------------------------------------------- one iteration
    def _photon_pass(self, i: int):
        """Iteration ``i``'s photon pass (random numbers from ``(seed, i)``): under path tracing
        the caustic photons alone (module docstring), none without delta lobes."""
        p = self.params
        if self.path_traced and not self.delta_lobes:
            return None
        rules = PhotonRules(self.settings, self.traits, caustics_only=self.path_traced)
        return photon_pass(
            self.scene, p.photons, iteration_seeds(p.seed, i)[1], p.aim, rules,
            self.emitter_media, self.emitter_powers,
        )  # fmt: skip

    def _passes(self, i: int, radius, timed: bool = True):
        """The photon pass and the eye pass of iteration ``i`` at ``radius`` (per pixel or one),
        ``timed`` as the pipeline's stages."""
        p = self.params
        check_once(self, p, self.size, self.check_memory)
        eye_seed, _ = iteration_seeds(p.seed, i)
        run = self.cache.run if timed else lambda _, compute: compute()
        photons = run("photon pass", lambda: self._photon_pass(i))
        rules = EyeRules(self.settings, self.traits, media_mode="continue",
                         surfaces="continue" if self.path_traced else "stop")  # fmt: skip
        points = run("eye pass", lambda: eye_pass(
            self.scene, self.sensor, eye_seed, rules, self.caustics(photons, i, radius),
            self.eye_spp, self.mirror_pixels(),
        ))  # fmt: skip
        return photons, points

    def _iteration(self, i: int, radius):
        """Eye pass, photon pass and gather of iteration ``i`` at ``radius`` (per pixel or one);
        path-traced eye paths read the caustic photons at ``radius`` themselves and
        no gather follows (the result's flux and count are zero)."""
        p, settings = self.params, self.settings
        photons, points = self._passes(i, radius)
        if self.path_traced:  # the eye paths read the caustic photons themselves
            w, h = self.size
            got = Gathered(dr.zeros(mi.Color3f, w * h), dr.zeros(mi.Float, w * h))
        else:
            got = self.cache.run("gather", lambda: gather(points, radius, photons, settings))
        if photons is not None:
            self.stats["photons"] += p.photons
            self.stats["photon_records"] += photons.count
            self.stats["aimed_photons"] += photons.aimed
            self.stats["aimed_on_specular"] += photons.caustic_fraction * photons.aimed
            self.stats["photon_rays"] += photons.rays
        self.stats["gathers"] += dr.width(points.found)
        self.stats["eye_rays"] += points.rays
        return points, got

    def photons_seen(self) -> float | None:
        """The share of the next iteration's photon records that lie within some visible point's
        gather radius — the photons the gather can use; the rest were traced for nothing (a
        diagnostic for the benchmarks: iteration ``iterations + 1`` is traced and not kept, and
        the photon's depth and the surface it lies on are not checked). None where the eye paths
        are path tracing (they read the photons at every vertex), in memoryless iterations and
        without photons."""
        if self.memoryless:
            return None
        w, h = self.size
        state = self._state or PixelState.start(w * h, self.initial_radius())
        photons, points = self._passes(self.iterations + 1, state.radius, timed=False)
        if photons is None or not photons.count:
            return None
        found = np.asarray(points.found, bool)
        where = np.asarray(points.si.p, np.float64).T[found]
        radius = np.repeat(np.asarray(state.radius, np.float64), points.spp)[found]
        if not len(where):
            return 0.0
        from scipy.spatial import cKDTree

        stored = cKDTree(np.asarray(photons.position, np.float64).T)
        pairs = cKDTree(where).sparse_distance_matrix(stored, radius.max(), output_type="coo_matrix")
        near = pairs.data < radius[pairs.row]
        return len(np.unique(pairs.col[near])) / photons.count

    def mirror_pixels(self) -> mi.UInt32 | None:
        """The pixels where the eye pass traces the lights' images in mirrors and glass
        (:func:`.visible.mirror_pixels`, found once per camera and :meth:`reset`); None in a
        scene without mirrors and glass."""
        if not self.delta_lobes:
            return None
        if self._mirrors is None:
            self._mirrors = mirror_pixels(self.scene, self.sensor)
        return self._mirrors

    def caustics(self, photons, i: int, radius) -> Caustics | None:
        """Iteration ``i``'s caustic photons as path-traced eye paths read them
        (:class:`~photonmap.core.eye_rules.Caustics`): at surfaces within ``radius``, in the
        media within ``ρ_i``; None under visible points or without photons."""
        if not self.path_traced or photons is None:
            return None
        surface = None
        if photons.count:
            grid = PhotonGrid.build(photons, radius)

            def surface(si, depth_left, active):
                return grid.radiance(si, radius, depth_left, active)

        return Caustics(self.volume_caustics(photons, i), surface)

    def initial_radius(self) -> float:
        """``r_1``: the ``radius`` parameter, or automatically :data:`RADIUS_PIXELS` pixel
        footprints (:meth:`~photonmap.core.progressive.Progressive.initial_radius`) — and where
        path-traced eye paths read the caustic photons with one radius, at most the disk that
        holds about :data:`CAUSTIC_PHOTONS` of iteration 1's (the median distance of the k-th
        nearest, as ``ρ_1``): caustic photons crowd into small bright regions, where a
        footprint-wide disk holds thousands of them, blurs the caustic and makes every read
        slow."""
        footprint = super().initial_radius()
        if self.params.radius > 0 or not (self.path_traced and self.delta_lobes):
            return footprint
        if self._r1_caustic is None:
            self._automatic_radii()
        return self._r1_caustic

    def _automatic_radii(self, first=None) -> None:
        """The automatic ``r_1`` of path-traced eye paths' caustic photons and ``ρ_1``, from
        iteration 1's photons (``first``, or traced here from ``(seed, 1)`` alone, so that
        memoryless blocks agree), both from one photon pass: the disk or sphere that holds about
        :data:`CAUSTIC_PHOTONS` or :data:`FIRST_PHOTONS` of them, within the footprint rule's
        ``r_1`` and the scene-wide bound."""
        first = first or self._photon_pass(1)
        footprint = super().initial_radius()
        self._r1_caustic = footprint
        if first.count:
            self._r1_caustic = density_radius(first.position, CAUSTIC_PHOTONS, footprint)
        bound = VOLUME_RADIUS * scene_bounds(self.scene)[1]
        self._rho1 = bound
        if first.volume is not None:
            self._rho1 = density_radius(first.volume.position, int(FIRST_PHOTONS), bound)

    def volume_radius_at(self, i: int) -> float:
        """``ρ_i = ρ_1 · i^((α−1)/3)``, the volume estimate's radius in iteration ``i`` (module
        docstring); ``ρ_1`` automatic until the first caustic volume photons are traced: the
        scene-wide bound :data:`VOLUME_RADIUS` × the diagonal."""
        p = self.params
        r1 = p.volume_radius or self._rho1 or VOLUME_RADIUS * scene_bounds(self.scene)[1]
        return r1 * i ** ((p.alpha - 1.0) / 3.0)

    def volume_caustics(self, photons, i: int):
        """Iteration ``i``'s caustic volume photons as the eye paths read them at medium
        collisions (:class:`~photonmap.core.eye_rules.Caustics`), or None where there are none. The
        automatic ``ρ_1`` is fixed by iteration 1's (whichever iterations run, so memoryless
        blocks agree): the sphere that holds about :data:`FIRST_PHOTONS` of them (the median
        distance of the k-th nearest), within the scene-wide bound."""
        if photons.volume is None:
            return None
        if not self.params.volume_radius and self._rho1 is None:
            self._automatic_radii(photons if i == 1 else None)
        radius = self.volume_radius_at(i)
        vmap = VolumeMap.build(photons.volume, cell_size=radius)
        self.stats["volume_photons"] += vmap.size
        stored = vmap.stored()

        def medium_light(mei, depth_left, active):
            return vmap.phase_sum(stored, mei, radius, depth_left, active)

        return medium_light

    def _memoryless_image(self, i: int) -> np.ndarray:
        radius = self.radius_at(i)
        points, got = self._iteration(i, radius)
        w, h = self.size
        return np.asarray(iteration_image(points, got, radius), np.float64).T.reshape(h, w, 3)

    def render_block(self, first: int, count: int) -> BlockSums:
        """The summed images of memoryless iterations ``first … first + count − 1`` (1-based;
        ``mode="memoryless"`` only). Independent of what was rendered before."""
        if not self.memoryless:
            raise ParameterError(
                "render_block needs independent iterations: set mode='memoryless' "
                f"(the pipeline's mode is {self.params.mode!r})"
            )
        if not (isinstance(first, int) and first >= 1 and isinstance(count, int) and count >= 1):
            raise ParameterError(
                f"render_block needs first >= 1 and count >= 1 (integers), got {first!r}, "
                f"{count!r}"
            )
        w, h = self.size
        total = np.zeros((h, w, 3))
        for i in range(first, first + count):
            total = total + self._memoryless_image(i)
        return BlockSums(total, count)

    def step(self) -> None:
        """Run the next iteration and fold it into the image."""
        i = self.iterations + 1
        if self.memoryless:
            w, h = self.size
            state = self._state or BlockSums(np.zeros((h, w, 3)), 0)
            new = state.merge(BlockSums(self._memoryless_image(i), 1))
        else:
            w, h = self.size
            state = self._state or PixelState.start(w * h, self.initial_radius())
            points, got = self._iteration(i, state.radius)
            automatic = state.iterations == 0 and self.params.radius == 0
            target = FIRST_PHOTONS if automatic else None
            new = state.updated(points, got, self.params.alpha, target)
        self._state, self.iterations = new, i  # one assignment: Ctrl-C keeps a whole iteration

    def image(self) -> mi.TensorXf:
        """The image of the iterations so far, ``(height, width, 3)`` linear radiance."""
        if self._state is None or self.memoryless:
            return self.finished(None if self._state is None else self._state.image())
        w, h = self.size
        return self.finished(np.asarray(self._state.image(), np.float32).T.reshape(h, w, 3))
