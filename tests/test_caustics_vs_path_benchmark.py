"""``benchmarks/caustics_vs_path.py``: the quick run writes the JSON schema the lead's tooling
reads, with a stand-in for ``photonmap.vcm.VCMPipeline`` (Mitsuba's ``path``, one sample per
pixel and step, behind the pipeline interface the benchmark drives); the headline is recomputed
here from the curves; the medians over runs and the reference check against synthetic runs; a
run without ``vcm`` does not import it. Speed is measured by the benchmark itself."""

import json
import math
import sys
import time
import types

import mitsuba as mi
import numpy as np
import pytest

from benchmarks_import import benchmark

SCENES = ["cornell_box", "glass_mesh"]


class FakeVCM:
    """The interface of a progressive pipeline: ``(scene, **params)``, ``step()``, ``image()``,
    ``iterations``, ``timer.ms``, ``stats`` and the merging radius ``mean_radius``."""

    def __init__(self, scene, max_depth, seed):
        self.scene, self.seed, self.iterations = scene, seed, 0
        self.integrator = mi.load_dict({"type": "path", "max_depth": max_depth})
        self.total = None
        self.timer = types.SimpleNamespace(ms={"light pass": 0.0, "camera pass": 0.0})
        self.stats = {"light_paths": 0, "camera_paths": 0, "light_vertices": 0}
        self.mean_radius = 0.1

    def step(self):
        start = time.perf_counter()
        seed = 1000 * self.seed + self.iterations
        image = np.array(mi.render(self.scene, integrator=self.integrator, spp=1, seed=seed))
        ms = 1e3 * (time.perf_counter() - start)
        self.timer.ms["light pass"] += ms / 2
        self.timer.ms["camera pass"] += ms / 2
        pixels = image.shape[0] * image.shape[1]
        self.stats["light_paths"] += pixels
        self.stats["camera_paths"] += pixels
        self.stats["light_vertices"] += 3 * pixels
        self.total = image if self.total is None else self.total + image
        self.iterations += 1
        self.mean_radius = 0.1 * self.iterations ** (-1 / 6)

    def image(self):
        return self.total / self.iterations


@pytest.fixture(scope="module")
def bench():
    return benchmark("caustics_vs_path")


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    return tmp_path_factory.mktemp("caustics_vs_path")


@pytest.fixture(scope="module")
def quick(bench, out):
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(sys.modules, "photonmap.vcm", types.SimpleNamespace(VCMPipeline=FakeVCM))
        result = bench.main(["--quick", "--scenes", ",".join(SCENES), "--out-dir", str(out)])
    return result


def finite(value) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)


def test_quick_run_writes_schema(bench, quick, out):
    data = json.loads((out / "caustics_vs_path_quick.json").read_text())
    assert data == json.loads(json.dumps(quick, default=str))
    assert (out / "caustics_vs_path_quick.png").stat().st_size > 1000
    for name in SCENES:
        for method in ("sppm", "vcm"):
            assert (out / f"caustics_{name}_{method}_quick.png").is_file()
    assert list(data["scenes"]) == SCENES
    headline = data["headline"]
    assert headline["methods"] == ["path", "sppm", "vcm", "surface"]
    assert headline["max_depth"] == {"cornell_box": 8, "glass_mesh": 24}
    for key in bench.NEW_KEYS:
        assert list(headline[key]) == SCENES
        values = [v for v in headline[key].values() if v is not None]
        assert headline["min_" + key] == (min(values) if values else None)
    assert headline["runs"] == 1 and headline["goal"] == {"cornell_box": 0.9, "glass_mesh": 5.0}
    for name, scene in data["scenes"].items():
        assert finite(scene["reference_rel_rmse"]) and finite(scene["reference_block_rel_rmse"])
        assert isinstance(scene["reference_ok"], bool) and len(scene["runs"]) == 1
        blend = scene["reference_blend"]  # ptracer's mean against path's where it is blended
        assert isinstance(blend["blended"], bool) and finite(blend["ptracer_over_path"])
        deep = blend["deep"]  # path again where ptracer cannot serve, or None
        if deep is not None:
            x0, y0, x1, y1 = deep["window"]
            w, h = scene["image"]
            assert 0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h
            assert deep["spp"] == bench.DEEP_SHARE * scene["reference_spp"]
        run = scene["runs"][0]
        for method in bench.METHODS:
            assert run[method] and all(finite(r["seconds"]) for r in run[method])
        for row in run["vcm"]:
            assert row["iterations"] >= 1 and 0 < row["radius"] <= 0.1
        h = scene["headline"]
        for key in ("light_paths_per_s", "camera_paths_per_s", "ray_intersect_per_s",
                    "photon_pass_ray_fraction", "eye_pass_ray_fraction"):  # fmt: skip
            if key == "photon_pass_ray_fraction" and name == "cornell_box":
                assert h[key] is None  # no mirror or glass: path tracing, no photon pass
                continue
            assert finite(h[key]) and h[key] > 0, (name, key)
        assert h["sppm_kernels_compiled_per_iteration"] == 0  # iterations reuse their kernels
        seen = h["photons_seen"]
        assert seen is None if name == "cornell_box" else 0 < seen <= 1
        assert len(run["ray_intersect"]["samples"]) == 3
        assert 0 < run["ray_intersect"]["bounce_rays"] <= run["ray_intersect"]["camera_rays"]
    table = (out / "caustics_vs_path_quick.md").read_text()
    assert "| glass_mesh | vcm |" in table and " iterations, r 0.0" in table


