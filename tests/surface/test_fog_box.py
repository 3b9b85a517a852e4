"""A glass ball and a diffuse floor inside a box of fog: the surface method
models the medium (volumetric photon mapping, Jensen & Christensen 1998) and agrees with Mitsuba's
``volpath`` on the same scene — with no warning: the fog is no longer ignored."""

import warnings
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

import mitsuba_reference
from photonmap.core.errors import PhotonmapWarning
from photonmap.core.image import block_means as blocks
from photonmap.surface.pipeline import SurfacePipeline

T = mi.ScalarTransform4f
W, H = 64, 48
EXAMPLE = Path(__file__).parents[2] / "examples" / "fog_box_sphere_light.xml"


def fog_box_scene(fog: bool) -> mi.Scene:
    """A fog box (a null-BSDF cube holding a homogeneous medium) around a glass ball, with a
    diffuse floor inside the box and a spherical area light above it: every light path and
    shadow ray to the floor crosses the box. Without ``fog`` the box and its medium are left
    out."""
    scene = {
        "type": "scene",
        "sensor": {
            "type": "perspective",
            "fov": 45,
            "to_world": T().look_at(origin=[0, 1.5, 9], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}},
        },
        "ball": {"type": "sphere", "radius": 0.7, "bsdf": {"type": "dielectric", "int_ior": 1.5}},
        "floor": {
            "type": "rectangle",
            "to_world": T().translate([0, -1.45, 0]).rotate([1, 0, 0], -90).scale(5),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.6}},
        },
        "light": {
            "type": "sphere",
            "center": [0, 6, 0],
            "radius": 0.4,
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 120.0}},
        },
    }
    if fog:
        scene["fog"] = {
            "type": "homogeneous",
            "sigma_t": 0.3,
            "albedo": {"type": "rgb", "value": 0.8},
        }
        scene["box"] = {
            "type": "cube",
            "to_world": T().scale([3, 1.5, 1.5]),
            "bsdf": {"type": "null"},
            "interior": {"type": "ref", "id": "fog"},
        }
        scene["ball"]["exterior"] = {"type": "ref", "id": "fog"}
    return mi.load_dict(scene)


@pytest.fixture(scope="module")
def reference():
    """Mitsuba ``volpath`` on the scene with the fog box."""
    volpath = mi.load_dict({"type": "volpath", "max_depth": 32})
    return mitsuba_reference.render(fog_box_scene(True), integrator=volpath, spp=1024, seed=5)


def test_fog_box_scene_agrees_with_volpath_without_warning(reference):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pipe = SurfacePipeline(
            fog_box_scene(True), photons=100_000, caustic_photons=200_000, fg_rays=16, spp=4
        )
        image = np.array(pipe.render())
    assert not [w for w in caught if issubclass(w.category, PhotonmapWarning)]
    assert pipe.stats["volume_photons"] > 0
    assert np.all(np.isfinite(image))
    mean = reference.mean()
    ratio = image.mean() / mean
    error = np.sqrt(np.mean((blocks(image) - blocks(reference)) ** 2)) / mean
    # measured over seeds 0-5: ratio 0.947-0.972 (against an 8192-spp reference, seeds 0-3:
    # 0.944-0.969, and 0.942-0.969 before the distances were weighted by the channels' mean pdf,
    # which changed the random stream), 4x4 block error 0.079-0.115 (the reference alone: 0.044
    # off an 8192-spp one). The 3-5 % deficit is the volume map's boundary bias: its
    # k-NN spheres reach out of the fog near the box's faces and the floor (it shrinks with more
    # photons: ratio 0.988 at 400k). Without the transmittance on the floor's shadow rays: 1.206;
    # without the volume photons that passed the glass: 0.930
    assert abs(ratio - 1) < 0.07, ratio
    assert error < 0.2, error


def fog_box_example(width: int = 48, height: int = 36) -> mi.Scene:
    """examples/fog_box_sphere_light.xml (a glass ball in a box of fog under a sphere light) at
    ``width`` x ``height``: with fog_box.xml's point light ``volpath`` cannot sample the volume
    caustic under the ball that the photons find (measured at 48x36: ours 4-5 % brighter, all
    of it in the caustic)."""
    xml = EXAMPLE.read_text()
    xml = xml.replace('value="320"', f'value="{width}"').replace('value="240"', f'value="{height}"')
    return mi.load_string(xml)


def test_glass_ball_in_fog_example_agrees_with_volpath():
    reference = mitsuba_reference.render(fog_box_example(), spp=4096, seed=1)  # its volpath, depth 32
    pipe = SurfacePipeline(
        fog_box_example(), photons=400_000, caustic_photons=0, spp=4, fg_rays=4, max_depth=32
    )
    image = np.array(pipe.render())
    mean = reference.mean()
    ratio = image.mean() / mean
    error = np.sqrt(np.mean((blocks(image) - blocks(reference)) ** 2)) / mean
    # measured over seeds 0-3: ratio 0.980-0.993, 4x4 block error 0.132-0.161 — most of it
    # volpath's: its volume caustic is a scatter of fireflies at 4096 spp (light paths through
    # the glass reach the small light only by chance). Without the volume caustic (volume
    # photons that passed the glass left out): 0.902
    assert abs(ratio - 1) < 0.05, ratio
    assert error < 0.28, error
