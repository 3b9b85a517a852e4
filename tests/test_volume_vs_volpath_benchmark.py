"""``benchmarks/volume_vs_volpath.py``: the quick run writes the JSON schema the lead's tooling
reads, its curves behave (volpath's error falls with its budget) and its headline
is what the docstring defines, recomputed here from the curves; the error, noise and curve
helpers against synthetic cases with known answers. Speed is measured by the benchmark itself."""

import json
import math

import numpy as np
import pytest

from benchmarks_import import benchmark

METHODS = ("volpath", "volume", "surface")


@pytest.fixture(scope="module")
def bench():
    return benchmark("volume_vs_volpath")


@pytest.fixture(scope="module")
def headlines():
    """The speedup analysis of ``volume_vs_volpath_report.py``."""
    return benchmark("volume_vs_volpath_report")


@pytest.fixture(scope="module")
def quick(bench, tmp_path_factory):
    out = tmp_path_factory.mktemp("volume_vs_volpath")
    result = bench.main(["--quick", "--out-dir", str(out)])
    return out, result


def finite(value) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)


def test_quick_run_writes_schema(bench, quick):
    out, result = quick
    data = json.loads((out / "volume_vs_volpath_quick.json").read_text())
    assert data == json.loads(json.dumps(result, default=str))
    assert (out / "volume_vs_volpath_quick.md").is_file()
    assert (out / "volume_vs_volpath_quick.png").stat().st_size > 1000
    for key in ("cpu_model", "cores", "mitsuba", "drjit", "date", "load_average"):
        assert data["machine"][key]
    assert len(data["load_average_end"]) == 3 and data["runs_per_point"] == 3
    assert list(data["scenes"]) == ["ball", "fog"]
    # the cached reference: two halves under out/cache, not the results folder
    assert len(list((out / "cache").glob("volume_vs_volpath_*_256spp_[12].exr"))) == 4
    for scene in data["scenes"].values():
        assert [h["spp"] for h in scene["reference"]["halves"]] == [128, 128]
    for name, scene in data["scenes"].items():
        assert finite(scene["reference_noise"]["rel_rmse"])
        for method in METHODS:
            rows = scene[method]
            assert len(rows) >= 2
            for row in rows:
                assert len(row["samples"]) == 3
                assert all(finite(r["load_1min"]) for r in row["samples"])
                for key in (*bench.KEYS, "brightness", "seconds"):
                    assert finite(row[key]) and row[key] >= 0, (name, method, key)
                    assert row[key] == pytest.approx(np.median([s[key] for s in row["samples"]]))
                assert row["seconds"] > 0 and 0.5 < row["brightness"] < 1.5
        for method in ("volume", "surface"):
            for key in bench.KEYS:
                h = scene["headline"][method][key]
                assert h["volpath_time_is"] in (
                    "interpolated",
                    "extrapolated",
                    "volpath_1spp_lower",
                    "below_reference_noise",
                )
                assert len(h["points"]) == len(scene[method])
            speedups = {
                key: scene["headline"][method][key]["speedup_vs_volpath_at_equal_rmse"]
                for key in bench.KEYS
            }
            headline = data["headline"][name]
            assert headline["by_error"][method] == speedups
            assert headline["speedup_vs_volpath_at_equal_rmse"][method] == speedups["rel_rmse"]
            assert list(headline["bias_floor"][method]) == list(bench.KEYS)
    table = (out / "volume_vs_volpath_quick.md").read_text()
    assert "## ball" in table and "## fog" in table and "speedup" in table


def test_volpath_error_falls_with_its_budget(quick):
    """In the fog-only box (no caustic fireflies) volpath's error falls like spp^−½ over
    1 → 4 → 16 spp: measured 1.65, 0.84, 0.42 at 48×36 (the 256-spp reference adds ~0.07)."""
    rows = quick[1]["scenes"]["fog"]["volpath"]
    errors = [r["rel_rmse"] for r in rows]
    assert [r["spp"] for r in rows] == [1, 4, 16]
    assert errors[1] < 0.6 * errors[0] and errors[2] < 0.6 * errors[1]
    for row in rows:  # each budget timed on its own: the median of its samples (no speed claim)
        seconds = sorted(r["seconds"] for r in row["samples"])
        assert all(t > 0 for t in seconds) and row["seconds"] == pytest.approx(
            np.median(seconds), rel=1e-12
        )


def loglog_time(ts, es, error):
    """volpath's time for ``error``: straight lines in (log t, log e) between its points, the
    slope −½ after the last one (written independently of the benchmark's helper)."""
    ts, es = np.asarray(ts, float), np.asarray(es, float)
    if error >= es[0]:
        return None
    for (t0, t1), (e0, e1) in zip(
        zip(ts[:-1], ts[1:], strict=True), zip(es[:-1], es[1:], strict=True), strict=True
    ):
        if e0 >= error >= e1:
            slope = (np.log(e1) - np.log(e0)) / (np.log(t1) - np.log(t0))
            return float(t0 * np.exp((np.log(error) - np.log(e0)) / slope))
    return float(ts[-1] * (es[-1] / error) ** 2)


