"""Multiple scattering in the voxel radiance grid (spec beyond-seeds §5).

``scattering="multiple"`` marches every photon order as Sun et al. 2008 §4.4 march the first
(expected-value deposits ``W·T`` along the curved path); a collision sampled against κ on the
way starts the next order with a Schlick-sampled direction and weight ``W·σ_s·T/p̄``
(``volume/scatter.py``). The oracles:

- **Schlick sampling** inverts the CDF of the phase function the viewing pass evaluates
  (``view.schlick``), and the mean cosine of the sampled directions is that of the phase function.
- **Invariance of the mean path length** (Blanco & Fournier 2003, "An invariance property of
  diffusive random walks"): in a non-absorbing (albedo 1), index-matched convex medium lit
  uniformly and isotropically from outside (Lambertian incidence on every face), the mean length
  of a photon's path inside is ``4V/S`` — for any σ_s and any phase function. In the N³ grid
  cube that is ``2N/3``, so the deposited fluence (length-weighted deposits: path length × power)
  sums to ``Φ · 2N/3`` with scattering of every order, while single scattering keeps only the
  uncollided part. Also, every collision sampled is a scattering event, so
  ``σ_s · Σ C = Φ · (mean number of scattering events)`` (both sides estimated).
- **A pure absorber** (σ_s = 0) scatters nothing: the result is single scattering, bit for bit
  (march and pipeline), and ``scattering="single"`` is Sun's marcher (its C, D and final photon
  states hashed before and after multiple scattering was added: identical).
- **A fog-only box against Mitsuba ``volpath``** at full depth (fog cube = grid box, point light
  above it, isotropic phase), and **the glass ball in a box of fog** of ``examples/fog_box.xml``
  (with a sphere light) against its ``volpath``.

Measured (seeds 0–3; see the constants for the bounds): invariance error ≤ 0.009 of 2N/3 over 20
seeds (σ_s N = 6, k = −0.5 / 0 / 0.5), the collision identity ≤ 0.001; against volpath: see
:data:`RATIO_BOUND` ff.
"""

import hashlib
import math
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy.stats import qmc

import mitsuba_reference
from photonmap import VolumePipeline
from photonmap.core.arrays import columns
from photonmap.core.errors import ParameterError, PhotonmapError
from photonmap.core.grid import GridBox
from photonmap.core.image import block_means
from photonmap.volume.emit import Photons, emit
from photonmap.volume.march import march
from photonmap.volume.scatter import schlick_cosine, schlick_direction
from photonmap.volume.scene import Light
from photonmap.volume.step import MarchGrids, Scattering
from photonmap.volume.view import schlick

# ------------------------------------------------------------------------------------------------
# Schlick sampling


@pytest.mark.parametrize("k", [-0.7, 0.0, 0.3, 0.9])
def test_schlick_sampling_inverts_the_viewing_phase_functions_cdf(k):
    """μ(ξ) from :func:`schlick_cosine` satisfies F(μ) = ξ, F integrated numerically from the
    phase function the viewing pass uses (2π ∫ p dμ)."""
    mu = np.linspace(-1.0, 1.0, 400001)
    pdf = 2.0 * math.pi * np.array(schlick(k, mi.Float(mu)))
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (pdf[1:] + pdf[:-1]) * np.diff(mu))])
    assert cdf[-1] == pytest.approx(1.0, abs=1e-5)  # the phase function is normalised
    xi = np.linspace(0.0, 1.0, 101)
    sampled = np.array(schlick_cosine(k, mi.Float(xi)), dtype=np.float64)
    assert np.max(np.abs(np.interp(sampled, mu, cdf) - xi)) < 1e-4


