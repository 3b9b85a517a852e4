"""Opaque surfaces in the volume method (``surfaces.py``, ``surface_march.py``, ``shading.py``):
photons and camera rays stop at them, the viewing pass shades them (direct light through the
grid's κ + the photons recorded on them), against Mitsuba ``volpath`` on scenes written as a user
would: a lamp in a fog box standing on a floor, a fog box on a larger floor under a point light
(and before a mirror), Mitsuba's Cornell box with fog over its floor, and Sun et al. 2008 Fig. 1's
setting, a glass ball over a floor in fog (the floor caustic).

The fog boxes reach a little below the floors (a floor coplanar with a ``null`` face is hit or
missed at random by both renderers), and the floors declare no ``exterior`` medium: ``volpath``
gives a surface's declared exterior medium to every ray leaving it, so a floor that declares the
fog outside the fog box has fog above it everywhere for ``volpath`` — 20 % darker there than the
scene the box describes. Metrics as in test_lights_vs_volpath.py: the brightness ratio and the
relative RMSE of 4 × 4-block means, ours deterministic, ``volpath`` at the seed given.
"""

import numpy as np
import pytest

import mitsuba_reference
from camera_blocks import blocks_near
from photonmap import PhotonmapWarning, VolumePipeline, mi
from photonmap.core.image import block_means

WIDTH, HEIGHT = 64, 48
ISOTROPIC = {"type": "isotropic"}


def camera(origin, target, fov=40.0) -> dict:
    return {
        "type": "perspective",
        "fov": fov,
        "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": WIDTH, "height": HEIGHT, "rfilter": {"type": "box"}},
    }


def fog_box(half, centre) -> dict:
    return {
        "type": "cube",
        "to_world": mi.ScalarTransform4f().translate(centre).scale(half),
        "bsdf": {"type": "null"},
        "interior": {"type": "ref", "id": "fog"},
    }


def floor(size: float, albedo=0.6) -> dict:
    return {
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(size),
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [albedo] * 3}},
    }


def lamp_in_fog() -> dict:
    """A small spherical lamp in a fog box on a diffuse floor, with a blue block (the shared
    tools' lamp_in_fog.xml with consistent media and an isotropic fog)."""
    block = mi.ScalarTransform4f().translate([0.9, 0.41, 0.3]).scale(0.4)
    return {
        "type": "scene",
        "fog": {"type": "homogeneous", "sigma_t": 0.4, "albedo": 0.85},
        "fog_box": fog_box([2.0, 1.3, 1.25], [0, 1.2, 0]),
        "floor": floor(5.0),
        "block": {
            "type": "cube",
            "to_world": block,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.3, 0.5, 0.7]}},
        },
        "lamp": {
            "type": "sphere",
            "center": LAMP,
            "radius": 0.15,
            "emitter": {"type": "area", "radiance": 30.0},
        },
        "sensor": camera([0, 2.2, 7.5], [0, 0.7, 0]),
    }


LAMP = [-0.7, 1.3, 0.0]


def fog_on_floor() -> dict:
    """A fog box standing on a larger floor, a point light above and beside it."""
    return {
        "type": "scene",
        "fog": {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.8},
        "fog_box": fog_box([1.2, 0.85, 0.8], [0, 0.75, 0]),
        "floor": floor(4.0),
        "light": {"type": "point", "position": [0.6, 3.0, 0.4], "intensity": 12.0},
        "sensor": camera([0, 2.5, 7.0], [0, 0.5, 0]),
    }


def fog_before_mirror() -> dict:
    """:func:`fog_on_floor` before a mirror (a perfect ``conductor``) that the camera sees it in,
    lit by a small spherical light (light through a mirror onto a diffuse floor is a path
    ``volpath`` samples only from an area light)."""
    scene = fog_on_floor()
    mirror = mi.ScalarTransform4f().translate([0, 1.0, -1.6]).scale([2.5, 1.2, 1.0])
    scene["mirror"] = {"type": "rectangle", "to_world": mirror, "bsdf": {"type": "conductor"}}
    scene["light"] = {
        "type": "sphere",
        "center": [0.6, 3.0, 0.4],
        "radius": 0.3,
        "emitter": {"type": "area", "radiance": 12.0 / (np.pi * 0.3**2)},
    }
    scene["sensor"] = camera([1.0, 2.0, 6.5], [0, 0.7, -0.5])
    return scene


