"""Files as a user writes them that once rendered wrong with exit status 0, or ended in a
traceback — each against Mitsuba's own integrator on the same file (``user_scenes.reference``),
through ``photonmap render`` in process (``user_scenes.render_inprocess``), at each method's
defaults unless a case says otherwise. What each case once did is in its docstring.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import user_scenes as us

REF_SPP = 512
# small budgets where a case is not about the defaults (the tests' own, ``user_scenes.TEST_SETS``)
SMALL = us.TEST_SETS

HEAD = """<scene version="3.0.0">
    <integrator type="{integrator}"><integer name="max_depth" value="{depth}"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>{clip}
        <transform name="to_world">
            <lookat origin="{eye}" target="{target}" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="64"/></sampler>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
            <rfilter type="box"/></film>
    </sensor>
"""
FLOOR = """    <shape type="rectangle">
        <transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf>
    </shape>
"""


def head(integrator="path", depth=12, eye="0, 1.5, 4", target="0, 0.4, 0", near_clip=None) -> str:
    clip = f'<float name="near_clip" value="{near_clip}"/>' if near_clip else ""
    return HEAD.format(integrator=integrator, depth=depth, eye=eye, target=target, clip=clip)


def sphere_light(x, y, z, radius, radiance) -> str:
    return f"""    <shape type="sphere">
        <point name="center" x="{x}" y="{y}" z="{z}"/><float name="radius" value="{radius}"/>
        <emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter>
    </shape>
"""


def instanced_balls(bsdf: str) -> str:
    """Two balls of ``bsdf`` as instances of one shape group (one moved, one also scaled) on
    the floor, under a sphere light."""
    return head() + sphere_light(0.5, 3, 0.5, 0.3, 30) + FLOOR + f"""
    <shape type="shapegroup" id="ball">
        <shape type="sphere"><float name="radius" value="0.5"/>{bsdf}</shape>
    </shape>
    <shape type="instance"><ref id="ball"/>
        <transform name="to_world"><translate x="-0.7" y="0.5"/></transform></shape>
    <shape type="instance"><ref id="ball"/>
        <transform name="to_world">
            <scale value="0.6"/><translate x="0.8" y="0.3" z="0.4"/></transform>
        </shape>
</scene>
"""


FILES = {
    # a spot light behind two frosted balls of milk, nothing else: all the light reaches the
    # camera through rough glass (Mitsuba's own participating-media test scene is built so)
    "spot_behind_rough_balls": head("volpath", 16, "0, 0.5, 4", "0, -0.2, 0") + """
    <emitter type="spot">
        <transform name="to_world">
            <lookat origin="0, -0.5, -2" target="0, 0.5, 0" up="0, 1, 0"/>
        </transform>
        <rgb name="intensity" value="1"/><float name="cutoff_angle" value="60"/>
    </emitter>
    <medium type="homogeneous" id="milk">
        <rgb name="sigma_t" value="0.1, 1.0, 0.1"/><rgb name="albedo" value="0.1"/>
    </medium>
    <shape type="sphere">
        <float name="radius" value="0.6"/>
        <bsdf type="roughdielectric">
            <float name="alpha" value="0.3"/><float name="int_ior" value="1.3"/>
        </bsdf>
        <ref name="interior" id="milk"/>
    </shape>
    <shape type="sphere">
        <point name="center" x="0.6" y="0.5" z="0.3"/><float name="radius" value="0.25"/>
        <bsdf type="roughdielectric">
            <float name="alpha" value="0.3"/><float name="int_ior" value="1.3"/>
        </bsdf>
        <ref name="interior" id="milk"/>
    </shape>
</scene>
""",
    # two glass panes of one BSDF over the floor under a sphere light: Mitsuba merges the two
    # rectangles into one mesh, without a name and with an invalid bounding box
    "two_glass_panes": head("path", 8, "0, 2.5, 3", "0, 0, 0") + sphere_light(0, 3, 0, 0.2, 60)
    + FLOOR + "".join(f"""
    <shape type="rectangle">
        <transform name="to_world">
            <scale value="0.5"/><rotate x="1" angle="{angle}"/><translate x="{x}" y="1"/>
        </transform>
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>
    </shape>""" for angle, x in ((-80, -0.6), (-100, 0.6))) + """