@pytest.mark.parametrize("k", [-0.5, 0.6])
def test_scattered_directions_have_the_phase_functions_mean_cosine(k):
    """Stratified ξ: the mean of d·ω over the sampled directions ω is ∫ μ p(μ) 2π dμ, the mean of
    the perpendicular components is 0, and every ω is a unit vector."""
    side = 512
    u, v = np.meshgrid((np.arange(side) + 0.5) / side, (np.arange(side) + 0.5) / side)
    d = np.array([0.3, -0.8, 0.52])
    d /= np.linalg.norm(d)
    count = side * side
    omega = schlick_direction(
        k, mi.Vector3f(*[np.full(count, c) for c in d]), mi.Point2f(u.ravel(), v.ravel())
    )
    omega = np.array(omega, dtype=np.float64).T
    mu = np.linspace(-1.0, 1.0, 400001)
    p = 2.0 * math.pi * np.array(schlick(k, mi.Float(mu)), dtype=np.float64)
    expected = np.trapezoid(mu * p, mu)
    np.testing.assert_allclose(np.linalg.norm(omega, axis=1), 1.0, atol=1e-5)
    assert np.mean(omega @ d) == pytest.approx(expected, abs=1e-4)
    perpendicular = omega - np.outer(omega @ d, d)
    np.testing.assert_allclose(perpendicular.mean(axis=0), 0.0, atol=1e-4)


# ------------------------------------------------------------------------------------------------
# Invariance of the mean path length in a non-absorbing cube

N = 24
INVARIANCE_BOUND = 0.015  # |Σ C / (Φ 2N/3) − 1|: measured ≤ 0.009 over 20 seeds
COLLISION_BOUND = 0.003  # |σ_s Σ C / (Φ · events) − 1|: measured ≤ 0.0009


def lambertian_photons(count: int, seed: int) -> Photons:
    """Unit-power photons entering the cube [0, N]³ uniformly over its six faces with
    cosine-weighted inward directions (scrambled Sobol points: face, position, direction)."""
    s = qmc.Sobol(5, seed=seed).random(count)
    face = np.minimum((s[:, 0] * 6).astype(int), 5)
    r, phi = np.sqrt(s[:, 3]), 2 * np.pi * s[:, 4]
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - s[:, 3])], 1)
    o, d = np.zeros((count, 3)), np.zeros((count, 3))
    for axis in range(3):
        m = face % 3 == axis
        inward = np.where(face[m] < 3, 1.0, -1.0)
        b, c = [a for a in range(3) if a != axis]
        o[m, axis] = np.where(inward > 0, 0.0, N)
        o[m, b], o[m, c] = s[m, 1] * N, s[m, 2] * N
        d[m, axis], d[m, b], d[m, c] = inward * local[m, 2], local[m, 0], local[m, 1]
    o, d, power = (columns(mi.Float, a) for a in (o, d, np.ones((count, 3))))
    return Photons(mi.Point3f(*o), mi.Vector3f(*d), mi.Color3f(*power), count)


def uniform_grids(n, sigma_s, kappa, ior=None, level=5):
    """March grids of a homogeneous medium (voxel units), σ_s included."""
    grid = lambda v: np.ascontiguousarray(np.broadcast_to(np.float32(v), (n, n, n, 3)))  # noqa: E731
    ior = np.ones((n, n, n), np.float32) if ior is None else ior.astype(np.float32)
    gz, gy, gx = np.gradient(ior.astype(np.float64))
    return MarchGrids.build(
        ior,
        np.stack([gx, gy, gz], -1).astype(np.float32),
        grid(kappa),
        np.full((n, n, n), level, np.float32),
        np.full((n, n, n), np.inf, np.float32),
        sigma_s=grid(sigma_s),
    )


@pytest.mark.parametrize("sigma, k, seed", [(0.1, 0.0, 0), (0.25, 0.5, 1), (0.25, -0.5, 2)])
def test_mean_path_length_is_four_volume_over_surface(sigma, k, seed):
    count = 2**16
    photons = lambertian_photons(count, seed)
    grids = uniform_grids(N, sigma, sigma)
    result = march(photons, grids, scattering=Scattering(phase_k=k, seed=seed))
    deposited = float(np.sum(np.array(result.C, dtype=np.float64))) / 3
    assert abs(deposited / (count * 2 * N / 3) - 1) < INVARIANCE_BOUND
    assert abs(sigma * deposited / result.scatterings - 1) < COLLISION_BOUND
    single = march(photons, grids)
    uncollided = float(np.sum(np.array(single.C, dtype=np.float64))) / 3
    assert uncollided / deposited < 0.75  # what the higher orders add is far above the bound


