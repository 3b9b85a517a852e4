"""The differentiable volume caustic (volume/gradients.py): derivatives against central finite
differences of the same estimator with the same photons, forward = reverse mode, exact zeros
where nothing reaches, the primal against a NumPy statement of the same discrete equations, the
ray equation against its exact solution in a linear index field, determinism and bad input."""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from photonmap.core.arrays import to_jit
from photonmap.core.errors import ParameterError
from photonmap.volume.gradients import DifferentiableVolumeCaustic, OrthoCamera, ParallelBeam

R = 8


def lens(r=R, amplitude=0.15, width=2.0, centre=(4.0, 5.5, 4.0)):
    """n = 1 + a·exp(−|x − c|²/w²) sampled at voxel centres, indexed [z, y, x]."""
    z, y, x = np.meshgrid(*(np.arange(r) + 0.5,) * 3, indexing="ij")
    d2 = (x - centre[0]) ** 2 + (y - centre[1]) ** 2 + (z - centre[2]) ** 2
    return 1.0 + amplitude * np.exp(-d2 / width**2)


def caustic(double=True, **kw):
    kw = {"ds": 0.5, "dt": 0.5, **kw}
    return DifferentiableVolumeCaustic(
        R,
        ParallelBeam(center=(4, 8, 4), width=4, side=16),
        OrthoCamera(16, 16),
        double=double,
        **kw,
    )


PARAMS = {"n": lens(), "sigma_s": 0.08, "sigma_a": 0.02}


def loss(img):
    return dr.sum(dr.square(img.array))


def objective(model, params):
    t = mi.TensorXf64 if model.Float is mi.Float64 else mi.TensorXf
    img = model.render(to_jit(t, np.asarray(params["n"])), params["sigma_s"], params["sigma_a"])
    return float(np.sum(np.asarray(img, np.float64) ** 2))


def central_difference(model, name, eps, voxel=None):
    lo, hi = dict(PARAMS), dict(PARAMS)
    if voxel is None:
        lo[name] -= eps
        hi[name] += eps
    else:
        lo[name], hi[name] = PARAMS[name].copy(), PARAMS[name].copy()
        lo[name][voxel] -= eps
        hi[name][voxel] += eps
    return (objective(model, hi) - objective(model, lo)) / (2 * eps)


VOXELS = [(5, 4, 4), (4, 4, 5), (3, 3, 4), (4, 6, 4), (4, 2, 4)]


@pytest.fixture(scope="module")
def reverse64():
    model = caustic()
    return model, model.value_and_grad(loss, PARAMS)


# ---- derivatives against finite differences -------------------------------------------------
def test_float64_gradients_match_central_differences(reverse64):
    """float64, ε = 1e-5 on n, 1e-4 on σ: measured relative error ≤ 6e-10 (n), ≤ 5e-7 (σ, the
    O(ε²) truncation of the difference); held to 1e-6."""
    model, (_, grad) = reverse64
    for name in ("sigma_s", "sigma_a"):
        fd = central_difference(model, name, 1e-4)
        assert grad[name][0] == pytest.approx(fd, rel=1e-6), name
    for voxel in VOXELS:
        fd = central_difference(model, "n", 1e-5, voxel)
        assert abs(fd) > 1e-5, voxel  # a voxel the caustic depends on
        assert grad["n"][voxel] == pytest.approx(fd, rel=1e-6), voxel


def test_float32_gradients_match_float64_and_finite_differences(reverse64):
    """float32 AD agrees with float64 AD to ≤ 1e-6 relative (measured ≤ 2e-7); float32 central
    differences (ε = 1e-3) are limited by the rounding of the loss: measured ≤ 0.6% on n."""
    model32 = caustic(double=False)
    _, grad32 = model32.value_and_grad(loss, PARAMS)
    _, (_, grad64) = reverse64
    for name in ("sigma_s", "sigma_a"):
        assert grad32[name][0] == pytest.approx(grad64[name][0], rel=1e-5)
        assert grad32[name][0] == pytest.approx(central_difference(model32, name, 1e-3), rel=1e-3)
    for voxel in VOXELS:
        assert grad32["n"][voxel] == pytest.approx(grad64["n"][voxel], rel=1e-5)
        assert grad32["n"][voxel] == pytest.approx(
            central_difference(model32, "n", 1e-3, voxel), rel=2e-2
        )


