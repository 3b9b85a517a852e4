"""Every BSDF Mitsuba ships for RGB rendering, on a ball in Mitsuba's Cornell box, through every
method that accepts a scene without media: the same brightness as Mitsuba's ``path`` on the same
scene, or a one-line refusal naming a method that renders it (the volume method needs fog; the
screen method shades surfaces by their diffuse reflectance and refuses what it would shade wrong;
sppm and vcm cannot weigh photons by the hair BSDF, whose lobe is measured against the fibre).
``polarizer``, ``retarder`` and ``measured_polarized`` exist only in polarized variants and
``measured`` needs a measured data file; they are left out."""

from __future__ import annotations

import warnings

import mitsuba as mi
import numpy as np
import pytest

import mitsuba_reference
from photonmap import METHODS, PhotonmapError, PhotonmapWarning

BUMPS = {"type": "bitmap", "raw": True,  # a bump map needs a texture with gradients: a bitmap
         "bitmap": mi.Bitmap(np.random.default_rng(0).random((16, 16, 1)).astype(np.float32))}
DIFFUSE = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.5, 0.3]}}
BSDFS = {
    "diffuse": DIFFUSE,
    "dielectric": {"type": "dielectric", "int_ior": 1.5},
    "thindielectric": {"type": "thindielectric", "int_ior": 1.5},
    "roughdielectric": {"type": "roughdielectric", "alpha": 0.2},
    "conductor": {"type": "conductor", "material": "Au"},
    "roughconductor": {"type": "roughconductor", "material": "Cu", "alpha": 0.25},
    "plastic": {"type": "plastic", "diffuse_reflectance": {"type": "rgb", "value": 0.5}},
    "roughplastic": {"type": "roughplastic", "alpha": 0.2},
    "pplastic": {"type": "pplastic", "alpha": 0.2},
    "principled": {"type": "principled", "base_color": {"type": "rgb", "value": [0.6, 0.4, 0.2]},
                   "roughness": 0.3, "metallic": 0.3},
    "principledthin": {"type": "principledthin", "roughness": 0.3, "spec_trans": 0.5},
    "twosided": {"type": "twosided", "bsdf": DIFFUSE},
    "mask": {"type": "mask", "opacity": 0.4, "bsdf": DIFFUSE},
    "blendbsdf": {"type": "blendbsdf", "weight": 0.5, "bsdf_0": DIFFUSE,
                  "bsdf_1": {"type": "conductor"}},
    "bumpmap": {"type": "bumpmap", "arg0": BUMPS, "scale": 0.5, "arg1": DIFFUSE},
    "normalmap": {"type": "normalmap", "normalmap": {"type": "rgb", "value": [0.6, 0.5, 0.9]},
                  "arg1": DIFFUSE},
    "hair": {"type": "hair"},
    "null": {"type": "null"},
}  # fmt: skip
SIZE = 24
SETS = {
    "surface": {"photons": 20000, "caustic_photons": 50000, "fg_rays": 4, "spp": 4},
    "sppm": {"iterations": 8, "photons": 10000},
    "vcm": {"iterations": 16, "spp": 1},
    "screen": {},
    "volume": {},
}


def scene(bsdf: dict) -> dict:
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=SIZE, height=SIZE, rfilter={"type": "box"})
    d["integrator"] = {"type": "path", "max_depth": 8}
    d.pop("small-box")
    d.pop("large-box")
    d["ball"] = {"type": "sphere", "center": [0.0, -0.5, 0.0], "radius": 0.45, "bsdf": bsdf}
    return d


_references: dict[str, np.ndarray] = {}


def reference(name: str) -> np.ndarray:
    if name not in _references:
        image = mitsuba_reference.render(mi.load_dict(scene(BSDFS[name])), spp=512, seed=1)
        _references[name] = image[..., :3]
    return _references[name]


@pytest.mark.parametrize("method", ["surface", "sppm", "vcm", "screen", "volume"])
@pytest.mark.parametrize("name", list(BSDFS))
def test_every_bsdf_renders_like_path_or_is_refused(name, method):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PhotonmapWarning)  # parts left out are named
            pipe = METHODS[method].pipeline(scene(BSDFS[name]), **SETS[method])
            image = np.array(pipe.render())
    except PhotonmapError as exc:
        message = str(exc)
        assert "\n" not in message and "--method" in message, message
        refusals = ("screen", "volume") + (("sppm", "vcm") if name == "hair" else ())
        assert method in refusals, f"{method} refused {name}: {message}"
        return
    ref = reference(name)
    assert image.shape == ref.shape and np.all(np.isfinite(image))
    assert image.mean() == pytest.approx(ref.mean(), rel=0.05), (name, method)


@pytest.mark.parametrize("name", ["dielectric", "conductor"])
def test_screen_mirror_and_glass_show_indirect_light(name):
    """What a glass or mirror ball shows is lit by direct and indirect light alike: the floor
    seen in the ball lies mostly in the ball's own shadow. The ball's pixels (the light's glints
    left out: one sample per pixel centre cannot resolve them) within 15 % of ``path``'s; with
    direct light only at the chains' ends they were at 0.45–0.49."""
    size = 48
    d = scene(BSDFS[name])
    d["sensor"]["film"].update(width=size, height=size)
    ref = mitsuba_reference.render(mi.load_dict(d), spp=1024, seed=1)[..., :3]
    pipe = METHODS["screen"].pipeline(d)
    image = np.array(pipe.render())
    sensor = pipe.sensor  # the ball's pixels: camera rays through the pixel centres hit it
    x, y = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size)
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x.ravel(), y.ravel()), mi.Point2f(0.5))
    hit = np.array(pipe.scene.ray_intersect(ray).p).T.reshape(size, size, 3)
    ball = np.linalg.norm(hit - np.array([0.0, -0.5, 0.0]), axis=-1) < 0.451
    ball &= (ref.max(-1) < 1.0) & (image.max(-1) < 1.0)  # no glints
    assert ball.sum() > 150
    assert image[ball].mean() == pytest.approx(ref[ball].mean(), rel=0.15)
