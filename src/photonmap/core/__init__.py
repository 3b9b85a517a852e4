"""Shared core of all photonmap pipelines: errors, LLVM discovery, sampling, grids, timing, I/O."""
