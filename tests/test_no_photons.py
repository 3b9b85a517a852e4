"""A light that shines past every shape stores no photons: SPPM and the surface method (its
direct-visualisation lookup included) render the black image Mitsuba renders, instead of failing
inside Dr.Jit on an empty photon array (``PhotonRecords.after_first``)."""

import mitsuba as mi
import numpy as np

from photonmap import ScreenPipeline, SPPMPipeline, SurfacePipeline


def test_a_light_shining_past_the_scene_renders_black():
    scene = {
        "type": "scene",
        "sensor": {
            "type": "perspective",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=[0, 1, 3], target=[0, 0, 0], up=[0, 1, 0]
            ),
            "film": {"type": "hdrfilm", "width": 16, "height": 12},
        },
        "floor": {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90),
            "bsdf": {"type": "diffuse"},
        },
        "light": {
            "type": "spot",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=[0, 1, 0], target=[0, 5, 0], up=[0, 0, 1]
            ),
            "intensity": 10.0,
        },
    }
    pipelines = [
        SPPMPipeline(scene, iterations=2, photons=500, mode=mode)
        for mode in ("sppm", "memoryless")
    ]
    pipelines += [
        SurfacePipeline(scene, photons=500, caustic_photons=500, lookup=lookup)
        for lookup in ("irradiance", "direct")
    ]
    for pipe in pipelines:
        image = np.array(pipe.render())
        assert image.shape == (12, 16, 3) and np.all(image == 0), pipe
    reference = np.array(mi.render(mi.load_dict(scene | {"integrator": {"type": "path"}}), spp=4))
    assert np.all(reference == 0)


def test_the_screen_method_with_no_photon_recorded_renders_the_direct_light():
    """A spot light on a lone floor: every path leaves the scene after its first hit, which the
    screen method lights directly and never records, so no photon is stored — the image is the
    direct light alone (it failed inside Dr.Jit on the empty records)."""
    scene = {
        "type": "scene",
        "sensor": {
            "type": "perspective",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=[0, 2, 3], target=[0, 0, 0], up=[0, 1, 0]
            ),
            "film": {"type": "hdrfilm", "width": 16, "height": 12},
        },
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90),
                  "bsdf": {"type": "diffuse"}},
        "light": {"type": "spot", "intensity": 10.0, "to_world": mi.ScalarTransform4f().look_at(
            origin=[0, 1, 0], target=[0, 0, 0], up=[0, 0, 1])},
    }  # fmt: skip
    pipe = ScreenPipeline(scene, bounces=2, photons=16**2)
    image = np.array(pipe.render())
    assert pipe.stats["photons"] == 0
    direct = np.array(ScreenPipeline(scene, max_depth=2, photons=16**2).render())
    assert np.all(np.isfinite(image)) and image.max() > 0
    assert np.array_equal(image, direct)
