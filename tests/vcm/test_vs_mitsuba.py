"""Every VCM mode against Mitsuba's own integrators and an analytic oracle: they must converge to
the same image (Georgiev et al. 2012; SmallVCM's algorithms check each other the same way).

- Furnace: a closed diffuse sphere lit by a point light at its centre has ``L = ρ/π · 1/(1 − ρ)``
  on every wall point (light subpaths from a delta light: no emission is ever met).
- ``mi.cornell_box()`` against ``path`` (``lt`` against ``ptracer``), off the light's own pixels
  (a light's image is the eye samples' antialiasing noise, the same for every method).
- A glass sphere on a plane under a small sphere light (caustic) against ``path``; ``lt`` against
  ``ptracer``, which like it cannot see the light through the glass.

Brightness (the mean over the compared pixels) within 2 %. Measured at these settings, seeds
0 and 1: furnace 0.996–1.006 (all modes), Cornell box and glass sphere in the table of the test
docstrings below.
"""

import math

import mitsuba as mi
import numpy as np
import pytest

import mitsuba_reference
from caustic_scene import spot_caustic_scene
from photonmap.core.image import compare
from photonmap.scenes import load_scene
from photonmap.vcm import VCMPipeline
from photonmap.vcm.mis import MODES

T = mi.ScalarTransform4f


def furnace(rho: float) -> mi.Scene:
    return mi.load_dict({
        "type": "scene",
        "sphere": {"type": "sphere", "flip_normals": True,
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": rho}}},
        "light": {"type": "point", "position": [0, 0, 0], "intensity": 1.0},
        "sensor": {"type": "perspective", "fov": 60,
                   "to_world": T().look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16}},
    })  # fmt: skip


def cornell() -> mi.Scene:
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=32, height=32, rfilter={"type": "box"})
    return mi.load_dict(d)


def glass_sphere() -> mi.Scene:
    scene, _ = load_scene("examples/glass_sphere_plane.xml")
    params = mi.traverse(scene.sensors()[0])
    params["film.size"] = (48, 36)
    params["film.crop_size"] = (48, 36)
    params.update()
    return scene


def references(make, depth):
    """``(make, images, mask)``: the scene's maker (each test builds its own scene, so that no
    scene outlives its test: Dr.Jit traces every BSDF alive into each kernel), ``path`` and
    ``ptracer`` at 4096 spp, and the pixels that do not see the light."""
    scene = make()
    out = {
        kind: mitsuba_reference.render(
            scene, integrator=mi.load_dict({"type": kind, "max_depth": depth}), spp=4096, seed=7
        )
        for kind in ("path", "ptracer")
    }
    return make, out, out["path"].max(axis=2) < 1.0


@pytest.fixture(scope="module")
def cornell_refs():
    return references(cornell, 8)


@pytest.fixture(scope="module")
def glass_refs():
    return references(glass_sphere, 12)


def brightness(image, ref, mask):
    return image[mask].mean() / ref[mask].mean()


def brightness_of(refs, mode, max_depth, spp, iterations):
    """The brightness of ``mode``'s image of ``refs``' scene against its ``path`` reference
    (``ptracer``'s for ``lt``), off the light's pixels."""
    make, images, mask = refs
    image = np.array(VCMPipeline(make(), mode=mode, max_depth=max_depth, spp=spp)
                     .run(iterations=iterations))  # fmt: skip
    return brightness(image, images["ptracer" if mode == "lt" else "path"], mask)


@pytest.mark.parametrize("mode", MODES)
def test_furnace(mode):
    rho = 0.7
    image = np.array(VCMPipeline(furnace(rho), mode=mode, max_depth=64, spp=1).run(iterations=128))
    assert abs(image.mean() / (rho / math.pi / (1 - rho)) - 1) < 0.02


@pytest.mark.parametrize("mode", MODES)
def test_cornell_box(cornell_refs, mode):
    """``spp = 4`` subpaths of each kind per pixel and iteration, 64 iterations. Measured
    brightness (seeds 0, 1): pt 0.999/0.997, lt 1.004/0.998, bpt 1.000/0.999, ppm 1.003/1.001,
    vcm 1.002/1.000."""
    assert abs(brightness_of(cornell_refs, mode, 8, spp=4, iterations=64) - 1) < 0.02


