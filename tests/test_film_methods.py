"""Every method renders the film of the user's file: ``mi.cornell_box()`` unchanged (Mitsuba's
default gaussian reconstruction filter) against Mitsuba's ``path`` per pixel, not only in 4×4
blocks. The error of the same method on the box-filtered film — what a method that ignores the
film's filter computes — against the gaussian reference is the contrast: the pixels at the
light's edges differ by up to half the light's radiance (relative RMSE ≈ 0.6 at 64²)."""

import mitsuba as mi
import numpy as np
import pytest

import mitsuba_reference
from photonmap import METHODS

SIZE = 64


def _scene(rfilter: str | None = None) -> mi.Scene:
    d = mi.cornell_box()  # gaussian filter, path max_depth 8
    d["sensor"]["film"].update(width=SIZE, height=SIZE)
    if rfilter is not None:
        d["sensor"]["film"]["rfilter"] = {"type": rfilter}
    return mi.load_dict(d)


@pytest.fixture(scope="module")
def reference():
    return mitsuba_reference.render(_scene(), spp=2048, seed=0).astype(np.float64)[..., :3]


def _rel_rmse(image, ref) -> float:
    return float(np.sqrt(np.mean((image - ref) ** 2)) / ref.mean())


RUNS = {
    "surface": dict(photons=50_000, caustic_photons=0, fg_rays=8, spp=16),
    "sppm": dict(iterations=32, photons=20_000),
    "screen": dict(),
}


BOUND = {"surface": 0.2, "sppm": 0.25, "screen": 0.25}


@pytest.mark.parametrize("method", list(RUNS))
def test_the_gaussian_film_matches_path_per_pixel(method, reference):
    """Measured (relative RMSE per pixel against path at 2048 spp): surface 0.12, sppm 0.10–0.16
    (seeds 0–2; path tracing, its paths splatted through the filter; 0.35 with one pixel per
    path by filter importance sampling), screen 0.15; the same methods on the box-filtered film
    against this reference 1.12 / 1.15 / 1.21."""
    pipeline = METHODS[method].pipeline
    image = np.array(pipeline(_scene(), **RUNS[method]).render(), dtype=np.float64)
    box = np.array(pipeline(_scene("box"), **RUNS[method]).render(), dtype=np.float64)
    err, err_box = _rel_rmse(image, reference), _rel_rmse(box, reference)
    assert err < BOUND[method], (err, err_box)
    assert err_box > 0.8, err_box


CROP = dict(crop_offset_x=14, crop_offset_y=6, crop_width=40, crop_height=30)


@pytest.mark.parametrize("method", list(RUNS))
def test_a_crop_window_renders_the_crop(method, reference):
    """A film with a crop window: the image is the crop's size and matches Mitsuba's render of
    the cropped film per pixel (the filter cut at the crop's edges), not the film's corner.
    Measured: surface 0.083, sppm 0.05–0.06 (seeds 0–2), screen 0.087; against the film's
    corner 6.5."""
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=SIZE, height=SIZE, **CROP)
    scene = mi.load_dict(d)
    truth = mitsuba_reference.render(scene, spp=2048, seed=1).astype(np.float64)[..., :3]
    image = np.array(METHODS[method].pipeline(scene, **RUNS[method]).render(), dtype=np.float64)
    assert image.shape == truth.shape == (30, 40, 3)
    assert _rel_rmse(image, truth) < BOUND[method]
    assert _rel_rmse(image, reference[:30, :40]) > 0.5
