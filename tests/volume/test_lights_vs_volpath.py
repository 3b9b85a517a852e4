"""Lights anywhere against Mitsuba ``volpath``: one fog box, one light of each
kind, single scattering.

The fog is a 4 × 2 × 2 box (σ_t 0.5, albedo 0.9, isotropic) in vacuum, the box grid over it
(32 × 16 × 16 voxels, 48 for the spot, point and sphere lights); the lights:
a point light and a spot light inside the fog, a spherical area emitter inside the fog, a
rectangle emitter above the grid (outside it, facing down), a constant
environment and an envmap with a bright patch (the background too). ``volpath`` at
``max_depth = 2`` is direct light plus single scattering here (Mitsuba does not count the
crossings of a ``null`` boundary; tests/volume/test_bounded_fog.py), what the volume method
computes with ``scattering="single"``, ``phase_k = 0`` and no table. Pixels whose camera ray
meets the spherical emitter are left out of both images (the viewing pass does not see emitter
shapes, volpath does).

Metrics (64 × 48, ours 128² photons per light and 4 spp, volpath 256 spp): the brightness
ratio mean(ours)/mean(volpath) and the relative RMSE of 4 × 4-block means. Measured values and
bounds (~1.5-2x) are at ``CASES``.
"""

import numpy as np
import pytest

import mitsuba_reference
from camera_blocks import blocks_near
from photonmap import VolumePipeline, mi
from photonmap.core.image import block_means

WIDTH, HEIGHT = 64, 48
SPHERE = (np.array([-1.0, 0.55, 0.2]), 0.15)
SPOT = [0.5, 0.6, 0.0]


def camera() -> dict:
    return {
        "type": "perspective",
        "fov": 45.0,
        "to_world": mi.ScalarTransform4f().look_at(
            origin=[0, 1.5, 9], target=[0, 0, 0], up=[0, 1, 0]
        ),
        "film": {"type": "hdrfilm", "width": WIDTH, "height": HEIGHT, "rfilter": {"type": "box"}},
    }


LIGHTS = {
    "point": {"type": "point", "position": [0.7, 0.3, 0.1], "intensity": 4.0},
    "spot": {
        "type": "spot",
        "intensity": 12.0,
        "cutoff_angle": 50.0,
        "beam_width": 30.0,
        "to_world": mi.ScalarTransform4f().look_at(
            origin=SPOT, target=[0.3, -1.0, 0.2], up=[0, 0, 1]
        ),
    },
    "sphere": {
        "type": "sphere",
        "center": SPHERE[0].tolist(),
        "radius": SPHERE[1],
        "emitter": {"type": "area", "radiance": 40.0},
    },
    "rectangle": {
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f()
        .translate([0.8, 4.0, 0.0])
        .rotate([1, 0, 0], 90)
        .scale(0.75),
        "emitter": {"type": "area", "radiance": 6.0},
    },
    "environment": {"type": "constant", "radiance": 0.3},
}


def sky_bitmap(width=64, height=32) -> mi.Bitmap:
    """A dim sky with a bright patch above and to one side (a flipped direction convention
    would light the fog from below and the other side)."""
    v, u = np.meshgrid(
        (np.arange(height) + 0.5) / height, (np.arange(width) + 0.5) / width, indexing="ij"
    )
    patch = np.exp(-((u - 0.15) ** 2 + (v - 0.25) ** 2) / 0.01)
    image = np.stack([0.05 + 6 * patch, 0.05 + 4 * patch, 0.08 + 2 * patch], axis=-1)
    return mi.Bitmap(image.astype(np.float32))


def fog_box(light: str) -> dict:
    return {
        "type": "scene",
        "fog": {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.9},
        "fog_box": {
            "type": "cube",
            "to_world": mi.ScalarTransform4f().scale([2, 1, 1]),
            "bsdf": {"type": "null"},
            "interior": {"type": "ref", "id": "fog"},
        },
        "light": LIGHTS[light] if light != "envmap" else {"type": "envmap", "bitmap": sky_bitmap()},
        "sensor": camera(),
    }


def compare(light: str, seed: int = 0) -> tuple[float, float]:
    """(brightness ratio, 4 × 4-block relative RMSE) of ours against volpath (``seed``)."""
    grid, spp, centre, radius = SETUP[light]
    scene = fog_box(light)
    integrator = mi.load_dict({"type": "volpath", "max_depth": 2})
    image = mi.render(mi.load_dict(scene), integrator=integrator, spp=spp, seed=seed)
    reference = np.array(image)[..., :3]
    pipe = VolumePipeline(
        scene, grid=grid, photons=128**2, phase_k=0.0, table=0.0, spp=4, scattering="single"
    )
    ours = np.array(pipe.render())
    a, b = block_means(ours), block_means(reference)
    keep = np.ones(a.shape[:2], bool)
    if radius > 0:
        keep = ~blocks_near(mi.load_dict(camera()), centre, radius, WIDTH, HEIGHT)
    a, b = a[keep], b[keep]
    return a.mean() / b.mean(), np.sqrt(np.mean((a - b) ** 2)) / b.mean()


