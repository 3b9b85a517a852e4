"""Photon tracing from Mitsuba emitters (spec seed-001 §2.2, A5; Steinhurst Algorithm 2.4): the
transport core's photon-path loop."""

import numpy as np
import pytest

from photonmap import dr, mi
from photonmap.core import photon_trace
from photonmap.core.emission import emit, emitter_powers, split_paths
from photonmap.core.errors import ParameterError, SceneError
from photonmap.core.photon_trace import PhotonRecords, PhotonRules, _check_power
from photonmap.core.sampling import rng
from photonmap.core.scene_info import SceneTraits
from photonmap.core.settings import PathSettings

T = mi.ScalarTransform4f
NAN = float("nan")


def trace_photons(scene, paths, max_depth=8, rr_depth=3, seed=0, caustics_only=False):
    """The records of ``paths`` light paths with at most ``max_depth`` interactions each (paths
    of ``max_depth + 1`` segments, Mitsuba's count)."""
    settings = PathSettings(max_depth + 1, rr_depth)
    rules = photon_trace.PhotonRules.of(scene, settings, caustics_only=caustics_only)
    return photon_trace.trace_photons(scene, paths, rules, seed).records


def closed_box(albedo, *lights, **shapes) -> mi.Scene:
    """A closed diffuse box (cube [−1, 1]³, normals flipped inwards) around ``lights``."""
    box = {"type": "cube", "flip_normals": True, "bsdf": diffuse(albedo)}
    entries = {f"light{i}": light for i, light in enumerate(lights)}
    return mi.load_dict({"type": "scene", "box": box, **entries, **shapes})


def diffuse(albedo) -> dict:
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}


def point(position=(0.3, -0.2, 0.1), intensity=1.0) -> dict:
    return {"type": "point", "position": list(position), "intensity": intensity}


def floor_disk(radius=1.0) -> dict:
    """A diffuse disk of ``radius`` at y = 0 facing +y."""
    return {
        "type": "disk",
        "to_world": T().rotate([1, 0, 0], -90).scale(radius),
        "bsdf": diffuse([0.5, 0.5, 0.5]),
    }


def sums(records: PhotonRecords, mask) -> tuple[np.ndarray, np.ndarray]:
    """Σ power over the records in ``mask`` and its Monte Carlo standard error (the sum is over
    ``records.paths`` independent paths, each contributing at most one record here)."""
    power = np.array(records.power, dtype=np.float64)[:, np.asarray(mask)]
    n = records.paths
    total = power.sum(axis=1)
    variance = (power**2).sum(axis=1) / n - (total / n) ** 2
    return total, np.sqrt(n * np.maximum(variance, 0.0))


def test_power_bookkeeping_in_a_closed_diffuse_box():
    albedo = np.array([0.8, 0.5, 0.3])
    records = trace_photons(closed_box(albedo.tolist(), point()), 20000, max_depth=6)
    emitted = records.emitted_power
    np.testing.assert_allclose(emitted, 4 * np.pi, rtol=1e-6)  # point light: Φ = 4π I
    depth = np.array(records.depth)
    assert depth.min() == 1 and depth.max() == 6
    # Hits 1 … rr_depth = 3 carry Φ·ρ^(d−1) exactly: every photon hits the box, a diffuse
    # bounce scales its power by ρ.
    for d in (1, 2, 3):
        np.testing.assert_allclose(sums(records, depth == d)[0], emitted * albedo ** (d - 1), 1e-4)
        assert np.sum(depth == d) == records.paths
    # Later hits go through Russian roulette: right on average.
    for d in (4, 5, 6):
        total, error = sums(records, depth == d)
        assert np.all(np.abs(total - emitted * albedo ** (d - 1)) < 4 * error + 1e-9), d
        assert np.sum(depth == d) < records.paths
    assert not np.any(np.array(records.caustic))


# albedo: bound on |Σ stored power / analytic - 1|, ~2x the largest of seeds 0-2 (measured
# 1e-4, 0.0011, 0.0027, 0.0034, 0.0046); without the Russian-roulette compensation the ratio
# falls by 0.001, 0.026, 0.12, 0.30, 0.53
TOTAL_POWER_BOUNDS = {0.1: 2e-4, 0.3: 0.002, 0.5: 0.005, 0.7: 0.006, 0.9: 0.008}


