"""The surface pipeline end to end (spec seed-001 §5.2 O12, O13)."""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mitsuba_reference
from photonmap.core.arrays import columns
from photonmap.core.errors import PhotonmapError
from photonmap.core.settings import PathSettings
from photonmap.surface.gather import irradiance_estimate
from photonmap.surface.photon_map import build_photon_maps
from photonmap.surface.pipeline import SurfacePipeline


def furnace(rho=0.5, radius=1.0, power=4 * math.pi, res=16):
    """A closed sphere, diffuse albedo ρ inside, a point light of intensity 1 W/sr at its centre,
    a camera at the centre: every wall point receives E = Φ/(4πR²) · 1/(1 − ρ)."""
    return mi.load_dict(
        {
            "type": "scene",
            "sphere": {
                "type": "sphere",
                "radius": radius,
                "flip_normals": True,
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": rho}},
            },
            "light": {
                "type": "point",
                "position": [0, 0, 0],
                "intensity": {"type": "rgb", "value": power / (4 * math.pi)},
            },
            "sensor": {
                "type": "perspective",
                "fov": 60,
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0, 0, 0], target=[0, 0, 1], up=[0, 1, 0]
                ),
                "film": {"type": "hdrfilm", "width": res, "height": res},
            },
        }
    )


@pytest.mark.parametrize("rho", [0.3, 0.7])
def test_furnace_irradiance_is_the_multiple_bounce_value(rho):
    scene = furnace(rho)
    global_map, _, _ = build_photon_maps(scene, 200_000, 0, settings=PathSettings(66, 3))
    rng = np.random.default_rng(1)
    n = rng.normal(size=(256, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    points, inward = mi.Point3f(*columns(mi.Float, n)), mi.Vector3f(*columns(mi.Float, -n))
    E = irradiance_estimate(global_map, points, inward, 100, 0.3)
    E = np.array(E)[0]
    expected = 1.0 / (1.0 - rho)  # Φ = 4π W on a sphere of area 4π m²
    # Monte Carlo (k = 100: ~10% per estimate, averaged over 256) and RR/depth truncation
    assert abs(E.mean() / expected - 1) < 0.03


def test_furnace_render_with_final_gather():
    rho = 0.5
    pipe = SurfacePipeline(
        furnace(rho), photons=100_000, caustic_photons=0, fg_rays=16, max_depth=64
    )
    L = np.array(pipe.render())
    expected = rho / math.pi * 1.0 / (1.0 - rho)  # L = ρ E / π
    assert np.all(np.isfinite(L))
    assert abs(L.mean() / expected - 1) < 0.05


def glass_sphere_over_floor(floor_y):
    """A glass ball (radius 1, n = 1.5) at the origin lit by a narrow spot light 20 above it (so
    the photons go to the ball), over a diffuse floor at height ``floor_y``."""
    return mi.load_dict(
        {
            "type": "scene",
            "ball": {
                "type": "sphere",
                "radius": 1.0,
                "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0},
            },
            "floor": {
                "type": "rectangle",
                "to_world": mi.ScalarTransform4f()
                .translate([0, floor_y, 0])
                .rotate([1, 0, 0], -90)
                .scale(6),
                "bsdf": {"type": "diffuse"},
            },
            "light": {
                "type": "spot",
                "cutoff_angle": 3.5,
                "beam_width": 3.4,
                "intensity": 100.0,
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0, 20, 0], target=[0, 0, 0], up=[0, 0, 1]
                ),
            },
            "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8}},
        }
    )


def test_glass_sphere_caustic_lies_where_geometric_optics_puts_it():
    n, R, D = 1.5, 1.0, 20.0
    f = n * R / (2 * (n - 1))  # ball-lens focal length from the centre (1.5 R)
    image = 1.0 / (1.0 / f - 1.0 / D)  # thin-lens image distance below the centre: 1.62
    spreads = []
    for floor in (-image, -2 * image):
        _, caustic, _ = build_photon_maps(
            glass_sphere_over_floor(floor), 1, 100_000, settings=PathSettings(9, 3)
        )
        p = np.array(caustic.photons.position).T
        assert len(p) > 1000
        assert np.allclose(p[:, 1], floor, atol=1e-3)
        assert np.hypot(np.median(p[:, 0]), np.median(p[:, 2])) < 0.05  # under the ball
        spreads.append(np.median(np.hypot(p[:, 0], p[:, 2])))
    # at the focal plane the caustic is a tight spot; twice as far it has spread
    assert spreads[0] < 0.25 * R and spreads[1] > 2 * spreads[0]


