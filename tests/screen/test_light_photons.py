"""Light G-buffer and photon tracing of the screen pipeline (spec seed-004 §2.2, §2.4; oracles
O6, O7, O9, O11, O12)."""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from photonmap.screen.light_gbuffer import find_light, light_gbuffer
from photonmap.screen.light_photons import random_map, trace_photons


def _rect(centre, half_u, half_v, normal, bsdf):
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = half_u, half_v, normal, centre
    return {"type": "rectangle", "to_world": mi.ScalarTransform4f(m), "bsdf": bsdf}


def _diffuse(rho):
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [rho] * 3}}


def _spot(position, down=True, cutoff=60.0, beam=60.0, intensity=1.0):
    z = (0, -1, 0) if down else (0, 1, 0)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = (1, 0, 0), (0, 0, 1 if down else -1), z, position
    return {
        "type": "spot",
        "to_world": mi.ScalarTransform4f(m),
        "cutoff_angle": cutoff,
        "beam_width": beam,
        "intensity": {"type": "rgb", "value": [intensity] * 3},
    }


def closed_box(rho=0.5, light=None):
    """A closed cube [-1, 1]³ of six inward-facing diffuse walls (slightly overlapping)."""
    s, b = 1.001, _diffuse(rho)
    walls = {
        "floor": _rect((0, -1, 0), (s, 0, 0), (0, 0, s), (0, 1, 0), b),
        "ceiling": _rect((0, 1, 0), (s, 0, 0), (0, 0, s), (0, -1, 0), b),
        "left": _rect((-1, 0, 0), (0, s, 0), (0, 0, s), (1, 0, 0), b),
        "right": _rect((1, 0, 0), (0, s, 0), (0, 0, s), (-1, 0, 0), b),
        "back": _rect((0, 0, 1), (s, 0, 0), (0, s, 0), (0, 0, -1), b),
        "front": _rect((0, 0, -1), (s, 0, 0), (0, s, 0), (0, 0, 1), b),
    }
    light = light or _spot((0.13, 0.5, 0.07))  # off-centre: no texel ray hits a corner seam
    return mi.load_dict({"type": "scene", **walls, "light": light})


def test_spot_frustum_solid_angle_and_point_sphere():
    """Σ Ω over a 90° square frustum is 2π/3 (spec §2.2); a point light emits 4π I."""
    scene = closed_box()
    light = find_light(scene)
    lgb = light_gbuffer(scene, light, 200, 200, half_angle=math.pi / 4)
    assert dr.all(lgb.valid)
    total = np.array(dr.sum(lgb.flux, axis=1)).ravel()
    assert np.allclose(total, 2 * math.pi / 3, rtol=1e-4)
    point = closed_box(
        light={
            "type": "point",
            "position": [0, 0.2, 0.1],
            "intensity": {"type": "rgb", "value": [2.0, 1.0, 0.5]},
        }
    )
    lgb = light_gbuffer(point, find_light(point), 64, 32)
    total = np.array(dr.sum(lgb.flux, axis=1)).ravel()
    assert np.allclose(total, 4 * math.pi * np.array([2.0, 1.0, 0.5]), rtol=1e-5)
    # outside the spot cone the flux is zero (A26)
    narrow = closed_box(light=_spot((0, 0.5, 0), cutoff=30.0, beam=30.0))
    light = find_light(narrow)
    lgb = light_gbuffer(narrow, light, 64, 64)
    d = np.array(lgb.si.p) - light.position[:, None]  # the texel rays, from the light to the hit
    d /= np.linalg.norm(d, axis=0)
    angle = np.degrees(np.arccos(np.clip(-d[1], -1, 1)))
    flux = np.array(lgb.flux)[0]
    assert np.all(flux[angle > 30.01] == 0) and np.all(flux[angle < 29.99] > 0)


def test_energy_bookkeeping_over_bounces():
    """O6: in a closed diffuse box (ρ = 0.5) bounce slot k holds Φ·ρ^k exactly; O7: hit 1 is
    never stored and every slot of bounce k is a hit of a path of the light G-buffer."""
    scene = closed_box(rho=0.5)
    light = find_light(scene)
    lgb = light_gbuffer(scene, light, 64, 64, half_angle=math.pi / 4)
    phi = np.array(dr.sum(lgb.flux, axis=1)).ravel()
    photons = trace_photons(scene, lgb, random_map(64, 64, seed=3), bounces=3)
    n = 64 * 64
    assert dr.width(photons.valid) == 3 * n
    power = np.array(photons.power)
    for k in range(3):
        slot = power[:, k * n : (k + 1) * n].sum(axis=1)
        assert np.allclose(slot, phi * 0.5 ** (k + 1), rtol=1e-5)
    assert np.all(np.array(photons.valid))
    assert np.all(np.array(photons.density) == 1.0)  # diffuse-only paths keep r_p = r