@pytest.mark.parametrize("albedo", list(TOTAL_POWER_BOUNDS))
def test_total_stored_power_in_a_closed_box(albedo):
    """Every photon path in a closed grey box with albedo ρ is stored at each of its
    ``max_depth`` = 16 interactions, so the stored power sums to ``Φ Σ_{d=1..16} ρ^(d−1)``;
    Russian roulette from depth 3 on keeps that sum right on average (spec §2.2)."""
    depth = 16
    records = trace_photons(closed_box([albedo] * 3, point()), 2**16, max_depth=depth)
    total = np.array(records.power, dtype=np.float64).sum(axis=1)
    expected = records.emitted_power * sum(albedo**d for d in range(depth))
    ratio = total / expected
    assert np.all(np.abs(ratio - 1) < TOTAL_POWER_BOUNDS[albedo]), ratio


def test_unbounded_paths_end_by_russian_roulette_alone():
    """``max_depth`` −1 (Mitsuba's unbounded): paths run until Russian roulette ends them, in as
    many chunks of the loop as they need, and the stored power sums to ``Φ / (1 − ρ)``."""
    albedo = 0.7
    scene = closed_box([albedo] * 3, point())
    records = photon_trace.trace_photons(
        scene, 2**15, PhotonRules.of(scene, PathSettings(-1, 3)), 1
    ).records
    total = np.array(records.power, dtype=np.float64).sum(axis=1)
    ratio = total / (records.emitted_power / (1 - albedo))
    assert np.all(np.abs(ratio - 1) < 0.01), ratio  # measured within 0.004 (seeds 0-2)
    assert int(np.array(records.depth).max()) > 3 * photon_trace.CHUNK


class CountingVertices(photon_trace.VertexRule):
    """A vertex rule whose per-path state counts the path's stored vertices: each record holds
    the count before it (its rank along the path)."""

    fields = {"path": mi.UInt32, "rank": mi.UInt32, "depth": mi.UInt32}

    def __init__(self, paths: int):
        self.paths = paths

    def extra(self):
        return dr.zeros(mi.UInt32, self.paths) + dr.opaque(mi.UInt32, 0)

    def record(self, state, si, bsdf, store, caustic):
        rank = mi.UInt32(state.extra)
        state.extra[store] += 1
        return state.path, rank, state.depth + 1

    def result(self, records, light, rays):
        return records


def test_a_vertex_rule_keeps_its_state_through_the_chunks():
    """A method's vertex rule sees the vertices the photon map stores (same paths, same
    depths: the same random numbers), and its per-path state follows each path through every
    chunk's compaction: along a path the ranks it counted are 0, 1, 2, … in depth order, past
    one chunk of :data:`~photonmap.core.photon_trace.CHUNK` interactions."""
    scene = closed_box([0.9] * 3, point())
    paths, seed = 4096, 3
    rules = photon_trace.PhotonRules(PathSettings(-1, 3), SceneTraits.of(scene))

    def traced(vertices):
        light = emit(scene, paths, seed)
        gen = rng(paths, seed, stream=1)
        return photon_trace.trace_light_paths(scene, light, gen, rules, vertices=vertices)[0]

    photons = traced(None)
    counted = traced(CountingVertices(paths))
    path, depth = (np.array(counted[k], np.int64) for k in ("path", "depth"))
    rank = np.array(counted["rank"], np.int64)
    order = np.lexsort((depth, path))
    expected = np.lexsort((np.array(photons.depth), np.array(photons.path)))
    assert np.array_equal(path[order], np.array(photons.path)[expected])
    assert np.array_equal(depth[order], np.array(photons.depth)[expected])
    first = np.r_[0, np.flatnonzero(np.diff(path[order])) + 1]  # each path's first record
    position = np.arange(len(order)) - np.repeat(first, np.diff(np.r_[first, len(order)]))
    assert np.array_equal(rank[order], position)
    assert rank.max() >= photon_trace.CHUNK


