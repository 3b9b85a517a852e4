"""Stages S2/S3 (materials, blur, gradient) and Perlin noise: oracles 7, 9, 10 of spec
seed-000-002 §5.2, against NumPy references."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import photonmap  # noqa: F401  (selects the Mitsuba variant)
from photonmap.core.arrays import to_jit
from photonmap.core.errors import ParameterError
from photonmap.core.grid import GridBox
from photonmap.core.noise import perlin3, permutation
from photonmap.volume.materials import (
    BLUR_TAPS,
    Perturbation,
    from_arrays,
    gradient,
    material_grids,
)
from photonmap.volume.scene import Medium
from photonmap.volume.voxelize import voxelize

SPEC_TAPS = [0.00761, 0.03607, 0.10959, 0.21344, 0.26656, 0.21344, 0.10959, 0.03607, 0.00761]
GAUSS_TAPS = np.exp(-0.5 * (np.arange(-4, 5) / 1.5) ** 2)
GAUSS_TAPS /= GAUSS_TAPS.sum()
N = 24
BOX = GridBox((-1.0, -1.0, -1.0), 2.0, N)
FOG = Medium(sigma_s=np.array([0.3, 0.2, 0.1]), sigma_a=np.array([0.05, 0.0, 0.1]), ior=1.0)
GLASS = Medium(sigma_s=np.array([0.0, 0.5, 1.0]), sigma_a=np.array([0.2, 0.4, 0.6]), ior=1.5)
WATER = Medium(sigma_s=np.array([2.0, 1.0, 0.0]), sigma_a=np.array([0.0, 0.1, 0.0]), ior=1.33)


def perlin_reference(p: np.ndarray, seed: int) -> np.ndarray:
    """Perlin's improved noise (his Java reference code), vectorised in float64."""
    perm = permutation(seed).astype(np.int64)
    cell = np.floor(p)
    f = p - cell
    x, y, z = (cell.astype(np.int64) & 255).T
    fade = f * f * f * (f * (f * 6 - 15) + 10)

    def grad(h, fx, fy, fz):
        h = h & 15
        u = np.where(h < 8, fx, fy)
        v = np.where(h < 4, fy, np.where((h == 12) | (h == 14), fx, fz))
        return np.where(h & 1, -u, u) + np.where(h & 2, -v, v)

    corners = {}
    for i in (0, 1):
        for j in (0, 1):
            for k in (0, 1):
                h = perm[perm[perm[x + i] + y + j] + z + k]
                corners[i, j, k] = grad(h, f[:, 0] - i, f[:, 1] - j, f[:, 2] - k)

    def lerp(a, b, t):
        return a + t * (b - a)

    u, v, w = fade.T
    along_x = {(j, k): lerp(corners[0, j, k], corners[1, j, k], u) for j in (0, 1) for k in (0, 1)}
    along_y = [lerp(along_x[0, k], along_x[1, k], v) for k in (0, 1)]
    return lerp(along_y[0], along_y[1], w)


def blur_reference(a: np.ndarray, taps) -> np.ndarray:
    """Separable convolution along the first three axes with clamp-to-edge addressing."""
    r = len(taps) // 2
    for axis in range(3):
        n = a.shape[axis]
        out = np.zeros_like(a)
        for o, w in zip(range(-r, r + 1), taps, strict=True):
            out += w * np.take(a, np.clip(np.arange(n) + o, 0, n - 1), axis=axis)
        a = out
    return a


def mapped(coverages, fog, h, noise_n=0.0, noise_s=0.0):
    """The S2 mapping in float64: fog values, then each object in turn, linear in coverage."""
    noise_n, noise_s = (np.broadcast_to(a, (N, N, N)) for a in (noise_n, noise_s))
    ior = np.full((N, N, N, 1), fog.ior)
    sigma_s = np.broadcast_to(fog.sigma_s * h, (N, N, N, 3))
    kappa = np.broadcast_to(fog.kappa * h, (N, N, N, 3))
    for cov, medium in coverages:
        c = cov[..., None]
        sigma_s_obj = medium.sigma_s * h * np.maximum(1 + noise_s, 0)[..., None]
        ior = ior + c * (medium.ior + noise_n[..., None] - ior)
        sigma_s = sigma_s + c * (sigma_s_obj - sigma_s)
        kappa = kappa + c * (sigma_s_obj + medium.sigma_a * h - kappa)
    return ior, sigma_s, kappa