def cornell_fog() -> dict:
    """Mitsuba's own Cornell box (``mi.cornell_box()``) with a fog box over its floor."""
    scene = mi.cornell_box()
    scene.pop("integrator")
    scene["fog"] = {"type": "homogeneous", "sigma_t": 0.6, "albedo": 0.8}
    scene["fog_box"] = fog_box([0.9, 0.45, 0.9], [0, -0.5, 0])
    scene["sensor"]["film"] = {
        "type": "hdrfilm",
        "width": WIDTH,
        "height": HEIGHT,
        "rfilter": {"type": "box"},
    }
    return scene


GLASS = ([0.0, 0.9, 0.0], 0.5)


def glass_over_floor() -> dict:
    """Sun et al. 2008 Fig. 1's setting: a glass ball above a floor in thin fog, a small
    spherical light above it (a point light's caustic is a path ``volpath`` cannot sample)."""
    radius = 0.25
    return {
        "type": "scene",
        "fog": {"type": "homogeneous", "sigma_t": 0.15, "albedo": 0.9},
        "fog_box": fog_box([1.5, 1.25, 1.5], [0, 1.15, 0]),
        "floor": floor(3.0),
        "glass": {
            "type": "sphere",
            "center": GLASS[0],
            "radius": GLASS[1],
            "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0},
        },
        "lamp": {
            "type": "sphere",
            "center": [0.0, 3.2, 0.0],
            "radius": radius,
            "emitter": {"type": "area", "radiance": 25.0 / (np.pi * radius**2)},
        },
        "sensor": camera([0, 2.0, 6.0], [0, 0.5, 0]),
    }


# scene: (builder, volpath spp, blocks left out: (centre, radius) or None)
SETUP = {
    "lamp_in_fog": (lamp_in_fog, 1024, (LAMP, 0.2)),
    "fog_on_floor": (fog_on_floor, 512, None),
    "fog_before_mirror": (fog_before_mirror, 1024, None),
    "glass_over_floor": (glass_over_floor, 1024, GLASS),
    "cornell_fog": (cornell_fog, 512, ([0, 0.99, 0], 0.3)),
}
OURS = {"grid": 48, "photons": 256**2, "spp": 4}


def compare(name: str, seed: int = 0) -> tuple[float, float, float]:
    """(brightness ratio, 4 × 4-block relative RMSE) of ours against volpath (``seed``), leaving
    out the blocks that see the lamp (a voxel grid cannot resolve the fog's 1/r² glow around a
    small light, nor the pixel filter's share of the lamp) and the glass ball (the volume
    method's curved rays through a blurred index grid, and no Fresnel reflection on the ball,
    are another test's subject). The third number is the brightness ratio of the blocks that
    see the floor within 0.45 of the point under the glass ball (its caustic), NaN elsewhere."""
    build, spp, left_out = SETUP[name]
    scene = build()
    integrator = mi.load_dict({"type": "volpath", "max_depth": 64})
    reference = mitsuba_reference.render(mi.load_dict(scene), integrator=integrator, spp=spp, seed=seed)
    ours = np.array(VolumePipeline(scene, **OURS).render())
    a, b = block_means(ours), block_means(reference[..., :3])
    sensor = mi.load_dict(scene["sensor"])
    keep = np.ones(a.shape[:2], bool)
    if left_out:
        keep = ~blocks_near(sensor, *left_out, WIDTH, HEIGHT)
    spot = float("nan")
    if name == "glass_over_floor":
        under = blocks_near(sensor, [0, 0, 0], 0.45, WIDTH, HEIGHT) & keep
        spot = a[under].mean() / b[under].mean()
    a, b = a[keep], b[keep]
    return a.mean() / b.mean(), np.sqrt(np.mean((a - b) ** 2)) / b.mean(), spot


# measured over volpath seeds 0-3 (ours deterministic; grid 48, 256² photons, 4 spp):
#   lamp_in_fog       ratio 1.000-1.004  error 0.044-0.047
#   fog_on_floor      ratio 0.998-0.999  error 0.018-0.021
#   fog_before_mirror ratio 0.994-1.004  error 0.052-0.061  (volpath noise: light via the mirror)
#                     (with the point light of fog_on_floor ours is 1.25x: volpath cannot sample
#                     a point light through a mirror, ours has it from the photons)
#   cornell_fog       ratio 0.992-0.995  error 0.059-0.066  (the walls' interreflection by
#                     direct visualisation of 256² photons: blotchy, no final gather)
#   glass_over_floor  ratio 1.022-1.026  error 0.110-0.117  (volpath's caustic noise included)
#                     caustic 1.14-1.18 (grid 96, 512² photons: 1.09 — the ball is 8 voxels in
#                     radius at grid 48, its blurred index focuses the caustic less sharply);
#                     without the photons on the surfaces 0.47 (the glass stops the shadow rays)
# Floors that did not stop the camera rays (before) showed the environment through them: black
# here, 0.37x on the shared tools' lamp_in_fog.xml.
CASES = {
    "lamp_in_fog": (0.05, 0.09),
    "fog_on_floor": (0.05, 0.04),
    "fog_before_mirror": (0.05, 0.12),
    "glass_over_floor": (0.05, 0.23),
    "cornell_fog": (0.05, 0.13),
}
CAUSTIC_BOUND = 0.3


