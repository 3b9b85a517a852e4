"""Find a libLLVM that Dr.Jit's LLVM backend and Mitsuba's integrators accept.

Dr.Jit loads libLLVM at run time. LLVM 14 is rejected by Dr.Jit; LLVM 15 runs simple kernels but
Mitsuba's integrators die with "LLVM ERROR: Cannot select ... fminimum" (DESIGN.md); LLVM 19 works.
:func:`configure` points ``DRJIT_LIBLLVM_PATH`` at the newest libLLVM >= 16 it finds, before Dr.Jit
initialises its LLVM backend. A path the user already set is respected.
"""

from __future__ import annotations

import glob
import os
import re

from .errors import BackendError

MIN_VERSION = 16

_SEARCH_DIRS = [
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
    "/opt/homebrew/opt/llvm/lib",
    "/usr/local/opt/llvm/lib",
]

INSTALL_HINT = (
    "Install one ('sudo apt-get install libllvm19' on Debian/Ubuntu, 'brew install llvm' on "
    "macOS; 'make demo' does the apt-get step when run as root), or set DRJIT_LIBLLVM_PATH to the "
    "path of a libLLVM >= 16 shared library."
)


def _version(path: str) -> int | None:
    name = os.path.basename(path)
    m = re.search(r"libLLVM[-.](?:so\.)?(\d+)", name) or re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def candidates() -> list[tuple[int, str]]:
    """All libLLVM shared libraries found, as (major version, path), newest first."""
    found: dict[str, int] = {}
    dirs = _SEARCH_DIRS + sorted(glob.glob("/usr/lib/llvm-*/lib"))
    for d in dirs:
        for pattern in ("libLLVM-*.so", "libLLVM.so.*", "libLLVM-*.so.*", "libLLVM.dylib"):
            for path in glob.glob(os.path.join(d, pattern)):
                v = _version(path)
                if path.endswith(".dylib") and v is None:
                    v = 99  # Homebrew's unversioned libLLVM.dylib is a current release
                if v is not None:
                    found.setdefault(os.path.realpath(path), v)
    return sorted(((v, p) for p, v in found.items()), reverse=True)


def configure() -> str:
    """Set ``DRJIT_LIBLLVM_PATH`` (unless already set) and return the path used."""
    user = os.environ.get("DRJIT_LIBLLVM_PATH")
    if user:
        if not os.path.exists(user):
            raise BackendError(f"DRJIT_LIBLLVM_PATH={user!r} does not exist. {INSTALL_HINT}")
        return user
    usable = [(v, p) for v, p in candidates() if v >= MIN_VERSION]
    if not usable:
        old = ", ".join(f"LLVM {v}" for v, _ in candidates()) or "none"
        raise BackendError(
            f"photonmap needs libLLVM >= {MIN_VERSION} for Dr.Jit's CPU backend (found: {old}). "
            + INSTALL_HINT
        )
    os.environ["DRJIT_LIBLLVM_PATH"] = usable[0][1]
    return usable[0][1]