def random_coverage(seed):
    rng = np.random.default_rng(seed)
    return np.clip(rng.uniform(-0.5, 1.5, (N, N, N)), 0, 1).astype(np.float32)


def test_blur_taps_are_the_spec_list():
    np.testing.assert_allclose(BLUR_TAPS, SPEC_TAPS, atol=5e-6)
    assert abs(np.sum(BLUR_TAPS) - 1.0) < 1e-12


def test_perlin_matches_reference():
    rng = np.random.default_rng(3)
    p = rng.uniform(-300, 300, (5000, 3))
    for seed in (0, 7):
        ours = perlin3(mi.Point3f(p.T.astype(np.float32)), seed).numpy()
        ref = perlin_reference(p.astype(np.float32).astype(np.float64), seed)
        np.testing.assert_allclose(ours, ref, atol=2e-5)
        assert np.abs(ref).max() <= 1.1 and ref.std() > 0.1
    lattice = rng.integers(-50, 50, (100, 3)).astype(np.float32)
    assert dr.all(perlin3(mi.Point3f(lattice.T), 1) == 0)
    a, b = (perlin3(mi.Point3f(p.T.astype(np.float32)), s).numpy() for s in (1, 2))
    assert np.abs(a - b).max() > 0.1


def test_mapping_and_blur_against_numpy():
    covs = [random_coverage(1), random_coverage(2)]
    grids = material_grids([(mi.TensorXf(covs[0]), GLASS), (mi.TensorXf(covs[1]), WATER)], FOG, BOX)
    ior, sigma_s, kappa = mapped(list(zip(covs, [GLASS, WATER], strict=True)), FOG, BOX.h)
    assert grids.ior.shape == (N, N, N, 1) and grids.kappa.shape == (N, N, N, 3)
    np.testing.assert_allclose(grids.ior.numpy(), blur_reference(ior, GAUSS_TAPS), atol=2e-5)
    np.testing.assert_allclose(grids.sigma_s.numpy(), sigma_s, atol=1e-6)
    np.testing.assert_allclose(grids.kappa.numpy(), kappa, atol=1e-6)
    blurred = material_grids([(mi.TensorXf(covs[0]), GLASS)], FOG, BOX, blur_all=True)
    _, sigma_s, kappa = mapped([(covs[0], GLASS)], FOG, BOX.h)
    for ours, ref in ((blurred.sigma_s, sigma_s), (blurred.kappa, kappa)):
        np.testing.assert_allclose(ours.numpy(), blur_reference(ref, GAUSS_TAPS), atol=1e-6)


def test_noise_perturbs_objects_only():
    cov = random_coverage(4)
    grids = material_grids(
        [(mi.TensorXf(cov), GLASS)],
        FOG,
        BOX,
        noise=Perturbation(ior=0.02, sigma_s=1.5, scale=4.0, seed=5),
    )
    c = np.arange(N) + 0.5
    p = np.stack(np.meshgrid(c, c, c, indexing="ij")[::-1], axis=-1).reshape(-1, 3) / 4.0
    noise_n = 0.02 * perlin_reference(p, 5).reshape(N, N, N)
    noise_s = 1.5 * perlin_reference(p, 6).reshape(N, N, N)
    ior, sigma_s, kappa = mapped([(cov, GLASS)], FOG, BOX.h, noise_n, noise_s)
    np.testing.assert_allclose(grids.ior.numpy(), blur_reference(ior, GAUSS_TAPS), atol=2e-5)
    np.testing.assert_allclose(grids.sigma_s.numpy(), sigma_s, atol=1e-6)
    np.testing.assert_allclose(grids.kappa.numpy(), kappa, atol=1e-6)
    assert np.any(1 + noise_s < 0)  # the clamp to σ_s >= 0 is exercised
    assert np.all(grids.sigma_s.numpy() >= 0)
    fog_only = material_grids(
        [(mi.TensorXf(np.zeros((N, N, N), np.float32)), GLASS)],
        FOG,
        BOX,
        noise=Perturbation(ior=0.02, sigma_s=0.8),
    )
    np.testing.assert_allclose(fog_only.ior.numpy(), 1.0, atol=1e-6)


