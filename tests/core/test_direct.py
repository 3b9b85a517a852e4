"""core.direct, the transport core's direct light: the power heuristic (Veach 1997, §9.2.4) in
float32 at the densities a light's own plane gives, and next-event estimation under MIS against
Mitsuba's ``path`` at ``max_depth`` 2 (direct light only) on the same camera hits."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mitsuba_reference
from photonmap.core.camera import pixel_rays
from photonmap.core.direct import direct_lighting, power_heuristic
from photonmap.core.sampling import rng
from photonmap.core.scene_info import SceneTraits

T = mi.ScalarTransform4f


def test_power_heuristic_is_a_squared_over_the_sum_of_squares():
    a = np.array([0.0, 1.0, 2.0, 0.5, 3.0], np.float32)
    b = np.array([0.0, 1.0, 1.0, 4.0, 0.0], np.float32)
    expected = np.where(a > 0, a**2 / np.maximum(a**2 + b**2, 1e-30), 0.0)
    got = np.array(power_heuristic(mi.Float(a), mi.Float(b)))
    assert np.allclose(got, expected, rtol=1e-6)


def test_power_heuristic_stays_finite_where_the_squares_overflow():
    """A point on an area light's own plane samples the light with a density of ~1e19 per
    steradian; a² overflows float32 and a² / (a² + b²) is NaN there (an SPPM eye path on the
    light of tests/scenes/fog_thindielectric_area.xml: a NaN image)."""
    a = mi.Float([3.9e19, 1e-30, 1.0, float("inf")])
    b = mi.Float([3e-21, 1.0, 3.9e19, 1.0])
    got = np.array(power_heuristic(a, b))
    assert np.all(np.isfinite(got))
    assert np.allclose(got, [1.0, 0.0, 0.0, 1.0])


def light_on_a_floor() -> mi.Scene:
    """A rectangle light facing a floor, seen from the side by the camera."""
    return mi.load_dict({
        "type": "scene",
        "camera": {
            "type": "perspective", "fov": 60,
            "to_world": T().look_at(origin=[2.5, 0.6, 0], target=[0, 0.8, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": 32, "height": 32, "rfilter": {"type": "box"}},
        },
        "floor": {"type": "rectangle", "to_world": T().scale(3).rotate([1, 0, 0], -90),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}},
        "light": {"type": "rectangle", "to_world": T().translate([0, 1, 0]).rotate([1, 0, 0], 90),
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 10.0}}},
    })  # fmt: skip


def camera_hits(scene, spp):
    sensor = scene.sensors()[0]
    w, h = (int(c) for c in sensor.film().crop_size())
    n = w * h * spp
    gen = rng(n, 3, 0)
    pixel = dr.arange(mi.UInt32, n) // spp
    ray, weight = pixel_rays(sensor, pixel, mi.Point2f(gen.next_float32(), gen.next_float32()))
    si = scene.ray_intersect(ray)
    return si, weight, gen, (w, h)


def cornell_box() -> mi.Scene:
    """``mi.cornell_box()`` at 64² (its own film is 256²: 16 times the work for the same 8×8
    blocks of 64 × 64 samples each)."""
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=64, height=64)
    return mi.load_dict(d)


@pytest.mark.parametrize("scene_of", [cornell_box, light_on_a_floor])
def test_direct_lighting_at_camera_hits_matches_path_at_max_depth_2(scene_of):
    scene = scene_of()
    spp = 64
    si, weight, gen, (w, h) = camera_hits(scene, spp)
    u = mi.Point2f(gen.next_float32(), gen.next_float32())
    L = weight * direct_lighting(scene, si, u, gen, si.is_valid(), SceneTraits.of(scene))
    ours = np.array(L).T.reshape(h, w, spp, 3).mean(axis=2)
    ref_integrator = mi.load_dict({"type": "path", "max_depth": 2, "hide_emitters": True})
    ref = mitsuba_reference.render(scene, integrator=ref_integrator, spp=1024, seed=5)
    assert np.all(np.isfinite(ours))
    assert ours.mean() == pytest.approx(ref.mean(), rel=0.03)
    ours, ref = (x.reshape(h // 8, 8, w // 8, 8, 3).mean(axis=(1, 3)) for x in (ours, ref))
    rel = np.sqrt(np.mean((ours - ref) ** 2)) / ref.mean()
    assert rel < 0.06