def test_a_mask_stores_photons_and_lets_the_rest_through():
    """A ``mask`` of opacity 0.3 over a diffuse floor: photons are stored on the mask (its
    smooth lobe) and 0.7 of the light goes straight through (its Null lobe, no interaction), so
    the floor's first hits carry 0.7 of what reaches the mask."""
    scene = mi.load_dict(
        {
            "type": "scene",
            "light": {"type": "directional", "direction": [0, -1, 0], "irradiance": 1.0},
            "mask": {
                "type": "rectangle", "to_world": T().translate([0, 1, 0]).rotate([1, 0, 0], 90),
                "bsdf": {"type": "mask", "opacity": 0.3, "bsdf": {"type": "diffuse",
                                                                   "reflectance": 0.0}},
            },
            "floor": {
                "type": "rectangle", "to_world": T().scale(10).rotate([1, 0, 0], -90),
                "bsdf": {"type": "diffuse", "reflectance": 0.0},
            },
        }
    )  # fmt: skip
    records = photon_trace.trace_photons(
        scene, 2**16, PhotonRules.of(scene, PathSettings(-1, 3)), 1
    ).records
    y = np.array(records.position)[1]
    power = np.array(records.power).sum(axis=0)
    on_mask = power[np.abs(y - 1) < 1e-3].sum()
    below = (np.abs(y) < 1e-3) & (np.abs(np.array(records.position)[0]) < 1)
    below &= np.abs(np.array(records.position)[2]) < 1
    assert abs(power[below].sum() / on_mask - 0.7) < 0.02  # measured 0.698
    assert np.all(np.array(records.depth)[below] == 1)  # passing the mask is no interaction


def test_null_boundaries_are_invisible_to_photons():
    """A null-BSDF cube (a fog box's boundary) around the light: photons cross it as if it were
    not there — first hits on the walls at depth 1, each depth's power as without it."""
    fog_box = {"type": "cube", "to_world": T().scale(0.5), "bsdf": {"type": "null"}}
    albedo = 0.5
    records = trace_photons(closed_box([albedo] * 3, point(), fog_box=fog_box), 4000, max_depth=3)
    depth = np.array(records.depth)
    np.testing.assert_allclose(np.abs(np.array(records.position)).max(axis=0), 1.0, atol=1e-5)
    for d in (1, 2, 3):
        assert np.sum(depth == d) == records.paths
        np.testing.assert_allclose(
            sums(records, depth == d)[0], records.emitted_power * albedo ** (d - 1), rtol=1e-4
        )


def glass_ball_over_floor():
    """A glass ball (n = 1.5, radius 0.5) 1 m above a diffuse floor, a point light above it."""
    return mi.load_dict(
        {
            "type": "scene",
            "floor": floor_disk(5.0),
            "glass": {
                "type": "sphere",
                "center": [0, 1, 0],
                "radius": 0.5,
                "bsdf": {"type": "dielectric", "int_ior": 1.5},
            },
            "light": point((0, 4, 0), 10.0),
        }
    )


def test_caustics_only_traces_exactly_the_caustic_records():
    """Caustic records end at a path's first smooth hit, so stopping every path there (the
    caustic map's cheap trace) keeps exactly the caustic records of a full trace."""
    scene = glass_ball_over_floor()
    full = trace_photons(scene, 2**14, seed=3)
    full = full.select(full.caustic)
    only = trace_photons(scene, 2**14, seed=3, caustics_only=True)
    assert only.count == full.count > 50 and only.paths == full.paths
    assert np.array(only.caustic).all()

    def rows(r):
        fields = (r.position, r.power, r.direction, r.normal)
        table = np.concatenate([np.array(f) for f in fields] + [np.array(r.depth)[None]])
        return table[:, np.lexsort(table[::-1])]

    np.testing.assert_array_equal(rows(only), rows(full))


def test_records_describe_the_hits():
    records = trace_photons(closed_box([0.5] * 3, point()), 4000, seed=3)
    position = np.array(records.position)
    direction = np.array(records.direction)
    normal = np.array(records.normal)
    assert records.count == dr.width(records.power) and records.paths == 4000
    np.testing.assert_allclose(np.abs(position).max(axis=0), 1.0, atol=1e-5)  # on the box
    np.testing.assert_allclose(np.linalg.norm(direction, axis=0), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=0), 1.0, atol=1e-5)
    assert np.all(np.sum(direction * normal, axis=0) < 0)  # photons arrive at the inner side
    # The first hit lies on the ray from the light.
    first = np.array(records.depth) == 1
    to_hit = position[:, first] - np.array([[0.3], [-0.2], [0.1]])
    cosine = np.sum(to_hit * direction[:, first], axis=0) / np.linalg.norm(to_hit, axis=0)
    np.testing.assert_allclose(cosine, 1.0, atol=1e-5)


