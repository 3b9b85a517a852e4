"""The kdB-tree and block hashing of Steinhurst 2007 Ch. 4 (spec seed-001 §2.8, Table 4.1, O21):
exact k-NN against a NumPy brute force and the Dr.Jit kd-tree, the recorded line streams, and
their traces through the cache simulator."""

from __future__ import annotations

from types import SimpleNamespace

import mitsuba as mi
import numpy as np
import pytest

from photonmap.analysis.bandwidth import bandwidth_table
from photonmap.analysis.blockhash import BlockHash
from photonmap.analysis.kdbtree import KDBTree
from photonmap.analysis.structures import fetches_per_block, recall, structure_trace
from photonmap.core.arrays import columns
from photonmap.core.errors import ParameterError
from photonmap.core.knn import COS_NORMAL
from photonmap.surface.gather_batch import ORDERS, GatherBatch, gather_order
from photonmap.surface.kdtree import KDTree

RNG = np.random.default_rng(7)


def unit(n: int) -> np.ndarray:
    v = RNG.standard_normal((n, 3))
    return (v / np.linalg.norm(v, axis=1)[:, None]).astype(np.float32)


def brute_force(p, normals, directions, q, qn, k, radius) -> np.ndarray:
    """The k-NN result of core.knn: accepted photons, k smallest (d², index), −1 unused."""
    r2 = np.float32(radius) ** 2 if np.isfinite(radius) else np.float32(np.inf)
    out = np.full((len(q), k), -1)
    for i in range(len(q)):
        d = p - q[i]
        d2 = (d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]
        ok = (d2 <= r2) & ((directions @ qn[i]) < 0)
        ok &= (normals @ qn[i]) >= np.float32(COS_NORMAL)
        idx = np.flatnonzero(ok)
        best = idx[np.lexsort((idx, d2[idx]))[:k]]
        out[i, : len(best)] = best
    return out


