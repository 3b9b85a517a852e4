"""The test suite as ``make test`` runs it: pytest spread over the machine's cores
(pytest-xdist, one worker per core while memory allows; ``PHOTONMAP_TEST_WORKERS`` overrides),
then one line with the suite's wall time and the number of Dr.Jit kernels it compiled — the new
files in Dr.Jit's kernel cache (``$DRJIT_CACHE_DIR``, else ``~/.drjit``). From an empty cache,
compiling kernels is most of the run: that count is the figure to watch.

    .venv/bin/python scripts/test_suite.py [PYTEST ARGS...]
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

WORKER_MEMORY_GB = 6  # a worker's peak resident memory, measured: 5.3 GB


def kernel_cache() -> Path:
    return Path(os.environ.get("DRJIT_CACHE_DIR") or Path.home() / ".drjit")


def kernels(cache: Path) -> int:
    try:
        return sum(1 for _ in cache.iterdir())
    except FileNotFoundError:
        return 0


def workers() -> int:
    """One per core the process may use, at most one per :data:`WORKER_MEMORY_GB` of memory."""
    if os.environ.get("PHOTONMAP_TEST_WORKERS"):
        return int(os.environ["PHOTONMAP_TEST_WORKERS"])
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return max(1, min(cores or 1, int(memory // WORKER_MEMORY_GB)))


def main(args: list[str]) -> int:
    cache, n = kernel_cache(), workers()
    before, start = kernels(cache), time.perf_counter()
    spread = ["-n", str(n), "--dist", "loadfile"] if n > 1 else ["-p", "no:xdist"]
    code = subprocess.call([sys.executable, "-m", "pytest", "-q", *spread, *args])
    seconds, compiled = time.perf_counter() - start, kernels(cache) - before
    print(f"test suite: {seconds:.0f} s wall with {n} worker{'s' * (n > 1)}, "
          f"{compiled} Dr.Jit kernels compiled (new in {cache})", flush=True)  # fmt: skip
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
