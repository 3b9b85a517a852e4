"""The final-gather trace of a render with the tiled irradiance cache (Steinhurst Ch. 5, Table 5.1;
spec seed-001 §2.9.3, O22) and the direction-bin count of the dir-binning order (A1).

A closed box (the Cornell box with a front wall, the camera inside): every final-gather ray hits a
diffuse surface, so a gathering pixel issues exactly ``fg_rays`` requests and the trace's size is
known without the renderer's own counts."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks_import import benchmark
from photonmap.analysis.bandwidth import bandwidth_table
from photonmap.analysis.stream import trace_final_gathers
from photonmap.core.errors import ParameterError
from photonmap.scenes import cornell
from photonmap.scenes.bushes import cornell_bushes
from photonmap.surface.gather_batch import OrderParams, direction_bin, gather_order
from photonmap.surface.pipeline import SurfacePipeline

W, H, FG = 32, 16, 4  # two 16 × 16 tiles
SMALL = dict(photons=4000, caustic_photons=0, fg_rays=FG, k=20, emitter_spp=0)


def closed_box() -> dict:
    """The bare box with the ceiling light, closed by a white front wall, seen from inside."""
    scene = cornell_bushes(W, H, bushes=0)
    w, h = cornell.WIDTH, cornell.HEIGHT
    scene["front"] = cornell.wall(
        (w / 2, h / 2, 0.0), (w / 2, 0, 0), (0, h / 2, 0), (0, 0, 1), cornell.WHITE
    )
    scene["sensor"]["to_world"] = cornell.mi.ScalarTransform4f().look_at(
        origin=[w / 2, h / 2, 0.02], target=[w / 2, h / 2, cornell.DEPTH], up=[0, 1, 0]
    )
    return scene


def traced(ic_error: float | None):
    """The trace of a render and the irradiance cache's plans (captured from the pipeline)."""
    plans = []
    original = SurfacePipeline.cache_plan

    def capture(self, *args):
        plans.append(original(self, *args))
        return plans[-1]

    cache = dict(irradiance_cache="tiled", ic_error=ic_error) if ic_error else {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SurfacePipeline, "cache_plan", capture)
        trace = trace_final_gathers(closed_box(), **SMALL, **cache)
    return trace, plans


@pytest.fixture(scope="module")
def full():
    return traced(None)[0]


def test_ic_trace_holds_exactly_the_planned_gathers(full):
    """With the cache, the kept requests are the ``fg_rays`` gathers of each planned pixel (the
    records and the non-Lambertian hits) and no other."""
    assert len(full.batch) == W * H * FG  # closed box: every ray of every pixel gathers
    trace, (plan,) = traced(0.3)
    assert 0 < len(plan.gather) < W * H // 2  # the cache saves most gathers here
    assert len(trace.batch) == len(plan.gather) * FG
    pixel, ray = trace.batch.pixel, trace.batch.ray
    assert np.array_equal(np.unique(pixel), np.sort(plan.gather))
    per_pixel = np.bincount(pixel, minlength=W * H)[plan.gather]
    assert np.array_equal(per_pixel, np.full(len(plan.gather), FG))
    assert len(np.unique(pixel * FG + ray)) == len(pixel) and ray.max() == FG - 1
    # bandwidth of every order is a count of real fetches, at most the uncached figure's lines
    for row in bandwidth_table(trace, ("naive", "tiled_hilbert")):
        assert 0 < row["bytes"] <= trace.visits * 128


def test_ic_without_interpolation_is_the_full_trace(full):
    """At a tiny ε_max every Lambertian hit is a record and gathers: the cached render's trace is
    the uncached one, request for request and node for node (the planned lanes are the identity,
    so even the final-gather directions coincide)."""
    trace, (plan,) = traced(1e-6)
    assert plan.record.all() and len(plan.gather) == W * H
    for field in ("pixel", "ray", "position", "direction"):
        assert np.array_equal(getattr(trace.batch, field), getattr(full.batch, field)), field
    assert np.array_equal(trace.count, full.count) and np.array_equal(trace.slots, full.slots)


def test_direction_bins_have_equal_solid_angle():
    """Spec A1: ``bins`` = 2^b world-space bins of equal solid angle — uniform directions on the
    sphere fill each bin alike (within 5 binomial σ), and 32 bins are the default order."""
    d = np.random.default_rng(3).normal(size=(200_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for bins in (1, 8, 16, 32, 64, 128):
        counts = np.bincount(direction_bin(d, bins), minlength=bins)
        expected = len(d) / bins
        assert len(counts) == bins
        assert np.abs(counts - expected).max() < 5 * np.sqrt(expected * (1 - 1 / bins)) + 1e-9
    assert np.array_equal(direction_bin(d), direction_bin(d, 32))
    with pytest.raises(ParameterError, match="power of two"):
        OrderParams(bins=12).validate()


def test_bin_count_changes_only_the_dirbin_order(full):
    """More bins refine the dir-binning order: bins = 1 is the tiled order (no specular pixels
    here); every bin count issues a permutation of the same requests."""
    b = full.batch
    tiled = gather_order(b, "tiled")
    assert np.array_equal(gather_order(b, "tiled_dirbin", OrderParams(bins=1)), tiled)
    for bins in (8, 128):
        perm = gather_order(b, "tiled_dirbin", OrderParams(bins=bins))
        assert np.array_equal(np.sort(perm), np.arange(len(b)))
        key = direction_bin(b.direction[perm], bins)
        tile = (b.pixel[perm] // W // 16) * 2 + b.pixel[perm] % W // 16
        assert np.all(np.diff(tile * 1000 + key) >= 0)


def test_table_5_1_claims():
    """O22/O23's claims are read off the table as the dissertation states them."""
    mod = benchmark("steinhurst_table_5_1")
    doc = {
        label: {
            "percent_of_naive": {
                c: dict(zip(mod.ORDERS, values, strict=True))
                for c, values in zip(("none", "tiled"), rows, strict=True)
            },
            "R_IC_image": r,
        }
        for (label, rows), r in zip(mod.DOC.items(), (0.6, 0.4, 0.3), strict=True)
    }
    assert all(mod.claims(doc).values())  # the dissertation's own numbers satisfy them all
    doc["two bushes"]["percent_of_naive"]["tiled"]["naive"] = 6.0  # IC alone beats Hilbert
    doc["many bushes"]["R_IC_image"] = 0.5
    failed = [k for k, v in mod.claims(doc).items() if not v]
    assert failed == [
        "two bushes: tiled Hilbert without IC < IC alone (naive)",
        "R_IC (R_IC_image) falls as bushes are added (O23)",
    ]


def test_o17_study_quick(tmp_path):
    """The O17 parameter study runs end to end and names its verdict per scene; with
    ``--sweeps-only`` it keeps the (N_FG, photons) table and re-traces the best setting, which
    is deterministic: the bin sweep comes out the same."""
    study = benchmark("steinhurst_o17_study")
    result = study.main(["--quick", "--out-dir", str(tmp_path)])
    assert (tmp_path / "steinhurst_o17_study_quick.md").is_file()
    for name, s in result["scenes"].items():
        assert len(s["settings"]) == 2 and set(s["bins"]) == {"8", "32"}
        assert all(v > 0 for r in s["settings"] for v in r["reduction_vs_uncached"].values())
        assert name in result["verdict"][name]
    again = study.main(["--quick", "--sweeps-only", "--out-dir", str(tmp_path)])
    for name, s in again["scenes"].items():
        assert s["settings"] == json.loads(json.dumps(result["scenes"][name]["settings"]))
        assert s["bins"] == result["scenes"][name]["bins"]