</scene>
""",
    # a point light behind a frosted pane, its glow seen through it; nothing diffuse
    "point_behind_frosted_pane": head("path", 8, "0, 0, 4", "0, 0, 0") + """
    <emitter type="point">
        <point name="position" x="0.3" y="0.2" z="-1"/><rgb name="intensity" value="2"/>
    </emitter>
    <shape type="cube">
        <transform name="to_world"><scale x="1.2" y="1.2" z="0.05"/></transform>
        <bsdf type="roughdielectric"><float name="alpha" value="0.4"/></bsdf>
    </shape>
</scene>
""",
    # glass balls as instances of one shape group
    "glass_instances": instanced_balls('<bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>'),
    # diffuse balls as instances, lit by an area light (vcm's light subpaths start on it)
    "diffuse_instances": instanced_balls(
        '<bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.4, 0.3"/></bsdf>'
    ),
    # direct light only, a camera whose near clip plane is at 1 (Mitsuba's instancing test)
    "near_clip": head("path", 2, near_clip=1) + sphere_light(0.5, 3, 0.5, 0.3, 30) + FLOOR + """
    <shape type="sphere">
        <point name="center" x="0" y="0.5" z="0"/><float name="radius" value="0.5"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.4, 0.3"/></bsdf>
    </shape>
</scene>
""",
    # rough metal balls as instances of one shape group
    "rough_metal_instances": instanced_balls(
        '<bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf>'
    ),
    # a bump map over a checkerboard, a texture Mitsuba cannot differentiate
    "bump_checkerboard": head() + sphere_light(1, 3, 1, 0.3, 30) + """
    <shape type="sphere">
        <bsdf type="bumpmap">
            <texture type="checkerboard">
                <transform name="to_uv"><scale x="8" y="8"/></transform>
            </texture>
            <bsdf type="diffuse"/>
        </bsdf>
    </shape>
</scene>
""",
    # six lights of four kinds over a floor and a wall
    "many_lights": head("path", 6, "0, 1.5, 5", "0, 0.6, 0") + FLOOR + """
    <shape type="rectangle">
        <transform name="to_world"><scale x="4" y="2"/><translate y="2" z="-1.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.6, 0.7"/></bsdf>
    </shape>
    <emitter type="point">
        <point name="position" x="-1.5" y="0.6" z="-1"/><rgb name="intensity" value="2"/>
    </emitter>
    <emitter type="point">
        <point name="position" x="1.2" y="1.5" z="0.5"/><rgb name="intensity" value="3, 2, 1"/>
    </emitter>
    <emitter type="spot">
        <transform name="to_world">
            <lookat origin="0, 2.5, 0" target="0, 0, 0" up="0, 0, 1"/>
        </transform>
        <rgb name="intensity" value="8"/><float name="cutoff_angle" value="25"/>
    </emitter>
    <emitter type="spot">
        <transform name="to_world">
            <lookat origin="-1, 1, 1" target="-1, 1, -2" up="0, 1, 0"/>
        </transform>
        <rgb name="intensity" value="4, 6, 8"/><float name="cutoff_angle" value="20"/>
    </emitter>
""" + sphere_light(1.5, 0.4, -1.2, 0.2, "8, 4, 2") + sphere_light(-0.3, 2.5, 1, 0.4, 2) + """</scene>
""",
    # a glass ball on a floor under a sphere light larger than the screen method's splats
    "glass_ball_large_light": head("path", 8) + sphere_light(1.5, 2.5, 1, 0.8, 3) + FLOOR + """
    <shape type="sphere">
        <transform name="to_world"><scale value="0.5"/><translate y="0.5"/></transform>
        <bsdf type="dielectric"/>
    </shape>
</scene>
""",
    # a gold ball under a small sphere light
    "gold_ball_small_light": head("path", 8) + sphere_light(1.5, 2.5, 1, 0.15, 80) + FLOOR + """
    <shape type="sphere">
        <point name="center" x="0" y="0.5" z="0"/><float name="radius" value="0.5"/>
        <bsdf type="conductor"><string name="material" value="Au"/></bsdf>
    </shape>
