"""Eye G-buffer, deferred direct light and the ray-traced shadow map (spec seed-004 §2.1, §2.3,
§2.9), against NumPy references on a plane."""

import math
import re

import drjit as dr
import mitsuba as mi
import numpy as np

from photonmap.screen.composite import glass_eye
from photonmap.screen.direct import direct_light
from photonmap.screen.gbuffer import eye_gbuffer
from photonmap.screen.light_gbuffer import find_light

W, H = 40, 30


def _rect(centre, half, normal, rho):
    m = np.eye(4)
    u = (half, 0, 0)
    v = (0, 0, half) if abs(normal[1]) > 0.5 else (0, half, 0)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = u, v, normal, centre
    return {"type": "rectangle", "to_world": mi.ScalarTransform4f(m),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": rho}}}  # fmt: skip


def _scene(**extra):
    """A floor y = 0 (ρ = (0.2, 0.4, 0.6)) seen from above by a 60° camera, a point light."""
    return mi.load_dict(_scene_dict(**extra))


def _scene_dict(**extra):
    return {
        "type": "scene",
        "floor": _rect((0, 0, 0), 10, (0, 1, 0), [0.2, 0.4, 0.6]),
        "light": {"type": "point", "position": [0.3, 2.0, 0.1],
                  "intensity": {"type": "rgb", "value": [1.0, 2.0, 3.0]}},
        "sensor": {"type": "perspective", "fov": 60, "fov_axis": "x",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 3, -1], target=[0, 0, 0],
                                                              up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": W, "height": H}},
        **extra,
    }  # fmt: skip


def test_eye_gbuffer_on_a_plane():
    scene = _scene()
    gbuf, specular = eye_gbuffer(scene, scene.sensors()[0])
    assert (gbuf.width, gbuf.height) == (W, H) and not dr.any(specular)
    assert math.isclose(gbuf.f_px, (W / 2) / math.tan(math.radians(30)), rel_tol=1e-6)
    pos, nrm = np.array(gbuf.pos).T, np.array(gbuf.nrm).T
    assert np.all(np.array(gbuf.valid))
    assert np.allclose(pos[:, 1], 0, atol=1e-5) and np.allclose(nrm, [0, 1, 0], atol=1e-6)
    eye, fwd = np.array(gbuf.eye), np.array(gbuf.forward)
    assert np.allclose(np.array(gbuf.depth), (pos - eye) @ fwd, atol=1e-5)
    assert np.allclose(np.array(gbuf.albedo).T, [0.2, 0.4, 0.6], atol=1e-6)
    # pixel (x, y) at index y·W + x, y = 0 the top row: the top row is farther away
    depth = np.array(gbuf.depth).reshape(H, W)
    assert depth[0].mean() > depth[-1].mean()


def test_direct_light_and_hard_shadow():
    """L = ρ/π·I·cos/D²; a small occluding square at y = 1 casts V_h = 0 with d = distance to it."""
    scene = _scene(blocker=_rect((0.15, 1.0, 0.05), 0.3, (0, 1, 0), [0.5] * 3))
    gbuf, _ = eye_gbuffer(scene, scene.sensors()[0])
    diag = 20.0
    out = direct_light(scene, gbuf, find_light(scene), diag)
    pos = np.array(gbuf.pos).T
    light = np.array([0.3, 2.0, 0.1])
    to_light = light - pos
    D = np.linalg.norm(to_light, axis=1)
    cos = to_light[:, 1] / D
    ref = np.array([0.2, 0.4, 0.6]) * [1.0, 2.0, 3.0] / math.pi * (cos / D**2)[:, None]
    on_floor = np.abs(pos[:, 1]) < 1e-4
    L = np.array(out.L).T
    assert np.allclose(L[on_floor], ref[on_floor], rtol=1e-4)
    assert np.allclose(np.array(out.light_dist)[on_floor], D[on_floor], rtol=1e-5)
    hard, d = np.array(out.hard), np.array(out.occluder_dist)
    # the analytic shadow: the ray from the floor point toward the light crosses y = 1 inside
    t = 1.0 / to_light[:, 1]
    cross = pos + t[:, None] * to_light
    inside = (np.abs(cross[:, 0] - 0.15) < 0.3) & (np.abs(cross[:, 2] - 0.05) < 0.3)
    clear = (
        on_floor
        & (np.abs(np.abs(cross[:, 0] - 0.15) - 0.3) > 0.02)
        & (np.abs(np.abs(cross[:, 2] - 0.05) - 0.3) > 0.02)
    )
    assert np.any(inside & clear) and np.any(~inside & clear)
    assert np.all(hard[clear] == np.where(inside[clear], 0.0, 1.0))
    shadowed = clear & inside
    assert np.allclose(d[shadowed], (t * D)[shadowed], rtol=1e-3)
    assert np.all(d[hard == 1] == 0)


def test_pixels_facing_away_are_no_blockers():
    """§2.3: n·l ≤ 0 gives V_h = 1 and no direct light (the light is below the floor)."""
    scene = _scene()
    params = mi.traverse(scene.emitters()[0])
    params["position"] = mi.Point3f(0, -1, 0)
    params.update()
    gbuf, _ = eye_gbuffer(scene, scene.sensors()[0])
    out = direct_light(scene, gbuf, find_light(scene), 20.0)
    assert np.all(np.array(out.hard) == 1) and np.all(np.array(out.L) == 0)


def test_mirror_pixels_are_ray_traced():
    """§2.9: a perfect mirror wall (z = 1) shows the directly lit floor: each mirror pixel equals
    ρ/π·I·cos/D² at the floor point its reflected eye ray reaches (NumPy reference)."""
    mirror = {"type": "rectangle", "bsdf": {"type": "conductor", "material": "none"},
              "to_world": mi.ScalarTransform4f().translate([0, 0, 1]).rotate([0, 1, 0], 180)
              .scale(10)}  # fmt: skip
    scene = _scene(mirror=mirror)
    gbuf, specular = eye_gbuffer(scene, scene.sensors()[0])
    spec = np.array(specular)
    assert spec.any() and not spec.all()
    assert np.all(np.array(gbuf.albedo)[:, spec] == 0)
    L = np.array(glass_eye(scene, gbuf, specular, find_light(scene), 20.0)[0]).T
    assert np.all(L[~spec] == 0)
    eye = np.array(gbuf.eye)
    pos = np.array(gbuf.pos).T[spec]
    d = (pos - eye) / np.linalg.norm(pos - eye, axis=1, keepdims=True)
    d[:, 2] *= -1  # reflect about the plane z = 1
    t = -pos[:, 1] / d[:, 1]
    ok = d[:, 1] < -1e-3
    floor = pos + t[:, None] * d
    to_light = np.array([0.3, 2.0, 0.1]) - floor
    D = np.linalg.norm(to_light, axis=1)
    ref = np.array([0.2, 0.4, 0.6]) * [1.0, 2.0, 3.0] / math.pi * (to_light[:, 1] / D**3)[:, None]
    assert ok.sum() > 20
    assert np.allclose(L[spec][ok], ref[ok], rtol=2e-3)


def test_textured_albedo():
    """The G-buffer albedo evaluates textures at the hit's uv (a checkerboard has two values)."""
    floor = _rect((0, 0, 0), 10, (0, 1, 0), [0.5] * 3)
    floor["bsdf"]["reflectance"] = {"type": "checkerboard", "color0": 0.1, "color1": 0.7,
                                    "to_uv": mi.ScalarTransform3f().scale([20, 20])}  # fmt: skip
    scene = mi.load_dict({**_scene_dict(), "floor": floor})
    gbuf, _ = eye_gbuffer(scene, scene.sensors()[0])
    values = np.unique(np.round(np.array(gbuf.albedo)[0].astype(float), 5))
    assert values.tolist() == [0.1, 0.7]


_KERNEL_NAME = re.compile(r"drjit_[0-9a-f]+")
_ALIGN = re.compile(r", align \d+")


def _kernel_text(kernel) -> str:
    """A launched kernel's LLVM IR without its name (the hash) and its alignment annotations.
    Dr.Jit loads an input with ``align 1`` instead of ``align 64`` when the array is a view whose
    address is not 64-byte aligned, which depends on the allocator's state: the same program then
    has another IR, another hash and misses the kernel cache, sometimes and not others."""
    ir = kernel["ir"]
    text = ir.getvalue() if hasattr(ir, "getvalue") else str(ir)
    return _ALIGN.sub("", _KERNEL_NAME.sub("drjit_", text))


def test_moving_the_light_reuses_the_light_gbuffer_kernels():
    """The light position enters the light G-buffer as opaque values, not literals: a moved
    light (each step of a drag in the viewer) runs the same kernels, which Dr.Jit finds in its
    in-memory kernel cache instead of compiling new ones (~70 ms each on cornell_ispm). Compared
    as kernel programs (:func:`_kernel_text`), not as cache hits, which also depend on the
    alignment of the input arrays; a literal position would put its value into the program."""
    import dataclasses

    from photonmap.scenes import load_scene
    from photonmap.screen.light_gbuffer import light_gbuffer

    scene, _ = load_scene("cornell_ispm")
    light = find_light(scene, 0)

    def kernels(position):
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        try:
            dr.kernel_history()  # clear it
            moved = dataclasses.replace(light, position=np.asarray(position))
            light_gbuffer(scene, moved, 8, 8)
            launched = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
            return [_kernel_text(k) for k in launched]
        finally:
            dr.set_flag(dr.JitFlag.KernelHistory, False)

    first = kernels([0.2, 0.5, 0.3])
    moved = kernels([0.25, 0.5, 0.3])
    assert first and all(first)
    assert len(moved) == len(first)
    changed = [i for i, (a, b) in enumerate(zip(first, moved, strict=True)) if a != b]
    assert not changed, f"kernels {changed} of {len(first)} changed with the light position"
