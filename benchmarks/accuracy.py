"""How the benchmarks score an image: Mitsuba references cached on disk, the pixels that see a
light left out, relative errors per pixel and of 4×4-block means, and the time a method needs for
an error read off its (time, error) curve in log-log.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

import photonmap  # noqa: F401 - selects the Mitsuba variant
from photonmap.core.camera import pixel_rays
from photonmap.core.eye_rules import EyeRules
from photonmap.core.eye_trace import trace_eye_paths
from photonmap.core.image import block_means, read_image, write_image
from photonmap.core.media import broadcast
from photonmap.core.sampling import rng
from photonmap.core.scene_info import SceneTraits
from photonmap.core.settings import PathSettings
from timing import timed


# -------------------------------------------------------------------------------- references
def cached_image(path: Path, render: Callable[[], np.ndarray]) -> np.ndarray:
    """The image stored at ``path`` (``.exr`` or ``.npy``), made by ``render()`` and stored there
    the first time; every call returns the stored image, so a first run and a cached one score
    against the same pixels."""
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        image = render()
        if path.suffix == ".npy":
            np.save(path, image)
        else:
            write_image(str(path), image)
    return np.load(path) if path.suffix == ".npy" else read_image(str(path))


def render_passes(scene, spp: int, per_pass: int, seed: int, integrator=None) -> np.ndarray:
    """Mitsuba's ``integrator`` (None: the scene's own) at ``spp`` samples per pixel, as the
    mean of passes of at most ``per_pass`` samples (a pass's wavefront fits in memory) with seeds
    ``seed``, ``seed + 1``, …"""
    passes = max(1, spp // per_pass)
    parts = (
        np.array(mi.render(scene, integrator=integrator, spp=spp // passes, seed=seed + i))
        for i in range(passes)
    )
    return sum(parts) / passes


def cropped(scene, box, render: Callable[[], np.ndarray]) -> np.ndarray:
    """``render()`` with the film of ``scene`` cropped to ``box = (x0, y0, x1, y1)`` (pixels),
    the film's crop restored afterwards. Mitsuba samples the crop alone, so pixels within the
    filter's reach of an edge cut inside the image miss the splats of the samples beyond it: use
    the crop's interior."""
    params = mi.traverse(scene)
    offset = next(k for k in params.keys() if k.endswith("film.crop_offset"))
    size = next(k for k in params.keys() if k.endswith("film.crop_size"))
    before = (list(params[offset]), list(params[size]))
    params[offset], params[size] = [box[0], box[1]], [box[2] - box[0], box[3] - box[1]]
    params.update()
    try:
        return render()
    finally:
        params[offset], params[size] = before
        params.update()


def blend_weights(pilot_a, pilot_b, where: np.ndarray, window: int = 9) -> np.ndarray:
    """Per pixel, the weight ``w`` of estimate A in the inverse-variance blend ``w A + (1 − w) B``
    of two unbiased estimates of one image, from independent pilot renders of each (two halves
    apiece, at a common fraction of A's and B's samples): a variance is the local mean
    (``window`` × ``window`` pixels, colour channels averaged) of the pilot halves' squared
    difference, and ``w = v_B / (v_A + v_B)`` where ``where`` holds, 1 elsewhere (B does not
    estimate those pixels). Weights from independent renders do not correlate with the images
    they blend, so the blend stays unbiased. Shape ``(height, width, 1)``."""
    from scipy.ndimage import uniform_filter

    def variance(first, second):
        d2 = np.mean((np.asarray(first, np.float64) - second) ** 2, axis=-1)
        return uniform_filter(d2, window, mode="nearest")

    va, vb = variance(*pilot_a), variance(*pilot_b)
    w = np.where(va + vb > 0, vb / np.maximum(va + vb, 1e-300), 0.5)
    return np.where(where, w, 1.0)[..., None]


def light_image_mask(scene, spp: int = 64) -> np.ndarray:
    """Pixels that see no emitter, neither directly nor through mirrors and glass, nor next to
    one that does. Those pixels are the light's images: a bright source a few pixels wide whose
    edges every method antialiases with the same pixel jitter (photon mapping follows the same
    specular eye paths as ``path``), so their noise says nothing about the light transport
    being compared and at low sample counts it swamps every other error in the image."""
    from scipy.ndimage import binary_dilation

    sensor = scene.sensors()[0]
    w, h = (int(c) for c in sensor.film().crop_size())
    lanes = w * h * spp
    gen = rng(lanes, 12345, 0)
    pixel = dr.arange(mi.UInt32, lanes) // spp
    ray, weight = pixel_rays(sensor, pixel, mi.Point2f(gen.next_float32(), gen.next_float32()))
    rules = EyeRules(PathSettings(16), SceneTraits.of(scene), media_mode="transmit")
    emitted = trace_eye_paths(scene, (ray, weight, broadcast(None, lanes)), gen, rules).radiance
    seen = np.array(dr.block_reduce(dr.ReduceOp.Add, dr.max(emitted), spp)).reshape(h, w) / spp
    return ~binary_dilation(seen > 0.01, iterations=1)


# ------------------------------------------------------------------------------------ errors
def masked_errors(image: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> dict:
    """Relative RMSE over the pixels of ``mask`` and of the 4×4-block means of the blocks
    entirely in it (noise averages out within a block, a bias does not), relative to the
    reference's mean over ``mask``."""
    mean = float(np.mean(np.abs(ref[mask])))
    d = np.asarray(image, np.float64) - ref
    blocks = block_means(mask[..., None].astype(np.float64))[..., 0] == 1.0
    bd = block_means(d)[blocks]
    return {
        "rel_rmse": float(np.sqrt(np.mean(d[mask] ** 2))) / mean,
        "block_rel_rmse": float(np.sqrt(np.mean(bd**2))) / mean,
    }


def reference_noise(ref: np.ndarray, difference: np.ndarray, mask: np.ndarray) -> dict:
    """The own errors (:func:`masked_errors`) of a reference ``ref`` = (A + B)/2 made of two
    independent halves with ``difference`` A − B: Var((A + B)/2) = E[(A − B)²]/4, so (A − B)/2
    is distributed as its error."""
    return masked_errors(ref + 0.5 * difference, ref, mask)


def errors(image: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> dict:
    """:func:`masked_errors`, the whole image's relative RMSE (``rel_rmse_full``) and the
    mean-brightness ratio over ``mask``."""
    image = np.asarray(image, np.float64)
    return {
        **masked_errors(image, ref, mask),
        "rel_rmse_full": float(np.sqrt(np.mean((image - ref) ** 2)) / ref.mean()),
        "brightness": float(image[mask].mean() / ref[mask].mean()),
    }


def vs_truth(error: float, reference_error: float) -> float:
    """An error against the truth, estimated from one against a reference whose own error is
    ``reference_error``: independent errors add in quadrature, E|x − ref|² = |x − truth|² +
    E|ref − truth|², so the reference's is subtracted."""
    return math.sqrt(max(error**2 - reference_error**2, 0.0))


def mitsuba_curve(scene, spps: Sequence[int], score, integrator=None, label="path",
                  seed: int = 7) -> list:  # fmt: skip
    """Mitsuba's ``integrator`` (None: the scene's own) at each of ``spps`` (``seed``), after a
    1-spp warm-up (kernel compilation): rows of ``spp``, ``seconds`` (Dr.Jit synchronised) and
    the errors ``score(image)``."""
    mi.render(scene, integrator=integrator, spp=1, seed=seed)
    rows = []
    for spp in spps:
        t, image = timed(
            lambda s=spp: np.array(mi.render(scene, integrator=integrator, spp=s, seed=seed))
        )
        rows.append({"spp": spp, "seconds": t, **score(image)})
        print(f"  {label} {spp} spp: {t:.2f} s, rel RMSE {rows[-1]['rel_rmse']:.4f}", flush=True)
    return rows


# ------------------------------------------------------------------------------------ curves
def curve(rows: Sequence[Mapping], key: str, x: str = "seconds") -> tuple[np.ndarray, np.ndarray]:
    """``(x, error)`` of ``rows`` as arrays, in increasing ``x``."""
    t = np.array([r[x] for r in rows], dtype=np.float64)
    e = np.array([r[key] for r in rows], dtype=np.float64)
    order = np.argsort(t, kind="stable")
    return t[order], e[order]


def loglog_between(xs: Sequence[float], errors: Sequence[float], error: float) -> float | None:
    """Where a falling curve reaches ``error``: log-log interpolation between the first pair of
    neighbouring points that brackets it; None if no pair does."""
    for i in range(len(xs) - 1):
        e0, e1 = errors[i], errors[i + 1]
        if e0 >= error >= e1:
            f = math.log(error / e0) / math.log(e1 / e0)
            return math.exp(math.log(xs[i]) + f * math.log(xs[i + 1] / xs[i]))
    return None


def loglog_time_for(rows: Sequence[Mapping], error: float, key: str = "rel_rmse"):
    """Time at which a (time, error) curve reaches ``error``: log-log interpolation, RMSE ∝ t^−½
    past either end; None if the curve never gets there (no pair brackets an error within its
    range)."""
    t, e = curve(rows, key)
    found = loglog_between(t, e, error)
    if found is not None:
        return found
    if error <= e[-1]:
        return t[-1] * (e[-1] / error) ** 2
    return t[0] * (e[0] / error) ** 2 if error > e[0] else None


def loglog_error_at(rows: Sequence[Mapping], seconds: float, key: str = "rel_rmse") -> float:
    """The error of a (time, error) curve at ``seconds``: log-log interpolation, RMSE ∝ t^−½
    past its last point."""
    t, e = curve(rows, key)
    if seconds >= t[-1]:
        return e[-1] * math.sqrt(t[-1] / seconds)
    return float(np.exp(np.interp(np.log(seconds), np.log(t), np.log(e))))