def test_forward_mode_equals_reverse_mode(reverse64):
    model, (_, grad) = reverse64
    rng = np.random.default_rng(3)
    tangent = rng.normal(size=(R, R, R))
    forward = model.forward_grad(loss, PARAMS, {"n": tangent})
    assert forward == pytest.approx(np.sum(grad["n"] * tangent), rel=1e-10)
    for name in ("sigma_s", "sigma_a"):
        assert model.forward_grad(loss, PARAMS, {name: 1.0}) == pytest.approx(
            grad[name][0], rel=1e-10
        )


def test_direct_dr_backward_equals_value_and_grad(reverse64):
    """render() + dr.backward (all threads) gives the same gradient up to rounding."""
    model, (_, grad) = reverse64
    n = to_jit(mi.TensorXf64, PARAMS["n"])
    dr.enable_grad(n)
    dr.backward(loss(model.render(n, PARAMS["sigma_s"], PARAMS["sigma_a"])))
    assert np.allclose(np.array(dr.grad(n)), grad["n"], rtol=1e-9, atol=1e-16)


def test_grid_sigma_gradients_match_finite_differences():
    """σ_s and σ_a given as grids: per-voxel derivatives (float64, ε = 1e-5)."""
    model = caustic(photon_steps=12, view_steps=12)
    params = {"n": lens(), "sigma_s": np.full((R,) * 3, 0.08), "sigma_a": np.full((R,) * 3, 0.02)}
    _, grad = model.value_and_grad(loss, params)

    def obj(p):
        img = model.render(*(to_jit(mi.TensorXf64, p[k]) for k in ("n", "sigma_s", "sigma_a")))
        return float(np.sum(np.asarray(img) ** 2))

    for name in ("sigma_s", "sigma_a"):
        for voxel in [(4, 3, 4), (6, 5, 3)]:
            lo, hi = dict(params), dict(params)
            lo[name], hi[name] = params[name].copy(), params[name].copy()
            lo[name][voxel] -= 1e-5
            hi[name][voxel] += 1e-5
            fd = (obj(hi) - obj(lo)) / 2e-5
            assert abs(fd) > 1e-6
            assert grad[name][voxel] == pytest.approx(fd, rel=1e-6), (name, voxel)


def test_gradient_is_exactly_zero_where_nothing_reaches():
    """The beam and the camera stay in x < 6.5; an n value at voxel column i reaches ∇n at
    i ± 1, read by trilinear interpolation up to 1 voxel further: columns i ≥ 9 are unseen."""
    r = 12
    model = DifferentiableVolumeCaustic(
        r,
        ParallelBeam(center=(3, 12, 6), width=3, side=8),
        OrthoCamera(8, 8, window=(0.0, 6.0, 0.0, 12.0)),
        photon_steps=24,
        view_steps=24,
    )
    n = lens(r, amplitude=0.1, width=1.5, centre=(3.0, 8.0, 6.0))
    sigma_s = np.full((r,) * 3, 0.05)
    _, grad = model.value_and_grad(loss, {"n": n, "sigma_s": sigma_s, "sigma_a": 0.01})
    for name in ("n", "sigma_s"):
        assert np.all(grad[name][:, :, 9:] == 0.0), name
        assert np.count_nonzero(grad[name][:, :, :6]) > 50, name


# ---- the primal against NumPy -----------------------------------------------------------------
def np_corners(r, p):
    """The 8 voxel centres around each point ``p`` of an ``r``³ grid: (weight, index, inside)."""
    u = np.clip(p, -1.0, r + 1.0) - 0.5
    i0 = np.floor(u).astype(int)
    f = u - i0
    for d in np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T:
        i = i0 + d
        yield np.prod(np.where(d == 1, f, 1 - f), axis=1), i, np.all((i >= 0) & (i < r), axis=1)


def np_trilinear(grid, p, zero_outside=False):
    r = grid.shape[0]
    out = np.zeros(len(p))
    for w, i, inside in np_corners(r, p):
        i = np.clip(i, 0, r - 1)
        out += w * grid[i[:, 2], i[:, 1], i[:, 0]] * (inside if zero_outside else 1.0)
    return out


def np_splat(grid, p, value):
    for w, i, inside in np_corners(grid.shape[0], p):
        np.add.at(grid, (i[inside, 2], i[inside, 1], i[inside, 0]), (w * value)[inside])


