"""The film's reconstruction filter (core.film_filter, core.camera.pixel_rays): filter importance
sampling (Ernst, Stamminger & Greiner 2006) against the tabulated filter, pixel images against a
NumPy oracle of Mitsuba's film (filter_oracle.py) and against Mitsuba's own ``path``, crops
included; the discrete filter of one-sample-per-pixel images; splatted samples against Mitsuba's
``ImageBlock``."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from filter_oracle import RADIUS, camera, expected_image, filter_1d, scene_dict
from photonmap.core.arrays import to_jit
from photonmap.core.camera import pixel_means, pixel_rays
from photonmap.core.film_filter import filter_image, pixel_kernel, sample_offsets, splat_means
from photonmap.core.sampling import rotated_hammersley

FILTERS = ("gaussian", "tent", "mitchell", "catmullrom", "lanczos")
CROP = ((7, 4), (21, 17))  # offset, size: the rectangles cross the crop's edges
CUT = ((26, 6), (12, 12))  # a bright line 0.0–0.8 px outside the crop's left edge: the cut
# filter of the edge pixels leaves it out (0.3 brighter if the filter were not cut)


@pytest.mark.parametrize("kind", FILTERS + ("box",))
def test_the_oracle_filters_are_mitsubas(kind):
    x = np.linspace(-RADIUS[kind] - 0.5, RADIUS[kind] + 0.5, 1001)
    mitsuba = np.array(mi.load_dict({"type": kind}).eval(to_jit(mi.Float, x)))
    inside = np.abs(np.abs(x) - 0.5) > 1e-3 if kind == "box" else slice(None)  # box: its edge
    atol = 5e-4 if kind == "gaussian" else 2e-6  # Mitsuba's gaussian uses a fast exp
    np.testing.assert_allclose(mitsuba[inside], filter_1d(kind, x)[inside], atol=atol)


def _window_cdf(kind, lo, hi):
    """The oracle's distribution of the offsets of a pixel whose filter is cut to [lo, hi]:
    density |w|, and the expected weight·g(δ) = ∫ w g / ∫ w."""
    x = np.linspace(lo, hi, 200001)
    w = filter_1d(kind, x)
    aw = np.abs(w)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (aw[1:] + aw[:-1]) * np.diff(x))])
    return x, w, cdf / cdf[-1]


@pytest.mark.parametrize("kind", FILTERS)
def test_offsets_are_distributed_as_the_filter(kind):
    """Offsets of an interior pixel and of the first pixel of a row (the filter cut at the crop's
    edge, δ ≥ −½): the Kolmogorov–Smirnov distance to |w| restricted to the window is within
    sampling noise, the map from jitter to offset is monotone (stratification survives), and
    E[weight · g(δ)] = ∫ w g / ∫ w over the window — the film's pixel for radiance g."""
    n, width = 1 << 18, 16
    r = RADIUS[kind]
    u = np.sort(np.random.default_rng(1).random(n).astype(np.float32))
    rfilter = mi.load_dict({"type": kind})
    _, w_full, _ = _window_cdf(kind, -r, r)
    x_full = np.linspace(-r, r, 200001)
    y_norm = np.trapezoid(np.abs(w_full), x_full) / np.trapezoid(w_full, x_full)
    interior = mi.UInt32(np.full(n, 8, np.uint32))
    for column, (lo, hi) in ((8, (-r, r)), (0, (-0.5, r))):
        index = mi.UInt32(np.full(n, column, np.uint32))
        jitter = mi.Point2f(u, np.full(n, 0.5, np.float32))  # y: δ = 0 in an interior row
        offset, weight = sample_offsets(rfilter, (width, width), False, index, interior, jitter)
        d = np.array(offset.x, dtype=np.float64)
        assert d.min() >= lo - 1e-6 and d.max() <= hi + 1e-6
        assert np.all(np.diff(d) >= -1e-6), "the offsets are not monotone in the jitter"
        assert np.abs(np.array(offset.y)).max() < 1e-3
        x, w, cdf = _window_cdf(kind, lo, hi)
        ks = np.abs(np.interp(d, x, cdf) - (np.arange(n) + 0.5) / n).max()
        assert ks < 1.8 / np.sqrt(n), (column, ks)  # KS test, p ≈ 0.003
        signed = (w < 0).any()
        assert (weight is not None) == signed
        # the x part of the weight: the y part is the whole filter's ∫|w| / ∫w (sign +)
        wx = np.ones(n) if weight is None else np.array(weight, dtype=np.float64) / y_norm
        for g in (lambda t: np.cos(2.3 * t) + t * t, lambda t: (t > 0.37).astype(float)):
            expected = np.trapezoid(w * g(x), x) / np.trapezoid(w, x)
            assert abs(np.mean(wx * g(d)) - expected) < 4e-3, (column, kind)


