"""S5 photon generation (spec seed-000-002 S5, oracles 16 and 17, A14, A16, A49)."""

import math

import drjit as dr
import numpy as np
import pytest

from photonmap.core import sampling
from photonmap.core.errors import SceneError
from photonmap.core.grid import GridBox
from photonmap.volume.emit import emit, photon_plane, plane_photons
from photonmap.volume.scene import Light

BOX = GridBox((0.0, 0.0, 0.0), 1.0, 32)


def _rows(v):
    """A Dr.Jit 3-vector array as a NumPy (count, 3) array."""
    return np.array(v).T


def _sum(color):
    return np.array([float(dr.sum(c)[0]) for c in color])


def test_point_light_plane_flux_is_intensity_times_solid_angle():
    """Oracle 16: Σ Φ over the plane = I·Ω, Ω = 4·asin(S²/(S² + 4d²)) for the square of side S
    at distance d on the axis (S = 2, d = 1: 2π/3)."""
    light = Light("point", np.array([2.0, 1.0, 0.5]), position=np.array([0.5, 3.0, 0.4]))
    plane = photon_plane(light, BOX)
    u, w = sampling.hammersley(2**16)
    _, _, power = plane_photons(light, BOX, plane, u, w)
    s, d = plane.side, 1.0
    omega = 4 * math.asin(s * s / (s * s + 4 * d * d))
    assert np.allclose(_sum(power), light.intensity * omega, rtol=1e-5)  # 3.6e-7 measured


def test_directional_light_down_a_face_keeps_every_photon_and_its_flux():
    light = Light("directional", np.array([1.0, 0.5, 0.25]), direction=np.array([0.0, -1.0, 0.0]))
    photons = emit(light, BOX, 4096)
    assert photons.count == 4096
    # Σ Φ = E · (face area in world units)
    assert np.allclose(_sum(photons.power), light.intensity * 1.0, rtol=1e-5)
    origin = _rows(photons.origin)
    assert np.allclose(origin[:, 1], 32.0) and np.all(
        (origin[:, [0, 2]] > 0) & (origin[:, [0, 2]] < 32)
    )


def test_kept_photons_are_exactly_those_whose_ray_hits_the_grid():
    light = Light("point", np.ones(3), position=np.array([-1.5, 2.5, 0.3]))
    count = 4096
    plane = photon_plane(light, BOX)
    u, w = sampling.hammersley(count)
    q = (
        plane.corner
        + np.outer(np.array(u), plane.e1) * plane.side
        + np.outer(np.array(w), plane.e2) * plane.side
    )
    p = BOX.to_voxel(light.position)
    d = q - p
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    with np.errstate(divide="ignore"):
        t0, t1 = (0 - p) / d, (32 - p) / d
    near = np.max(np.minimum(t0, t1), axis=1)
    far = np.min(np.maximum(t0, t1), axis=1)
    expected = int(np.sum(near < far))
    photons = emit(light, BOX, count)
    assert 0.2 * count < photons.count < count
    assert abs(photons.count - expected) <= 2  # float ties at grazing corners
    lit = _rows(photons.power)[:, 0] > 0
    assert lit.sum() == photons.count
    origin = _rows(photons.origin)[lit]
    on_face = np.any(np.isclose(origin, 0, atol=1e-3) | np.isclose(origin, 32, atol=1e-3), axis=1)
    assert np.all(on_face)


def test_plane_covers_the_whole_grid():
    light = Light("point", np.ones(3), position=np.array([0.5, 3.125, 0.5]))
    plane = photon_plane(light, BOX)
    p = BOX.to_voxel(light.position)
    corners = np.array([[x, y, z] for x in (0, 32) for y in (0, 32) for z in (0, 32)], float)
    rel = corners - p
    t = 1.0 / (rel @ plane.normal)
    hit = p + rel * t[:, None] - plane.corner
    a, b = hit @ plane.e1, hit @ plane.e2
    assert np.all((a >= -1e-9) & (a <= plane.side + 1e-9) & (b >= -1e-9) & (b <= plane.side + 1e-9))


def test_spot_light_masks_photons_outside_its_cone():
    spot = Light(
        "spot",
        np.ones(3),
        position=np.array([0.5, 3.0, 0.5]),
        direction=np.array([0.0, -1.0, 0.0]),
        cos_inner=math.cos(0.05),
        cos_outer=math.cos(0.08),
    )
    photons = emit(spot, BOX, 2**14)
    d = _rows(photons.direction)[_rows(photons.power)[:, 0] > 0]
    assert photons.count > 0 and len(d) == photons.count
    assert np.all(d @ np.array([0, -1.0, 0]) >= math.cos(0.08) - 1e-6)


def test_paper_fidelity_gives_constant_photon_energy():
    light = Light("point", np.ones(3), position=np.array([0.5, 3.0, 0.5]))
    power = _rows(emit(light, BOX, 1024, fidelity="paper").power)
    power = power[power[:, 0] > 0]
    assert len(power) > 900 and np.allclose(power, power[0])
    physical = _rows(emit(light, BOX, 1024).power)
    assert physical.max() > physical.min() * 1.001  # cos³θ vignetting


def test_photon_plane_of_a_light_inside_the_grid_is_refused():
    """Only the plane-based emission='adaptive' refuses it (emit() sends such a
    light's photons from its position, tests/volume/test_lights_anywhere.py)."""
    light = Light("point", np.ones(3), position=np.array([0.5, 0.5, 0.5]))
    with pytest.raises(SceneError, match="inside or beside the volume grid.*emission='uniform'"):
        photon_plane(light, BOX)
