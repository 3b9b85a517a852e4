"""Shared test set-up: import photonmap (selects the LLVM variant); PHOTONMAP_JIT_DEBUG=1 turns on
Dr.Jit's debug mode, which reports out-of-range gathers and scatters (DESIGN.md, Dr.Jit notes);
each test module starts with no scene of an earlier one alive."""

import gc
import os
import sys

import pytest

import photonmap  # first, before drjit: it starts Dr.Jit's threads with SIGINT blocked

dr = photonmap.dr

sys.path.insert(0, os.path.dirname(__file__))  # shared test helpers (knn_reference)

if os.environ.get("PHOTONMAP_JIT_DEBUG"):
    dr.set_flag(dr.JitFlag.Debug, True)


@pytest.fixture(autouse=True, scope="module")
def no_scene_of_an_earlier_module():
    """Collect the garbage an earlier module left (scenes held in reference cycles, e.g. by the
    tracebacks of the errors it checked). Every BSDF, shape and emitter alive is traced into
    each symbolic call Dr.Jit records, so a scene left over would make this module's kernels
    differ with the modules a worker happened to run before (compiled again on every run, the
    kernel cache notwithstanding) and slow their tracing."""
    gc.collect()


# The modules that take longest from an empty kernel cache (``--durations=0`` of a cold run,
# 2 workers), longest first. ``make test`` spreads whole modules over the workers in collection
# order (pytest-xdist ``--dist loadfile``); started last, one of them kept a worker busy for
# minutes after the other had finished. The order changes no result.
LONGEST_FIRST = (
    "tests/test_user_scenes.py",
    "tests/vcm/test_vs_mitsuba.py",
    "tests/test_bsdf_zoo.py",
    "tests/test_docs.py",
    "tests/volume/test_gradients.py",
    "tests/sppm/test_differentiable.py",
    "tests/sppm/test_media.py",
    "tests/test_volume_vs_volpath_benchmark.py",
    "tests/cluster/test_ray.py",
    "tests/test_interrupts.py",
)


def pytest_collection_modifyitems(items):
    """The modules of :data:`LONGEST_FIRST` first, in that order; the others after them, as
    collected."""
    rank = {path: i for i, path in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))
