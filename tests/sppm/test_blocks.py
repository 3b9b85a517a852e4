"""The memoryless mode's independent iterations (Knaus & Zwicker 2011; the API distributed
rendering builds on): ``render_block`` ranges merge into the same sums as one block, ``run`` equals
``render_block(1, N).image()``, an iteration depends only on ``(seed, i)``."""

import pathlib

import numpy as np
import pytest

from photonmap import ParameterError
from photonmap.sppm import BlockSums, SPPMPipeline

SCENE = str(pathlib.Path(__file__).resolve().parents[2] / "examples/glass_sphere_plane.xml")


@pytest.fixture(scope="module")
def pipe():
    p = SPPMPipeline(SCENE, photons=20_000, mode="memoryless", seed=3)
    p.set_camera(width=40, height=30)
    return p


def test_blocks_merge_to_the_whole(pipe):
    whole = pipe.render_block(1, 4)
    parts = pipe.render_block(3, 2).merge(pipe.render_block(1, 2))  # any order
    assert whole.iterations == parts.iterations == 4
    assert whole.total.shape == (30, 40, 3) and whole.total.dtype == np.float64
    np.testing.assert_allclose(parts.total, whole.total, rtol=1e-12, atol=1e-12)
    assert whole.image().dtype == np.float32
    np.testing.assert_allclose(whole.image(), whole.total / 4, rtol=1e-6)


def test_run_equals_render_block(pipe):
    block = pipe.render_block(1, 3)
    pipe.reset()
    image = np.asarray(pipe.run(iterations=3))
    assert pipe.iterations == 3
    np.testing.assert_array_equal(image, block.image())


def test_iterations_differ_and_depend_on_seed(pipe):
    a, b = pipe.render_block(1, 1).total, pipe.render_block(2, 1).total
    assert not np.array_equal(a, b)  # new random numbers (and radius) per iteration
    assert np.array_equal(a, pipe.render_block(1, 1).total)
    other = SPPMPipeline(SCENE, photons=20_000, mode="memoryless", seed=4)
    other.set_camera(width=40, height=30)
    assert not np.array_equal(a, other.render_block(1, 1).total)


def test_block_errors(pipe):
    with pytest.raises(ParameterError, match="first >= 1"):
        pipe.render_block(0, 2)
    with pytest.raises(ParameterError, match="count >= 1"):
        pipe.render_block(1, 0)
    with pytest.raises(ParameterError, match="different image sizes"):
        BlockSums(np.zeros((2, 2, 3)), 1).merge(BlockSums(np.zeros((3, 2, 3)), 1))
    sppm = SPPMPipeline(SCENE, photons=1000)
    with pytest.raises(ParameterError, match="mode='memoryless'"):
        sppm.render_block(1, 1)


def test_iteration_seeds_are_distinct():
    """Every (seed, iteration) pair draws its own random numbers, and the eye and photon
    passes of one iteration their own streams."""
    from photonmap.core.progressive import iteration_seeds

    seeds = [iteration_seeds(s, i) for s in range(4) for i in range(1, 200)]
    flat = [x for pair in seeds for x in pair]
    assert len(set(flat)) == len(flat)
    assert iteration_seeds(3, 7) == iteration_seeds(3, 7)
