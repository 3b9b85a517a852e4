"""The surface method in a box of fog over a diffuse floor lit only by a constant environment:
photons enter the fog from the environment, the floor's final-gather rays fly through the fog and
read its in-scattered light, the sky is seen through the fog with its transmittance — against
Mitsuba ``volpath`` on the same scene."""

import mitsuba as mi
import numpy as np

import mitsuba_reference
from fog_scene import fog_box
from photonmap.core.image import block_means as blocks
from photonmap.surface.pipeline import SurfacePipeline

T = mi.ScalarTransform4f


def fog_over_floor() -> mi.Scene:
    """The 3 x 2 x 2 fog box of test_fog_media (σ_t = 1, albedo 0.8) above a white floor, under
    a uniform sky of radiance 1."""
    floor = {
        "type": "rectangle",
        "to_world": T().translate([0, -1.2, 0]).rotate([1, 0, 0], -90).scale(4),
        "bsdf": {"type": "diffuse"},
    }
    sky = {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}
    return fog_box(floor=floor, sky=sky)


def test_fog_under_a_sky_agrees_with_volpath():
    volpath = mi.load_dict({"type": "volpath", "max_depth": 64})
    reference = mitsuba_reference.render(fog_over_floor(), integrator=volpath, spp=1024, seed=3)
    pipe = SurfacePipeline(
        fog_over_floor(), photons=400_000, caustic_photons=0, spp=4, fg_rays=16, max_depth=32
    )
    image = np.array(pipe.render())
    assert pipe.stats["volume_photons"] > 10_000
    mean = reference.mean()
    ratio = image.mean() / mean
    error = np.sqrt(np.mean((blocks(image) - blocks(reference)) ** 2)) / mean
    # measured over seeds 0-1: ratio 0.982-0.986, 4x4 block error 0.039-0.045 (the 1-2 % deficit:
    # the volume map's boundary bias at the faces of the box). Without the in-scattered light
    # of the final-gather rays that scatter in the fog: ratio 0.918
    assert abs(ratio - 1) < 0.035, ratio
    assert error < 0.08, error
