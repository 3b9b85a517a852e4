"""Bad pipeline input ends in a ParameterError that says what was wrong and how to fix it, never in
a NaN image (issue item 9). Bad scenes: test_scene_errors.py; bad material grids and media:
test_materials.py."""

import numpy as np
import pytest

from photonmap import VolumePipeline
from photonmap.core.errors import ParameterError, PhotonmapError
from photonmap.core.memory import available_memory
from photonmap.volume.params import PHOTON_BYTES, VolumeParams, check_grid, memory_estimate

NAN, INF = float("nan"), float("inf")


@pytest.fixture(scope="module")
def pipe():
    return VolumePipeline("glass_sphere_fog", grid=32, photons=4096, width=16, height=12)


def test_zero_photons():
    with pytest.raises(ParameterError, match=r"photons must lie in \[1, 2147483648\], got 0: .*1024"):
        VolumePipeline("glass_sphere_fog", grid=32, photons=0)


@pytest.mark.parametrize("grid", [32.5, 64.0, "64", True, -8, 0, 3])
def test_grid_must_be_an_integer_of_at_least_4(grid):
    with pytest.raises(ParameterError, match=r"grid must be an integer.*got"):
        VolumePipeline("glass_sphere_fog", grid=grid)


def test_grid_that_does_not_fit_in_memory():
    available = available_memory()
    assert available and available > 0
    with pytest.raises(ParameterError) as info:
        VolumePipeline("glass_sphere_fog", grid=2048)
    message = str(info.value)
    assert message.startswith("grid=2048 needs about ")
    assert " TB of memory" in message and "2048³ voxels × " in message
    assert "is available: use a smaller grid (grid <= " in message
    fits = int(message.split("grid <= ")[1].split()[0])
    assert 4 <= fits < 2048
    assert memory_estimate(fits)[0] <= available < memory_estimate(fits + 2)[0]


def test_memory_estimate_counts_the_grids():
    total, per_voxel = memory_estimate(64, objects=1, photons=1000, threads=2)
    # cached: coverage 4 + materials 28 + ∇n 12 + octree 8 + march 56 (σ_s for multiple
    # scattering) + C, D twice 48 + view 64; while tracing: the 8-channel int64 accumulator, one
    # copy per thread and the scattered orders' accumulator
    assert per_voxel == 220 + 64 * 4
    assert total == per_voxel * 64**3 + PHOTON_BYTES * 1000
    assert memory_estimate(64, objects=3, threads=8)[1] == per_voxel + 8 + 64 * 6
    need = memory_estimate(64)[0] / 2**20  # with this machine's thread count
    with pytest.raises(
        ParameterError, match=rf"needs about {need:.1f} MB .* only 16\.0 MB is avail"
    ):
        check_grid(64, objects=1, photons=0, available=16 * 2**20)
    with pytest.raises(ParameterError, match=r"3,000,000 photons × \d+ bytes.*or fewer photons"):
        check_grid(64, photons=3_000_000, available=2**28)
    check_grid(64, available=2**30)  # fits
    with pytest.raises(ParameterError, match=r"limit of 2³² entries per array: use grid <= 645"):
        check_grid(700, available=2**50)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"phase_k": 1.0}, r"phase_k must lie in \(-1, 1\), got 1.0: Schlick's k is 0 for iso"),
        ({"phase_k": -1.5}, r"phase_k must lie in \(-1, 1\)"),
        ({"phase_k": NAN}, "phase_k must be a finite number, got nan"),
        ({"eps": -0.01}, r"eps must be > 0, got -0.01: the octree tolerance"),
        ({"eps": NAN}, "eps must be a finite number"),
        ({"eps2": 0.001}, r"eps2 must be >= 0.005, got 0.001: .*set eps2 = eps"),
        ({"ds_min": INF}, "ds_min must be a finite number, got inf"),
        ({"ds_max": 0.5}, r"ds_max must be >= 1.0, got 0.5: .* >= ds_min"),
        ({"table": 1.5}, r"table must lie in \[0, 1\]"),
        ({"iso_reflect": 2.0}, r"iso_reflect must lie in \[0, 1\]"),
        ({"ior_noise": -0.1}, "ior_noise must be >= 0, got -0.1"),
        ({"sigma_s_noise": NAN}, "sigma_s_noise must be a finite number"),
        ({"iso_ior": 0.5}, "iso_ior must be >= 1, got 0.5: .*0 = automatic"),
        ({"spp": 0}, "spp must be >= 1, got 0"),
        ({"seed": -1}, r"seed must lie in \[0, 4294967295\], got -1"),
        ({"photons": 4096.0}, r"photons must be an integer, got 4096.0 \(float\)"),
        ({"photons": 2**40}, r"photons must lie in \[1, 2147483648\]"),
        ({"eps": "small"}, r"eps must be a number, got 'small'"),
        ({"smoothing": 1}, r"smoothing must be a bool, got 1"),
        ({"sampler": "sobol"}, "sampler must be one of hammersley, halton, grid, jittered, random"),
        ({"fidelity": "exact"}, "fidelity must be one of physical, paper"),
    ],
)
def test_set_params_rejects_bad_values(pipe, params, message):
    before = pipe.params
    with pytest.raises(ParameterError, match=message):
        pipe.set_params(**params)
    assert pipe.params == before  # a rejected change changes nothing


