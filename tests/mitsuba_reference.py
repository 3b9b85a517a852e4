"""Mitsuba's own images for the tests' comparisons, kept between runs.

``render(scene, integrator, spp, seed)`` is ``np.array(mi.render(...))``: the same call, and on a
later run the image that call gave (two fresh renders with one seed differ in the last bits: the
film adds samples with atomics, in the threads' order). The image is kept under
``benchmarks/results/cache/references/`` (git-ignored; CI starts without it), named by a digest
of everything the render depends on: Mitsuba's version and variant, the scene's and the
integrator's full description (``str``: every object with its properties), every differentiable
parameter's value (``mi.traverse``: vertices, textures, transforms, at full precision), ``spp``
and ``seed``. A second run of the suite reads the images instead of rendering them again; a test
that changes its scene gets a new digest.
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
from pathlib import Path

import numpy as np

CACHE = Path(__file__).resolve().parent.parent / "benchmarks" / "results" / "cache" / "references"


def digest(scene, integrator=None, spp: int | None = None, seed: int = 0) -> str:
    """The hex digest naming the render of ``scene`` with these settings. Mitsuba loads a
    scene's objects in parallel, so their order varies between loads of the same file: the
    objects' descriptions and the parameters are digested as sorted lists."""
    import mitsuba as mi

    objects = [*scene.shapes(), *scene.emitters(), *scene.sensors(), scene.integrator(),
               scene.environment(), integrator]  # fmt: skip
    params = mi.traverse(scene)
    values = []
    for key in params.keys():
        try:
            value = params[key]
        except TypeError:  # a parameter Mitsuba's own getter cannot read (hair's): its description
            continue
        values.append(re.sub(r"object_\d+", "object", key).encode() + b"=" + _bytes(value))
    h = hashlib.sha256()
    for part in (mi.__version__, mi.variant(), spp, seed, *sorted(map(str, objects)), *sorted(values)):
        h.update(repr(part).encode())
    return h.hexdigest()[:32]


def _bytes(value) -> bytes:
    value = getattr(value, "matrix", value)  # a transform: its matrix
    try:
        array = np.asarray(value)
    except (TypeError, ValueError, RuntimeError):
        array = None
    if array is None or array.dtype == object:
        return repr(value).encode()
    return np.ascontiguousarray(array).tobytes()


def render(scene, integrator=None, spp: int | None = None, seed: int = 0) -> np.ndarray:
    """``np.array(mi.render(scene, integrator=integrator, spp=spp, seed=seed))``, read from the
    cache when an earlier run rendered it."""
    import mitsuba as mi

    path = CACHE / f"{digest(scene, integrator, spp, seed)}.npy"
    if path.exists():
        return np.load(path)
    image = np.array(mi.render(scene, integrator=integrator, spp=spp or 0, seed=seed))
    CACHE.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=CACHE, suffix=".npy")  # whole or absent for a parallel run
    with os.fdopen(fd, "wb") as f:
        np.save(f, image)
    os.replace(tmp, path)
    return image