@pytest.mark.parametrize("name", list(CASES))
def test_surfaces_match_volpath(name):
    ratio, error, caustic = compare(name)
    ratio_bound, error_bound = CASES[name]
    assert abs(ratio - 1) < ratio_bound, ratio
    assert error < error_bound, error
    if name == "glass_over_floor":
        assert abs(caustic - 1) < CAUSTIC_BOUND, caustic


# ------------------------------------------------------------------------------------------------
# Oracles and messages


def plate_in_fog(**plate_bsdf) -> dict:
    """A fog cube cut in half by a horizontal opaque plate wider than it, a point light above."""
    plate = mi.ScalarTransform4f().translate([0, 0.0, 0]).rotate([1, 0, 0], -90).scale(1.5)
    return {
        "type": "scene",
        "fog": {"type": "homogeneous", "sigma_t": 0.6, "albedo": 0.9},
        "fog_box": fog_box([1.0, 1.0, 1.0], [0, 0, 0]),
        "plate": {
            "type": "rectangle",
            "to_world": plate,
            "bsdf": plate_bsdf or {"type": "diffuse"},
        },
        "light": {"type": "point", "position": [0.3, 2.5, 0.2], "intensity": 10.0},
        "sensor": camera([0, 1.0, 5.0], [0, 0, 0]),
    }


@pytest.mark.parametrize("scattering", ["single", "multiple"])
def test_photons_stop_at_an_opaque_plate(scattering):
    """Nothing below the plate is lit by photons: no fluence in the voxels below it (beyond the
    3×3×3 smoothing's reach) and no photon recorded under it; with multiple scattering photons
    are recorded on its top (the fog scatters light onto it), and nothing is left out (``spp``
    4: one ray per pixel centre would be named as aliasing the plate's edges)."""
    pipe = VolumePipeline(plate_in_fog(), grid=32, photons=128**2, scattering=scattering, spp=4)
    with pytest.warns(PhotonmapWarning) if scattering == "single" else _no_warning():
        pipe.render()
    C = pipe.grids["C"]  # (z, y, x, 3): the plate is at y = 0, voxel 16
    assert C[:, 18:].sum() > 0
    assert C[:, :14].max() == 0
    photons = pipe.stage_output("photon tracing").surface
    y = np.array(photons.position)[1] if photons.count else np.zeros(0)
    assert np.all(y > -1e-3)
    assert (photons.count > 100) == (scattering == "multiple")


def _no_warning():
    import warnings
    from contextlib import contextmanager

    @contextmanager
    def strict():
        with warnings.catch_warnings():
            warnings.simplefilter("error", PhotonmapWarning)
            yield

    return strict()


def test_what_is_not_rendered_is_named():
    """A partly transparent surface is rendered as fully transparent: a PhotonmapWarning names
    the shape and the method that renders it."""
    scene = plate_in_fog(type="mask", opacity=0.5, bsdf={"type": "diffuse"})
    scene["plate"]["id"] = "veil"
    with pytest.warns(PhotonmapWarning, match=r"'veil', partly transparent.*sppm"):
        VolumePipeline(scene, grid=16, photons=64**2)


def test_camera_move_reruns_the_viewing_pass_only():
    """Spec §4.1's rerun matrix with surfaces: the surface photons are a photon-stage output
    (a camera move keeps them), the shading a viewing-stage output (a light move redoes both)."""
    pipe = VolumePipeline(fog_on_floor(), grid=24, photons=64**2, spp=1)
    first = np.array(pipe.render())
    photons = pipe.stage_output("photon tracing").surface
    pipe.set_camera(origin=[0.5, 2.4, 6.8])
    moved = np.array(pipe.render())
    assert pipe.recomputed == ["viewing"] and not np.array_equal(first, moved)
    assert pipe.stage_output("photon tracing").surface is photons
    pipe.set_light(0, position=[-0.6, 3.0, 0.4])
    pipe.render()
    assert {"photon generation", "photon tracing", "viewing"} <= set(pipe.recomputed)


if __name__ == "__main__":
    for name in CASES:
        print(name, [np.round(compare(name, seed), 4).tolist() for seed in range(4)])
