"""The screen method on ordinary Mitsuba scenes: area lights (a sphere light's
direct light against the analytic cap irradiance, the light seen in a mirror), ``null``-BSDF
shapes invisible, media and extra lights warned about, a NaN index of refraction refused."""

import math
import warnings

import mitsuba as mi
import numpy as np
import pytest

from photonmap import PhotonmapWarning, SceneError, ScreenPipeline

W = H = 32
FAST = {"photons": 48**2, "subsample": 2}


def _cornell(width=W, height=H, **extra):
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=width, height=height, rfilter={"type": "box"})
    d.update(extra)
    return d


def _render(scene, **params):
    with warnings.catch_warnings():
        warnings.simplefilter("error", PhotonmapWarning)  # none expected here
        pipe = ScreenPipeline(scene, **FAST, **params)
    return pipe, np.array(pipe.render())


# ---------------------------------------------------------------------------- area lights
def _sphere_light_scene(h=2.0, radius=0.5, radiance=3.0):
    """A floor y = 0 (ρ = 0.5) under a sphere light of radius R at height h, seen from above."""
    return {
        "type": "scene",
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90)
                  .scale(20), "bsdf": {"type": "diffuse", "reflectance": 0.5}},
        "light": {"type": "sphere", "center": [0, h, 0], "radius": radius,
                  "emitter": {"type": "area", "radiance": radiance}},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1.2, 0.01],
                                                              target=[0, 0, 0], up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": W, "height": H}},
    }  # fmt: skip


def test_sphere_light_direct_light_is_the_cap_irradiance():
    """A floor point at horizontal distance x from a sphere light (radius R, centre at height h,
    radiance Le) sees the full spherical cap: E = π Le sin²α · cos θ with sin α = R/D, cos θ = h/D
    (D the centre distance), so L = ρ/π E = ρ Le R² h / D³. Catches a sphere treated as a point
    with a Lambertian lobe (cos θ_L of its "normal") and shadow rays blocked by the light itself
    (both far off)."""
    h, R, Le = 2.0, 0.5, 3.0
    pipe, image = _render(_sphere_light_scene(h, R, Le), shadows="hard", bounces=1)
    g = pipe.outputs["gbuffer"]
    pos = np.array(g.pos).T
    D = np.sqrt(pos[:, 0] ** 2 + h**2 + pos[:, 2] ** 2)
    ref = 0.5 * Le * R**2 * h / D**3
    direct = pipe.outputs["direct"]
    error = np.array(direct.L)[0] / ref - 1
    # 16 stratified light samples per pixel: measured max 0.73 %, mean 5.6e-5
    assert np.abs(error).max() < 0.012 and abs(error.mean()) < 2e-4
    assert np.all(np.array(direct.hard) == 1)  # nothing but the light itself on the way
    assert np.allclose(image[..., 0].ravel(), ref, rtol=0.012)  # no indirect light off one floor


def test_soft_shadows_take_the_area_lights_own_size():
    """The ISG virtual light radius of an area light is the radius of a disk of its mean projected
    area: a sphere's own radius, √(A/π) for a rectangle; ``light_size`` sizes only spot and point
    lights (and the fixed-radius blur)."""
    pipe = ScreenPipeline(_sphere_light_scene(radius=0.5), **FAST)
    assert pipe.light.radius == pytest.approx(0.5, rel=1e-5)
    pipe = ScreenPipeline(_cornell(), **FAST, light_size=0.3)
    assert pipe.light.radius == pytest.approx(math.sqrt(0.46 * 0.38 / math.pi), rel=1e-5)
    assert pipe.shadow_radius() == pipe.light.radius
    pipe.set_params(shadows="fixed_radius")
    assert pipe.shadow_radius() == pytest.approx(0.3 * pipe.diagonal)
    spot = ScreenPipeline("cornell_ispm", width=16, height=12, light_size=0.03, **FAST)
    assert spot.shadow_radius() == pytest.approx(0.03 * spot.diagonal)


