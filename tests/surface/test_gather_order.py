"""Gather batches and Steinhurst's gather orders (spec seed-001 §2.7; oracles O1, O2, O8)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from photonmap import ParameterError, SurfacePipeline
from photonmap.core.order import hilbert3_index
from photonmap.surface.gather_batch import (
    ORDERS,
    GatherBatch,
    OrderParams,
    RequestLayout,
    _hashed,
    direction_bin,
    gather_order,
)

sys.path.insert(0, str(Path(__file__).parents[1] / "analysis"))
from queues_reference import hashed_reference  # noqa: E402


@pytest.fixture(scope="module")
def renders():
    """The Cornell box (32×32, exact k-NN final gathers on the kd-tree) in every order."""
    pipe = SurfacePipeline(
        "cornell_steinhurst",
        width=32,
        height=32,
        photons=5000,
        caustic_photons=5000,
        fg_rays=8,
        k=20,
        lookup="knn",
        structure="kdtree",
        emitter_spp=0,
        tile=8,
    )
    out = {}
    for order in ORDERS:
        pipe.set_params(gather_order=order)
        out[order] = np.array(pipe.render())
    return out


def test_every_order_renders_the_same_image(renders):
    """O1: reordering the gathers changes nothing in the image, bit for bit."""
    naive = renders["naive"]
    assert naive.mean() > 0.05
    for order, image in renders.items():
        assert np.array_equal(image, naive), order


def _batch(n=3000, width=24, height=20, seed=3):
    rng = np.random.default_rng(seed)
    pixel = np.sort(rng.integers(0, width * height, n))
    ray = np.zeros(n, np.int64)
    for start in np.flatnonzero(np.r_[True, pixel[1:] != pixel[:-1]]):
        run = pixel == pixel[start]
        ray[run] = np.arange(run.sum())
    d = rng.normal(size=(n, 3))
    return GatherBatch(
        position=rng.random((n, 3)).astype(np.float32) * 2 - 1,
        normal=np.tile(np.float32([0, 1, 0]), (n, 1)),
        direction=d / np.linalg.norm(d, axis=1, keepdims=True),
        pixel=pixel,
        ray=ray,
        specular=rng.random(width * height)[pixel] < 0.1,
        width=width,
        height=height,
        bounds=(np.full(3, -1.0), np.full(3, 1.0)),
    )


def test_orders_are_permutations_with_their_keys_sorted():
    """O2 (each order is a permutation) and the defining sort keys of each order (§2.7)."""
    b = _batch()
    params = OrderParams(tile=8, grid=5)
    tile = (b.pixel // b.width // 8) * 3 + b.pixel % b.width // 8
    for order in ORDERS:
        perm = gather_order(b, order, params)
        assert np.array_equal(np.sort(perm), np.arange(len(b))), order
        if order.startswith("tiled"):
            assert np.all(np.diff(tile[perm]) >= 0), order
    naive = gather_order(b, "naive", params)
    assert np.all(np.diff(b.pixel[naive] * 10**6 + b.ray[naive]) > 0)
    dirbin = gather_order(b, "tiled_dirbin", params)
    key = tile * 100 + b.specular * 50 + direction_bin(b.direction)
    assert np.all(np.diff(key[dirbin]) >= 0)
    hilbert = gather_order(b, "hilbert", params)
    assert not np.array_equal(hilbert, naive)


def test_hashed_queues_match_a_one_request_at_a_time_simulation():
    """The vectorised hashed queues (§2.7.6, A2) equal the request-by-request queue model."""
    rng = np.random.default_rng(0)
    for _ in range(30):
        n = int(rng.integers(1, 2500))
        p, s = int(rng.choice([3, 5, 17])), int(rng.integers(1, 16))
        stream = np.sort(rng.integers(0, int(rng.integers(1, 5)), n))
        queue = rng.integers(0, p, n) if rng.random() < 0.5 else rng.integers(0, 2, n)
        got = _hashed(stream, queue, OrderParams(queues=p, slots=s))
        assert np.array_equal(got, hashed_reference(stream, queue, p, s))


def test_hilbert_index_is_a_curve():
    """O8: a bijection on the 2^b grid whose consecutive indices are face-adjacent cells."""
    bits = 3
    cells = np.stack(np.meshgrid(*[np.arange(1 << bits)] * 3, indexing="ij"), -1).reshape(-1, 3)
    index = hilbert3_index(cells, bits)
    assert np.array_equal(np.sort(index), np.arange(len(cells)))
    steps = np.abs(np.diff(cells[np.argsort(index)], axis=0)).sum(axis=1)
    assert np.all(steps == 1)


def test_bad_order_parameters():
    b = _batch(10)
    with pytest.raises(ParameterError, match="gather order"):
        gather_order(b, "zigzag")
    with pytest.raises(ParameterError, match="slots"):
        gather_order(b, "hashed", OrderParams(slots=0))
    with pytest.raises(ParameterError, match="gather_order"):
        SurfacePipeline("cornell_steinhurst", width=8, height=8, gather_order="zigzag")


def test_orders_with_the_irradiance_cache():
    """With the tiled irradiance cache only the planned hits gather: their requests carry their
    own pixels (not the lane's index in the plan) and every order still gives the same image."""
    pipe = SurfacePipeline(
        "cornell_steinhurst",
        width=16,
        height=16,
        photons=4000,
        caustic_photons=2000,
        fg_rays=4,
        k=20,
        lookup="knn",
        emitter_spp=0,
        tile=8,
        irradiance_cache="tiled",
        ic_error=0.1,
    )
    images = {}
    for order in ("naive", "hilbert"):
        pipe.kept_requests = []
        pipe.set_params(gather_order=order)
        images[order] = np.array(pipe.render())
    assert np.array_equal(images["naive"], images["hilbert"])
    gathered = pipe.stats["ic_final_gathers"]
    assert 0 < gathered < 16 * 16
    assert sum(len(b.pixel) for b in pipe.kept_requests) <= gathered * 4


def test_a_request_of_a_planned_lane_carries_its_query_points_pixel():
    """``RequestLayout.lanes`` maps the gathering lanes back to their query points."""
    spp = 2
    layout = RequestLayout(
        4, 4, spp, np.zeros(32, bool), (np.zeros(3), np.ones(3)), lanes=np.array([5, 9, 30])
    )
    xyz = np.zeros((4, 3))
    batch = layout.batch(np.array([0, 1, 1, 2]), np.array([0, 0, 1, 0]), xyz, xyz, xyz)
    assert list(batch.pixel) == [2, 4, 4, 15]
    assert list(batch.ray % (1 << 20)) == [0, 0, 1, 0]
    assert list(batch.ray >> 20) == [1, 1, 1, 0]