@pytest.mark.parametrize("name", SCENES)
def test_headline_is_computed_from_the_curves(bench, quick, name):
    """The speedups: the other method's time for the last row's error (log-log on its curve,
    t^−½ past its ends) over the last row's seconds."""
    from accuracy import loglog_time_for

    scene = quick["scenes"][name]["runs"][0]
    h = scene["headline"]

    def ratio(rows, final, key="block_rel_rmse"):
        t = loglog_time_for(rows, final[key], key)
        return None if t is None else t / final["seconds"]

    path, sppm, vcm = scene["path"], scene["sppm"], scene["vcm"]
    pairs = {
        "vcm_speedup_vs_path_at_equal_block_rmse": ratio(path, vcm[-1]),
        "vcm_speedup_vs_sppm_at_equal_block_rmse": ratio(sppm, vcm[-1]),
        "sppm_speedup_vs_path_at_equal_block_rmse": ratio(path, sppm[-1]),
        "speedup_vs_path_at_equal_rmse": ratio(path, sppm[-1], "rel_rmse"),
    }
    for key, expected in pairs.items():
        assert h[key] == (None if expected is None else pytest.approx(expected)), key
    assert h["speedup_vs_path_at_equal_block_rmse"] == h["sppm_speedup_vs_path_at_equal_block_rmse"]
    rates = scene["vcm_rates"]
    assert h["light_paths_per_s"] == pytest.approx(
        rates["stats"]["light_paths"] / (rates["stages_ms"]["light pass"] / 1e3)
    )


def test_a_run_without_vcm_does_not_import_it(bench, out):
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(sys.modules, "photonmap.vcm", None)  # any import of it fails
        result = bench.main(["--quick", "--scenes", "glass_mesh", "--methods", "path,sppm",
                             "--out-dir", str(out)])  # fmt: skip
    scene = result["scenes"]["glass_mesh"]
    run = scene["runs"][0]
    assert "vcm" not in run and "surface" not in run and scene["max_depth"] == 24
    assert run["headline"]["vcm_speedup_vs_path_at_equal_block_rmse"] is None
    assert finite(run["headline"]["sppm_speedup_vs_path_at_equal_block_rmse"])
    with pytest.raises(SystemExit, match="unknown"):
        bench.main(["--quick", "--methods", "path,bdpt", "--out-dir", str(out)])


def test_a_scene_headline_is_the_median_of_its_runs(bench):
    runs = [{"a": 1.0, "b": None, "c": None}, {"a": 3.0, "b": 2.0, "c": None},
            {"a": 2.0, "b": 4.0, "c": None}]  # fmt: skip
    assert bench.median_headline(runs) == {"a": 2.0, "b": 3.0, "c": None}


@pytest.mark.parametrize(("reference", "ok"), [(0.01, True), (0.02, False)])
def test_a_noisy_reference_reports_no_ratio(bench, reference, ok):
    """The reference's 4×4 error must be at most a third of the smallest compared (0.05 here)."""
    finals = [{"sppm": [{"block_rel_rmse": 0.09}], "vcm": [{"block_rel_rmse": e}]}
              for e in (0.05, 0.07)]  # fmt: skip
    headline = {key: 6.0 for key in bench.SPEEDUPS}
    res = {"runs": finals, "reference_block_rel_rmse": reference, "headline": headline}
    check = bench.reference_check("pool", res)
    assert check["reference_ok"] is ok and check["smallest_block_rel_rmse"] == 0.05
    assert check["goal"] == 5.0 and check["goal_met"] is ok
    assert all((headline[key] == 6.0) is ok for key in bench.SPEEDUPS)
    assert bench.reference_check("diffuse_room", {**res, "headline": {
        key: 0.95 for key in bench.SPEEDUPS}})["goal"] == 0.9  # fmt: skip


