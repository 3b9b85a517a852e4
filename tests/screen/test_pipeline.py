"""ScreenPipeline: the stage graph (spec §7), the built-in scenes, the ``ispm`` plugin and bad
input."""

import math
import re

import mitsuba as mi
import numpy as np
import pytest

import photonmap
from photonmap import ParameterError, SceneError, ScreenPipeline
from photonmap.screen.pipeline import STAGES

SMALL = {"width": 48, "height": 36}
FAST = {"photons": 24**2, "subsample": 4}


@pytest.fixture(scope="module")
def pipe():
    p = ScreenPipeline("cornell_ispm", **SMALL, **FAST)
    p.render()
    return p


def test_first_render_runs_every_stage_and_is_finite():
    p = ScreenPipeline("cornell_ispm", **SMALL, **FAST)
    image = np.array(p.render())
    assert image.shape == (36, 48, 3)
    assert np.all(np.isfinite(image)) and image.max() > 0
    assert p.recomputed == list(STAGES)
    assert set(p.timer.ms) == set(STAGES)
    assert p.stats["photon_slots"] == 24 * 24 * 2
    assert 0 < p.stats["photons"] <= p.stats["photon_slots"]
    for key in ("gbuffer", "photons", "direct", "visibility", "indirect_low", "indirect"):
        assert key in p.outputs
    again = np.array(p.render())
    assert p.recomputed == [] and np.array_equal(again, image)  # O12: deterministic


def test_invalidate_and_stage_output():
    """The public stage-cache interface (core.stages.StageCache): ``invalidate()`` makes the next
    frame a full frame (the benchmark's), ``invalidate(name)`` reruns that stage only (its inputs
    are unchanged, so the stages after it keep theirs), unknown names are refused."""
    p = ScreenPipeline("cornell_ispm", **SMALL, **FAST)
    image = np.array(p.render())
    assert p.stages == STAGES
    assert p.stage_output("composite") is p.outputs["image"]
    p.invalidate()
    assert np.array_equal(np.array(p.render()), image) and p.recomputed == list(STAGES)
    p.invalidate("soft shadows")
    p.render()
    assert p.recomputed == ["soft shadows"]
    with pytest.raises(ParameterError, match="no stage 'shadows'"):
        p.invalidate("shadows")
    with pytest.raises(ParameterError, match="has not run yet"):
        ScreenPipeline("cornell_ispm", **SMALL, **FAST).stage_output("splatting")


@pytest.mark.parametrize(
    ("change", "kept"),
    [
        (("camera", {"origin": (0.28, 0.3, -0.7)}), {"light G-buffer", "photon tracing"}),
        (("params", {"radius": 0.06}), {"eye G-buffer", "light G-buffer", "photon tracing",
                                        "direct + shadow rays", "soft shadows", "subsample",
                                        "glass"}),
        (("params", {"splat": "icosahedron"}), {"eye G-buffer", "photon tracing", "soft shadows",
                                                 "subsample"}),
        (("params", {"subsample": 2}), {"eye G-buffer", "photon tracing", "soft shadows"}),
        (("params", {"light_size": 0.03}), {"eye G-buffer", "photon tracing", "splatting",
                                            "upsampling"}),
        (("params", {"bounces": 1}), {"eye G-buffer", "light G-buffer", "soft shadows"}),
        (("light", {"position": (0.25, 0.5, 0.3)}), {"eye G-buffer", "subsample"}),
    ],
)  # fmt: skip
def test_a_change_reruns_only_what_it_needs(change, kept):
    p = ScreenPipeline("cornell_ispm", **SMALL, **FAST)
    before = np.array(p.render())
    kind, args = change
    if kind == "camera":
        p.set_camera(**args)
    elif kind == "params":
        p.set_params(**args)
    else:
        p.set_light(**args)
    after = np.array(p.render())
    assert p.recomputed, "something must rerun"
    assert not kept & set(p.recomputed), p.recomputed
    assert "composite" in p.recomputed
    assert not np.array_equal(before, after)


def test_two_bounces_add_light():
    """O7: the B = 2 photon map holds the B = 1 map, so L_ind(B=2) ≥ L_ind(B=1) per pixel."""
    p = ScreenPipeline("cornell_ispm", **SMALL, **FAST, bounces=1)
    p.render()
    one = np.array(p.outputs["indirect_low"])
    p.set_params(bounces=2)
    p.render()
    two = np.array(p.outputs["indirect_low"])
    assert np.all(two >= one - 1e-6) and two.sum() > 1.05 * one.sum()