def test_sampled_shadows_of_a_spot_are_its_hard_shadows():
    spot = ScreenPipeline("cornell_ispm", width=32, height=24, shadows="hard", **FAST)
    hard = np.array(spot.render())
    spot.set_params(shadows="sampled")
    assert np.array_equal(np.array(spot.render()), hard)


def test_sampled_shadows_equal_the_unshadowed_light_where_nothing_blocks():
    pipe, image = _render(_sphere_light_scene(), shadows="sampled", bounces=1)
    direct = pipe.outputs["direct"]
    assert np.allclose(np.array(direct.L_sampled), np.array(direct.L), rtol=1e-6)


def test_the_light_is_seen_directly_and_in_a_mirror():
    """The Cornell box's ceiling light shows its radiance Le to the eye, and a mirror back wall
    shows it again (camera → mirror → light); without emission both would be black."""
    Le = np.array([18.387, 13.9873, 6.75357])
    pipe, image = _render(_cornell())
    seen = np.array(pipe.outputs["gbuffer"].emission).T.reshape(H, W, 3)
    full = np.all(np.isclose(seen, Le, rtol=1e-4), axis=-1)  # pixels wholly on the light
    assert full.sum() >= 2 and np.all(image[full] >= Le)
    mirror_bsdf = {"type": "conductor", "material": "none"}
    mirror = _cornell(back={**mi.cornell_box()["back"], "bsdf": mirror_bsdf})
    pipe, image = _render(mirror)
    specular = np.array(pipe.outputs["specular"]).reshape(H, W)
    glass = np.array(pipe.outputs["glass"]).T.reshape(H, W, 3)
    mirrored = specular & np.all((glass >= Le * (1 - 1e-3)) & (glass <= Le * 1.05), axis=-1)
    assert mirrored.sum() >= 2  # the light's reflection: Le and the light it reflects itself


def test_area_light_photons_carry_the_emitted_power():
    """The light G-buffer of the Cornell box's light holds Φ_e = π Le A in all when a front wall
    closes the box (every ray hits), and no first hit lies on the light itself."""
    front = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 1])
             .rotate([0, 1, 0], 180), "bsdf": {"type": "ref", "id": "white"}}  # fmt: skip
    pipe = ScreenPipeline(_cornell(front=front), **FAST)
    pipe.render()
    lgb = pipe.outputs["light_gbuffer"]
    radiance = np.array([18.387, 13.9873, 6.75357])
    area = 0.46 * 0.38  # the rectangle's scale (0.23, 0.19)
    assert np.allclose(np.array(lgb.flux).sum(axis=1), np.pi * radiance * area, rtol=1e-4)
    assert np.all(np.array(lgb.valid))
    light = mi.ShapePtr(pipe.light.shape)
    assert not np.any(np.array(lgb.si.shape == light))


def test_one_light_is_used_and_the_others_are_named():
    """A faint extra lamp is left out with a warning; lit by the lamp alone, the scene would lack
    the ceiling light's 98 % of the power: refused."""
    d = _cornell(lamp={"type": "point", "position": [0, 0.5, 0], "intensity": 0.01})
    with pytest.warns(PhotonmapWarning, match=r"index 1\) and ignores the light of: PointLight"):
        pipe = ScreenPipeline(d, light=1, **FAST)
    assert pipe.light.kind == "area"
    with pytest.raises(SceneError, match=r"PointLight.*AreaLight .* shape 'light'\) carry 9\d%"):
        ScreenPipeline(d, **FAST)


def test_a_scene_whose_other_lights_matter_is_refused():
    d = _cornell(lamp={"type": "point", "position": [0, 0.5, 0], "intensity": 0.5})
    with pytest.raises(SceneError, match=r"carry \d+% of the emitted power; render this scene "
                       r"with --method sppm"):  # fmt: skip
        ScreenPipeline(d, **FAST)