def test_same_seed_same_image_and_structures_agree():
    kw = dict(photons=20_000, caustic_photons=10_000, fg_rays=4, width=24, height=24)
    a = np.array(SurfacePipeline("cornell_steinhurst", **kw).render())
    b = np.array(SurfacePipeline("cornell_steinhurst", **kw).render())
    assert np.array_equal(a, b) and np.all(np.isfinite(a)) and a.mean() > 0
    c = np.array(SurfacePipeline("cornell_steinhurst", seed=3, **kw).render())
    assert not np.array_equal(a, c)
    d = np.array(SurfacePipeline("cornell_steinhurst", structure="kdtree", **kw).render())
    assert np.array_equal(a, d)  # the same photons found either way


@pytest.mark.parametrize("change", [{"k": 50}, {"lookup": "knn"}, {"radius": 0.3}])
def test_lookup_changes_keep_the_photon_maps(change):
    """k, lookup, irradiance_every and radius only change the derived lookup data: the photons
    are not traced again, and the image is a fresh pipeline's with the same parameters."""
    kw = dict(photons=5000, caustic_photons=5000, fg_rays=2, width=16, height=16)
    pipe = SurfacePipeline("cornell_steinhurst", **kw)
    pipe.render()
    assert "photon maps" in pipe.timer.ms and "irradiance" in pipe.timer.ms
    global_map, caustic_map, _ = pipe.photon_maps()
    pipe.set_params(**change)
    image = np.array(pipe.render())
    assert "photon maps" not in pipe.timer.ms
    assert ("irradiance" in pipe.timer.ms) == (change.get("lookup", "irradiance") == "irradiance")
    again = pipe.photon_maps()
    assert again[0] is global_map and again[1] is caustic_map
    assert np.array_equal(
        image, np.array(SurfacePipeline("cornell_steinhurst", **kw, **change).render())
    )
    pipe.render()  # nothing changed: neither maps nor irradiance are rebuilt
    assert "photon maps" not in pipe.timer.ms and "irradiance" not in pipe.timer.ms
    pipe.set_params(seed=1)  # a tracing parameter: the maps are traced again
    pipe.render()
    assert "photon maps" in pipe.timer.ms


@pytest.mark.parametrize("lookup", ["knn", "direct"])
def test_lookup_modes_agree_with_the_default_on_average(lookup):
    kw = dict(photons=50_000, caustic_photons=10_000, fg_rays=16, width=16, height=16)
    ref = np.array(SurfacePipeline("cornell_spot_indirect", **kw).render()).mean()
    other = np.array(SurfacePipeline("cornell_spot_indirect", lookup=lookup, **kw).render()).mean()
    assert abs(other / ref - 1) < 0.15


@pytest.mark.parametrize(
    "params, message",
    [
        ({"photons": 0}, r"photons must be >= 1, got 0: light paths"),
        ({"k": 0}, "k must be >= 1"),
        ({"k": 2.5}, "k must be an integer, got 2.5"),
        ({"fg_rays": True}, "fg_rays must be an integer, got True"),
        ({"caustic_photons": -1}, "caustic_photons must be >= 0"),
        ({"radius": -1.0}, "radius must be >= 0"),
        ({"radius": float("nan")}, "radius must be a finite number"),
        ({"seed": -1}, r"seed must lie in \[0, 4294967295\]"),
        ({"seed": 2**32}, "seed must lie in"),
        ({"structure": "octree"}, "structure must be one of hash, kdtree, got 'octree'"),
        ({"lookup": "magic"}, "lookup must be one of"),
        ({"fg_sampling": 3}, "fg_sampling must be a str"),
        ({"photonz": 3}, "unknown"),
    ],
)
def test_bad_parameters(params, message):
    with pytest.raises(PhotonmapError, match=message):
        SurfacePipeline("cornell_steinhurst", width=8, height=8, **params)


