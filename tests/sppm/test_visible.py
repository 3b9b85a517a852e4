"""The eye pass's paths to the lights' images in mirrors and glass (``sppm/visible.py``): traced
in the pixels that may show one (``mirror_pixels``) alone, the image is the one that tracing every
pixel gives, bit for bit — each path keeps its lane's random numbers (``core.sampling.rng`` of
a subset of lanes)."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from photonmap.core.camera import pixel_rays
from photonmap.core.sampling import rng
from photonmap.sppm import SPPMPipeline


def test_the_generators_of_some_lanes_are_theirs_in_the_whole_wavefront():
    lanes = mi.UInt32([3, 4, 17, 999])
    some, every = rng(1000, 5, 2, lanes), rng(1000, 5, 2)
    for _ in range(3):
        got, whole = np.array(some.next_float32()), np.array(every.next_float32())
        assert np.array_equal(got, whole[np.array(lanes)])


def _cornell_with_glass() -> mi.Scene:
    d = mi.cornell_box()  # the ceiling light is in view; a glass ball shows it again
    d["sensor"]["film"].update(width=48, height=48)
    del d["small-box"], d["large-box"]
    d["ball"] = {"type": "sphere", "center": [0.3, -0.7, 0.2], "radius": 0.25,
                 "bsdf": {"type": "dielectric"}}  # fmt: skip
    return mi.load_dict(d)


@pytest.mark.parametrize("transport", ["photons", "paths"])
def test_the_mirror_pixels_alone_give_the_image_of_all(transport):
    """The same image from the mirror pixels alone (SUBPIXELS² rays found them) as from every
    pixel; with a generator per path that did not keep its lane's sequence, 25 of the light's
    pixels differed."""
    scene = _cornell_with_glass()
    images, counts = [], []
    for every_pixel in (False, True):
        pipe = SPPMPipeline(scene, seed=3, photons=20_000, transport=transport)
        if every_pixel:
            pipe.mirror_pixels = lambda: dr.arange(mi.UInt32, 48 * 48)
        counts.append(dr.width(pipe.mirror_pixels()))
        images.append(np.array(pipe.run(iterations=2)))
    assert counts[0] < 0.5 * counts[1]
    assert np.array_equal(images[0], images[1])


def test_the_mirror_pixels_hold_the_lights_and_the_glass():
    scene = _cornell_with_glass()
    pipe = SPPMPipeline(scene, seed=3, photons=20_000)
    mask = np.zeros(48 * 48, bool)
    mask[np.array(pipe.mirror_pixels())] = True
    mask = mask.reshape(48, 48)
    image = np.array(mi.render(scene, spp=16, seed=0))[..., :3]
    light = image.max(axis=2) > 5  # the ceiling light seen directly
    assert light.any() and mask[light].all()
    ray, _ = pixel_rays(scene.sensors()[0], dr.arange(mi.UInt32, 48 * 48), mi.Point2f(0.5, 0.5),
                        filtered=False)  # fmt: skip
    si = scene.ray_intersect(ray)
    glass = np.array(mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Delta)).reshape(48, 48)
    assert glass.sum() > 20 and mask[glass].all()  # the pixel centres that see the ball
    assert mask.mean() < 0.5


def test_a_view_without_lights_mirrors_or_glass_has_no_mirror_pixels():
    """The glass ball behind the camera, the camera looking down at the floor: no pixel can show
    a light, and the iterations render (they once failed on the empty set)."""
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=16, height=16)
    d["sensor"]["to_world"] = mi.ScalarTransform4f().look_at(origin=[0, 0.5, 3.9],
                                                            target=[0, -1, 0], up=[0, 1, 0])
    d["ball"] = {"type": "sphere", "center": [0.0, 0.0, 5.0], "radius": 0.2,
                 "bsdf": {"type": "dielectric"}}  # fmt: skip
    pipe = SPPMPipeline(mi.load_dict(d), seed=1, photons=5000)
    assert dr.width(pipe.mirror_pixels()) == 0
    image = np.array(pipe.run(iterations=2))
    assert np.isfinite(image).all() and image.mean() > 0
