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
