"""Shared test set-up: import photonmap (selects the LLVM variant); PHOTONMAP_JIT_DEBUG=1 turns on
Dr.Jit's debug mode, which reports out-of-range gathers and scatters (DESIGN.md, Dr.Jit notes)."""

import os
import sys

import photonmap  # first, before drjit: it starts Dr.Jit's threads with SIGINT blocked

dr = photonmap.dr

sys.path.insert(0, os.path.dirname(__file__))  # shared test helpers (knn_reference)

if os.environ.get("PHOTONMAP_JIT_DEBUG"):
    dr.set_flag(dr.JitFlag.Debug, True)