def test_without_fog_the_mean_chord_is_four_volume_over_surface():
    """Cauchy's formula, the σ → 0 end of the invariance: checks the photon source itself."""
    count = 2**16
    result = march(
        lambertian_photons(count, 0), uniform_grids(N, 0.0, 0.0), scattering=Scattering()
    )
    deposited = float(np.sum(np.array(result.C, dtype=np.float64))) / 3
    assert deposited / (count * 2 * N / 3) == pytest.approx(1.0, abs=5e-4)  # measured 2e-4
    assert result.scatterings == 0


# ------------------------------------------------------------------------------------------------
# A pure absorber scatters nothing: single scattering, bit for bit


def digest(result) -> str:
    arrays = [result.C, result.D]
    if result.count is not None:
        arrays += [result.count, result.weight]
    return hashlib.sha256(b"".join(np.array(a).tobytes() for a in arrays)).hexdigest()


@pytest.mark.parametrize("weighted", [False, True])
def test_pure_absorber_gives_single_scattering_bit_for_bit(weighted):
    """A glass-ball n field (curved paths, octree levels 0–3) in a coloured absorber."""
    n = 32
    z, y, x = np.meshgrid(*[np.arange(n) + 0.5] * 3, indexing="ij")
    r = np.sqrt((x - 16) ** 2 + (y - 14) ** 2 + (z - 16) ** 2)
    ior = 1.0 + 0.4 / (1.0 + np.exp((r - 8.0) / 1.5))
    grids = uniform_grids(n, 0.0, [0.02, 0.04, 0.07], ior=ior, level=3)
    box = GridBox((0.0, 0.0, 0.0), float(n), n)
    light = Light(kind="point", position=np.array([14.0, 60.0, 17.0]), intensity=np.ones(3))
    photons = emit(light, box, 64**2)
    weights = mi.Float(np.linspace(0.5, 2.0, photons.generated)) if weighted else None
    single = march(photons, grids, weights=weights)
    multiple = march(photons, grids, weights=weights, scattering=Scattering(0.3, 7))
    assert multiple.scatterings == 0
    assert single.steps == multiple.steps
    assert digest(multiple) == digest(single)


def test_multiple_scattering_needs_sigma_s_in_the_march_grids():
    grids = uniform_grids(8, 0.1, 0.1)
    grids.scatter = None
    with pytest.raises(ParameterError, match="sigma_s"):
        march(lambertian_photons(16, 0), grids, scattering=Scattering())


def small_pipeline(**params) -> VolumePipeline:
    return VolumePipeline("glass_sphere_fog", grid=24, photons=32**2, width=32, height=24, **params)


def test_pure_absorbing_fog_renders_single_scattering_bit_for_bit():
    """The pipeline: the built-in glass ball in fog made a pure absorber (σ_s = 0, same κ)."""
    grids = {}
    for mode in ("single", "multiple"):
        pipe = small_pipeline(scattering=mode)
        pipe.set_material("fog", sigma_s=0.0, sigma_a=pipe.world.fog.kappa)
        image = np.array(pipe.render())
        grids[mode] = (pipe.grids["C"], pipe.grids["D"], image)
        assert pipe.stats["scatterings"] == 0
    for single, multiple in zip(grids["single"], grids["multiple"], strict=True):
        assert np.array_equal(single, multiple)


AFTER_PHOTONS = ["photon tracing", "smoothing", "view grids", "viewing"]
RERUNS = {  # mode → (stages a σ_s change keeping κ reruns, stages a phase k change reruns)
    "single": (["materials", "view grids", "viewing"], ["viewing"]),
    "multiple": (["materials", "march grids", *AFTER_PHOTONS], AFTER_PHOTONS),
}


