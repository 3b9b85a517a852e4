"""The rays the transport core's loops report casting — the counts behind the benchmarks' ray
rates (rays per second against Mitsuba's own ``ray_intersect`` rate) — against paths whose rays
are known: in a closed diffuse box without Russian roulette every path has exactly the
interactions ``max_depth`` allows, and every eye-path vertex with a segment left adds one shadow
ray."""

import numpy as np
import pytest

from photonmap import dr, mi
from photonmap.core.eye_rules import EyeRules
from photonmap.core.eye_trace import trace_eye_paths
from photonmap.core.photon_trace import PhotonRules, trace_photons
from photonmap.core.sampling import rng
from photonmap.core.scene_info import SceneTraits
from photonmap.core.settings import PathSettings

NO_ROULETTE = 1000
PATHS = 4096


def closed_box() -> mi.Scene:
    """A closed grey diffuse box (cube [−1, 1]³ facing in) around a point light."""
    return mi.load_dict({
        "type": "scene",
        "box": {"type": "cube", "flip_normals": True,
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}},
        "light": {"type": "point", "position": [0.3, -0.2, 0.1]},
    })  # fmt: skip


@pytest.mark.parametrize("interactions", [1, 3, 11])  # 11: over a chunk of 8
def test_photon_paths_cast_one_ray_per_interaction(interactions):
    settings = PathSettings(interactions + 1, NO_ROULETTE)  # records of depth ≤ interactions
    scene = closed_box()
    records = trace_photons(scene, PATHS, PhotonRules.of(scene, settings), seed=3).records
    assert records.count == PATHS * interactions  # every path stores at every interaction
    assert records.rays == PATHS * interactions


def test_an_open_scene_counts_the_rays_that_leave():
    """A point light over a floor, one interaction allowed: every path casts one ray, hit or
    miss."""
    scene = mi.load_dict({
        "type": "scene",
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90)},
        "light": {"type": "point", "position": [0, 1, 0]},
    })  # fmt: skip
    rules = PhotonRules.of(scene, PathSettings(2, NO_ROULETTE))
    records = trace_photons(scene, PATHS, rules, seed=1).records
    assert 0 < records.count < PATHS
    assert records.rays == PATHS


def eye_rays(surfaces: str, max_depth: int) -> np.ndarray:
    scene = closed_box()
    n = 1024
    gen = rng(n, 5, 0)
    d = mi.warp.square_to_uniform_sphere(mi.Point2f(gen.next_float32(), gen.next_float32()))
    ray = mi.Ray3f(mi.Point3f(0.0, 0.2, 0.0) + dr.zeros(mi.Point3f, n), d)
    rules = EyeRules(PathSettings(max_depth, NO_ROULETTE), SceneTraits.of(scene), surfaces=surfaces)
    eye = trace_eye_paths(scene, (ray, mi.Spectrum(1.0), mi.MediumPtr(None)), gen, rules)
    return np.asarray(eye.rays)


def test_visible_point_paths_cast_one_ray():
    assert np.all(eye_rays("stop", 8) == 1)  # the first surface is diffuse: the path ends


@pytest.mark.parametrize("max_depth", [1, 4])
def test_path_traced_eye_paths_cast_segments_and_shadow_rays(max_depth):
    """``max_depth`` segments, and a shadow ray at every vertex but the last (its light would
    need one more segment)."""
    assert np.all(eye_rays("continue", max_depth) == 2 * max_depth - 1)