def test_glass_sphere_caustic_and_eye_refraction():
    p = ScreenPipeline("cornell_glass_sphere", **SMALL, photons=48**2, subsample=2)
    image = np.array(p.render())
    assert np.all(np.isfinite(image))
    photons = p.outputs["photons"]
    density = np.array(photons.density)[np.array(photons.valid)]
    assert np.any(density >= 16)  # caustic photons: two refractions (A9 radius scaling)
    specular = np.array(p.outputs["specular"])
    assert specular.any()
    glass = np.array(p.outputs["glass"]).T
    assert glass[specular].max() > 0 and np.all(glass[~specular] == 0)


def test_glass_sphere_focus_lies_just_above_the_floor():
    """The glass sphere's refractive caustic focuses 1.5 R below its centre (η = 1.5): 20 mm above
    the floor (y = 0) of cornell_glass_sphere."""
    ispm = photonmap.scenes.ispm
    assert math.isclose(ispm.SPHERE_CENTER[1] - 1.5 * ispm.SPHERE_RADIUS, 0.02)


def test_area_light_scene_and_mesh_scene():
    """Area lights by sampling (cornell_steinhurst's ceiling light, mirror and glass spheres) and
    the procedural-mesh Cornell box."""
    p = ScreenPipeline("cornell_steinhurst", width=32, height=32, photons=16**2)
    assert p.light.kind == "area"
    radiance = np.array(mi.traverse(p.light.emitter)["radiance.value"]).ravel()
    area = np.array(p.light.emitter.get_shape().surface_area()).ravel()[0]
    assert np.allclose(p.light.power, np.pi * radiance * area, rtol=1e-4)  # Φ_e = π L_e A
    image = np.array(p.render())
    assert np.all(np.isfinite(image)) and image.mean() > 0
    m = ScreenPipeline("cornell_mesh", triangles=2000, **SMALL, **FAST)
    image = np.array(m.render())
    assert np.all(np.isfinite(image)) and image.mean() > 0


def test_ispm_plugin_matches_the_pipeline():
    scene = mi.load_dict(photonmap.scenes.SCENES["cornell_ispm"].build(**SMALL))
    integrator = mi.load_dict({"type": "ispm", "photons": 24**2, "subsample": 4})
    image = np.array(mi.render(scene, integrator=integrator))
    ref = np.array(ScreenPipeline("cornell_ispm", **SMALL, **FAST).render())
    assert np.allclose(image, ref, atol=1e-6)
    with pytest.raises(RuntimeError, match="unknown parameter"):
        mi.load_dict({"type": "ispm", "raduis": 0.1})


# ---------------------------------------------------------------------------------- bad input
def _no_light_scene():
    d = photonmap.scenes.SCENES["cornell_ispm"].build(**SMALL)
    d.pop("spot")
    d["sun"] = {"type": "directional", "direction": [0, -1, 0]}
    return d


@pytest.mark.parametrize(
    ("params", "error", "message"),
    [
        ({"photons": 0}, ParameterError, "photons must be >= 1"),
        ({"radius": -0.1}, ParameterError, "radius must be >= 0"),
        ({"radius": math.nan}, ParameterError, "radius must be a finite number"),
        ({"radius": True}, ParameterError, "radius must be a number"),
        ({"compression": 1.5}, ParameterError, "compression must lie in (0, 1]"),
        ({"subsample": 0}, ParameterError, "subsample must be >= 1"),
        ({"subsample": 2.5}, ParameterError, "subsample must be an integer"),
        ({"subsample": "x"}, ParameterError, "subsample must be an integer"),
        ({"bounces": -1}, ParameterError, "bounces must lie in [0, 8]"),
        ({"bounces": 9}, ParameterError, "bounces must lie in [0, 8]"),
        ({"max_depth": -2}, ParameterError, "max_depth must be >= -1"),
        ({"hide_emitters": "yes"}, ParameterError, "hide_emitters must be one of"),
        ({"seed": -1}, ParameterError, "seed must lie in [0, 4294967295]"),
        ({"splat": "disk"}, ParameterError, "splat must be one of quad, icosahedron"),
        ({"shadows": "blurry"}, ParameterError, "shadows must be one of"),
        ({"isg_samples": "4"}, ParameterError, "isg_samples must be two positive integers"),
        ({"light_size": -1.0}, ParameterError, "light_size must be >= 0"),
        ({"raduis": 0.1}, ParameterError, "unknown parameter 'raduis'"),
    ],
)
def test_bad_parameters(params, error, message):
    with pytest.raises(error, match=re.escape(message)):
        ScreenPipeline("cornell_ispm", **SMALL, **params)