# ---------------------------------------------------------------------------- null shapes
def _same_image(a, b, mean: float, pixels: float):
    """Equal up to the rays that graze a wall or pass a corner right behind a null surface:
    Mitsuba offsets a ray that crosses a surface along the normal, which moves such a hit.
    ``mean``: bound of mean |a − b| / mean b; ``pixels``: of the fraction of pixels off by more
    than 1 % of mean b, which the mean leaves out: where the few grazing hits land depends on the
    CPU's vector width (Dr.Jit compiles for the host), and one of them alone can pass ``mean``."""
    d = np.abs(a - b)
    off = d.max(-1) > 0.01 * b.mean()
    assert off.mean() < pixels
    assert d[~off].mean() < mean * b.mean()


def test_null_bsdf_cube_is_invisible():
    """A null-BSDF cube enclosing the small box and part of the floor and walls changes nothing:
    eye, shadow, light G-buffer and photon rays pass through it (and it leaves the scene's
    diagonal, the unit of the radii, alone although it reaches below the floor)."""
    cube = {"type": "cube", "bsdf": {"type": "null"},
            "to_world": mi.ScalarTransform4f().translate([0.3, -0.6, 0.3]).scale(0.6)}  # fmt: skip
    for shadows in ("soft", "sampled"):
        _, plain = _render(_cornell(), shadows=shadows)
        pipe, boxed = _render(_cornell(cube=cube), shadows=shadows)
        _same_image(boxed, plain, 4e-4, 0.006)  # measured 0.8e-4, 2 of 1024 pixels (AVX2)


# ---------------------------------------------------------------------------- media
def test_a_medium_is_refused_with_the_method_that_renders_it():
    """The screen method renders surfaces in vacuum: a scene with fog is refused, naming the
    medium and the method to use, rather than rendered as if the fog were not there."""
    fog = {"type": "cube", "bsdf": {"type": "null"},
           "to_world": mi.ScalarTransform4f().scale(0.9),
           "interior": {"type": "homogeneous", "albedo": 0.8, "sigma_t": 2.0}}  # fmt: skip
    with pytest.raises(SceneError, match=r"cannot render participating media \(Homogeneous.*"
                                         r"--method sppm"):
        ScreenPipeline(_cornell(fog=fog), **FAST)


# ---------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("ior", [math.nan, math.inf])
def test_a_non_finite_index_of_refraction_is_refused(ior):
    ball = {"type": "sphere", "radius": 0.2, "bsdf": {"type": "dielectric", "int_ior": ior}}
    with pytest.raises(SceneError, match=r"shape 'ball' \(Sphere\).*index of refraction"):
        ScreenPipeline(_cornell(ball=ball))


# ---------------------------------------------------------------------------- BSDFs it shades
def _with_ball(bsdf: dict) -> dict:
    return _cornell(ball={"type": "sphere", "center": [0.3, -0.6, 0.2], "radius": 0.3,
                          "bsdf": bsdf})  # fmt: skip


@pytest.mark.parametrize("bsdf, says", [
    ({"type": "roughconductor", "alpha": 0.2}, r"\(RoughConductor\) has no diffuse lobe"),
    ({"type": "roughdielectric", "alpha": 0.1}, r"\(RoughDielectric\) has no diffuse lobe"),
    ({"type": "mask", "opacity": 0.3, "bsdf": {"type": "diffuse"}}, r"is partly transparent"),
])  # fmt: skip
def test_surfaces_it_would_render_wrong_are_refused(bsdf, says):
    with pytest.raises(SceneError, match=says + r".*render this scene with --method sppm"):
        ScreenPipeline(_with_ball(bsdf), **FAST)


@pytest.mark.parametrize("bsdf, says", [
    ({"type": "roughplastic", "alpha": 0.2}, r"the glossy or specular lobes of shape 'ball'"),
    ({"type": "bumpmap", "arg1": {"type": "diffuse"},
      "arg0": {"type": "bitmap", "raw": True, "data": mi.TensorXf(np.full((4, 4, 1), 0.5))}},
     r"the bumpmap of shape 'ball' \(shaded with its own normal\)"),
])  # fmt: skip
def test_parts_it_leaves_out_are_named(bsdf, says):
    with pytest.warns(PhotonmapWarning, match=says):
        ScreenPipeline(_with_ball(bsdf), **FAST)