</scene>
""",
}


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("user_files")
    paths = {}
    for name, text in FILES.items():
        paths[name] = folder / f"{name}.xml"
        paths[name].write_text(text)
    return paths


def compared(path: Path, method: str, sets: dict | None = None) -> tuple[us.Run, dict]:
    run = us.render_inprocess(path, method, sets)
    assert run.returncode == 0, run.error
    assert np.all(np.isfinite(run.image))
    return run, us.errors(run.image, us.reference(path, REF_SPP)[0])


def test_surface_lights_through_rough_glass(files):
    """A spot light seen only through rough glass: ``surface`` rendered it black (brightness
    0.000; its eye paths follow rough glass as glass, and nothing sampled the light at the
    rough vertices). The same root left out a point light seen through a frosted pane."""
    for name, bound in (("spot_behind_rough_balls", 0.3), ("point_behind_frosted_pane", 0.3)):
        run, errors = compared(files[name], "surface", SMALL["surface"])
        assert abs(errors["brightness"] - 1) < 0.06, (name, errors)
        assert errors["block_rel_rmse"] < bound, (name, errors)


@pytest.mark.parametrize("method", ["surface", "sppm", "vcm"])
def test_instances(files, method):
    """Shape instances: ``vcm`` ended in ``Shape::pdf_position(): not implemented`` (a call
    through a shape pointer traces every shape, and an instance implements none); ``surface``
    aimed no photon at instanced glass (an instance's ``bsdf()`` is a default diffuse one)."""
    names = ["diffuse_instances"] + (["glass_instances"] if method != "vcm" else [])
    for name in names:
        run, errors = compared(files[name], method, SMALL[method])
        assert abs(errors["brightness"] - 1) < 0.05, (name, errors)
        assert errors["block_rel_rmse"] < 0.25, (name, errors)


def test_vcm_with_a_near_clip_plane(files):
    """A near clip plane at 1: ``vcm`` read the camera's importance at unit distance, where
    Mitsuba's is 0 for every oblique ray (nearer than the plane), and its MIS weights came out
    5 % dark over the whole image."""
    run, errors = compared(files["near_clip"], "vcm", SMALL["vcm"])
    assert abs(errors["brightness"] - 1) < 0.02, errors
    assert errors["block_rel_rmse"] < 0.1, errors


def test_instanced_glass_is_aimed_at(files):
    import mitsuba as mi

    from photonmap.core.aim import specular_spheres
    from photonmap.core.bsdf import has_delta_lobes, surface_shapes

    scene = mi.load_file(str(files["glass_instances"]))
    assert has_delta_lobes(scene)
    assert [s.class_name() for s in surface_shapes(scene)].count("Sphere") == 3
    spheres = specular_spheres(scene)
    assert len(spheres) == 2
    assert np.allclose(spheres[0][0], [-0.7, 0.5, 0.0], atol=1e-4)
    assert spheres[0][1] >= 0.5 * np.sqrt(3) - 1e-3  # around the instance's box
    diffuse = mi.load_file(str(files["diffuse_instances"]))
    assert specular_spheres(diffuse) == [] and not has_delta_lobes(diffuse)


def test_merged_glass_is_aimed_at(files):
    """Mitsuba merges shapes of equal BSDFs into one mesh whose ``bbox()`` is invalid: photons
    were aimed at a sphere centred on NaN: ``sppm`` and ``surface`` rendered the two panes'
    scene at 0.55 and 0.56 of its brightness (block error 0.73), now 0.98 and 1.03 (0.19, 0.18)."""
    import mitsuba as mi

    from photonmap.core.aim import specular_spheres

    scene = mi.load_file(str(files["two_glass_panes"]))
    merged = [s for s in scene.shapes() if not s.bbox().valid()]
    assert len(merged) == 1, "the two panes are no longer merged: the case tests nothing"
    ((centre, radius),) = specular_spheres(scene)
    corners = np.array(merged[0].vertex_positions_buffer()).reshape(-1, 3)
    assert np.all(np.isfinite(centre)) and np.isfinite(radius)
    assert np.all(np.linalg.norm(corners - centre, axis=1) <= radius)
    for method in ("sppm", "surface"):
        run, errors = compared(files["two_glass_panes"], method, SMALL[method])
        assert abs(errors["brightness"] - 1) < 0.05, (method, errors)
        assert errors["block_rel_rmse"] < 0.25, (method, errors)


def test_screen_reads_instanced_surfaces(files):
    """The screen method shades by diffuse reflectance and refuses a BSDF without a diffuse
    lobe; an instanced rough metal ball passed as the default diffuse BSDF Mitsuba reports for
    an instance."""
    run = us.render_inprocess(files["rough_metal_instances"], "screen")
    assert run.returncode == 2 and "(RoughConductor) has no diffuse lobe" in run.error, run.error


@pytest.mark.parametrize("method", ["volume", "surface", "screen", "sppm", "vcm"])
def test_bump_map_over_a_texture_without_derivatives_is_refused(files, method):
    """A bump map over a checkerboard: Mitsuba has no derivative of that texture; surface, sppm
    and vcm ended in ``dr.while_loop(): encountered an exception``, screen in Mitsuba's
    traceback."""
    run = us.render_inprocess(files["bump_checkerboard"], method)
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "bumpmap needs a texture Mitsuba can differentiate" in lines[0]
    assert "eval_1_grad" in lines[0]


def test_surface_direct_light_of_many_lights(files):
    """Six lights: at one eye sample per pixel ``surface`` picked one light per pixel, a
    firefly wherever it picked a near one (4 × 4-block error 0.6 on Mitsuba's own scene of
    various emitters); one emitter sample per light now."""
    run, errors = compared(files["many_lights"], "surface")
    assert abs(errors["brightness"] - 1) < 0.05, errors
    assert errors["block_rel_rmse"] < 0.2, errors


def test_screen_caustic_where_it_falls(files):
    """A glass ball's caustic: splatted into the subsampled buffer, the upsampler put it as a
    block of light beside the ball (4 × 4-block error 0.14 here, 0.29 at 48 × 48; now 0.07)."""
    run, errors = compared(files["glass_ball_large_light"], "screen")
    assert not run.warnings, run.warnings  # the light is larger than the splats
    assert abs(errors["brightness"] - 1) < 0.05, errors
    assert errors["block_rel_rmse"] < 0.1, errors


def test_screen_warns_of_a_small_light_in_a_mirror(files):
    """A gold ball under a small light: its image in the ball and its caustic are below the
    screen method's resolution (8 % dark); the method says so, naming the ball."""
    run = us.render_inprocess(files["gold_ball_small_light"], "screen")
    assert run.returncode == 0
    assert len(run.warnings) == 1 and "SmoothConductor" in run.warnings[0], run.warnings
    assert "approximately" in run.warnings[0] and "--method sppm" in run.warnings[0]


def test_the_cli_leaves_spp_to_the_method(files):
    """``photonmap render`` without ``--spp`` passed ``spp=1`` to every method, overriding the
    automatic eye paths per pixel of ``vcm`` and of ``sppm`` in media: ``vcm`` on
    ``tests/scenes/glass_slabs_depth24.xml`` at its defaults had a 4×4 error of 0.234 (0.082
    with its own 16 per pixel at 48×48), ``sppm`` on ``fog_null_point.xml`` 0.152 (0.050)."""
    from typer.testing import CliRunner

    from photonmap.cli import app
    from photonmap.vcm.pipeline import auto_spp

    def camera_paths(*extra) -> str:
        args = ["render", str(files["near_clip"]), "--method", "vcm", "-o",
                str(files["near_clip"].with_suffix(".exr")), "--set", "iterations=1",
                "--timings", *extra]  # fmt: skip
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
        return result.stdout

    assert f"camera paths {32 * 32 * auto_spp(32, 32):,}" in camera_paths()
    assert auto_spp(32, 32) > 1
    assert "camera paths 2,048" in camera_paths("--spp", "2")


def test_volume_warns_of_one_ray_per_pixel_centre():
    """``volume`` casts one ray through each pixel centre by default (Sun et al. 2008 §4.5),
    which aliases the edges of the surfaces that the film's filter averages: on
    ``tests/scenes/glass_ball_medium.xml`` a 4×4 error of 0.207, 0.189 with ``spp`` 4. It says
    which parameter to raise, and is quiet once it is raised."""
    path = us.scene_path("glass_ball_medium")

    def said(spp: int) -> list[str]:
        run = us.render_inprocess(path, "volume", {**SMALL["volume"], "spp": spp})
        assert run.returncode == 0, run.error
        return [w for w in run.warnings if "one camera ray through each pixel centre" in w]

    one = said(1)
    assert len(one) == 1 and "raise --set spp (or --spp), e.g. to 4" in one[0], one
    assert said(4) == []


def test_volume_says_what_spp_a_small_light_seen_through_glass_needs():
    """A lamp in a fog box seen through a glass ball (``tests/scenes/nested_aov_volpath.xml``):
    one ray through each pixel centre sees the lamp's small image through the ball whole or not
    at all — a pixel of 23 against the reference's 2.9, a 4×4 error of 0.69; 0.75 with ``spp``
    4 and 0.17 with 64. The warning names the spp such a scene needs."""
    run = us.render_inprocess(us.scene_path("nested_aov_volpath"), "volume", SMALL["volume"])
    said = [w for w in run.warnings if "one camera ray through each pixel centre" in w]
    assert len(said) == 1 and "64 where a small light is seen through glass" in said[0], said