def np_render(model, n, sigma_s, sigma_a, curved=True):
    """Eqs 4–6, the splat and the view pass in NumPy float64, written from the docstring."""
    r = model.R
    gz, gy, gx = np.gradient(n, edge_order=1)
    kappa = sigma_s + sigma_a

    def advance(x, v, h):
        nn = np_trilinear(n, x)
        g = np.stack([np_trilinear(a, x) for a in (gx, gy, gz)], 1)
        return x + (h / nn)[:, None] * v, v + h * g

    x, d, power = model.light.photons()
    v = np_trilinear(n, x)[:, None] * d
    energy = np.full(len(x), power)
    fluence = np.zeros((r, r, r))
    for _ in range(model.photon_steps):
        x1, v = advance(x, v, model.ds)
        dl = np.linalg.norm(x1 - x, axis=1)
        e1 = energy * np.exp(-kappa * dl)
        np_splat(fluence, 0.5 * (x + x1), 0.5 * (energy + e1) * dl)
        x, energy = x1, e1
    x, d = model.camera.rays(r)
    v = np_trilinear(n, x)[:, None] * d if curved else d.copy()
    t, radiance = np.ones(len(x)), np.zeros(len(x))
    for _ in range(model.view_steps):
        x1, v = advance(x, v, model.dt) if curved else (x + model.dt * v, v)
        dl = np.linalg.norm(x1 - x, axis=1)
        mid = 0.5 * (x + x1)
        phi = np_trilinear(fluence, mid, zero_outside=True)
        radiance += t * np.exp(-0.5 * kappa * dl) * sigma_s / (4 * math.pi) * phi * dl
        t *= np.exp(-kappa * dl)
        x = x1
    return radiance.reshape(model.camera.height, model.camera.width), fluence


@pytest.mark.parametrize("curved", [True, False])
def test_primal_matches_numpy_reference(curved):
    r = 6
    model = DifferentiableVolumeCaustic(
        r,
        ParallelBeam(center=(3, 6, 3), direction=(0.2, -1, 0.1), width=3, side=5),
        OrthoCamera(5, 4),
        ds=0.4,
        photon_steps=18,
        dt=0.6,
        curved_view=curved,
        double=True,
    )
    n = lens(r, amplitude=0.2, width=1.5, centre=(3.0, 3.5, 3.0))
    image = np.asarray(model.render(to_jit(mi.TensorXf64, n), 0.1, 0.03))
    reference, fluence = np_render(model, n, 0.1, 0.03, curved)
    assert reference.max() > 0 and fluence.max() > 0
    assert np.allclose(image, reference, rtol=1e-10, atol=0)
    ours = np.asarray(model.trace(to_jit(mi.TensorXf64, n), 0.03, 0.1)[0]).reshape(r, r, r)
    assert np.allclose(ours, fluence, rtol=1e-10, atol=1e-14)


def test_constant_index_gives_straight_rays():
    r = 8
    model = DifferentiableVolumeCaustic(
        r,
        ParallelBeam(center=(4, 8, 4), direction=(0.3, -1, 0.2), width=3, side=4),
        photon_steps=10,
        ds=0.5,
        double=True,
    )
    _, x, v, _ = model.trace(to_jit(mi.TensorXf64, np.full((r, r, r), 1.33)))
    origins, d, _ = model.light.photons()
    x = np.stack([np.asarray(c) for c in x], 1)
    v = np.stack([np.asarray(c) for c in v], 1)
    assert np.allclose(x, origins + 10 * 0.5 * d, atol=1e-12)
    assert np.allclose(v, 1.33 * d, atol=1e-12)