def test_fixed_random_map_slots_and_determinism():
    """O7: the B = 2 map contains the B = 1 map slot for slot; O12: a fixed PRM gives identical
    maps, another seed a different one."""
    scene = closed_box()
    lgb = light_gbuffer(scene, find_light(scene), 32, 32)
    prm = random_map(32, 32, seed=0)
    one = trace_photons(scene, lgb, prm, 1)
    two = trace_photons(scene, lgb, prm, 2)
    again = trace_photons(scene, lgb, random_map(32, 32, seed=0), 2)
    other = trace_photons(scene, lgb, random_map(32, 32, seed=1), 2)
    n = 32 * 32
    assert np.array_equal(np.array(one.pos), np.array(two.pos)[:, :n])
    assert np.array_equal(np.array(one.power), np.array(two.power)[:, :n])
    assert np.array_equal(np.array(two.pos), np.array(again.pos))
    assert not np.array_equal(np.array(two.pos), np.array(other.pos))


def _ceiling_irradiance(photons, points, r, height):
    """E at ``points`` (x, z) on the plane y = ``height`` from the normalized cone kernel."""
    pos, power = np.array(photons.pos).T, np.array(photons.power)[0]
    keep = np.array(photons.valid) & (np.abs(pos[:, 1] - height) < 1e-3)
    pos, power = pos[keep], power[keep]
    out = []
    for x, z in points:
        rho = np.hypot(pos[:, 0] - x, pos[:, 2] - z)
        out.append(np.sum(power * 3 / (math.pi * r * r) * np.clip(1 - rho / r, 0, None)))
    return np.array(out)


def test_analytic_one_bounce_spot():
    """O9: a downward spot (I = 1, 90° square frustum) 1 above a ρ = 0.5 floor, ceiling 2 above
    the floor: one-bounce irradiance on the ceiling E_c(0, 0.5, 1) = 0.066764, 0.061543, 0.048640
    (spec §5). 4 PRM seeds, 500² photons, r = 0.2: noise ≈ 1%, kernel bias ≈ 0.3%."""
    floor = _rect((0, 0, 0), (50, 0, 0), (0, 0, 50), (0, 1, 0), _diffuse(0.5))
    ceiling = _rect((0, 2, 0), (50, 0, 0), (0, 0, 50), (0, -1, 0), _diffuse(0.5))
    scene = mi.load_dict({"type": "scene", "floor": floor, "ceiling": ceiling,
                          "light": _spot((0, 1, 0))})  # fmt: skip
    lgb = light_gbuffer(scene, find_light(scene), 500, 500, half_angle=math.pi / 4)
    points = [(0.0, 0.0), (0.5, 0.0), (1.0, 0.0)]
    estimates = [
        _ceiling_irradiance(trace_photons(scene, lgb, random_map(500, 500, s), 1), points, 0.2, 2)
        for s in range(4)
    ]
    assert np.allclose(np.mean(estimates, axis=0), [0.066764, 0.061543, 0.048640], rtol=0.04)


def test_glass_ball_focus():
    """O11: a glass ball (η = 1.5, R = 1) in a nearly collimated beam focuses paraxial light
    1.5 R from its centre: on a receiver plane there the irradiance peaks on the axis (within
    0.1 R) and, with r = 0.1 R, exceeds 10× the unobstructed irradiance."""
    sphere = {"type": "sphere", "radius": 1.0,
              "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}}  # fmt: skip
    plane = _rect((0, -1.5, 0), (10, 0, 0), (0, 0, 10), (0, 1, 0), _diffuse(0.5))
    scene = mi.load_dict({"type": "scene", "ball": sphere, "plane": plane,
                          "light": _spot((0, 100, 0), cutoff=1.0, beam=1.0)})  # fmt: skip
    lgb = light_gbuffer(scene, find_light(scene), 400, 400)
    photons = trace_photons(scene, lgb, random_map(400, 400, 0), 2)
    assert np.all(np.array(photons.density)[np.array(photons.valid)] >= 4)  # A9: h = 4 per event
    grid = [(x, z) for x in np.linspace(-0.5, 0.5, 11) for z in np.linspace(-0.5, 0.5, 11)]
    E = _ceiling_irradiance(photons, grid, 0.1, -1.5)
    peak = grid[int(np.argmax(E))]
    assert math.hypot(*peak) <= 0.1 + 1e-9
    unobstructed = 1.0 / 101.5**2
    assert E.max() > 10 * unobstructed


def test_no_photons_stored_on_glass_or_mirror():
    """A3: specular hits use up a bounce but store nothing."""
    mirror = {"type": "sphere", "radius": 0.3, "bsdf": {"type": "conductor"}}
    scene = mi.load_dict({"type": "scene", "floor": _rect((0, 0, 0), (5, 0, 0), (0, 0, 5),
                          (0, 1, 0), _diffuse(0.5)), "ball": mirror,
                          "light": _spot((0, 2, 0))})  # fmt: skip
    lgb = light_gbuffer(scene, find_light(scene), 64, 64)
    photons = trace_photons(scene, lgb, random_map(64, 64), 2)
    pos = np.array(photons.pos).T[np.array(photons.valid)]
    assert len(pos) > 0
    assert np.all(np.abs(np.linalg.norm(pos - [0, 0, 0], axis=1) - 0.3) > 1e-3)  # none on ball


@pytest.mark.parametrize("bad", [0, -1, 1.5])
def test_bad_bounces(bad):
    from photonmap import ParameterError

    scene = closed_box()
    lgb = light_gbuffer(scene, find_light(scene), 4, 4)
    with pytest.raises(ParameterError, match="bounces"):
        trace_photons(scene, lgb, random_map(4, 4), bad)
