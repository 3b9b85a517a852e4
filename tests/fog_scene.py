"""The fog-only box the surface-media tests share (test_fog_media, test_fog_media_kinds,
test_fog_env, test_fog_area_light): a 3 × 2 × 2 ``cube`` holding the medium ``fog`` behind a
``boundary`` BSDF, seen by a 48 × 36 camera, plus the light and shapes a test adds; and the spot
light several of them use."""

import mitsuba as mi
import numpy as np

from photonmap.core.arrays import to_jit

T = mi.ScalarTransform4f
W, H = 48, 36
FOG = {"type": "ref", "id": "fog"}
GREY_FOG = {"type": "homogeneous", "sigma_t": 1.0, "albedo": 0.8}  # isotropic


def fog_box(fog: dict = GREY_FOG, boundary: str = "null", **extra) -> mi.Scene:
    """The fog box with medium ``fog`` behind a ``boundary`` BSDF (``null``, ``thindielectric``)
    and the scene entries ``extra`` (lights, floors, emitters; refer to the medium as ``FOG``)."""
    return mi.load_dict(
        {
            "type": "scene",
            "sensor": {
                "type": "perspective",
                "fov": 40,
                "to_world": T().look_at(origin=[0, -0.2, 3.6], target=[0, -0.6, 0], up=[0, 1, 0]),
                "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}},
            },
            "fog": fog,
            "box": {
                "type": "cube",
                "to_world": T().scale([1.5, 1, 1]),
                "bsdf": {"type": boundary},
                "interior": FOG,
            },
            **extra,
        }
    )


def spot_in_fog() -> dict:
    """A spot light inside the fog, aimed down and to the side (its medium is the fog, as
    Mitsuba needs to be told)."""
    return {
        "type": "spot",
        "cutoff_angle": 30,
        "beam_width": 20,
        "to_world": T().look_at(origin=[0, 0.9, 0], target=[0.3, -1, 0], up=[0, 0, 1]),
        "intensity": 10.0,
        "medium": FOG,
    }


def heterogeneous_fog() -> dict:
    """A ``heterogeneous`` medium filling the box: σ_t from a random 12 x 8 x 8 grid in
    [0.3, 2], albedo 0.8, isotropic."""
    grid = 0.3 + 1.7 * np.random.default_rng(0).random((8, 8, 12, 1))
    return {
        "type": "heterogeneous",
        "albedo": 0.8,
        "sigma_t": {
            "type": "gridvolume",
            "data": to_jit(mi.TensorXf, grid),
            "to_world": T().translate([-1.5, -1, -1]).scale([3, 2, 2]),
        },
    }
