"""A NumPy oracle of Mitsuba's film: the expected value of each pixel for a scene whose radiance
is a known function of the image position — emitting rectangles, axis-aligned in the image, on a
black background, seen by a perspective camera that faces them.

A pixel of Mitsuba's film converges to ∫ w(δ) L(c + δ) dδ / ∫ w(δ) dδ over the positions the
film samples (the crop; without ``sample_border`` the filter of a pixel is cut at the crop's edge),
w(δ) = w(δx)·w(δy). For L a sum of rectangles' indicators times their radiance, each term is a
product of 1D integrals of w: the oracle is exact up to the quadrature of the 1D filter.
"""

import math

import mitsuba as mi
import numpy as np

DEPTH = 4.0  # distance of the emitters' plane from the camera


def filter_1d(kind: str, x: np.ndarray) -> np.ndarray:
    """Mitsuba's filters with their default parameters, written out (float64)."""
    x = np.abs(x)
    if kind == "gaussian":  # stddev 0.5, radius 4 stddev, shifted to reach zero at the radius
        s, r = 0.5, 2.0
        return np.maximum(np.exp(-(x**2) / (2 * s * s)) - math.exp(-(r**2) / (2 * s * s)), 0.0)
    if kind == "tent":  # radius 1
        return np.maximum(1.0 - x, 0.0)
    if kind == "box":
        return (x <= 0.5).astype(np.float64)
    if kind in ("mitchell", "catmullrom"):  # Mitchell & Netravali 1988, radius 2
        b, c = (1 / 3, 1 / 3) if kind == "mitchell" else (0.0, 0.5)
        near = (12 - 9 * b - 6 * c) * x**3 + (-18 + 12 * b + 6 * c) * x**2 + (6 - 2 * b)
        far = (
            (-b - 6 * c) * x**3
            + (6 * b + 30 * c) * x**2
            + (-12 * b - 48 * c) * x
            + (8 * b + 24 * c)
        )
        return np.where(x < 1, near, np.where(x < 2, far, 0.0)) / 6
    if kind == "lanczos":  # 3 lobes
        return np.where(x < 3, np.sinc(x) * np.sinc(x / 3), 0.0)
    raise ValueError(kind)


RADIUS = {"gaussian": 2.0, "tent": 1.0, "box": 0.5, "mitchell": 2.0, "catmullrom": 2.0,
          "lanczos": 3.0}  # fmt: skip

# rectangles in pixel coordinates of the full film (x0, x1, y0, y1) and their RGB radiance:
# edges inside pixels, a line thinner than a pixel, one that leaves the film at its corner
RECTS = [
    ((3.3, 17.8, 2.6, 11.2), (1.0, 0.5, 0.25)),
    ((20.45, 37.1, 14.7, 26.9), (0.2, 0.8, 0.4)),
    ((25.2, 26.0, 1.5, 12.3), (2.0, 2.0, 2.0)),
    ((-6.0, 6.4, 15.3, 40.0), (0.3, 0.3, 1.0)),
    ((9.5, 14.5, 17.5, 22.5), (1.5, 0.1, 0.1)),
]


def camera(width, height, rfilter, crop=None, sample_border=False) -> dict:
    film = {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": rfilter},
            "sample_border": sample_border}  # fmt: skip
    if crop is not None:
        (ox, oy), (cw, ch) = crop
        film.update(crop_offset_x=ox, crop_offset_y=oy, crop_width=cw, crop_height=ch)
    return {
        "type": "perspective", "fov": 40.0, "fov_axis": "x", "film": film,
        "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=[0, 0, -1],
                                                   up=[0, 1, 0]),
        "sampler": {"type": "independent"},
    }  # fmt: skip


def scene_dict(width=40, height=30, rfilter="gaussian", crop=None, sample_border=False) -> dict:
    """The rectangles as area emitters on the plane z = −DEPTH, placed where the camera sees the
    given pixel coordinates (each pixel position maps affinely onto the plane)."""
    tan = math.tan(math.radians(40.0) / 2)

    def world(px, py):  # looking down −z with +y up: image x along world +x, image y along −y
        x = (2 * px / width - 1) * tan * DEPTH
        y = -(2 * py / height - 1) * tan * DEPTH * height / width
        return x, y

    scene = {"type": "scene", "sensor": camera(width, height, rfilter, crop, sample_border)}
    for k, ((x0, x1, y0, y1), rgb) in enumerate(RECTS):
        (ax, ay), (bx, by) = world(x0, y0), world(x1, y1)
        to_world = mi.ScalarTransform4f().translate([(ax + bx) / 2, (ay + by) / 2, -DEPTH]) @ (
            mi.ScalarTransform4f().scale([abs(bx - ax) / 2, abs(by - ay) / 2, 1.0])
        )
        scene[f"rect{k}"] = {
            "type": "rectangle", "to_world": to_world, "bsdf": {"type": "diffuse",
            "reflectance": {"type": "rgb", "value": 0.0}},
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": list(rgb)}},
        }  # fmt: skip
    return scene


def _cumulative(kind: str):
    r = RADIUS[kind]
    x = np.linspace(-r, r, 400001)
    w = filter_1d(kind, x)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(x))])
    return lambda t: np.interp(np.clip(t, -r, r), x, cum)


def expected_image(width=40, height=30, rfilter="gaussian", crop=None, sample_border=False):
    """The film's expected image (crop height × crop width × 3), float64."""
    (ox, oy), (cw, ch) = crop if crop is not None else ((0, 0), (width, height))
    F = _cumulative(rfilter)
    r = RADIUS[rfilter]

    def axis(n, offset, a, b):
        c = np.arange(n) + 0.5  # crop-relative centres
        lo, hi = (np.full(n, -r), np.full(n, r)) if sample_border else (-c, n - c)
        norm = F(hi) - F(lo)
        lo_k = np.maximum(lo, a - offset - c)
        hi_k = np.minimum(hi, b - offset - c)
        return np.where(hi_k > lo_k, F(hi_k) - F(lo_k), 0.0) / norm

    image = np.zeros((ch, cw, 3))
    for (x0, x1, y0, y1), rgb in RECTS:
        image += np.outer(axis(ch, oy, y0, y1), axis(cw, ox, x0, x1))[..., None] * np.array(rgb)
    return image