@pytest.mark.parametrize("mode", ["vcm", "lt"])
def test_one_subpath_per_pixel_and_iteration(cornell_refs, mode):
    """256 iterations of one subpath of each kind per pixel: the same estimate as the 64 of
    four above (light tracing's splats are divided by ``spp``). Measured brightness (seeds
    0, 1): lt 1.004/1.000, vcm 1.006/1.010."""
    assert abs(brightness_of(cornell_refs, mode, 8, spp=1, iterations=256) - 1) < 0.02


@pytest.mark.parametrize("mode", MODES)
def test_glass_sphere(glass_refs, mode):
    """``spp`` 4, 64 iterations. Measured brightness (seeds 0, 1): pt 1.004/1.008, lt
    0.997/1.001, bpt 0.997/1.008, ppm 0.992/1.012, vcm 1.000/1.007."""
    assert abs(brightness_of(glass_refs, mode, 12, spp=4, iterations=64) - 1) < 0.02


def test_error_falls_with_iterations():
    """Convergence on a caustic: the glass ball focusing a spot light onto the floor the camera
    sees (``tests/caustic_scene.py``) against ``ptracer`` at 1024 spp (5 % per-pixel noise).
    The relative RMSE after 4N iterations is at most 0.8 of that after N (N = 4; measured
    0.60–0.69 over seeds 0–2; brightness after 16 iterations 1.006–1.010)."""
    scene = spot_caustic_scene(-2.2)
    ptracer = mi.load_dict({"type": "ptracer", "max_depth": 16})
    ref = mitsuba_reference.render(scene, integrator=ptracer, spp=1024, seed=0)
    pipe = VCMPipeline(scene, max_depth=16, spp=1)
    early = compare(np.array(pipe.run(iterations=4)), ref)
    late = compare(np.array(pipe.run(iterations=12)), ref)
    assert pipe.iterations == 16
    assert late["rel_rmse"] <= 0.8 * early["rel_rmse"], (early["rel_rmse"], late["rel_rmse"])
    assert abs(late["brightness"] - 1) < 0.03, late["brightness"]


def light_in_glass() -> mi.Scene:
    """A small sphere light inside a glass ball over a diffuse floor: every light subpath starts
    in glass and refracts out (the radiance and importance conventions of Mitsuba's dielectric
    must agree across the techniques)."""
    return mi.load_dict({
        "type": "scene",
        "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(3),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.6}}},
        "ball": {"type": "sphere", "center": [0, 0.7, 0], "radius": 0.5,
                 "bsdf": {"type": "dielectric", "int_ior": 1.5}},
        "lamp": {"type": "sphere", "center": [0, 0.7, 0], "radius": 0.12,
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 20.0}}},
        "sensor": {"type": "perspective", "fov": 45,
                   "to_world": T().look_at(origin=[0, 2.5, 3.5], target=[0, 0.3, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 32, "height": 24,
                            "rfilter": {"type": "box"}}},
    })  # fmt: skip


@pytest.fixture(scope="module")
def light_in_glass_refs():
    ref = mitsuba_reference.render(light_in_glass(), integrator=mi.load_dict({"type": "path",
                   "max_depth": 12}), spp=8192, seed=1)  # fmt: skip
    return ref, ref.max(axis=2) < 1.0


@pytest.mark.parametrize("mode", ["vcm", "bpt", "ppm"])
def test_light_inside_glass(light_in_glass_refs, mode):
    """Off the light's pixels, within 4 % of ``path`` (measured at ``spp`` 4 and 64
    iterations, seeds 0, 1: vcm 0.998/0.993, bpt 0.995/0.998, ppm 0.997/0.998; ``pt`` samples
    this light only by BSDF samples through the glass and is left out: 0.94–1.03 at 256
    iterations of one subpath). With the light subpaths' throughput scaled by η² at each
    refraction they came out at 0.46–0.53."""
    ref, mask = light_in_glass_refs
    image = np.array(VCMPipeline(light_in_glass(), mode=mode, max_depth=12, spp=4)
                     .run(iterations=64))  # fmt: skip
    assert abs(brightness(image, ref, mask) - 1) < 0.04
