"""Memory: what is available, and what a render will need, so that one that cannot fit is
refused before it allocates anything, with one line naming what takes the memory.

Each method estimates its own need from its parameters and the image size (``volume.params``,
``surface.memory``, ``sppm.memory``, ``screen.memory``: a few named parts, rough upper bounds
measured on the LLVM backend) and refuses through :func:`check_memory`, which also refuses
arrays past Dr.Jit's 2³² entries. The available memory is the smallest of the system's
``MemAvailable``, the cgroup's limit and the address-space limit (``ulimit -v``), unless
:func:`set_memory_limit` (the CLI's ``--max-memory``) or ``PHOTONMAP_MAX_MEMORY`` says otherwise.
"""

from __future__ import annotations

import os
import re
import weakref

from .errors import ParameterError

MAX_SIDE = 16384  # pixels per image side
DRJIT_MAX_ENTRIES = 2**32  # Dr.Jit arrays hold fewer entries than this
_limit: int | None = None  # set_memory_limit()
# bytes in flight per camera sample (rough upper bounds measured on the LLVM backend: the eye
# pass's interactions, the final-gather batch, the view pass's march state, the G-buffers)
BYTES_PER_SAMPLE = {
    "surface": 1200, "volume": 400, "screen": 2000, "sppm": 1200, "vcm": 1200,
}  # fmt: skip


def parse_size(text: str, what: str = "--max-memory") -> int:
    """``"8G"``, ``"512M"``, ``"1.5e9"``, ``"64 KiB"`` → bytes (K, M, G, T, P: powers of 1024)."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:e[0-9]+)?)\s*([kmgtp]?)i?b?\s*", str(text).lower())
    if not match:
        raise ParameterError(f"{what}: expected a size such as 8G, 512M or 2e9 bytes, got {text!r}")
    value = float(match.group(1)) * 1024 ** " kmgtp".index(match.group(2) or " ")
    if not value >= 1:
        raise ParameterError(f"{what} must be at least 1 byte, got {text!r}")
    return int(value)


def set_memory_limit(limit: int | str | None) -> None:
    """Use ``limit`` bytes (or a size text, :func:`parse_size`) as the memory available to
    renders instead of what the system reports; None: the system's again."""
    global _limit
    _limit = (
        None if limit is None else (parse_size(limit) if isinstance(limit, str) else int(limit))
    )


def available_memory() -> int | None:
    """Bytes of memory available to this process, or None if unknown: the limit set by
    :func:`set_memory_limit` or ``PHOTONMAP_MAX_MEMORY`` if any, else the smallest of
    ``MemAvailable`` (/proc/meminfo; the physical memory elsewhere), the cgroup's
    ``memory.max`` less its ``memory.current``, and the address-space limit (``ulimit -v``)
    less the process's virtual size."""
    if _limit is not None:
        return _limit
    if os.environ.get("PHOTONMAP_MAX_MEMORY"):
        return parse_size(os.environ["PHOTONMAP_MAX_MEMORY"], "PHOTONMAP_MAX_MEMORY")
    found = [v for v in (_system_available(), _cgroup_headroom(), _rlimit_headroom()) if v]
    return min(found) if found else None


def _system_available() -> int | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read().strip()
    except OSError:
        return None


def _cgroup_headroom() -> int | None:
    """``memory.max − memory.current`` of this process's cgroup (v2), if it has a limit."""
    own = _read("/proc/self/cgroup") or ""
    paths = [line.split("::", 1)[1] for line in own.splitlines() if line.startswith("0::")]
    for path in [*paths, "/"]:
        folder = os.path.join("/sys/fs/cgroup", path.lstrip("/"))
        limit, current = _read(f"{folder}/memory.max"), _read(f"{folder}/memory.current")
        if limit is not None and current is not None:
            if limit == "max":
                return None
            return max(int(limit) - int(current), 0)
    return None


def _rlimit_headroom() -> int | None:
    """The address-space limit (``ulimit -v``) less the process's present virtual size."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    except (ImportError, OSError, ValueError, AttributeError):
        return None
    if soft == resource.RLIM_INFINITY:
        return None
    status = _read("/proc/self/status") or ""
    size = re.search(r"^VmSize:\s+(\d+) kB", status, re.M)
    return max(soft - (int(size.group(1)) * 1024 if size else 0), 0)


def human_bytes(n: float) -> str:
    """``1536`` → ``"1.5 KB"`` (units of 1024)."""
    for unit in ("B", "KB", "MB", "GB", "TB", "PB"):
        if n < 1024 or unit == "PB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} PB"  # pragma: no cover


def check_memory(
    method: str, parts: dict[str, float], hint: str, entries=None, available: int | None = None
) -> int:
    """Raise a :class:`ParameterError` (one line) when the ``parts`` of a render (name → bytes)
    add up to more than ``available`` bytes (default :func:`available_memory`), or when one of
    ``entries`` (an array's description → its number of entries) reaches Dr.Jit's 2³² entries;
    ``hint`` says what to lower. Returns the estimate in bytes."""
    need = int(sum(parts.values()))
    available = available_memory() if available is None else available
    if available is not None and need > available:
        big = sorted(parts.items(), key=lambda kv: -kv[1])
        detail = ", ".join(f"{name} {human_bytes(v)}" for name, v in big if v >= need / 100)
        raise ParameterError(
            f"these {method} settings need about {human_bytes(need)} of memory ({detail}), but "
            f"only {human_bytes(available)} is available: {hint}"
        )
    for name, count in (entries or {}).items():
        if count >= DRJIT_MAX_ENTRIES:
            raise ParameterError(
                f"the {method} method would need an array of {name} = {count:,.0f} entries, more "
                f"than Dr.Jit's limit of 2³² per array: {hint}"
            )
    return need


_PASSED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""Per pipeline: the (parameters, image size) that last passed its memory check."""


def check_once(pipe, params, size, check) -> None:
    """``check(params, size)`` unless ``pipe`` last passed it with equal parameters and image
    size: a render's check runs before its first frame and after each change, not again for an
    unchanged frame (the memory the pipeline keeps between frames would count twice)."""
    size = tuple(int(c) for c in size)
    key = (params, size)
    if _PASSED.get(pipe) != key:
        check(params, size)
        _PASSED[pipe] = key


def check_side(name: str, value: int | None) -> None:
    """An image side given by the user: None (keep the scene's) or an integer in 1 … 16384."""
    if value is not None and not 1 <= value <= MAX_SIDE:
        raise ParameterError(f"{name} must lie in 1 … {MAX_SIDE} pixels, got {value}")


def image_bytes(method: str, width: int, height: int, spp: int = 1) -> int:
    """Bytes in flight for a ``width × height`` image at ``spp`` camera samples per pixel."""
    return BYTES_PER_SAMPLE[method] * int(width) * int(height) * max(int(spp), 1)


def check_image_memory(
    method: str, width: int, height: int, spp: int = 1, available: int | None = None
) -> int:
    """Raise a :class:`ParameterError` when a ``width × height`` image at ``spp`` samples per
    pixel would need more memory than is available; return the estimate in bytes."""
    need = image_bytes(method, width, height, spp)
    available = available_memory() if available is None else available
    if available is not None and need > available:
        raise ParameterError(
            f"a {width}×{height} image at {spp} sample(s) per pixel needs about "
            f"{human_bytes(need)} with the {method} method, but only {human_bytes(available)} "
            "is available: render a smaller image or fewer samples per pixel"
        )
    return need