def test_caustic_records_lie_under_a_glass_sphere():
    scene = glass_ball_over_floor()
    records = trace_photons(scene, 2**17)
    caustic = np.array(records.caustic)
    depth = np.array(records.depth)
    position = np.array(records.position)
    assert caustic.sum() > 500
    assert depth[caustic].min() >= 2 and not caustic[depth == 1].any()
    np.testing.assert_allclose(position[1, caustic], 0.0, atol=1e-5)  # on the floor
    radius = np.hypot(position[0], position[2])
    power = np.array(records.power).sum(axis=0)
    under = caustic & (radius < 0.5)
    assert power[under].sum() > 0.8 * power[caustic].sum()
    assert not (~caustic & (depth == 1) & (radius < 0.45)).any()  # the sphere's shadow
    # The sphere focuses: the caustic is brighter than the direct light around the shadow.
    direct = (depth == 1) & (radius > 1.0) & (radius < 1.5)
    caustic_density = power[caustic & (radius < 0.25)].sum() / (np.pi * 0.25**2)
    assert caustic_density > 2 * power[direct].sum() / (np.pi * (1.5**2 - 1.0))
    # A diffuse sphere in the same place makes no caustic.
    scene = mi.load_dict(
        {
            "type": "scene",
            "floor": floor_disk(5.0),
            "ball": {"type": "sphere", "center": [0, 1, 0], "radius": 0.5},
            "light": point((0, 4, 0), 10.0),
        }
    )
    assert not np.array(trace_photons(scene, 2**12).caustic).any()


def rough_ball_over_floor(light: dict) -> mi.Scene:
    """A rough glass ball (roughdielectric, GGX α 0.1) 1 m above a diffuse floor."""
    ball = {"type": "sphere", "center": [0, 1, 0], "radius": 0.5,
            "bsdf": {"type": "roughdielectric", "int_ior": 1.5, "alpha": 0.1}}  # fmt: skip
    return mi.load_dict({"type": "scene", "floor": floor_disk(5.0), "ball": ball, "light": light})


def test_followed_rough_glass_holds_no_records_and_makes_caustics():
    """With ``rough_glass`` (the surface method) rough glass is followed as glass is: no record on
    it, and the light it brings to the floor is caustic — the same light that without it lands
    there after two smooth bounces (in and out of the ball)."""
    scene = rough_ball_over_floor(point((0, 4, 0), 10.0))
    settings = PathSettings(9, 3)
    followed = photon_trace.trace_photons(
        scene, 2**17, PhotonRules.of(scene, settings, rough_glass=True), 1
    ).records
    shaded = photon_trace.trace_photons(scene, 2**17, PhotonRules.of(scene, settings), 1).records
    for records in (followed, shaded):
        assert records.count > 0
    y = np.array(followed.position)[1]
    assert np.all(np.abs(y) < 1e-4)  # all on the floor
    assert np.array(shaded.position)[1].max() > 0.4  # records on the ball
    assert not np.array(shaded.caustic).any()

    def under_the_ball(records, mask):
        position = np.array(records.position)
        near = (np.hypot(position[0], position[2]) < 0.45) & (np.abs(position[1]) < 1e-4)
        return sums(records, near & mask)

    depth = np.array(shaded.depth)
    caustic, error = under_the_ball(followed, np.array(followed.caustic))
    through, error2 = under_the_ball(shaded, depth == 3)  # light, ball in, ball out, floor
    assert caustic.sum() > 0.05 * 10.0 * 4 * np.pi / 100  # a real share of the light
    assert np.all(np.abs(caustic - through) < 4 * np.hypot(error, error2) + 1e-6)


def test_aimed_emission_aims_at_followed_rough_glass():
    light = {"type": "rectangle", "to_world": T().translate([0, 4, 0]).rotate([1, 0, 0], 90),
             "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 5.0}}}  # fmt: skip
    scene = rough_ball_over_floor(light)
    assert emit(scene, 4096, 0, 0.5).aimed_paths == 0  # rough glass is not specular
    assert emit(scene, 4096, 0, 0.5, rough_glass=True).aimed_paths > 1000


def spot(position=(0, 0, 0), target=(0, -1, 0)) -> dict:
    return {
        "type": "spot",
        "to_world": T().look_at(origin=list(position), target=list(target), up=[0, 0, 1]),
        "cutoff_angle": 40.0,
        "beam_width": 25.0,
        "intensity": 2.0,
    }


def area_quad() -> dict:
    to_world = T().translate([0, 0.5, 0]).rotate([1, 0, 0], 90).scale(0.3)
    return {
        "type": "rectangle",
        "to_world": to_world,
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [3.0, 2.0, 1.0]}},
    }