# light: grid, volpath spp, centre and radius of the left-out region (radius 0: none)
SETUP = {
    "point": (48, 1024, LIGHTS["point"]["position"], 0.3),
    "spot": (48, 1024, SPOT, 0.3),
    "sphere": (48, 1024, SPHERE[0], SPHERE[1] + 0.3),
    "rectangle": (32, 256, None, 0.0),
    "environment": (32, 256, None, 0.0),
    "envmap": (32, 256, None, 0.0),
}
# light: (ratio bound |r − 1|, block-error bound); measured over volpath seeds 0-1 (the test
# uses seed 0), ours deterministic, on the box grid with S9's exact step integrals:
#   point        ratio 1.020-1.022  error 0.128-0.137  (grid 32: 1.04; 64: 1.01 — the
#   sphere       ratio 1.023-1.025  error 0.084-0.096   discretisation near a light in the fog)
#   spot         ratio 0.995-0.998  error 0.125-0.160
#   rectangle    ratio 1.004-1.005  error 0.075
#   environment  ratio 1.0000-1.0002 error 0.0032-0.0037
#   envmap       ratio 0.9993-1.0003 error 0.009-0.011
# (Before box grids, in the grid cube of side 4 with S9's end-of-step transmittance (the paper's
# rule, 3 % dark here) the ratios were 0.985-1.014: that rule's bias and the half voxel of optical
# depth photons miss entering fog inside the grid (octree.py) cancelled.)
# The blocks left out around the point light, the spot's apex and the sphere hold the 1/r
# singularity of the in-scattered radiance near a small light, which a voxel grid cannot resolve
# (and volpath's own noise there is 0.16-2.3 in block error between 1024 and 4096 spp).
# Mutations (emit.py, by hand, then reverted), ratio / error: Φ halved gives 0.49-0.51 for the
# point, spot and area lights, 0.96 / 0.077 and 0.90 / 0.22 for the environments (whose
# background stays); an environment's photons started on their exit faces 0.92 / 0.15; its
# projected area without the |ω_a| 1.04 / 0.084; the envmap's photons sent towards the bright
# patch instead of from it (the direction convention, which a constant environment cannot
# show) 1.012 / 0.136; a distant emitter's cone weight without cos θ_e (rectangle) 1.09 / 0.23.
# Not caught here, at this resolution, and caught by test_lights_anywhere.py instead: spec
# A16's smoothstep spot profile (1.018 / 0.127), an area emitter's directions uniform over the
# hemisphere instead of its cosine lobe (sphere 0.996 / 0.094).
CASES = {
    "point": (0.035, 0.25),
    "spot": (0.02, 0.27),
    "sphere": (0.04, 0.16),
    "rectangle": (0.025, 0.12),
    "environment": (6e-4, 0.012),
    "envmap": (0.002, 0.03),
}


@pytest.mark.parametrize("light", list(CASES))
def test_light_kind_matches_volpath_single_scattering(light):
    ratio, error = compare(light)
    ratio_bound, error_bound = CASES[light]
    assert abs(ratio - 1) < ratio_bound, ratio
    assert error < error_bound, error


if __name__ == "__main__":
    for name in CASES:
        print(name, [np.round(compare(name, seed), 4).tolist() for seed in range(3)])


def test_a_hidden_environment_matches_volpath():
    """hide_emitters: the environment met by camera rays themselves — through the fog, which is
    no interaction — is hidden, as volpath hides it; the fog it lights is not."""
    scene = fog_box("environment")
    integrator = mi.load_dict({"type": "volpath", "max_depth": 2, "hide_emitters": True})
    reference = mitsuba_reference.render(mi.load_dict(scene), integrator=integrator, spp=256)[..., :3]
    pipe = VolumePipeline(scene, grid=32, photons=128**2, phase_k=0.0, table=0.0, spp=4,
                          scattering="single", hide_emitters="true")  # fmt: skip
    hidden = np.array(pipe.render())
    pipe.set_params(hide_emitters="false")
    shown = np.array(pipe.render())
    a, b = block_means(hidden), block_means(reference)
    assert a.mean() / b.mean() == pytest.approx(1.0, abs=0.03)
    assert np.sqrt(np.mean((a - b) ** 2)) / b.mean() < 0.05
    assert np.all(hidden <= shown + 1e-6) and shown.mean() > 2 * hidden.mean()