def test_unknown_parameters_list_the_valid_ones(pipe):
    with pytest.raises(ParameterError, match=r"unknown volume parameter\(s\) gird; valid: .*eps2"):
        pipe.set_params(gird=3)
    with pytest.raises(ParameterError, match=r"valid: .*grid, grid_bbox, .*phase_k.*also accepts"):
        VolumePipeline("glass_sphere_fog", grid=32, phtons=5)
    with pytest.raises(ParameterError, match=r"valid: .*grid, grid_bbox, .*phase_k.*table$"):
        VolumePipeline({"type": "scene"}, grid=32, width=5)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"sigma_s": NAN}, r"sigma_s of glass must be finite, got \[nan, nan, nan\]: pass finite"),
        ({"sigma_a": [0.1, INF, 0.1]}, "sigma_a of glass must be finite"),
        ({"ior": NAN}, r"ior of glass must be finite"),
        ({"sigma_s": -1.0}, r"sigma_s of glass must be >= 0, got \[-1.0, -1.0, -1.0\]"),
        ({"sigma_a": [0.1, -0.2, 0.1]}, "sigma_a of glass must be >= 0"),
        ({"ior": 0.9}, r"n \(ior\) of glass must be >= 1, got 0.9: .* denser than the fog"),
        ({"sigma_s": [1.0, 2.0]}, "sigma_s of glass must be a number or 3 numbers"),
        ({"ior": "glass"}, r"n \(ior\) of glass must be a number"),
    ],
)
def test_set_material_rejects_bad_values(pipe, kwargs, message):
    before = pipe.world.objects[0].medium
    with pytest.raises(ParameterError, match=message):
        pipe.set_material("glass", **kwargs)
    assert pipe.world.objects[0].medium is before


def test_set_material_names_the_objects(pipe):
    with pytest.raises(ParameterError, match=r"no refractive object 'lens'; objects: \['glass'\]"):
        pipe.set_material("lens", ior=1.2)
    with pytest.raises(ParameterError, match="sigma_s of fog must be finite"):
        pipe.set_material("fog", sigma_s=NAN)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"position": [0.5, NAN, 0.5]}, r"light position must be finite, got \[0.5, nan, 0.5\]"),
        ({"intensity": INF}, "light intensity must be finite"),
        ({"intensity": [1.0, -1.0, 1.0]}, "light intensity must be >= 0 in every channel"),
        ({"position": [1.0, 2.0]}, r"light position must be 3 numbers \(x, y, z\)"),
        ({"kind": "laser"}, "light kind must be point, spot or directional, got 'laser'"),
        ({"kind": "directional"}, "a directional light needs a non-zero direction"),
        ({"colour": 1.0}, r"unknown light field\(s\) \['colour'\]; valid: .*intensity"),
    ],
)
def test_set_light_rejects_bad_values(pipe, kwargs, message):
    before = pipe.world.lights[0]
    with pytest.raises(ParameterError, match=message):
        pipe.set_light(**kwargs)
    assert pipe.world.lights[0] is before
    with pytest.raises(ParameterError, match=r"no light 3; the scene has 1 \(valid indices 0..0\)"):
        pipe.set_light(3, intensity=1.0)


def test_set_volume_rejects_bad_grids():
    pipe = VolumePipeline("glass_sphere_fog", grid=32, photons=4096, width=16, height=12)
    ones = np.ones((32, 32, 32))
    with pytest.raises(ParameterError, match=r"needs n, sigma_s and kappa the first time"):
        pipe.set_volume(n=ones)
    bad = ones.copy()
    bad[3, 4, 5] = NAN
    with pytest.raises(ParameterError, match="n of the volume grids has NaN or infinite values"):
        pipe.set_volume(n=bad, sigma_s=ones * 0, kappa=ones)
    with pytest.raises(ParameterError, match="kappa of the volume grids has NaN or infinite"):
        pipe.set_volume(n=ones, sigma_s=ones * 0, kappa=ones * INF)
    with pytest.raises(ParameterError, match=r"grid 'n' has shape \(32, 32, 8\)"):
        pipe.set_volume(n=ones[..., :8], sigma_s=ones, kappa=ones)
    with pytest.raises(ParameterError, match="set_volume: sigma_s must be a numeric array"):
        pipe.set_volume(n=ones, sigma_s="fog", kappa=ones)
    assert pipe.world.grids is None  # nothing was accepted
    pipe.set_volume(n=ones, sigma_s=ones * 0.5, kappa=ones)
    assert np.all(np.isfinite(np.array(pipe.render())))


def test_no_photon_reaching_the_grid_gives_a_black_finite_image():
    """A spot light turned away from the grid: zero photons enter, no NaN."""
    pipe = VolumePipeline("glass_sphere_fog", grid=32, photons=4096, width=16, height=12, table=0)
    pipe.set_light(kind="spot", direction=[0.0, 1.0, 0.0], cos_inner=0.95, cos_outer=0.9)
    img = np.array(pipe.render())
    assert pipe.stats["photons_propagated"] == 0
    assert np.all(np.isfinite(img)) and np.all(pipe.grids["C"] == 0)


def test_every_error_is_a_photonmap_error():
    assert issubclass(ParameterError, PhotonmapError) and issubclass(ParameterError, ValueError)
    VolumeParams().validate()  # the defaults are valid
