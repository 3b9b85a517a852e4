"""Memory: what is available, and what an image of a given size will need, so that a render that
cannot fit is refused before it starts."""

from __future__ import annotations

import os

from .errors import ParameterError

MAX_SIDE = 16384  # pixels per image side
# bytes in flight per camera sample (rough upper bounds measured on the LLVM backend: the eye
# pass's interactions, the final-gather batch, the view pass's march state, the G-buffers)
BYTES_PER_SAMPLE = {"surface": 1200, "volume": 400, "screen": 2000, "sppm": 1200}


def available_memory() -> int | None:
    """Bytes of memory available to this process (``MemAvailable`` of /proc/meminfo, else the
    physical memory), or None if unknown."""
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


def human_bytes(n: float) -> str:
    """``1536`` → ``"1.5 KB"``."""
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if n < 1024 or unit == "TB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} TB"  # pragma: no cover


def check_side(name: str, value: int | None) -> None:
    """An image side given by the user: None (keep the scene's) or an integer in 1 … 16384."""
    if value is not None and not 1 <= value <= MAX_SIDE:
        raise ParameterError(f"{name} must lie in 1 … {MAX_SIDE} pixels, got {value}")


def check_image_memory(method: str, width: int, height: int, spp: int = 1,
                       available: int | None = None) -> int:
    """Raise a :class:`ParameterError` when a ``width × height`` image at ``spp`` samples per
    pixel would need more memory than is available; return the estimate in bytes."""
    need = BYTES_PER_SAMPLE[method] * int(width) * int(height) * max(int(spp), 1)
    available = available_memory() if available is None else available
    if available is not None and need > available:
        raise ParameterError(
            f"a {width}×{height} image at {spp} sample(s) per pixel needs about "
            f"{human_bytes(need)} with the {method} method, but only {human_bytes(available)} "
            "is available: render a smaller image or fewer samples per pixel"
        )
    return need
