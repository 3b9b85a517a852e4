"""The address stream of a render's final gathers (spec seed-001 §2.3, §2.6) and the
``photonmap analyze bandwidth`` command."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest
from typer.testing import CliRunner

from photonmap.analysis.bandwidth import bandwidth_table
from photonmap.analysis.cache import simulate_lines
from photonmap.analysis.stream import GatherTrace, cropped_scene, trace_final_gathers
from photonmap.cli import app
from photonmap.core.arrays import columns
from photonmap.surface.gather_batch import ORDERS
from photonmap.surface.pipeline import SurfacePipeline

SMALL = dict(photons=4000, caustic_photons=0, fg_rays=4, k=20, emitter_spp=0)


@pytest.fixture(scope="module")
def trace():
    return trace_final_gathers(
        cropped_scene("cornell_steinhurst", 128, (48, 64), (16, 16)), **SMALL
    )


def test_visits_are_kd_tree_traversals(trace):
    """Each gather's visit list starts at the root, visits a node at most once and only after its
    parent, and contains the k photons the gather returns (the exact record reads of Jensen's
    locate)."""
    assert len(trace.batch) > 500 and trace.count.min() >= 1
    pipe = SurfacePipeline(
        cropped_scene("cornell_steinhurst", 128, (48, 64), (16, 16)),
        **SMALL,
        lookup="knn",
        structure="kdtree",
    )
    gmap = pipe.photon_maps()[0]
    picked = np.arange(0, len(trace.batch), 37)
    found = gmap.knn(
        mi.Point3f(*columns(mi.Float, trace.batch.position[picked])),
        mi.Vector3f(*columns(mi.Float, trace.batch.normal[picked])),
        20,
        pipe.radii()[1],
    )
    index, count, _ = found.numpy()
    slot_of = np.empty(gmap.size, np.int64)
    slot_of[gmap.structure.order.numpy()] = np.arange(1, gmap.size + 1)
    for row, r in enumerate(picked):
        nodes = trace.slots[trace.offset[r] : trace.offset[r] + trace.count[r]].astype(np.int64)
        assert nodes[0] == 1 and len(np.unique(nodes)) == len(nodes)
        assert nodes.max() <= trace.photons
        seen = {int(n): i for i, n in enumerate(nodes)}
        assert all(seen[n // 2] < seen[n] for n in nodes[1:])
        assert set(slot_of[index[row, : count[row]]]) <= set(seen)


def test_orders_permute_the_same_reads(trace):
    """O2: every order reads the same multiset of lines; the uncached figure is 20 B a node."""
    naive = np.sort(trace.lines("naive", 128))
    assert len(naive) == trace.visits and trace.uncached_bytes() == 20 * trace.visits
    for order in ORDERS[1:]:
        assert np.array_equal(np.sort(trace.lines(order, 128)), naive), order
    rows = {r["order"]: r for r in bandwidth_table(trace, ("naive", "hilbert"), ways=8)}
    assert rows["hilbert"]["misses"] < rows["naive"]["misses"]
    assert rows["hilbert"]["misses"] >= len(np.unique(naive // 6))


def test_analyze_bandwidth_cli(tmp_path):
    runner = CliRunner()
    args = ["analyze", "bandwidth", "cornell_steinhurst", "--size", "128", "--crop", "48,64,16,16"]
    sets = [x for k, v in SMALL.items() for x in ("--set", f"{k}={v}")]
    plot = tmp_path / "cache.png"
    result = runner.invoke(
        app, [*args, *sets, "--sweep", "cache", "--order", "tiled", "--plot", str(plot)]
    )
    assert result.exit_code == 0, result.output
    assert "tiled" in result.output and plot.stat().st_size > 1000
    bad = runner.invoke(app, [*args, "--order", "zigzag"])
    assert bad.exit_code == 2 and "zigzag" in bad.output
    bad = runner.invoke(app, [*args, "--cache", "lots"])
    assert bad.exit_code == 2 and "size" in bad.output


def test_compiled_walk_is_the_renderers_traversal(trace):
    """The compiled walk visits exactly the heap slots, in the same order, as the renderer's
    Dr.Jit traversal (KDTree.visits) — the stream the simulator counts is the real one."""
    pipe = SurfacePipeline(
        cropped_scene("cornell_steinhurst", 128, (48, 64), (16, 16)),
        **SMALL,
        lookup="knn",
        structure="kdtree",
    )
    gmap = pipe.photon_maps()[0]
    count, slots = gmap.structure.visits(
        mi.Point3f(*columns(mi.Float, trace.batch.position)),
        SMALL["k"],
        pipe.radii()[1],
        mi.Vector3f(*columns(mi.Float, trace.batch.normal)),
        gmap.photons.normal,
        gmap.photons.direction,
    )
    assert np.array_equal(count, trace.count)
    assert np.array_equal(slots.astype(np.int64), trace.slots)


def test_recorded_requests_are_the_rendered_ones(trace):
    """Recording the requests without gathering them (the simulator's fast path) keeps the
    requests of a full render."""
    pipe = SurfacePipeline(
        cropped_scene("cornell_steinhurst", 128, (48, 64), (16, 16)),
        **SMALL,
        lookup="knn",
        structure="kdtree",
    )
    pipe.kept_requests = []
    pipe.render()
    (batch,) = pipe.kept_requests
    for field in ("position", "normal", "direction", "pixel", "ray", "specular"):
        assert np.array_equal(getattr(batch, field), getattr(trace.batch, field)), field


def test_streamed_simulation_equals_the_stored_stream(trace):
    """The fused walk + cache bank (full-scale path) counts the same misses as the stored line
    stream fed to the same caches, for every order, capacity, line size and the 8-way cache."""
    caps = [2048, 8192, 32768]
    for order in ORDERS:
        fused = trace.simulate(order, [64, 128], caps, ways=8)
        assert fused.visits == trace.visits
        for row, line in enumerate((64, 128)):
            stream = trace.lines(order, line)
            per_cap = np.diff(np.array(caps) // line, prepend=0)
            missed, sa, compulsory = simulate_lines(stream, per_cap, caps[0] // line // 8, 8)
            assert list(fused.misses[row]) == list(missed), (order, line)
            assert fused.set_associative[row] == sa and fused.compulsory[row] == compulsory
    stored = GatherTrace(trace.batch, trace.tree)  # the same gathers, reads kept and replayed
    assert stored.store_reads(128) and stored.visits == trace.visits
    for order in ORDERS:
        fused, replayed = (t.simulate(order, [128], caps, ways=8) for t in (trace, stored))
        assert np.array_equal(fused.misses, replayed.misses), order
        assert fused.set_associative == replayed.set_associative
        assert fused.compulsory == replayed.compulsory