def test_sphere_range_and_mass_after_blur():
    """Oracles 7 and 9: n ∈ [n_air, n_obj] and Σ(n − n_air) = (n_obj − n_air)·Σcov ≈ …·V."""
    n, r = 40, 0.5
    box = GridBox((-1.0, -1.0, -1.0), 2.0, n)
    cov = voxelize(mi.load_dict({"type": "sphere", "radius": r}), box)
    ior = material_grids([(cov, GLASS)], FOG, box).ior.numpy()
    assert ior.min() >= 1.0 - 1e-6 and ior.max() <= 1.5 + 1e-6
    assert ior.max() > 1.499 and np.count_nonzero((ior > 1.001) & (ior < 1.499)) > 1000
    mass = np.sum(ior.astype(np.float64) - 1.0)
    assert abs(mass - 0.5 * cov.numpy().sum()) < 1e-5 * mass
    volume = 4.0 / 3.0 * np.pi * (r / box.h) ** 3
    assert abs(mass - 0.5 * volume) < 1e-4 * 0.5 * volume  # 5.1e-5 measured


def test_from_arrays_converts_to_voxel_units():
    rng = np.random.default_rng(0)
    ior = rng.uniform(1.0, 1.5, (N, N, N))
    sigma_s = rng.uniform(0.0, 2.0, (N, N, N))
    kappa = sigma_s[..., None] + rng.uniform(0.0, 1.0, (N, N, N, 3))
    grids = from_arrays({"n": ior, "sigma_s": sigma_s, "kappa": kappa}, BOX)
    np.testing.assert_allclose(grids.ior.numpy()[..., 0], ior, rtol=1e-6)
    np.testing.assert_allclose(
        grids.sigma_s.numpy(), np.repeat(sigma_s[..., None] * BOX.h, 3, -1), rtol=1e-6
    )
    np.testing.assert_allclose(grids.kappa.numpy(), kappa * BOX.h, rtol=1e-6)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda g: g["n"].__setitem__((1, 2, 3), np.nan), "NaN or infinite"),
        (lambda g: g["kappa"].__setitem__((0, 0, 0), np.inf), "NaN or infinite"),
        (lambda g: g["sigma_s"].__setitem__((0, 0, 0), -0.1), ">= 0"),
        (lambda g: g["n"].__setitem__((4, 4, 4), 0.9), "n of the volume grids must be >= 1"),
        (lambda g: g["kappa"].__setitem__((5, 5, 5), 0.1), "smaller than sigma_s"),
        (lambda g: g.__setitem__("n", np.ones((N, N, N + 1))), "shape"),
        (lambda g: g.__setitem__("sigma_s", np.ones((N, N, N, 2))), "shape"),
        (lambda g: g.pop("kappa"), "keys"),
        (lambda g: g.__setitem__("sigma_t", g["kappa"]), "keys"),
    ],
)
def test_from_arrays_rejects_bad_data(change, message):
    grids = {
        "n": np.full((N, N, N), 1.2),
        "sigma_s": np.full((N, N, N), 0.5),
        "kappa": np.full((N, N, N, 3), 0.7),
    }
    change(grids)
    with pytest.raises(ParameterError, match=message):
        from_arrays(grids, BOX)


def test_material_grids_rejects_bad_input():
    cov = mi.TensorXf(np.zeros((N, N, N), np.float32))
    bad = Medium(sigma_s=np.ones(3), sigma_a=np.array([0.0, -0.5, 0.0]), ior=1.5)
    with pytest.raises(ParameterError, match="object 0"):
        material_grids([(cov, bad)], FOG, BOX)
    with pytest.raises(ParameterError, match="fog"):
        material_grids([], Medium(ior=float("nan")), BOX)
    with pytest.raises(ParameterError, match="coverage 0"):
        material_grids([(mi.TensorXf(np.zeros((N, N, 8), np.float32)), GLASS)], FOG, BOX)


def test_gradient_of_linear_field_is_exact():
    """Oracle 10, including the one-sided faces; channel order (∂x, ∂y, ∂z)."""
    z, y, x = np.meshgrid(*[np.arange(N, dtype=np.float64)] * 3, indexing="ij")
    ior = 1.2 + 0.01 * x - 0.003 * y + 0.0005 * z
    g = gradient(to_jit(mi.TensorXf, ior[..., None])).numpy()
    assert g.shape == (N, N, N, 3)
    np.testing.assert_allclose(g, np.broadcast_to([0.01, -0.003, 0.0005], g.shape), atol=2e-6)


def test_gradient_matches_numpy():
    a = np.random.default_rng(1).uniform(1, 1.5, (7, 9, 11)).astype(np.float32)
    g = gradient(mi.TensorXf(a)).numpy()
    ref = np.stack([np.gradient(a.astype(np.float64), axis=axis) for axis in (2, 1, 0)], -1)
    np.testing.assert_allclose(g, ref, atol=1e-6)