def test_linear_index_bends_the_ray_by_the_catenary():
    """n = n₀ + g·(y − y₀) and a ray along x at y₀: the exact ray is the catenary
    y − y₀ = (n₀/g)(cosh(g x/n₀) − 1) ≈ g x²/(2 n₀) (curvature g/n₀). Forward Euler (eqs 4–5)
    over 12 voxels lags it by a first-order error: measured 1.05% of the 0.60-voxel bend at
    Δs = 1/8 and half that at Δs = 1/16."""
    r, n0, g, y0, length = 16, 1.2, 0.01, 8.0, 12.0
    y = np.arange(r) + 0.5
    n = np.broadcast_to((n0 + g * (y - y0))[None, :, None], (r, r, r)).copy()
    errors = []
    for ds in (0.125, 0.0625):
        model = DifferentiableVolumeCaustic(
            r,
            ParallelBeam(center=(2, y0, 8), direction=(1, 0, 0), width=0.01, side=1),
            photon_steps=round(length / ds),
            ds=ds,
            double=True,
        )
        _, _, _, _, path = model.trace(to_jit(mi.TensorXf64, n), record=True)
        xs = np.array([float(p[0][0]) for p in path]) - 2.0
        ys = np.array([float(p[1][0]) for p in path]) - y0
        exact = n0 / g * (np.cosh(g * xs / n0) - 1.0)
        assert xs[-1] == pytest.approx(length, rel=3e-3)  # |v| = n up to O(g²)
        assert ys[-1] == pytest.approx(g * length**2 / (2 * n0), rel=0.02)  # curvature g/n₀
        errors.append(np.max(np.abs(ys - exact)) / exact[-1])
    assert errors[0] < 0.012
    assert errors[0] / errors[1] == pytest.approx(2.0, rel=0.05)


# ---- determinism, bad input ---------------------------------------------------------------------
def test_same_inputs_give_the_same_image_and_gradient():
    """Up to the thread order of Dr.Jit's float scatter-adds (module docstring, Determinism)."""
    model = caustic(double=False, photon_steps=12, view_steps=12)
    runs = [model.value_and_grad(loss, PARAMS) for _ in range(2)]
    images = [np.asarray(model.render(to_jit(mi.TensorXf, PARAMS["n"]), 0.08, 0.02)) for _ in range(2)]
    assert runs[0][0] == pytest.approx(runs[1][0], rel=1e-5)
    for name in PARAMS:
        np.testing.assert_allclose(runs[0][1][name], runs[1][1][name], rtol=1e-4,
                                   atol=1e-6 * np.abs(runs[0][1][name]).max(), err_msg=name)
    np.testing.assert_allclose(images[0], images[1], rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"n": np.zeros((R, R, R))}, "n must be > 0"),
        ({"n": -lens()}, "n must be > 0"),
        ({"n": np.ones((R, R, R + 1))}, "shape"),
        ({"n": np.where(lens() > 1.1, np.nan, lens())}, "NaN"),
        ({"n": 1.3}, "must be a grid"),
        ({"sigma_s": -0.1}, "sigma_s must be ≥ 0"),
        ({"sigma_s": float("nan")}, "NaN"),
        ({"sigma_a": np.ones((R, R))}, "shape"),
        ({"sigma_a": "fog"}, "sigma_a must be"),
    ],
)
def test_bad_input_raises_parameter_error(change, message):
    model = caustic(photon_steps=2, view_steps=2)
    params = {**PARAMS, **change}
    with pytest.raises(ParameterError, match=message):
        model.render(params["n"], params["sigma_s"], params["sigma_a"])
    with pytest.raises(ParameterError, match=message):
        model.value_and_grad(loss, params)


def test_bad_settings_raise_parameter_error():
    with pytest.raises(ParameterError, match="resolution"):
        DifferentiableVolumeCaustic(1)
    with pytest.raises(ParameterError, match="ds"):
        DifferentiableVolumeCaustic(8, ds=0.0)
    with pytest.raises(ParameterError, match="photon_steps"):
        DifferentiableVolumeCaustic(8, photon_steps=2.5)
    with pytest.raises(ParameterError, match="direction"):
        DifferentiableVolumeCaustic(8, ParallelBeam(direction=(0, 0, 0)))
    with pytest.raises(ParameterError, match="irradiance"):
        DifferentiableVolumeCaustic(8, ParallelBeam(irradiance=float("nan")))
    model = caustic(photon_steps=2, view_steps=2)
    with pytest.raises(ParameterError, match="unknown parameters"):
        model.value_and_grad(loss, {**PARAMS, "kappa": 0.1})
    with pytest.raises(ParameterError, match="shape"):
        model.forward_grad(loss, PARAMS, {"n": np.ones((R, R))})
    with pytest.raises(ParameterError, match="not in params"):
        model.forward_grad(loss, {"n": lens(), "sigma_s": 0.1}, {"sigma_a": 1.0})