def test_caustic_estimate_is_shared_only_by_plain_pixels():
    """caustic_radiance: one estimate per pixel whose samples all see the same surface directly,
    Eq 2.6 at every sample elsewhere (edges, mirror and glass pixels)."""
    import drjit as dr

    from photonmap.core.camera import pixel_rays
    from photonmap.core.eye_rules import EyeRules
    from photonmap.core.eye_trace import trace_eye_paths
    from photonmap.core.media import broadcast
    from photonmap.core.sampling import rng
    from photonmap.surface.eye_terms import caustic_radiance
    from photonmap.surface.gather import radiance_estimate

    pipe = SurfacePipeline("cornell_steinhurst", photons=2000, caustic_photons=100_000)
    _, caustic_map, _ = pipe.photon_maps()
    radius, _ = pipe.radii()
    w, spp = 24, 4
    lanes = w * w * spp
    gen = rng(lanes, 0, 0)
    pipe.set_camera(width=w, height=w)
    pixel = dr.arange(mi.UInt32, lanes) // spp
    ray, weight = pixel_rays(pipe.sensor, pixel, mi.Point2f(gen.next_float32(), gen.next_float32()))
    rules = EyeRules(pipe.settings, pipe.traits)
    eye = trace_eye_paths(pipe.scene, (ray, weight, broadcast(None, lanes)), gen, rules)
    si, found, bounces = eye.si, eye.found, eye.bounces
    shared = np.array(caustic_radiance(caustic_map, si, found, bounces, spp, 50, radius))
    each = np.array(radiance_estimate(caustic_map, si, si.bsdf(), 50, radius, found))
    shared, each = (a.reshape(3, w * w, spp) for a in (shared, each))
    direct = np.array(found & (bounces == 0)).reshape(w * w, spp)
    normal = np.array(si.sh_frame.n).reshape(3, w * w, spp)
    lit = np.array(dr.max(si.emitter(pipe.scene).eval(si)) > 0).reshape(w * w, spp)
    one_wall = direct.all(axis=1) & (np.ptp(normal, axis=2).max(0) == 0) & ~lit.any(axis=1)
    assert 0.3 < one_wall.mean() < 1 and each.max() > 0
    first = each[:, one_wall][..., :1].repeat(spp, -1)
    np.testing.assert_allclose(shared[:, one_wall], first, rtol=1e-5)
    mixed = ~direct.all(axis=1)  # edges, mirror and glass: every sample keeps its own estimate
    assert mixed.sum() > 10
    np.testing.assert_allclose(shared[:, mixed], each[:, mixed], rtol=1e-5, atol=1e-7)


def test_extra_samples_clean_up_the_lights_and_their_specular_images():
    """emitter_spp: the pixels that see the area light or the mirror and glass spheres get extra
    samples of that term; they approach a high-sample path render where the light shows, and no
    other pixel changes."""
    from photonmap.core.bsdf import is_specular
    from photonmap.core.camera import pixel_rays
    from photonmap.scenes import SCENES

    kw = dict(photons=5000, caustic_photons=20_000, fg_rays=1, width=48, height=48)
    scene = mi.load_dict(SCENES["cornell_steinhurst"].build(width=48, height=48))
    path = mi.load_dict({"type": "path", "max_depth": 16})
    ref = mitsuba_reference.render(scene, integrator=path, spp=1024, seed=3)
    plain = np.array(SurfacePipeline("cornell_steinhurst", emitter_spp=0, **kw).render())
    extra = np.array(SurfacePipeline("cornell_steinhurst", emitter_spp=256, **kw).render())
    bright = ref.max(-1) > 1.0  # the light and its images dominate these pixels
    ray, _ = pixel_rays(scene.sensors()[0], dr.arange(mi.UInt32, 48 * 48), mi.Point2f(0.5))
    si = scene.ray_intersect(ray)
    spheres = np.array(is_specular(si.bsdf(), si.is_valid())).reshape(48, 48)
    near = np.pad(bright | spheres, 2)
    near = np.any([near[y : y + 48, x : x + 48] for y in range(5) for x in range(5)], axis=0)
    changed = np.any(extra != plain, axis=-1)
    assert bright.sum() > 10 and changed.any() and not changed[~near].any()

    def error(img):
        return np.sqrt(np.mean((img[bright] - ref[bright]) ** 2))

    assert error(extra) < 0.6 * error(plain)
