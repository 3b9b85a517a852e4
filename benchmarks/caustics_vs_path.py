"""Progressive photon mapping (``sppm``, Hachisuka & Jensen 2009) and vertex connection and
merging (``vcm``, Georgiev et al. 2012) against Mitsuba's ``path`` (and the two-pass
``surface`` method) on caustic scenes: time to equal error.

Scenes (``--scenes``, default all), each rendered by every method with the same ``max_depth``
(the scene's own ``<integrator>``'s, 12 where it has none or an unbounded one, unless fixed
here):

- ``glass_sphere`` (examples/glass_sphere_plane.xml): a glass ball on a plane under a small
  spherical area light; max_depth 12.
- ``glass_knot`` (examples/glass_knot_plane.xml): a procedural glass trefoil knot of 4088
  triangles; 12.
- ``cornell`` (the built-in ``cornell_steinhurst``): Cornell box with a glass and a mirror
  sphere; 12.
- ``cornell_box``: ``mi.cornell_box()`` itself (two diffuse boxes, gaussian film filter); its 8.
- ``cornell_glass`` (examples/cornell_glass_sphere.xml): ``mi.cornell_box()`` without its boxes,
  with a glass sphere on the floor (box filter); 32.
- ``glass_mesh`` (examples/glass_mesh_glints.xml): a faceted glass gem whose glints are light
  totally internally reflected several times, so they need paths of more than 8 segments;
  fixed at 24.
- ``veach_lamp`` (examples/veach_lamp.xml): a room lit off the ceiling by a sphere light hidden
  in an aluminium bowl, a glass egg on a table; 32.
- ``pool`` (examples/pool.xml): a wavy water surface over a diffuse pool floor seen from above,
  a small sphere light: the caustic on the floor is seen through the water (L S D S E); 12.
- ``diffuse_room`` (examples/diffuse_room.xml): a diffuse room and furniture under a large
  ceiling light, no mirror or glass; 8.

References (:func:`reference`): ``path`` at ``--ref-spp`` samples per pixel in two halves of
different seeds, blended in the pixels where the camera sees only smooth surfaces with Mitsuba's
``ptracer`` at a quarter of the samples (light paths connected to the camera: it finds the
caustics seen directly that ``path`` finds by chance) by inverse-variance weights from
independent pilot renders (:func:`accuracy.blend_weights`) — where the two agree: where their
means over those pixels differ by more than :data:`BLEND_AGREEMENT` (``cornell_steinhurst``:
Mitsuba's ``ptracer`` renders 0.08× of ``path``'s light there), ``path`` alone serves and
``reference_blend`` says so. Where ``ptracer`` cannot serve (the camera sees glass or a
mirror first), ``path`` alone is the reference, and its noise there (caustics seen through
glass) is most of the reference's: ``path`` renders the bounding box of those pixels again, as a
crop of the film, at :data:`DEEP_SHARE` times the samples, averaged in by sample count
(``reference_blend["deep"]``: the window and its samples per pixel; skipped where the box covers
more than :data:`DEEP_MAX_AREA` of the image). All cached in ``results/cache/`` (not in git; the
file names hold the scene, size, max_depth, spp and window). The halves' difference estimates the
reference's own error, reported as ``reference_rel_rmse`` and ``reference_block_rel_rmse``.

Methods (``--methods``, default ``path,sppm,vcm,surface``): ``path`` at 4 … 4096 spp (timed
renders); ``sppm`` and ``vcm`` for ``--seconds`` each, one run of the progressive pipeline each
(:func:`run_progressive`: a class made as ``cls(scene, **params)`` with ``step()``,
``image()``, ``iterations``, ``timer.ms`` and ``stats``; a warm-up run with the same parameters
first compiles the kernels), their errors measured at checkpoints with the clock stopped;
``surface`` at a few budgets. Each scene is run ``--runs`` times (default 3) after its
reference, the methods interleaved (run 1 of each, then run 2 of each, …; seeds differ per
run); a scene's headline is the median of its runs' headlines. ``vcm`` is
``photonmap.vcm.VCMPipeline(scene, max_depth=…, seed=…)``, imported only when it is asked for.
Errors: relative RMSE per pixel and of 4×4-pixel block means, over the pixels that do not see
a light directly or through mirrors and glass (:func:`accuracy.light_image_mask`: a light's
image is antialiasing noise of the eye samples, the same for every method); whole-image values
are kept.

Headline per scene (keys whose methods did not run are None):

- ``speedup_vs_path_at_equal_rmse``: the time ``path`` needs (log-log interpolation, ``t^-1/2``
  past its last budget: :func:`accuracy.loglog_time_for`) for the error ``sppm`` reaches in
  ``--seconds``, divided by ``--seconds``; the same against the truth (``..._vs_truth``: the
  reference's own error, which both methods' errors contain, subtracted in quadrature — it
  compresses the raw ratio once ``sppm`` nears it) and for 4×4 block errors
  (``speedup_vs_path_at_equal_block_rmse``, also named
  ``sppm_speedup_vs_path_at_equal_block_rmse``);
- ``vcm_speedup_vs_path_at_equal_block_rmse`` and ``vcm_speedup_vs_sppm_at_equal_block_rmse``:
  the time ``path`` (its spp curve) and ``sppm`` (its checkpoint rows) need for the 4×4-block
  error ``vcm`` reaches at the end, read off their curves the same way, divided by ``vcm``'s
  seconds; ``vcm_…`` and ``sppm_speedup_vs_path_at_equal_block_rmse_vs_truth``: the same with
  the reference's own 4×4-block error subtracted in quadrature from every curve (at 30 s both
  progressive methods come within 1.5–2× of it, which compresses the raw ratios);
- rates: ``photons_per_s`` and ``gathers_per_s`` of the SPPM run; ``light_paths_per_s`` and
  ``camera_paths_per_s`` of the VCM run (its ``stats`` over its ``"light pass"`` and
  ``"camera pass"`` stage times); ``ray_intersect_per_s``, Mitsuba's own ray casting on the
  scene (:func:`ray_intersect_rate`, measured in the same run), the yardstick for both;
- against that limit: ``photon_pass_ray_fraction`` and ``eye_pass_ray_fraction``, the rays the
  SPPM passes cast per second of their stage (path segments and shadow rays, the pipeline's
  ``photon_rays`` and ``eye_rays``) over ``ray_intersect_per_s``; ``photons_seen``, the share of
  an iteration's photon records within some visible point's gather radius
  (``SPPMPipeline.photons_seen``, at the run's final radii; None where the eye paths are path
  tracing); ``sppm_/vcm_kernels_compiled_per_iteration``, the kernels the warm-up pipeline's
  iterations after its first :data:`WARM_STEPS` traced anew, per iteration (target 0);
- ``reference_ok``: the reference's own 4×4-block error at most a third of the smallest 4×4
  error compared (the progressive methods' final ones, over the runs); where it is not, the
  scene's speedups are None — no reportable ratio, a missed goal. ``goal`` and ``goal_met``:
  5× ``path`` where the scene has mirrors or glass, 0.9× on the plain ones (:data:`PLAIN`), for
  the faster of ``sppm`` and ``vcm`` (``best_speedup_vs_path_at_equal_block_rmse``).

The top-level headline holds the per-scene values of the speedups and rates and the minimum of
each over the scenes.

Writes ``results/caustics_vs_path.json``, ``.md`` (every row; budgets: spp, iterations and
radius, photon paths), ``.png`` (error against time, a panel per scene, a colour per method:
per-pixel relative RMSE solid, 4×4-block dashed) and each scene's last progressive images
``caustics_<scene>_<sppm|vcm>.png`` (``_quick`` with ``--quick``: tiny images, 8 iterations
each). ``--iterations N`` gives each progressive method ``N`` iterations instead of
``--seconds`` (errors after 1, 2, 4, 8, … of them).

    .venv/bin/python benchmarks/caustics_vs_path.py [--quick] [--seconds 30 | --iterations N] \\
        [--methods path,sppm,vcm,surface] [--scenes glass_mesh,veach_lamp]
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

import report
from accuracy import (
    blend_weights,
    cached_image,
    cropped,
    errors,
    light_image_mask,
    loglog_time_for,
    mitsuba_curve,
    reference_noise,
    render_passes,
    vs_truth,
)
from photonmap.core.image import write_image
from photonmap.core.sampling import rng
from photonmap.core.settings import UNBOUNDED, PathSettings
from photonmap.scenes import load_scene
from timing import Budget, checkpoints, kernel_history, median, timed

NAME = "caustics_vs_path"
EXAMPLES = report.REPO / "examples"


@dataclass(frozen=True)
class Scene:
    """A benchmark scene: ``source`` for :func:`photonmap.scenes.load_scene` (or a function
    returning one), the image size of a full and of a quick run, ``max_depth`` (None: the
    scene's own, :data:`DEFAULT_MAX_DEPTH` where that is unbounded) and the most samples per
    pixel its reference takes (None: ``--ref-spp``)."""

    source: str | Callable[[], dict]
    size: tuple[int, int]
    quick_size: tuple[int, int]
    max_depth: int | None = None
    reference_spp: int | None = None


SCENES = {
    "glass_sphere": Scene(str(EXAMPLES / "glass_sphere_plane.xml"), (160, 120), (48, 36)),
    "glass_knot": Scene(str(EXAMPLES / "glass_knot_plane.xml"), (160, 120), (48, 36)),
    "cornell": Scene("cornell_steinhurst", (128, 128), (40, 40)),
    "cornell_box": Scene(lambda: mi.cornell_box(), (128, 128), (40, 40)),
    "cornell_glass": Scene(str(EXAMPLES / "cornell_glass_sphere.xml"), (128, 128), (40, 40)),
    # its glints need paths of more than 8 segments: never below 24
    "glass_mesh": Scene(str(EXAMPLES / "glass_mesh_glints.xml"), (160, 120), (48, 36), 24),
    "veach_lamp": Scene(str(EXAMPLES / "veach_lamp.xml"), (160, 120), (48, 36)),
    # most pixels see the floor through the water, where path alone serves and converges
    # slowly at any affordable count (the reference check says whether it is good enough)
    "pool": Scene(str(EXAMPLES / "pool.xml"), (160, 120), (48, 36), reference_spp=16384),
    # diffuse: path converges quickly
    "diffuse_room": Scene(str(EXAMPLES / "diffuse_room.xml"), (160, 120), (48, 36),
                          reference_spp=16384),  # fmt: skip
}
PLAIN = ("cornell_box", "diffuse_room")  # no mirror or glass: par with path is the goal
GOAL_SPECULAR, GOAL_PLAIN = 5.0, 0.9  # speedup against path at equal 4×4-block error
REFERENCE_SHARE = 1 / 3  # the reference's own 4×4 error, at most this share of the smallest
WARM_STEPS, PROBE_STEPS = 2, 3  # warm-up iterations that compile, then that are counted
DEFAULT_MAX_DEPTH = 12
CHECKPOINTS = (1, 2, 4, 8, 15, 30, 60, 120)  # seconds of compute at which errors are taken
QUICK_ITERATIONS = 8  # --quick: iterations of each progressive method (a count, not seconds)
# surface budgets: (global photon paths, caustic photon paths, final-gather rays, spp)
BUDGETS = [(50_000, 300_000, 4, 2), (100_000, 1_000_000, 8, 4), (200_000, 2_000_000, 8, 8)]
QUICK_BUDGETS = [(20_000, 50_000, 2, 1)]
METHODS = ("path", "sppm", "vcm", "surface")
LABELS = {"path": "Mitsuba path", "sppm": "sppm", "vcm": "vcm", "surface": "surface"}
COLORS = {"path": "C0", "sppm": "C1", "vcm": "C3", "surface": "C2"}
VCM_SEED = 1
RAYS, QUICK_RAYS = 1 << 20, 1 << 16  # camera rays of ray_intersect_rate


# ------------------------------------------------------------------------------------ scenes
def load(name: str, size) -> mi.Scene:
    """Scene ``name`` of :data:`SCENES` with its film set to ``size``."""
    source = SCENES[name].source
    scene, _ = load_scene(source() if callable(source) else source)
    params = mi.traverse(scene.sensors()[0])
    params["film.size"] = size
    params["film.crop_size"] = size
    params.update()
    return scene


def max_depth_of(name: str, scene: mi.Scene) -> int:
    """The ``max_depth`` every method renders scene ``name`` with (:class:`Scene`)."""
    fixed = SCENES[name].max_depth
    if fixed is not None:
        return fixed
    depth = PathSettings.of(scene).max_depth
    return DEFAULT_MAX_DEPTH if depth == UNBOUNDED else depth


def path_integrator(max_depth: int, kind: str = "path"):
    return mi.load_dict({"type": kind, "max_depth": max_depth})


TRACER_SHARE, PILOT_SHARE = 4, 64  # ptracer's samples and the pilots' (each), of the reference's
BLEND_AGREEMENT = 0.02  # ptracer's and path's means where blended: at most this far apart
# path's samples again, ×, over the bounding box of the pixels ptracer does not serve (seen
# through glass, in mirrors), where that box is at most DEEP_MAX_AREA of the image
DEEP_SHARE, DEEP_MAX_AREA = 4, 0.5


def camera_sees_smooth(scene) -> np.ndarray:
    """Pixels whose neighbourhood (the film filter's reach and a pixel) shows no light, mirror,
    glass or ``null`` boundary first (the complement of :func:`photonmap.sppm.visible.mirror_pixels`):
    there ``ptracer``, which reaches the camera from smooth surfaces only, renders what ``path``
    renders."""
    from photonmap.sppm.visible import mirror_pixels

    sensor = scene.sensors()[0]
    w, h = (int(c) for c in sensor.film().crop_size())
    shown = np.zeros(w * h, bool)
    shown[np.asarray(mirror_pixels(scene, sensor), np.int64)] = True
    return ~shown.reshape(h, w)


def reference(name, scene, size, spp, max_depth, cache: Path) -> tuple[list[np.ndarray], dict]:
    """The two halves of the reference at ``spp`` samples per pixel (cached; module docstring):
    ``path``'s, blended with ``ptracer``'s where :func:`camera_sees_smooth` and the two agree,
    then deepened where ``ptracer`` cannot serve (:func:`deepened`); and ``{"blended",
    "ptracer_over_path", "deep"}`` (the ratio of their means where blended; the deep window)."""
    stem = f"caustics_{name}_{size[0]}x{size[1]}_d{max_depth}_{spp}spp"

    def halves(kind: str, samples: int, seed: int, tag: str = "", box=None) -> list[np.ndarray]:
        def render(half):
            return render_passes(
                scene, samples // 2, 512, seed * (half + 1), path_integrator(max_depth, kind)
            )

        return [
            cached_image(
                cache / f"{stem}{tag}_{half}.exr",
                lambda h=half: render(h) if box is None else cropped(scene, box, lambda: render(h)),
            ).astype(np.float64)
            for half in (0, 1)
        ]

    path = halves("path", spp, 100_000)
    where = camera_sees_smooth(scene)
    info = {"blended": False, "ptracer_over_path": None}
    if where.any():
        tracer = halves("ptracer", spp // TRACER_SHARE, 300_000, "_ptracer")
        ratio = float(sum(t[where].mean() for t in tracer) / sum(p[where].mean() for p in path))
        info = {"blended": abs(ratio - 1) <= BLEND_AGREEMENT, "ptracer_over_path": ratio}
        if info["blended"]:
            pilot = spp // PILOT_SHARE  # at the same ratio of samples as path and ptracer above
            w = blend_weights(halves("path", pilot, 1_000_000, "_pilot_path"),
                              halves("ptracer", pilot // TRACER_SHARE, 3_000_000, "_pilot_ptracer"),
                              where)  # fmt: skip
            path = [w * p + (1 - w) * t for p, t in zip(path, tracer, strict=True)]
        else:
            print(f"  ptracer renders {ratio:.3f}x path where both see: path alone", flush=True)
            where[:] = False  # path alone everywhere: deepen wherever it is alone
    reach = math.ceil(float(scene.sensors()[0].film().rfilter().radius())) + 1
    window = deep_window(where, reach)
    info["deep"] = None
    if window is not None:
        box, inner = window
        tag = f"_deep{DEEP_SHARE}x_{'_'.join(str(c) for c in box)}"
        deep = halves("path", spp * DEEP_SHARE, 200_000, tag, box)
        path = deepened(path, deep, where, box, inner)
        info["deep"] = {"window": list(inner), "spp": spp * DEEP_SHARE}
    return path, info


def deep_window(where: np.ndarray, reach: int):
    """``(box, inner)``: ``inner`` the bounding box ``(x0, y0, x1, y1)`` of the pixels outside
    ``where`` (those ``path`` alone estimates), ``box`` that grown by ``reach`` pixels (the film
    filter's, and one) within the image; None where there are none, or where ``inner`` covers
    more than :data:`DEEP_MAX_AREA` of the image (a deep pass there costs ``DEEP_SHARE`` whole
    references)."""
    ys, xs = np.nonzero(~where)
    if not len(xs):
        return None
    h, w = where.shape
    inner = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    if (inner[2] - inner[0]) * (inner[3] - inner[1]) > DEEP_MAX_AREA * w * h:
        return None
    box = (max(0, inner[0] - reach), max(0, inner[1] - reach),
           min(w, inner[2] + reach), min(h, inner[3] + reach))  # fmt: skip
    return box, inner


def deepened(halves, deep, where, box, inner) -> list[np.ndarray]:
    """``halves`` with ``path``'s deep pass (``deep``: two halves rendered in the crop ``box``
    at :data:`DEEP_SHARE` times the samples) averaged in by sample count over the pixels of
    ``inner`` outside ``where``. ``box`` reaches past ``inner`` by the filter's reach: a crop's
    edge pixels miss the splats of the samples beyond it, so only its interior is used."""
    x0, y0, x1, y1 = inner
    alone = ~where[y0:y1, x0:x1, None]
    out = []
    for half, extra in zip(halves, deep, strict=True):
        half = half.copy()
        inside = extra[y0 - box[1] : y1 - box[1], x0 - box[0] : x1 - box[0]]
        mixed = (half[y0:y1, x0:x1] + DEEP_SHARE * inside) / (1 + DEEP_SHARE)
        half[y0:y1, x0:x1] = np.where(alone, mixed, half[y0:y1, x0:x1])
        out.append(half)
    return out


# ----------------------------------------------------------------------------------- methods
def compiled_per_iteration(pipe, steps: int = PROBE_STEPS) -> float:
    """The kernels ``steps`` more iterations of ``pipe`` trace anew (not in memory: compiled, or
    loaded from Dr.Jit's disk cache), per iteration."""
    with kernel_history() as launches:
        for _ in range(steps):
            pipe.step()
    return sum(k["type"] == "JIT" and not k.get("in_memory", True) for k in launches) / steps


def run_progressive(label: str, cls, scene, score, budget: Budget, params: dict,
                    extra: Callable | None = None):  # fmt: skip
    """One run of the progressive pipeline ``cls(scene, **params)`` for ``budget`` (seconds of
    compute in calls of ``step()``, or a number of them), after a warm-up pipeline with the same
    parameters: its first :data:`WARM_STEPS` steps compile the kernels (iteration 1 has kernels of
    its own: SPPM's photon-density start), its next :data:`PROBE_STEPS` count the kernels an
    iteration traces anew (:func:`compiled_per_iteration`). At each checkpoint (of
    :data:`CHECKPOINTS`, or after 1, 2, 4, … steps) the clock stops and a row is taken:
    ``iterations``, ``seconds``, ``extra(pipe)`` and ``score(image)``. Returns the rows, the
    run's ``timer.ms`` and ``stats`` (with ``kernels_compiled_per_iteration``), the pipeline and
    its last image."""
    warm = cls(scene, **params)
    for _ in range(WARM_STEPS):
        warm.step()
    compiled = compiled_per_iteration(warm)
    del warm
    pipe = cls(scene, **params)
    rows = []
    for spent in checkpoints(pipe.step, budget, CHECKPOINTS):
        image = np.array(pipe.image())
        rows.append({"iterations": pipe.iterations, "seconds": spent,
                     **(extra(pipe) if extra else {}), **score(image)})  # fmt: skip
        print(f"  {label} {pipe.iterations} it: {spent:.1f} s, rel RMSE "
              f"{rows[-1]['rel_rmse']:.4f}", flush=True)  # fmt: skip
    stats = {**pipe.stats, "kernels_compiled_per_iteration": compiled}
    return rows, dict(pipe.timer.ms), stats, pipe, image


def per_second(count, ms: dict, stage: str):
    """``count`` over the seconds of ``stage`` (None without that stage)."""
    return count / (ms[stage] / 1e3) if ms.get(stage) else None


def run_sppm(scene, score, budget: Budget, photons: int, max_depth: int, seed: int, rays: float):
    """SPPM for ``budget``: rows (with the mean gather radius), rates (the passes' ray rates as
    fractions of ``rays``, Mitsuba's ray casting per second) and the last image."""
    from photonmap.sppm import SPPMPipeline

    rows, ms, stats, pipe, image = run_progressive(
        "sppm", SPPMPipeline, scene, score, budget,
        {"photons": photons, "max_depth": max_depth, "seed": seed},
        extra=lambda pipe: {"mean_radius": pipe.mean_radius},
    )  # fmt: skip
    photon_rays = per_second(stats["photon_rays"], ms, "photon pass") if stats["photons"] else None
    eye_rays = per_second(stats["eye_rays"], ms, "eye pass")
    rates = {
        "photons_per_s": per_second(stats["photons"], ms, "photon pass"),
        "gathers_per_s": per_second(stats["gathers"], ms, "gather"),
        "eye_paths_per_s": per_second(stats["gathers"], ms, "eye pass"),
        "photon_rays_per_s": photon_rays,
        "eye_rays_per_s": eye_rays,
        "photon_pass_ray_fraction": photon_rays and photon_rays / rays,
        "eye_pass_ray_fraction": eye_rays and eye_rays / rays,
        "photons_seen": pipe.photons_seen(),
        "kernels_compiled_per_iteration": stats["kernels_compiled_per_iteration"],
        "aimed_fraction_on_specular": (
            stats["aimed_on_specular"] / stats["aimed_photons"] if stats["aimed_photons"] else None
        ),
        "stages_ms": ms,
        "stats": stats,
    }
    return rows, rates, image


def run_vcm(scene, score, budget: Budget, max_depth: int, seed: int):
    """VCM for ``budget``: rows (with the merging radius), rates and the last image."""
    from photonmap.vcm import VCMPipeline

    rows, ms, stats, _, image = run_progressive(
        "vcm", VCMPipeline, scene, score, budget, {"max_depth": max_depth, "seed": seed},
        extra=lambda pipe: {"radius": pipe.mean_radius},
    )  # fmt: skip
    rates = {
        "kernels_compiled_per_iteration": stats["kernels_compiled_per_iteration"],
        "light_paths_per_s": per_second(stats["light_paths"], ms, "light pass"),
        "camera_paths_per_s": per_second(stats["camera_paths"], ms, "camera pass"),
        "light_vertices_per_light_path": (
            stats["light_vertices"] / stats["light_paths"] if stats["light_paths"] else None
        ),
        "stages_ms": ms,
        "stats": stats,
    }
    return rows, rates, image


def run_surface(scene, score, budgets, max_depth: int):
    from photonmap.surface.pipeline import SurfacePipeline

    SurfacePipeline(scene, photons=1000, caustic_photons=1000, fg_rays=1,
                    max_depth=max_depth).render()  # compile  # fmt: skip
    rows = []
    for photons, caustic, fg, spp in budgets:
        pipe = SurfacePipeline(scene, photons=photons, caustic_photons=caustic, fg_rays=fg,
                               spp=spp, max_depth=max_depth)  # fmt: skip
        t, image = timed(lambda p=pipe: np.array(p.render()))
        rows.append({"photons": photons, "caustic_photons": caustic, "fg_rays": fg, "spp": spp,
                     "seconds": t, **score(image)})  # fmt: skip
        print(f"  surface {photons}/{caustic}/{fg}/{spp}: {t:.2f} s, "
              f"rel RMSE {rows[-1]['rel_rmse']:.4f}", flush=True)  # fmt: skip
    return rows


def ray_intersect_rate(scene, rays: int, repeats: int = 3, seed: int = 0) -> dict:
    """Mitsuba's own ray casting on ``scene``, in rays per second: ``scene.ray_intersect`` on
    ``rays`` camera rays through uniformly random film positions, then on one bounce ray from
    each surface point they hit, in a cosine-distributed direction about its shading normal.
    The rays of both batches are made and evaluated before the clock starts; each batch's clock
    stops after ``dr.eval`` of its whole ``SurfaceInteraction`` (and Dr.Jit's queue is empty).
    Rate = rays cast / seconds of both batches; median of ``repeats`` runs after an untimed one
    (kernel compilation)."""
    sensor = scene.sensors()[0]
    gen = rng(rays, seed, 0)
    film = mi.Point2f(gen.next_float32(), gen.next_float32())
    ray, _ = sensor.sample_ray(0.0, 0.5, film, mi.Point2f(0.5))
    dr.eval(ray)

    def cast(r):
        si = scene.ray_intersect(r)
        dr.eval(si)
        return si

    si = cast(ray)
    hit = dr.compress(si.is_valid())
    si = dr.gather(type(si), si, hit)
    local = mi.warp.square_to_cosine_hemisphere(
        mi.Point2f(*(dr.gather(mi.Float, gen.next_float32(), hit) for _ in range(2)))
    )
    bounce = si.spawn_ray(si.to_world(local))
    dr.eval(bounce)
    count = rays + dr.width(bounce)
    samples = []
    for _ in range(repeats + 1):
        seconds = timed(cast, ray)[0] + timed(cast, bounce)[0]
        samples.append(count / seconds)
    return {"camera_rays": rays, "bounce_rays": dr.width(bounce),
            "ray_intersect_per_s": median(samples[1:]), "samples": samples[1:]}  # fmt: skip


# ------------------------------------------------------------------------------------ scoring
def time_for(rows, final, key: str = "rel_rmse") -> float | None:
    """The time the curve ``rows`` needs for the error ``final[key]`` (log-log,
    :func:`accuracy.loglog_time_for`); None without either or if it never gets there."""
    if not rows or final is None:
        return None
    t = loglog_time_for(rows, final[key], key)
    return float(t) if t else None


def time_ratio(rows, final, key: str = "block_rel_rmse") -> float | None:
    """:func:`time_for` over ``final["seconds"]``: the speedup of ``final``'s method."""
    t = time_for(rows, final, key)
    return t / final["seconds"] if t else None


def scene_headline(res: dict) -> dict:
    """The headline of one scene's result ``res`` (module docstring)."""
    path, sppm, vcm, surface = (res.get(m, []) for m in METHODS)
    s_final, v_final = (sppm[-1] if sppm else None), (vcm[-1] if vcm else None)
    t_path = time_for(path, s_final)
    s_rates, v_rates = res.get("sppm_rates", {}), res.get("vcm_rates", {})
    sppm_block = time_ratio(path, s_final)
    return {
        "sppm_rel_rmse": s_final and s_final["rel_rmse"],
        "path_seconds_for_that_error": t_path,
        "speedup_vs_path_at_equal_rmse": t_path / s_final["seconds"] if t_path else None,
        "speedup_vs_path_at_equal_rmse_vs_truth": time_ratio(path, s_final, "rel_rmse_vs_truth"),
        "speedup_vs_path_at_equal_block_rmse": sppm_block,
        "sppm_speedup_vs_path_at_equal_block_rmse": sppm_block,
        "surface_seconds_for_that_error": time_for(surface, s_final),
        "vcm_rel_rmse": v_final and v_final["rel_rmse"],
        "vcm_block_rel_rmse": v_final and v_final["block_rel_rmse"],
        "vcm_speedup_vs_path_at_equal_block_rmse": time_ratio(path, v_final),
        "vcm_speedup_vs_sppm_at_equal_block_rmse": time_ratio(sppm, v_final),
        "sppm_speedup_vs_path_at_equal_block_rmse_vs_truth": time_ratio(
            path, s_final, "block_rel_rmse_vs_truth"
        ),
        "vcm_speedup_vs_path_at_equal_block_rmse_vs_truth": time_ratio(
            path, v_final, "block_rel_rmse_vs_truth"
        ),
        "best_speedup_vs_path_at_equal_block_rmse": max(
            (r for r in (sppm_block, time_ratio(path, v_final)) if r is not None), default=None
        ),
        "photons_per_s": s_rates.get("photons_per_s"),
        "gathers_per_s": s_rates.get("gathers_per_s"),
        "aimed_fraction_on_specular": s_rates.get("aimed_fraction_on_specular"),
        "photon_pass_ray_fraction": s_rates.get("photon_pass_ray_fraction"),
        "eye_pass_ray_fraction": s_rates.get("eye_pass_ray_fraction"),
        "photons_seen": s_rates.get("photons_seen"),
        "sppm_kernels_compiled_per_iteration": s_rates.get("kernels_compiled_per_iteration"),
        "vcm_kernels_compiled_per_iteration": v_rates.get("kernels_compiled_per_iteration"),
        "light_paths_per_s": v_rates.get("light_paths_per_s"),
        "camera_paths_per_s": v_rates.get("camera_paths_per_s"),
        "ray_intersect_per_s": res["ray_intersect"]["ray_intersect_per_s"],
    }


SPEEDUPS = (
    "speedup_vs_path_at_equal_rmse", "speedup_vs_path_at_equal_rmse_vs_truth",
    "speedup_vs_path_at_equal_block_rmse", "sppm_speedup_vs_path_at_equal_block_rmse",
    "vcm_speedup_vs_path_at_equal_block_rmse", "vcm_speedup_vs_sppm_at_equal_block_rmse",
    "sppm_speedup_vs_path_at_equal_block_rmse_vs_truth",
    "vcm_speedup_vs_path_at_equal_block_rmse_vs_truth", "best_speedup_vs_path_at_equal_block_rmse",
)  # fmt: skip


def median_headline(runs: list[dict]) -> dict:
    """Each key's median over the runs' headlines (over the runs where it is not None; None
    where it is None in all)."""
    out = {}
    for key in runs[0]:
        values = [r[key] for r in runs if r[key] is not None]
        out[key] = float(np.median(values)) if values else None
    return out


def reference_check(name: str, res: dict) -> dict:
    """``reference_ok``, ``goal`` and ``goal_met`` of scene ``name`` (module docstring); where
    the reference is too noisy to judge, the headline's speedups become None."""
    finals = [r[m][-1]["block_rel_rmse"] for r in res["runs"] for m in ("sppm", "vcm") if r.get(m)]
    smallest = min(finals, default=None)
    ok = smallest is None or res["reference_block_rel_rmse"] <= REFERENCE_SHARE * smallest
    h = res["headline"]
    if not ok:
        h.update({key: None for key in SPEEDUPS})
    goal = GOAL_PLAIN if name in PLAIN else GOAL_SPECULAR
    best = h["best_speedup_vs_path_at_equal_block_rmse"]
    return {"reference_ok": ok, "smallest_block_rel_rmse": smallest, "goal": goal,
            "goal_met": best is not None and best >= goal}  # fmt: skip


def one_run(scene, run: int, args, budget: Budget, max_depth: int, score, noise) -> tuple:
    """Run ``run`` (0, 1, …: its seeds) of the methods ``args.methods`` on one scene: their
    curves, rates and headline, and the last images of the progressive methods."""
    res: dict = {"ray_intersect": ray_intersect_rate(scene, args.rays, seed=run)}
    rays = res["ray_intersect"]["ray_intersect_per_s"]
    print(f"  run {run + 1}: ray_intersect {rays / 1e6:.2f} M rays/s", flush=True)
    images = {}
    for method in args.methods:
        if method == "path":
            res["path"] = mitsuba_curve(
                scene, args.spps, score, path_integrator(max_depth), seed=7 + run
            )
        elif method == "sppm":
            res["sppm"], res["sppm_rates"], images["sppm"] = run_sppm(
                scene, score, budget, args.photons, max_depth, run, rays
            )
        elif method == "vcm":
            res["vcm"], res["vcm_rates"], images["vcm"] = run_vcm(
                scene, score, budget, max_depth, VCM_SEED + run
            )
        else:
            res["surface"] = run_surface(scene, score, args.budgets, max_depth)
    for method in METHODS:
        for row in res.get(method, []):
            row["rel_rmse_vs_truth"] = vs_truth(row["rel_rmse"], noise["rel_rmse"])
            row["block_rel_rmse_vs_truth"] = vs_truth(row["block_rel_rmse"],
                                                      noise["block_rel_rmse"])  # fmt: skip
    res["headline"] = scene_headline(res)
    res["load_average_after"] = report.load_average()
    return res, images


def scene_result(name: str, size, args, ref_spp: int, budget: Budget) -> tuple[dict, dict]:
    """The reference of one scene and ``args.runs`` runs of the methods on it (the methods
    interleaved), the median headline and the last run's images of the progressive methods."""
    scene = load(name, size)
    max_depth = max_depth_of(name, scene)
    (a, b), blend = reference(name, scene, size, ref_spp, max_depth, args.out_dir / "cache")
    ref = (a + b) / 2
    mask = light_image_mask(scene)
    noise = reference_noise(ref, a - b, mask)
    print(f"  max_depth {max_depth}, reference rel RMSE {noise['rel_rmse']:.4f}", flush=True)

    def score(image):
        return errors(image, ref, mask)

    res: dict = {"image": list(size), "max_depth": max_depth, "reference_spp": ref_spp,
                 "reference_rel_rmse": noise["rel_rmse"],
                 "reference_block_rel_rmse": noise["block_rel_rmse"], "reference_blend": blend,
                 "runs": []}  # fmt: skip
    for run in range(args.runs):
        result, images = one_run(scene, run, args, budget, max_depth, score, noise)
        res["runs"].append(result)
    res["headline"] = median_headline([r["headline"] for r in res["runs"]])
    res.update(reference_check(name, res))
    if not res["reference_ok"]:
        print(f"  the reference's 4×4 error {noise['block_rel_rmse']:.4f} is more than a third "
              f"of {res['smallest_block_rel_rmse']:.4f}: no ratio reported", flush=True)  # fmt: skip
    res["load_average_after"] = report.load_average()
    return res, images


NEW_KEYS = (
    "sppm_speedup_vs_path_at_equal_block_rmse",
    "vcm_speedup_vs_path_at_equal_block_rmse",
    "vcm_speedup_vs_sppm_at_equal_block_rmse",
    "sppm_speedup_vs_path_at_equal_block_rmse_vs_truth",
    "vcm_speedup_vs_path_at_equal_block_rmse_vs_truth",
    "light_paths_per_s",
    "camera_paths_per_s",
    "ray_intersect_per_s",
    "best_speedup_vs_path_at_equal_block_rmse",
    "photon_pass_ray_fraction",
    "eye_pass_ray_fraction",
    "photons_seen",
    "sppm_kernels_compiled_per_iteration",
    "vcm_kernels_compiled_per_iteration",
)


def smallest(values: dict):
    return min((v for v in values.values() if v is not None), default=None)


def headline(results: dict, methods, budget: Budget, started: float) -> dict:
    def per_scene(key: str) -> dict:
        return {n: r["headline"][key] for n, r in results.items()}

    speedups = per_scene("speedup_vs_path_at_equal_rmse")
    out = {
        "methods": list(methods),
        **{f"{m}_{'iterations' if budget.steps else 'seconds'}": budget.each
           for m in ("sppm", "vcm")},
        "max_depth": {n: r["max_depth"] for n, r in results.items()},
        "speedup_vs_path_at_equal_rmse": speedups,
        "min_speedup_vs_path_at_equal_rmse": smallest(speedups),
        "speedup_vs_path_at_equal_rmse_vs_truth": per_scene(
            "speedup_vs_path_at_equal_rmse_vs_truth"
        ),
        "speedup_vs_path_at_equal_block_rmse": per_scene("speedup_vs_path_at_equal_block_rmse"),
        "photons_per_s": per_scene("photons_per_s"),
        "gathers_per_s": per_scene("gathers_per_s"),
    }
    for key in NEW_KEYS:
        out[key] = per_scene(key)
        out["min_" + key] = smallest(out[key])
    out["runs"] = len(next(iter(results.values()))["runs"]) if results else 0
    out["reference_ok"] = {n: r["reference_ok"] for n, r in results.items()}
    out["goal"] = {n: r["goal"] for n, r in results.items()}
    out["goal_met"] = {n: r["goal_met"] for n, r in results.items()}
    out["runtime_s"] = time.perf_counter() - started
    return out


# ------------------------------------------------------------------------------------ output
def budget_text(method: str, row: dict) -> str:
    if method == "path":
        return f"{row['spp']} spp"
    if method == "sppm":
        return f"{row['iterations']} iterations, r {row['mean_radius']:.3g}"
    if method == "vcm":
        return f"{row['iterations']} iterations, r {report.fmt(row.get('radius'), 3)}"
    return (f"{row['photons']:,} + {row['caustic_photons']:,} paths, {row['fg_rays']} FG, "
            f"{row['spp']} spp")  # fmt: skip


def markdown(out: dict) -> str:
    records = [
        {"scene": name, "method": method, "run": i + 1, **r}
        for name, res in out["scenes"].items()
        for i, run in enumerate(res["runs"])
        for method in METHODS
        for r in run.get(method, [])
    ]
    table = report.records_table(
        records,
        [
            ("scene", "scene", None),
            ("method", "method", None),
            ("run", "run", None),
            ("budget", lambda r: budget_text(r["method"], r), None),
            ("seconds", "seconds", 2),
            ("rel. RMSE", "rel_rmse", 4),
            ("4×4 block rel. RMSE", "block_rel_rmse", 4),
        ],
    )
    refs = "\n".join(
        f"- {n}: max_depth {r['max_depth']}, reference {r['reference_spp']} spp, its own rel. "
        f"RMSE {r['reference_rel_rmse']:.4f} (4×4 blocks {r['reference_block_rel_rmse']:.4f}); "
        f"Mitsuba ray_intersect {r['headline']['ray_intersect_per_s'] / 1e6:.2f} M rays/s "
        f"(median); reference ok: {r['reference_ok']}; load after {r['load_average_after']}"
        for n, r in out["scenes"].items()
    )
    return table + "\n\n" + report.bullets(out["headline"]) + "\n\n" + refs + "\n"


def plot(results: dict, path: Path) -> None:
    """Error against time, a panel per scene (four to a row), a colour per method: per-pixel
    relative RMSE solid, 4×4-block dashed (the first run), the reference's own errors dotted
    grey."""
    cols = min(4, len(results))
    rows = -(-len(results) // cols)
    with report.figure(path, rows, cols, size=(4.6 * cols, 3.9 * rows)) as axes:
        panels = [ax for row in axes for ax in row]
        for ax, (name, res) in zip(panels, results.items(), strict=False):
            run = res["runs"][0]
            for method in METHODS:
                if run.get(method):
                    seconds = [r["seconds"] for r in run[method]]
                    color = COLORS[method]
                    ax.loglog(seconds, [r["rel_rmse"] for r in run[method]], "o-", color=color,
                              label=LABELS[method])  # fmt: skip
                    ax.loglog(seconds, [r["block_rel_rmse"] for r in run[method]], "s--",
                              color=color, ms=4)  # fmt: skip
            for key in ("reference_rel_rmse", "reference_block_rel_rmse"):
                ax.axhline(res[key], color="grey", lw=0.6, ls=":")
            ax.set(title=f"{name} (max_depth {res['max_depth']})", xlabel="wall time (s)",
                   ylabel="rel. RMSE: pixels —, 4×4 blocks --")  # fmt: skip
            ax.legend(fontsize=8)
        for ax in panels[len(results) :]:
            ax.set_visible(False)


def method_list(text: str) -> list[str]:
    methods = [m for m in text.replace(" ", "").split(",") if m]
    unknown = sorted(set(methods) - set(METHODS))
    if unknown or not methods:
        raise SystemExit(f"--methods: unknown {unknown}; choose from {', '.join(METHODS)}")
    return [m for m in METHODS if m in methods]


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, f"tiny images, {QUICK_ITERATIONS} iterations (smoke)")
    parser.add_argument("--seconds", type=float, default=30.0,
                        help="compute time of each progressive method (sppm, vcm)")  # fmt: skip
    parser.add_argument("--iterations", type=int, default=None,
                        help="a budget of iterations of each progressive method instead")  # fmt: skip
    parser.add_argument("--photons", type=int, default=100_000, help="SPPM photons/iteration")
    parser.add_argument("--ref-spp", type=int, default=65536, help="path reference spp")
    parser.add_argument("--runs", type=int, default=None,
                        help="interleaved runs per scene (default 3; 1 with --quick)")  # fmt: skip
    parser.add_argument("--scenes", default=",".join(SCENES), help="comma-separated subset")
    parser.add_argument("--methods", default=",".join(METHODS),
                        help=f"comma-separated subset of {','.join(METHODS)}")  # fmt: skip
    args = parser.parse_args(argv)
    args.methods = method_list(args.methods)
    names = [n for n in args.scenes.replace(" ", "").split(",") if n]
    if unknown := sorted(set(names) - set(SCENES)):
        raise SystemExit(f"--scenes: unknown {unknown}; choose from {', '.join(SCENES)}")
    if args.iterations is not None and args.iterations < 1:
        raise SystemExit("--iterations must be at least 1")
    args.runs = args.runs if args.runs is not None else 1 if args.quick else 3
    if args.runs < 1:
        raise SystemExit("--runs must be at least 1")
    iterations = QUICK_ITERATIONS if args.quick else args.iterations
    budget = Budget(iterations, steps=True) if iterations else Budget(args.seconds)
    ref_spp = 512 if args.quick else args.ref_spp
    args.spps = [4, 16, 64] if args.quick else [4, 16, 64, 256, 1024, 4096]
    args.budgets = QUICK_BUDGETS if args.quick else BUDGETS
    args.rays = QUICK_RAYS if args.quick else RAYS
    results, started = {}, time.perf_counter()
    for name in names:
        size = SCENES[name].quick_size if args.quick else SCENES[name].size
        print(f"{name} {size[0]}x{size[1]}", flush=True)
        spp = min(ref_spp, SCENES[name].reference_spp or ref_spp)
        results[name], images = scene_result(name, size, args, spp, budget)
        for method, image in images.items():
            stem = report.results_stem(args.out_dir, f"caustics_{name}_{method}", args.quick)
            write_image(str(stem.with_suffix(".png")), image)
    out = {"machine": report.machine_info(),
           "headline": headline(results, args.methods, budget, started),
           "scenes": results, "sppm_photons_per_iteration": args.photons}  # fmt: skip
    stem = report.results_stem(args.out_dir, NAME, args.quick)
    text = markdown(out)
    plot(results, stem.with_suffix(".png"))
    return report.publish(stem, out, text)


if __name__ == "__main__":
    main()