@pytest.mark.parametrize("mode", list(RERUNS))
def test_sigma_s_and_phase_k_rerun_the_photon_stages_only_with_multiple_scattering(mode):
    """Spec §4.1 reruns S9 alone for a σ_s change that keeps κ, and for a new phase k; with
    multiple scattering both steer the photons, so photon tracing reruns (photon generation does
    not; the march grids hold σ_s, but not k). The result equals a fresh pipeline's."""
    sigma_change, phase_change = RERUNS[mode]
    pipe = small_pipeline(scattering=mode)
    pipe.render()
    fog = pipe.world.fog
    half = {"sigma_s": 0.5 * fog.sigma_s, "sigma_a": fog.kappa - 0.5 * fog.sigma_s}
    pipe.set_material("fog", **half)
    pipe.render()
    assert pipe.recomputed == sigma_change
    pipe.set_params(phase_k=-0.2)
    incremental = np.array(pipe.render())
    assert pipe.recomputed == phase_change
    fresh = small_pipeline(scattering=mode, phase_k=-0.2)
    fresh.set_material("fog", **half)
    assert np.array_equal(np.array(fresh.render()), incremental)


def test_scattering_must_be_single_or_multiple():
    with pytest.raises(ParameterError, match="scattering must be one of single, multiple"):
        small_pipeline(scattering="double")


# ------------------------------------------------------------------------------------------------
# A fog-only box against Mitsuba volpath (full depth)

WIDTH, HEIGHT = 64, 48
SIGMA_T, ALBEDO = [0.3, 0.5, 0.9], [0.95, 0.85, 0.6]  # per world unit; the cube's side is 4
RATIO_BOUND = 0.03  # |mean brightness ratio − 1|: measured 0.017–0.021 (seeds 0–3)
BLOCK_BOUND = 0.1  # relative RMSE of 4×4-block means: measured 0.063–0.071
GAIN_BOUND = 0.008  # per channel |(ours: multiple/single) / (volpath: full/depth 2) − 1|: ≤ 0.0045


def fog_cube() -> dict:
    """A coloured fog cube [−2, 2]³ (``null`` boundary, isotropic phase), a point light above
    it and off its axis, a camera in front and above: every camera ray through the fog sees
    light scattered up to many times (volpath at full depth is 1.58× depth 2 here)."""
    look = mi.ScalarTransform4f().look_at(origin=[2.5, 3.0, 9.0], target=[0, 0, 0], up=[0, 1, 0])
    return {
        "type": "scene",
        "fog": {
            "type": "homogeneous",
            "sigma_t": {"type": "rgb", "value": SIGMA_T},
            "albedo": {"type": "rgb", "value": ALBEDO},
        },
        "fog_box": {
            "type": "cube",
            "to_world": mi.ScalarTransform4f().scale(2.0),
            "bsdf": {"type": "null"},
            "interior": {"type": "ref", "id": "fog"},
        },
        "light": {"type": "point", "position": [1.0, 7.0, 0.5], "intensity": 60.0},
        "sensor": {
            "type": "perspective",
            "fov": 45.0,
            "to_world": look,
            "film": {
                "type": "hdrfilm",
                "width": WIDTH,
                "height": HEIGHT,
                "rfilter": {"type": "box"},
            },
        },
    }


@pytest.fixture(scope="module")
def volpath() -> dict:
    """volpath at full depth and at depth 2 (direct light + single scattering), 1024 spp. Not
    under ``PHOTONMAP_JIT_DEBUG``: Dr.Jit 1.5's debug mode drops the film's packet scatters
    (DESIGN.md), which halves volpath's image."""
    scene = mi.load_dict(fog_cube())
    out = {}
    with dr.scoped_set_flag(dr.JitFlag.Debug, False):
        for depth in (-1, 2):
            integrator = mi.load_dict({"type": "volpath", "max_depth": depth})
            out[depth] = mitsuba_reference.render(scene, integrator=integrator, spp=1024)[..., :3]
    return out