@pytest.fixture(scope="module")
def cloud():
    """Photons with many exact ties (a coarse lattice) and coherent normals: two thirds on the
    floor facing +y, the rest random; queries on photons and between them."""
    n = 3000
    p = RNG.random((n, 3)).astype(np.float32)
    p[: n // 3] = np.round(p[: n // 3] * 6) / 6
    p[n // 3 : 2 * n // 3, 1] = 0
    normals = unit(n)
    normals[: 2 * n // 3] = (0, 1, 0)
    directions = unit(n)
    directions[: 2 * n // 3, 1] = -np.abs(directions[: 2 * n // 3, 1])
    q = RNG.random((240, 3)).astype(np.float32)
    q[:60] = p[:60]
    q[60:160, 1] = 0
    qn = unit(240)
    qn[60:160] = (0, 1, 0)
    return p, normals, directions, q, qn


@pytest.mark.parametrize("line", [64, 128, 1024])
@pytest.mark.parametrize(("k", "radius"), [(20, 0.25), (7, np.inf)])
def test_kdb_knn_is_exact(cloud, line, k, radius):
    """The kdB-tree's gather finds exactly the photons of the brute force and of the Dr.Jit
    kd-tree (same k, radius, normal test; ties by photon index)."""
    p, normals, directions, q, qn = cloud
    found, _, _ = KDBTree(p, line).knn(q, qn, normals, directions, k, radius)
    expected = brute_force(p, normals, directions, q, qn, k, radius)
    assert (expected >= 0).sum() > 0.4 * expected.size  # not a vacuous comparison
    np.testing.assert_array_equal(found, expected)
    kd = KDTree(mi.Point3f(*columns(mi.Float, p))).knn(
        mi.Point3f(*columns(mi.Float, q)),
        k,
        radius,
        mi.Vector3f(*columns(mi.Float, qn)),
        mi.Vector3f(*columns(mi.Float, normals)),
        mi.Vector3f(*columns(mi.Float, directions)),
    )
    index, count, _ = kd.numpy()
    np.testing.assert_array_equal(np.where(index == 0xFFFFFFFF, -1, index.astype(np.int64)), found)


def test_kdb_layout_and_streams(cloud):
    """Leaves hold ⌊(L − 8)/20⌋ photons (all full but one), regions ⌊L/28⌋ entries, every photon
    in one leaf; each gather reads the root first, then only nodes whose parent it read before,
    none twice."""
    p, normals, directions, q, qn = cloud
    tree = KDBTree(p, 128)
    leaves = tree.kind == 1
    assert tree.leaf_capacity == 6 and tree.fan_out == 4
    assert (KDBTree(p, 64).leaf_capacity, KDBTree(p, 1024).fan_out) == (2, 36)
    assert np.count_nonzero(leaves) == -(-len(p) // 6)
    assert np.count_nonzero(tree.count[leaves] < 6) <= 1 and tree.count[~leaves].max() <= 4
    assert np.array_equal(np.sort(tree.perm), np.arange(len(p)))
    parent = np.full(tree.lines, -1)
    for node in np.flatnonzero(~leaves):
        parent[tree.child[tree.first[node] : tree.first[node] + tree.count[node]]] = node
    _, reads, lines = tree.knn(q, qn, normals, directions, 20, 0.25)
    offset = np.cumsum(reads) - reads
    assert reads.min() >= 2 and lines.max() < tree.lines
    for r in range(len(q)):
        mine = lines[offset[r] : offset[r] + reads[r]]
        assert mine[0] == 0 and len(np.unique(mine)) == len(mine)
        position = {int(n): i for i, n in enumerate(mine)}
        assert all(position[parent[n]] < i for i, n in enumerate(mine) if i > 0)


def test_block_hash_streams_and_recall(cloud):
    """Each gather reads its bucket in every table, then at most A blocks listed in them; recall
    of the exact k nearest is measured (0.91 on this cloud at A = 20, 0.97 at A = 60) and bounded
    below; no bucket holds more pointers than its line."""
    p, normals, directions, q, qn = cloud
    bh = BlockHash(p, 128, k=20, accuracy=20)
    found, reads, lines = bh.knn(q, qn, normals, directions, 20, 0.25)
    offset = np.cumsum(reads) - reads
    assert reads.max() <= bh.tables + 20
    for r in range(len(q)):
        mine = lines[offset[r] : offset[r] + reads[r]]
        buckets, blocks = mine[: bh.tables], mine[bh.tables :]
        assert np.all((buckets >= bh.blocks) & (buckets < bh.lines))
        listed = np.concatenate(
            [
                bh.entries[bh.bucket_first[b] : bh.bucket_first[b] + bh.bucket_count[b]]
                for b in buckets - bh.blocks
            ]
        )
        assert np.all(np.isin(blocks, listed)) and len(np.unique(blocks)) == len(blocks)
    exact = brute_force(p, normals, directions, q, qn, 20, 0.25)
    assert bh.bucket_count.max() <= bh.bucket_capacity == 32
    measured = recall(found, exact)
    assert measured >= 0.85
    more = BlockHash(p, 128, k=20, accuracy=60).knn(q, qn, normals, directions, 20, 0.25)[0]
    assert recall(more, exact) > measured


@pytest.fixture(scope="module")
def fake_trace(cloud):
    """A GatherTrace stand-in: a 16 × 8 image, 2 gathers per pixel at the cloud's queries."""
    p, normals, directions, q, qn = cloud
    n = 256
    pick = RNG.integers(0, len(q), n)
    batch = GatherBatch(
        q[pick],
        qn[pick],
        unit(n),
        np.repeat(np.arange(128), 2),
        np.tile([0, 1], 128),
        np.zeros(n, bool),
        16,
        8,
        (np.zeros(3), np.ones(3)),
    )
    return SimpleNamespace(
        batch=batch, k=20, radius=0.25, photon_data=(p, normals, directions), photons=len(p)
    )


@pytest.mark.parametrize("structure", ["kdbtree", "blockhash"])
def test_structure_traces_in_the_cache_simulator(fake_trace, structure):
    """An order's stream is its gathers' line lists in that order, the same lines in every
    order; a cache larger than the structure misses each distinct line once (compulsory misses
    only); bandwidth_table works unchanged."""
    trace = structure_trace(fake_trace, structure)
    _, _, reads, offset, lines = trace.build(128)
    perm = gather_order(fake_trace.batch, "hilbert")
    expected = np.concatenate([lines[offset[r] : offset[r] + reads[r]] for r in perm])
    assert np.array_equal(trace.lines("hilbert", 128), expected)
    naive = np.sort(trace.lines("naive", 128))
    for order in ORDERS[1:]:
        assert np.array_equal(np.sort(trace.lines(order, 128)), naive), order
    size = trace.footprint_lines(256) * 256
    for order in ("naive", "hilbert"):
        row = fetches_per_block(trace, order, size, 256)
        assert row["misses"] == row["distinct_lines"] == len(np.unique(trace.lines(order, 256)))
    small = fetches_per_block(trace, "naive", 16 * 128, 128)
    assert small["fetches_per_block"] > 1
    rows = bandwidth_table(trace, ("naive", "hilbert"), cache_bytes=16 * 128)
    assert rows[0]["misses"] == small["misses"] and trace.uncached_bytes() > 0


def test_bad_parameters(cloud, fake_trace):
    p = cloud[0]
    for line in (27, 48):  # no room for one photon; a region of one entry
        with pytest.raises(ParameterError, match="line|region"):
            KDBTree(p, line)
    with pytest.raises(ParameterError, match="header"):
        BlockHash(p, 20)
    with pytest.raises(ParameterError, match="accuracy"):
        BlockHash(p, 128, accuracy=0)
    with pytest.raises(ParameterError, match="structure"):
        structure_trace(fake_trace, "octree")
    with pytest.raises(ParameterError, match="k must"):
        KDBTree(p, 128).knn(p[:2], p[:2], p, p, 0, 1.0)


def test_analyze_bandwidth_structure_cli():
    """``photonmap analyze bandwidth --structure kdbtree`` prints the orders' table on the
    kdB-tree; an unknown structure is refused."""
    from typer.testing import CliRunner

    from photonmap.cli import app

    args = ["analyze", "bandwidth", "cornell_steinhurst", "--size", "128", "--crop", "56,64,8,8"]
    small = dict(photons=2000, caustic_photons=0, fg_rays=2, k=10, emitter_spp=0)
    sets = [x for k, v in small.items() for x in ("--set", f"{k}={v}")]
    runner = CliRunner()
    result = runner.invoke(app, [*args, *sets, "--structure", "kdbtree", "--order", "hilbert"])
    assert result.exit_code == 0, result.output
    assert "on the kdbtree" in result.output and "hilbert" in result.output
    # the rows are the kdB-tree's misses, not the kd-tree's
    kd = runner.invoke(app, [*args, *sets, "--structure", "kdtree", "--order", "hilbert"])
    assert kd.exit_code == 0, kd.output
    row = [line for line in result.output.splitlines() if line.startswith("hilbert")]
    kd_row = [line for line in kd.output.splitlines() if line.startswith("hilbert")]
    assert len(row) == len(kd_row) == 1 and row != kd_row
    bad = runner.invoke(app, [*args, "--structure", "octree"])
    assert bad.exit_code == 2 and "kdbtree" in bad.output