def test_bad_set_params_keeps_the_old_ones(pipe):
    with pytest.raises(ParameterError, match="radius"):
        pipe.set_params(radius=-1.0)
    assert pipe.params.radius == 0


def test_scene_without_a_usable_light():
    with pytest.raises(SceneError, match="needs a spot, point or area light"):
        ScreenPipeline(_no_light_scene())


def test_light_inside_geometry():
    d = photonmap.scenes.SCENES["cornell_ispm"].build(**SMALL)
    d["ball"] = {"type": "sphere", "center": [0.278, 0.3, 0.279], "radius": 0.1,
                 "bsdf": {"type": "diffuse"}}  # fmt: skip
    d["spot"] = {"type": "point", "position": [0.278, 0.3, 0.279]}
    with pytest.raises(SceneError, match="lies inside geometry"):
        ScreenPipeline(d)
    p = ScreenPipeline("cornell_ispm", **SMALL, **FAST)  # a light moved into a block: refused
    with pytest.raises(SceneError, match="lies inside geometry"):
        p.set_light(position=(0.37, 0.2, 0.35))  # inside the tall block


def test_light_intensity_scales_the_image_linearly():
    p = ScreenPipeline("cornell_ispm", **SMALL, **FAST)
    one = np.array(p.render())
    p.set_light(intensity=np.array(photonmap.scenes.ispm.SPOT_INTENSITY) * 2)
    two = np.array(p.render())
    assert np.allclose(two, 2 * one, rtol=1e-4, atol=1e-7)
    assert "eye G-buffer" not in p.recomputed and "photon tracing" in p.recomputed
    with pytest.raises(ParameterError, match="intensity"):
        p.set_light(intensity=-1)


def test_shadow_modes_bracket_the_hard_shadow(pipe):
    """Every shadow mode renders; hard ⊂ soft ⊂ 1 in visibility terms: the blurred modes only
    move visibility between 0 and 1 near shadow edges."""
    vis = {}
    for mode in ("hard", "soft", "fixed_radius"):
        pipe.set_params(shadows=mode)
        pipe.render()
        vis[mode] = np.array(pipe.outputs["visibility"])
    assert set(np.unique(vis["hard"])) <= {0.0, 1.0}
    for mode in ("soft", "fixed_radius"):
        assert vis[mode].min() >= 0 and vis[mode].max() <= 1
        changed = vis[mode] != vis["hard"]
        assert 0 < changed.mean() < 0.5


def small_cornell(**integrator) -> dict:
    scene = mi.cornell_box()
    scene["sensor"]["film"].update(width=32, height=32, rfilter={"type": "box"})
    scene["integrator"] = {"type": "path", **integrator}
    return scene


@pytest.mark.parametrize("max_depth, bounces", [(2, 0), (3, 1), (6, 4), (-1, 8)])
def test_recorded_bounces_come_from_the_files_max_depth(max_depth, bounces):
    p = ScreenPipeline(small_cornell(max_depth=max_depth), photons=16**2)
    assert p.recorded_bounces() == bounces
    p.set_params(max_depth=5)
    assert p.recorded_bounces() == 3
    p.set_params(bounces=2)
    assert p.recorded_bounces() == 2


def test_max_depth_2_renders_direct_light_only():
    p = ScreenPipeline(small_cornell(max_depth=2), photons=16**2)
    image = np.array(p.render())
    assert p.outputs["photons"] is None and p.stats["photon_slots"] == 0
    assert not np.array(p.outputs["indirect"]).any()
    p.set_params(max_depth=3)
    brighter = np.array(p.render())
    assert brighter.mean() > 1.1 * image.mean()


def test_hide_emitters_hides_the_light_seen_directly():
    shown = ScreenPipeline(small_cornell(max_depth=3), photons=16**2)
    hidden = ScreenPipeline(small_cornell(max_depth=3, hide_emitters=True), photons=16**2)
    a, b = np.array(shown.render()), np.array(hidden.render())
    light = np.array(shown.outputs["gbuffer"].emission).max(axis=0).reshape(32, 32) > 0
    assert light.sum() > 4
    assert np.all(b[light] < 0.5 * a[light])
    np.testing.assert_allclose(b[~light], a[~light])
    shown.set_params(hide_emitters="true")
    np.testing.assert_allclose(np.array(shown.render()), b)