@pytest.fixture(scope="module")
def ours() -> dict:
    """Our renders of the same file: the fog cube is the grid box (grid 32, 2¹⁶ photons)."""
    out = {}
    for mode in ("single", "multiple"):
        pipe = VolumePipeline(
            fog_cube(),
            grid=32,
            grid_bbox=([-2.0] * 3, [2.0] * 3),
            photons=2**16,
            phase_k=0.0,
            spp=4,
            scattering=mode,
        )
        out[mode] = np.array(pipe.render())
    return out


def test_fog_cube_matches_volpath_at_full_depth(volpath, ours):
    image, reference = ours["multiple"], volpath[-1]
    assert abs(image.mean() / reference.mean() - 1) < RATIO_BOUND
    a, b = block_means(image), block_means(reference)
    assert np.sqrt(np.mean((a - b) ** 2)) / b.mean() < BLOCK_BOUND


def test_higher_orders_add_what_volpath_adds_in_each_channel(volpath, ours):
    """The discretisation errors of grid and viewing pass (the blue channel's κh is largest)
    cancel in the gain of all orders over single scattering, which then matches volpath's
    gain of full depth over depth 2 per channel (spectral-MIS free flights, RGB albedo)."""
    gain = ours["multiple"].mean(axis=(0, 1)) / ours["single"].mean(axis=(0, 1))
    expected = volpath[-1].mean(axis=(0, 1)) / volpath[2].mean(axis=(0, 1))
    assert np.all(expected > 1.3)
    np.testing.assert_allclose(gain / expected, 1.0, atol=GAIN_BOUND)


def test_photons_superpose_exactly_with_their_weights():
    """Photons are independent (each its own random stream, exact fixed-point sums), so marching
    two groups together deposits exactly what marching each alone does (the other group's power
    set to 0), also for Pfeuti's per-voxel photon count and weight sum (emission="adaptive"),
    whose weights must follow each photon through the compactions between orders."""
    n = 24
    box = GridBox((0.0, 0.0, 0.0), float(n), n)
    light = Light(kind="point", position=np.array([10.0, 50.0, 13.0]), intensity=np.ones(3))
    photons = emit(light, box, 32**2)
    count = photons.generated
    group = np.arange(count) % 3 == 0
    weights = mi.Float(np.where(group, 1.0, 3.0))
    grids = uniform_grids(n, 0.08, 0.1)

    def run(mask):
        power = Photons(
            photons.origin, photons.direction, photons.power * mi.Float(mask.astype(float)), count
        )
        r = march(power, grids, weights=weights, scattering=Scattering(0.4, 3))
        wsum = np.array(r.weight, dtype=np.float64) * np.array(r.count, dtype=np.float64)
        return np.array(r.C, dtype=np.float64), np.array(r.count), wsum, r.scatterings

    both, a, b = run(np.ones(count, bool)), run(group), run(~group)
    assert a[3] > 0 and b[3] > 0 and both[3] == a[3] + b[3]
    np.testing.assert_allclose(both[0], a[0] + b[0], rtol=1e-6, atol=1e-9)
    assert np.array_equal(both[1], a[1] + b[1])
    np.testing.assert_allclose(both[2], a[2] + b[2], rtol=1e-6)


def test_multiple_scattering_is_the_default_and_only_adds_light():
    """The first order is Sun's march bit for bit, so the higher orders can only add fluence:
    C(multiple) ≥ C(single) in every voxel and channel (the built-in SPHERE; measured gain of
    ΣC 1.165 at 64³, image brightness 1.185, no pixel darker)."""
    default = small_pipeline()
    assert default.params.scattering == "multiple"
    image = np.array(default.render())
    single = small_pipeline(scattering="single")
    image_single = np.array(single.render())
    C, C_single = default.grids["C"], single.grids["C"]
    assert np.all(C >= C_single)
    assert 1.05 < C.sum() / C_single.sum() < 1.3
    assert image.mean() > image_single.mean()


# ------------------------------------------------------------------------------------------------
# The glass ball in a box of fog (examples/fog_box.xml) against volpath (full depth)