def test_a_box_filter_keeps_the_uniform_jitter_bit_for_bit():
    """Box-filter films trace exactly the rays of before: (x + jitter) / width in the sensor's
    sample space, weight 1."""
    sensor = mi.load_dict(camera(40, 30, "box"))
    n = 40 * 30 * 4
    pixel = dr.arange(mi.UInt32, n) // 4
    rng = np.random.default_rng(3)
    jitter = mi.Point2f(*rng.random((2, n)).astype(np.float32))
    ray, weight = pixel_rays(sensor, pixel, jitter)
    pos = mi.Point2f(
        (mi.Float(pixel % 40) + jitter.x) / 40.0, (mi.Float(pixel // 40) + jitter.y) / 30.0
    )
    expected, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    assert np.array_equal(np.array(ray.d), np.array(expected.d))
    assert np.array_equal(np.array(ray.o), np.array(expected.o))
    assert np.all(np.array(weight) == 1.0)


def test_a_crop_window_sees_the_full_films_pixels():
    """Pixel (x, y) of a crop is pixel (x + offset_x, y + offset_y) of the full film (the sensor's
    sample space spans the crop, as in Mitsuba's own integrators)."""
    full = mi.load_dict(scene_dict(rfilter="box"))
    crop = mi.load_dict(scene_dict(rfilter="box", crop=CROP))
    (ox, oy), (cw, ch) = CROP
    local = np.arange(cw * ch)
    jitter = mi.Point2f(0.25, 0.75)
    a, _ = pixel_rays(crop.sensors()[0], mi.UInt32(local), jitter)
    b, _ = pixel_rays(
        full.sensors()[0], mi.UInt32((local // cw + oy) * 40 + local % cw + ox), jitter
    )
    np.testing.assert_allclose(np.array(a.d), np.array(b.d), atol=2e-6)


def _render_emission(scene, spp: int, seed: int = 0, filtered: bool = True) -> np.ndarray:
    """The radiance the eye rays of :func:`pixel_rays` see (the emitters), stratified jitter
    (rotated Hammersley per pixel), each pixel the mean of its weighted samples."""
    w, h = (int(c) for c in scene.sensors()[0].film().crop_size())
    lanes = w * h * spp
    idx = dr.arange(mi.UInt32, lanes)
    pixel = idx // spp
    rng = mi.PCG32(w * h, mi.UInt64(seed), dr.arange(mi.UInt64, w * h))
    shift = mi.Point2f(rng.next_float32(), rng.next_float32())
    jitter = rotated_hammersley(spp, idx % spp, dr.gather(mi.Point2f, shift, pixel))
    ray, weight = pixel_rays(scene.sensors()[0], pixel, jitter, filtered=filtered)
    si = scene.ray_intersect(ray)
    L = dr.select(si.is_valid(), si.emitter(scene).eval(si), 0.0) * weight
    return np.array(pixel_means(mi.Spectrum(L), spp), dtype=np.float64).T.reshape(h, w, 3)


CASES = [(k, None, False) for k in FILTERS] + [
    ("gaussian", CROP, False), ("mitchell", CROP, False), ("gaussian", CUT, False),
    ("mitchell", CUT, False), ("gaussian", None, True), ("gaussian", CUT, True),
    ("tent", CROP, True),
]  # fmt: skip


@pytest.mark.parametrize("kind,crop,border", CASES)
def test_pixels_converge_to_the_films_filtered_image(kind, crop, border):
    """Eye rays through pixel_rays see the emitting rectangles; every pixel matches the NumPy
    oracle of Mitsuba's film — ∫ w L / ∫ w over the sampled region — within the noise of 1024
    stratified samples (measured: RMS 3·10⁻⁴ gaussian, 1.4·10⁻³ mitchell, 3.6·10⁻³ lanczos,
    largest pixel error 0.024; the radiance is up to 2). Uniform jitter in the pixel (the box
    filter's sampling) misses it by 0.085 (mitchell, cut crop) to 0.53 in some pixel."""
    scene = mi.load_dict(scene_dict(rfilter=kind, crop=crop, sample_border=border))
    expected = expected_image(rfilter=kind, crop=crop, sample_border=border)
    image = _render_emission(scene, 1024)
    assert image.shape == expected.shape
    err = image - expected
    rms, worst = np.sqrt(np.mean(err**2)), np.abs(err).max()
    assert rms < 0.006 and worst < 0.04, (rms, worst)
    box = _render_emission(scene, 256, filtered=False)
    assert np.abs(box - expected).max() > 0.08


@pytest.mark.parametrize(
    "kind,crop,border", [("gaussian", None, False), ("tent", CROP, False),
                         ("mitchell", CUT, False), ("gaussian", CUT, True)]
)  # fmt: skip
def test_the_oracle_is_mitsubas_film(kind, crop, border):
    """Mitsuba's ``path`` at 4096 spp on the same scene agrees with the oracle per pixel (its
    noise: RMS ~2·10⁻³), including the pixels at the crop's edges, where the film's filter is
    cut (or not, with ``sample_border``)."""
    scene = mi.load_dict(scene_dict(rfilter=kind, crop=crop, sample_border=border))
    image = mi.render(scene, integrator=mi.load_dict({"type": "path", "max_depth": 1}),
                      spp=4096, seed=5)  # fmt: skip
    image = np.array(image, dtype=np.float64)[..., :3]
    expected = expected_image(rfilter=kind, crop=crop, sample_border=border)
    err = image - expected
    assert np.sqrt(np.mean(err**2)) < 0.005 and np.abs(err).max() < 0.05
    ours = _render_emission(scene, 1024)
    assert np.sqrt(np.mean((ours - image) ** 2)) < 0.006


def _footprint_taps(kind: str) -> np.ndarray:
    """The oracle filter's integral over each pixel at integer offsets −n … n."""
    n = int(np.ceil(RADIUS[kind] - 0.5))
    taps = []
    for d in range(-n, n + 1):
        x = np.linspace(d - 0.5, d + 0.5, 20001)
        taps.append(np.trapezoid(filter_1d(kind, x), x))
    return np.array(taps)


@pytest.mark.parametrize("kind", ("gaussian", "tent", "mitchell", "lanczos"))
def test_filter_image_is_the_filter_over_each_pixel_cut_at_the_edges(kind):
    """filter_image against a brute-force NumPy convolution: the taps are the filter's integrals
    over the pixels at integer offsets (radius ⌈r − ½⌉), each output pixel normalised by the
    taps inside the image; the "centre" rule takes the filter at the offsets."""
    film = mi.load_dict(camera(13, 9, kind)).film()
    n = int(np.ceil(RADIUS[kind] - 0.5))
    taps = _footprint_taps(kind)
    np.testing.assert_allclose(pixel_kernel(film.rfilter()), taps, atol=2e-4)
    centre = filter_1d(kind, np.arange(-n, n + 1))
    np.testing.assert_allclose(pixel_kernel(film.rfilter(), "centre"), centre, atol=5e-4)
    image = np.random.default_rng(2).random((9, 13, 3))
    expected = np.zeros_like(image)
    for y in range(9):
        for x in range(13):
            total, norm = 0.0, 0.0
            for dy in range(-n, n + 1):
                for dx in range(-n, n + 1):
                    if 0 <= y + dy < 9 and 0 <= x + dx < 13:
                        k = taps[dy + n] * taps[dx + n]
                        total, norm = total + k * image[y + dy, x + dx], norm + k
            expected[y, x] = total / norm
    np.testing.assert_allclose(filter_image(image, film), expected, atol=2e-4)
    tensor = filter_image(to_jit(mi.TensorXf, image), film)
    assert isinstance(tensor, mi.TensorXf)
    np.testing.assert_allclose(np.array(tensor), expected, atol=3e-4)
    box = mi.load_dict(camera(13, 9, "box")).film()
    assert filter_image(image, box) is image


@pytest.mark.parametrize("kind,crop", [("gaussian", None), ("mitchell", CROP), ("lanczos", CUT)])
def test_splatted_samples_are_mitsubas_image_block(kind, crop):
    """splat_means against Mitsuba's own film block (``ImageBlock.put`` of each sample with the
    film's filter, then the colour channels over the weight channel) on random samples, 3 per
    pixel, crops included: equal to float rounding, and the same bits on every run (a gather in
    a fixed order; Mitsuba's atomic scatter is not)."""
    film = mi.load_dict(_film_dict(kind, crop))
    (ox, oy), (w, h) = (tuple(int(c) for c in v) for v in (film.crop_offset(), film.crop_size()))
    spp = 3
    rng = np.random.default_rng(4)
    jitter = rng.random((2, w * h * spp)).astype(np.float32)
    L = rng.random((3, w * h * spp)).astype(np.float32) * 2.0
    ours = [np.array(splat_means(film, mi.Point2f(jitter), mi.Color3f(L), spp)) for _ in range(2)]
    assert np.array_equal(ours[0], ours[1])
    block = mi.ImageBlock(film.crop_size(), film.crop_offset(), 4, rfilter=film.rfilter())
    lane = np.arange(w * h * spp) // spp
    pos = mi.Point2f(ox + lane % w + jitter[0], oy + lane // w + jitter[1])
    block.put(pos, [mi.Float(L[0]), mi.Float(L[1]), mi.Float(L[2]), mi.Float(1.0)])
    t = np.array(block.tensor(), dtype=np.float64).reshape(h * w, 4)
    expected = (t[:, :3] / t[:, 3:]).T
    assert np.abs(ours[0] - expected).max() < 2e-5 * np.abs(expected).max()


def _film_dict(kind: str, crop) -> dict:
    film = {"type": "hdrfilm", "width": 40, "height": 30, "rfilter": {"type": kind}}
    if crop is not None:
        (ox, oy), (cw, ch) = crop
        film.update(crop_offset_x=ox, crop_offset_y=oy, crop_width=cw, crop_height=ch)
    return film