def spot_power(intensity=2.0, beam_width=25.0, cutoff=40.0) -> float:
    """Φ = 2π I ∫ falloff(θ) sin θ dθ for Mitsuba's spot fall-off, linear in θ from the beam
    width to the cut-off angle."""
    beam, cut = np.radians(beam_width), np.radians(cutoff)
    theta = np.linspace(beam, cut, 10001)
    ramp = np.trapezoid((cut - theta) / (cut - beam) * np.sin(theta), theta)
    return 2 * np.pi * intensity * (1 - np.cos(beam) + ramp)


ENVMAP = np.full((16, 32, 3), 0.7, dtype=np.float32)
INSIDE_THE_BOX = {  # lights in a closed box: Σ depth-1 power = emitted power = Φ
    "point": (point(), 4 * np.pi * 1.0),
    "spot": (spot(), spot_power()),
    "area": (area_quad(), np.pi * np.array([3.0, 2.0, 1.0]) * 0.6**2),  # Φ = π L A
}
ABOVE_A_DISK = {  # lights above a unit disk: the power reaching its front
    "directional": (
        {"type": "directional", "direction": [0, -1, 0], "irradiance": 2.5},
        2.5 * np.pi,
    ),
    "constant": ({"type": "constant", "radiance": 0.7}, np.pi * 0.7 * np.pi),  # E = π L
    "envmap": ({"type": "envmap", "bitmap": mi.Bitmap(ENVMAP)}, np.pi * 0.7 * np.pi),
}


@pytest.mark.parametrize("kind", list(INSIDE_THE_BOX))
def test_lights_inside_a_closed_box(kind):
    light, power = INSIDE_THE_BOX[kind]
    scene = closed_box([0.5] * 3, light)
    np.testing.assert_allclose(emitter_powers(scene)[0], power, rtol=0.01)
    records = trace_photons(scene, 2**14)
    np.testing.assert_allclose(records.emitted_power, power, rtol=0.02)
    total, _ = sums(records, np.array(records.depth) == 1)
    np.testing.assert_allclose(total, records.emitted_power, rtol=1e-4)
    assert np.all(np.isfinite(np.array(records.power)))


@pytest.mark.parametrize("kind", list(ABOVE_A_DISK))
def test_lights_from_far_away(kind):
    light, arriving = ABOVE_A_DISK[kind]
    scene = mi.load_dict({"type": "scene", "floor": floor_disk(), "light": light})
    records = trace_photons(scene, 2**15)
    # Directional and environment light is emitted through the scene's bounding sphere.
    np.testing.assert_allclose(records.emitted_power, emitter_powers(scene)[0], rtol=0.02)
    front = (np.array(records.depth) == 1) & (np.array(records.direction)[1] < 0)
    total, error = sums(records, front)
    assert np.all(np.abs(total - arriving) < 4 * error), (total, arriving, error)


def test_budget_split_follows_power():
    np.testing.assert_array_equal(split_paths(np.array([[1.0] * 3, [3.0] * 3]), 1000), [250, 750])
    counts = split_paths(np.array([0.3, 1.1, 2.9, 0.7]), 13)
    assert counts.sum() == 13
    assert np.all(np.abs(counts - 13 * np.array([0.3, 1.1, 2.9, 0.7]) / 5.0) < 1)
    np.testing.assert_array_equal(split_paths(np.array([1e-6, 1.0, 1e-6]), 10), [1, 8, 1])
    with pytest.raises(ParameterError, match="at least 3 paths"):
        split_paths(np.ones(3), 2)
    # Two point lights of intensity 1 and 3, each in its own closed box.
    rooms = {
        "left": {"type": "cube", "flip_normals": True, "to_world": T().translate([-3, 0, 0])},
        "right": {"type": "cube", "flip_normals": True, "to_world": T().translate([3, 0, 0])},
    }
    scene = mi.load_dict(
        {
            "type": "scene",
            **rooms,
            "dim": point((-3, 0, 0), 1.0),
            "bright": point((3, 0, 0), 3.0),
        }
    )
    records = trace_photons(scene, 1000, max_depth=1)
    left = np.array(records.position)[0] < 0
    assert left.sum() == 250 and (~left).sum() == 750
    np.testing.assert_allclose(sums(records, left)[0], 4 * np.pi, rtol=1e-5)
    np.testing.assert_allclose(sums(records, ~left)[0], 12 * np.pi, rtol=1e-5)


