"""Bytes of photon tracing per light path, shared by the estimates of the surface and sppm methods
(their ``memory`` modules): the chunked wavefront of :mod:`.photon_trace` holds ``CHUNK`` record
slots per path at a time (``paths × CHUNK`` slots, whatever ``max_depth``), plus the records it
keeps.

``interactions`` per path: ``max_depth − 1`` when bounded (records of depth ``d ≤ max_depth −
1``), else :data:`UNBOUNDED_RECORDS` (Russian roulette ends the paths: measured ≈ 9 records per
path kept in the Cornell box of white walls at unbounded depth).
"""

from __future__ import annotations

from .photon_trace import CHUNK
from .settings import UNBOUNDED

UNBOUNDED_RECORDS = 16  # records per path assumed when max_depth is unbounded


def interactions(max_depth: int) -> int:
    """Surface and medium interactions a path may record: ``max_depth − 1`` (at least 1)."""
    return UNBOUNDED_RECORDS if max_depth == UNBOUNDED else max(int(max_depth) - 1, 1)


def path_bytes(max_depth: int, path: int, slot: int, record: int) -> int:
    """Bytes per light path: ``path`` (its loop state), ``CHUNK × slot`` (the record slots of
    one chunk) and ``interactions × record`` (the records kept: the map, its sort keys, derived
    lookups)."""
    return path + CHUNK * slot + interactions(max_depth) * record
