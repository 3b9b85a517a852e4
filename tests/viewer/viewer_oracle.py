"""The viewer tests' scene and oracle: a small glass_sphere_fog (32³ grid, 64² photons, 96 × 72)
served by the viewer, and the oracle: the same changes made through the package API
(``VolumePipeline`` setters), rendered and converted to 8-bit sRGB as the viewer does."""

from __future__ import annotations

import io

import numpy as np

SCENE = "glass_sphere_fog"
OVERRIDES = {"grid": 32, "photons": 64**2}
SIZE = (96, 72)


def pixels(png: bytes) -> np.ndarray:
    """An encoded image as uint8 (h, w, 3)."""
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def direct(edit=None, size=SIZE) -> np.ndarray:
    """The oracle: a fresh VolumePipeline with ``edit(pipe)`` applied, rendered, in sRGB8."""
    from photonmap import VolumePipeline
    from photonmap.viewer.worker import to_srgb8

    pipe = VolumePipeline(SCENE, **OVERRIDES, width=size[0], height=size[1])
    if edit is not None:
        edit(pipe)
    return to_srgb8(np.asarray(pipe.render()))