def test_the_reference_blend_weighs_by_inverse_variance():
    """Two unbiased estimates of variance 4 and 1: the first weighs 1/5 where both estimate the
    pixel, 1 where only it does; the blend's variance is the smaller 4/5."""
    from accuracy import blend_weights

    gen = np.random.default_rng(0)
    shape = (48, 48, 3)
    a, b = ([gen.normal(0.0, sd, shape) for _ in range(2)] for sd in (2.0, 1.0))
    where = np.ones(shape[:2], bool)
    where[:, :8] = False
    w = blend_weights(a, b, where)
    assert w.shape == (48, 48, 1) and np.all(w[:, :8] == 1.0)
    assert np.median(w[:, 8:]) == pytest.approx(0.2, abs=0.03)
    x, y = gen.normal(0.0, 2.0, shape), gen.normal(0.0, 1.0, shape)
    blend = (w * x + (1 - w) * y)[:, 8:]
    assert np.var(blend) == pytest.approx(0.8, rel=0.1)


def test_the_deep_pass_is_averaged_in_by_samples_where_path_alone_serves(bench):
    """The window is the bounding box of the pixels outside ``where``, grown by the filter's
    reach within the image; there the deep pass (``DEEP_SHARE`` times the samples) and the
    reference average by sample count; elsewhere the reference is untouched; no window where the
    box covers more than ``DEEP_MAX_AREA`` of the image or every pixel is served."""
    where = np.ones((20, 30), bool)
    where[5:9, 1:4] = False
    where[12, 2] = False
    box, inner = bench.deep_window(where, reach=2)
    assert inner == (1, 5, 4, 13) and box == (0, 3, 6, 15)
    halves = [np.full((20, 30, 3), 1.0), np.full((20, 30, 3), 2.0)]
    deep = [np.full((12, 6, 3), 6.0), np.full((12, 6, 3), 7.0)]
    out = bench.deepened(halves, deep, where, box, inner)
    k = bench.DEEP_SHARE
    for half, value, extra in zip(out, (1.0, 2.0), (6.0, 7.0), strict=True):
        assert np.all(half[~where] == pytest.approx((value + k * extra) / (1 + k)))
        assert np.all(half[where] == value)
    assert bench.deep_window(np.ones((20, 30), bool), 2) is None
    wide = np.ones((20, 30), bool)
    wide[0, 0] = wide[-1, -1] = False  # a box of the whole image
    assert bench.deep_window(wide, 2) is None


def test_a_cropped_render_matches_the_full_render_inside_and_restores_the_film():
    """``accuracy.cropped``: Mitsuba renders the crop alone (its shape), its interior agrees with
    the same pixels of the full render within noise (relative RMSE measured 0.095 at 256 spp;
    0.35 against the pixels one further right and down, 5.5 against the image's corner), and the
    film is whole again afterwards."""
    from accuracy import cropped

    d = mi.cornell_box()
    d["sensor"]["film"].update(width=32, height=32, rfilter={"type": "box"})
    scene = mi.load_dict(d)
    path = mi.load_dict({"type": "path", "max_depth": 8})
    full = np.array(mi.render(scene, integrator=path, spp=256, seed=1))
    crop = cropped(scene, (4, 8, 20, 28),
                   lambda: np.array(mi.render(scene, integrator=path, spp=256, seed=2)))  # fmt: skip
    assert crop.shape == (20, 16, 3)
    inside = crop[1:-1, 1:-1]

    def rel_rmse(pixels):
        return np.sqrt(np.mean((inside - pixels) ** 2)) / pixels.mean()

    assert rel_rmse(full[9:27, 5:19]) < 0.15
    assert rel_rmse(full[10:28, 6:20]) > 0.25 and rel_rmse(full[1:19, 1:15]) > 1.0
    assert tuple(scene.sensors()[0].film().crop_size()) == (32, 32)
    assert np.array(mi.render(scene, integrator=path, spp=1)).shape == (32, 32, 3)