@pytest.mark.parametrize("name", ["ball", "fog"])
def test_headline_is_computed_from_the_curves(quick, name):
    scene = quick[1]["scenes"][name]
    vp = sorted(scene["volpath"], key=lambda r: r["seconds"])
    for method in ("volume", "surface"):
        for key in ("rel_rmse", "block_rel_rmse", "rel_rmse_full"):
            h = scene["headline"][method][key]
            best = min(scene[method], key=lambda r: r[key])
            assert h["at_error"] == best[key] and h["method_seconds"] == best["seconds"]
            t = loglog_time([r["seconds"] for r in vp], [r[key] for r in vp], best[key])
            if t is None:
                assert h["speedup_vs_volpath_at_equal_rmse"] is None
            else:
                assert h["speedup_vs_volpath_at_equal_rmse"] == pytest.approx(
                    t / best["seconds"], rel=1e-9
                )
            speedups = [p["speedup"] for p in h["points"] if p["speedup"] is not None]
            assert h["max_speedup"] == (max(speedups) if speedups else None)


def test_volpath_time_on_an_inverse_square_root_curve(headlines):
    """On e = t^−½ the time for e is e^−2: between points, past the last, refused above the
    first."""
    rows = [{"seconds": t, "e": t**-0.5} for t in (0.01, 0.1, 1.0, 10.0)]
    assert headlines.volpath_time_for(rows, 0.5, "e") == (pytest.approx(4.0), "interpolated")
    assert headlines.volpath_time_for(rows, 0.1, "e") == (pytest.approx(100.0), "extrapolated")
    assert headlines.volpath_time_for(rows, 20.0, "e") == (None, "volpath_1spp_lower")
    assert headlines.volpath_time_for(rows, 0.0, "e") == (None, "below_reference_noise")


def test_a_flattening_curve_reports_its_bias_floor(headlines):
    volpath = [{"seconds": t, "e": t**-0.5} for t in (0.01, 0.1, 1.0, 10.0)]
    biased = [{"seconds": t, "e": e} for t, e in ((0.1, 0.6), (0.4, 0.5), (1.6, 0.48))]
    h = headlines.headline_for(biased, volpath, "e")
    assert not h["error_still_falling"] and h["bias_floor"] == 0.48
    assert not h["reaches_volpath_lowest_error"] and "cannot reach" in h["note"]
    # the lowest-error point: volpath needs 0.48^−2 s, the method 1.6 s
    assert h["speedup_vs_volpath_at_equal_rmse"] == pytest.approx(0.48**-2 / 1.6)
    falling = [{"seconds": t, "e": 0.1 * t**-0.5} for t in (0.1, 0.4, 1.6)]
    h = headlines.headline_for(falling, volpath, "e")
    assert h["error_still_falling"] and h["bias_floor"] is None and "note" not in h
    assert h["max_speedup"] == pytest.approx(100.0)  # 100× less time at every point


def test_errors_against_the_truth_subtract_the_reference_noise(bench):
    """Synthetic images: truth 1 + a smooth pattern, reference halves with Gaussian noise σ_r,
    a render with its own noise σ_m. The halves' difference gives the reference's noise σ_r/√2,
    the raw error is √(σ_m² + σ_r²/2) and the error against the truth σ_m (relative to the mean
    1; 4×4 blocks: σ/4)."""
    rng = np.random.default_rng(7)
    h, w = 120, 160
    y, x = np.mgrid[0:h, 0:w]
    truth = np.repeat((1 + 0.2 * np.sin(x / 9.0) * np.cos(y / 7.0))[..., None], 3, axis=2)
    sr, sm = 0.3, 0.2
    a, b = (truth + rng.normal(0, sr, truth.shape) for _ in range(2))
    mask = np.ones((h, w), bool)
    mask[40:44, 60:62] = False  # a light's image: left out
    target = bench.Target(0.5 * (a + b), a - b, mask)
    mean = truth[mask].mean()
    assert target.noise["rel_rmse"] == pytest.approx(sr / math.sqrt(2) / mean, rel=0.02)
    assert target.noise["block_rel_rmse"] == pytest.approx(sr / 4 / math.sqrt(2) / mean, rel=0.05)
    image = truth + rng.normal(0, sm, truth.shape)
    image[40:44, 60:62] = 1e6  # masked: counts only in the whole-image errors
    errors = target.errors(image)
    assert errors["rel_rmse"] == pytest.approx(math.hypot(sm, sr / math.sqrt(2)) / mean, rel=0.02)
    assert errors["rel_rmse_vs_truth"] == pytest.approx(sm / mean, rel=0.03)
    assert errors["block_rel_rmse_vs_truth"] == pytest.approx(sm / 4 / mean, rel=0.1)
    assert errors["rel_rmse_full"] > 100
    assert bench.Target(truth, 0 * truth, mask).errors(1.1 * truth)["block_rel_rmse"] == (
        pytest.approx(0.1 * np.sqrt(np.mean(truth[mask] ** 2)) / mean, rel=0.01)
    )


def test_light_mask_covers_the_light_seen_through_the_ball_only(bench):
    """The light is out of view: only its images in the glass ball are masked (10 pixels at
    160×120: 2 images, dilated); the fog-only box has none."""
    ball = bench.light_image_mask("ball", (160, 120))
    assert 4 <= (~ball).sum() <= 30
    rows, cols = np.nonzero(~ball)
    assert 70 <= cols.min() and cols.max() <= 90  # on the ball, which is centred
    assert bench.light_image_mask("fog", (160, 120)).all()
