"""Shared test set-up: import photonmap (selects the LLVM variant); PHOTONMAP_JIT_DEBUG=1 turns on
Dr.Jit's debug mode, which reports out-of-range gathers and scatters (DESIGN.md, Dr.Jit notes)."""

import os
import sys

import drjit as dr

import photonmap  # noqa: F401

sys.path.insert(0, os.path.dirname(__file__))  # shared test helpers (knn_reference)

if os.environ.get("PHOTONMAP_JIT_DEBUG"):
    dr.set_flag(dr.JitFlag.Debug, True)