def test_same_seed_same_records():
    scene = closed_box([0.6, 0.5, 0.4], point(), spot((0, 0.5, 0), (0, 1, 0)))
    a, b = (trace_photons(scene, 3000, seed=7) for _ in range(2))
    c = trace_photons(scene, 3000, seed=8)
    for name in ("position", "power", "direction", "normal", "depth", "caustic"):
        np.testing.assert_array_equal(np.array(getattr(a, name)), np.array(getattr(b, name)))
    assert a.count != c.count or not np.array_equal(np.array(a.position), np.array(c.position))


def test_select_keeps_bookkeeping():
    records = trace_photons(closed_box([0.5] * 3, point()), 500)
    first = records.select(records.depth == 1)
    assert first.count == 500 and first.paths == 500
    np.testing.assert_array_equal(first.emitted_power, records.emitted_power)
    np.testing.assert_array_equal(np.array(first.depth), 1)


def test_scene_without_emitters():
    scene = mi.load_dict({"type": "scene", "ball": {"type": "sphere"}})
    with pytest.raises(SceneError, match="no emitter.*add a light"):
        trace_photons(scene, 100)
    np.testing.assert_array_equal(emitter_powers(scene).shape, (0, 3))


def test_scene_without_shapes():
    scene = mi.load_dict({"type": "scene", "sky": {"type": "constant"}})
    with pytest.raises(SceneError, match="no shapes"):
        trace_photons(scene, 100)


def test_dark_emitters_are_named():
    scene = closed_box([0.5] * 3, point(intensity=2.0), point(intensity=0.0))
    with pytest.raises(SceneError, match="emitter 'light1' .*emits no power"):
        trace_photons(scene, 100)
    dark_quad = {**area_quad(), "emitter": {"type": "area", "radiance": 0.0}}
    scene = closed_box([0.5] * 3, **{"lamp": dark_quad})
    with pytest.raises(SceneError, match="area light of shape 'lamp' emits no power"):
        trace_photons(scene, 100)


def test_nan_in_a_texture_names_the_shape():
    texels = np.full((4, 4, 3), 0.5, dtype=np.float32)
    texels[1, 2, 0] = NAN
    ball = {
        "type": "sphere",
        "radius": 0.3,
        "bsdf": {"type": "diffuse", "reflectance": {"type": "bitmap", "data": mi.TensorXf(texels)}},
    }
    with pytest.raises(SceneError, match="shape 'ball'.*'reflectance.data'"):
        trace_photons(closed_box([0.5] * 3, point(), ball=ball), 100)
    checks = {"type": "checkerboard", "color0": {"type": "rgb", "value": [0.2, NAN, 0.2]}}
    tiled = {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": checks}}
    with pytest.raises(SceneError, match="shape 'tiles'.*'reflectance.color0.value'"):
        trace_photons(closed_box([0.5] * 3, point(), tiles=tiled), 100)


def test_nan_in_an_emitter_is_named():
    with pytest.raises(SceneError, match="emitter 'light0'.*NaN"):
        trace_photons(closed_box([0.5] * 3, point(intensity=NAN)), 100)


def test_nan_power_after_tracing_is_reported():
    records = trace_photons(closed_box([0.5] * 3, point()), 10, max_depth=1)
    records.power = dr.select(records.depth == 1, mi.Color3f(NAN), records.power)
    with pytest.raises(SceneError, match="10 photon records have NaN"):
        _check_power(records)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"paths": 0}, "at least 1"),
        ({"paths": 10, "max_depth": -1}, "max_depth"),
        ({"paths": 10, "rr_depth": 0}, "rr_depth"),
    ],
)
def test_bad_parameters(kwargs, message):
    with pytest.raises(ParameterError, match=message):
        trace_photons(closed_box([0.5] * 3, point()), **kwargs)