EXAMPLE = Path(__file__).parents[2] / "examples" / "fog_box_sphere_light.xml"
BALL_RATIO_BOUND = 0.04  # |brightness ratio − 1|: measured 0.016–0.024 (seeds 0–3)
BALL_BLOCK_BOUND = 0.2  # relative RMSE of 4×4-block means: measured 0.125–0.133


def fog_box_example(width: int = 48, height: int = 36) -> str:
    """examples/fog_box_sphere_light.xml (a glass ball, n = 1.5, in a 4 × 4 × 4 box of grey fog,
    σ_t 0.25, albedo 0.9, under a sphere light of radius 0.2: ``volpath`` cannot sample the
    volume caustic of fog_box.xml's point light through the glass) at ``width`` × ``height``."""
    xml = EXAMPLE.read_text()
    return xml.replace('value="320"', f'value="{width}"').replace('value="240"', f'value="{height}"')


def test_glass_ball_in_fog_agrees_with_volpath():
    """Ours: grid 64 over the fog box, 2¹⁶ photons from the sphere light, isotropic phase.
    volpath: its own integrator of the file (depth 32), 4096 spp. Most of the block error is
    volpath's: its volume caustic is a scatter of fireflies (light paths through the glass reach
    the small light only by chance; its 1024- and 8192-spp images differ by 0.13); the rest is
    ours, a caustic under the ball a little brighter and the ball's inside darker (no Fresnel
    reflection, the 9³ blur of n at the glass surface). Single scattering is far off here:
    ratio 0.70, block error 0.39 (volpath's full depth is 1.4× its depth 2)."""
    scene = fog_box_example()
    with dr.scoped_set_flag(dr.JitFlag.Debug, False):  # see the volpath fixture
        reference = mitsuba_reference.render(mi.load_string(scene), spp=4096, seed=1)[..., :3]
    pipe = VolumePipeline(
        mi.load_string(scene),
        grid=64,
        grid_bbox=([-2.0] * 3, [2.0] * 3),
        photons=2**16,
        phase_k=0.0,
        table=0.0,
        spp=4,
    )
    image = np.array(pipe.render())
    assert [light.kind for light in pipe.world.lights] == ["area"]
    mean = reference.mean()
    assert abs(image.mean() / mean - 1) < BALL_RATIO_BOUND
    error = np.sqrt(np.mean((block_means(image) - block_means(reference)) ** 2)) / mean
    assert error < BALL_BLOCK_BOUND


def test_a_corrupted_accumulator_is_refused_not_rendered(monkeypatch):
    """A negative sum of non-negative deposits (seen once while building multiple scattering,
    not reproduced) must stop the render with a PhotonmapError, not give a wrong image."""
    from photonmap.volume import march as march_module

    real = march_module.accumulate

    def corrupted(*args, **kwargs):
        first, second, unit, steps, *rest = real(*args, **kwargs)
        return -first - 1, second, unit, steps, *rest

    monkeypatch.setattr(march_module, "accumulate", corrupted)
    pipe = VolumePipeline("glass_sphere_fog", grid=24, photons=1024, width=16, height=12)
    with pytest.raises(PhotonmapError, match="negative energy"):
        pipe.render()


def test_more_scattering_orders_compile_no_more_kernels():
    """Every order after the first marches, rolls the roulette and compacts with the kernels of
    the orders before it (the order is opaque, the state is evaluated once before the
    compaction's gathers): a fog twice as dense scatters twice as often with the same kernels.
    Before, the kernels grew with the orders (57 and 143 distinct for these two fogs)."""

    def kernels(sigma: float) -> tuple[set, int]:
        photons, grids = lambertian_photons(2**12, 0), uniform_grids(N, sigma, sigma)
        dr.eval()
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history()
            result = march(photons, grids, scattering=Scattering(phase_k=0.3, seed=1))
            launched = [k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
        return set(launched), result.scatterings

    thin, thin_events = kernels(0.25)
    dense, dense_events = kernels(0.5)
    assert dense_events > 1.8 * thin_events
    assert dense == thin and len(thin) < 40
