"""Cache simulator for photon-map memory traffic (Steinhurst 2007 §3.2, §3.5; spec seed-001 §2.6,
ambiguities A17; oracles O4, O20).

A stream of cache-line ids (the exact record reads of a batch of gathers) goes through a
**fully associative LRU** cache. LRU is a stack algorithm (Mattson et al. 1970): an access hits in
a cache of ``C`` lines iff its *stack distance* — the number of distinct lines touched since the
previous access to its line — is below ``C``. One pass over the stream therefore gives the misses
of every cache size (the Fig 3.9 curve at once).

**Stack distances without a sequential loop.** With ``prev[t]`` the previous access to the line of
access ``t`` (−1 if none), the lines touched in ``(prev[t], t)`` are those whose first access in
that window is some ``j`` with ``prev[j] < prev[t]``, and every ``j ≤ prev[t]`` has
``prev[j] < j ≤ prev[t]``, so::

    distance(t) = #{ j < t : prev[j] < prev[t] } − (prev[t] + 1)

— an offline dominance count, done here for all ``t`` at once with a wavelet matrix over
``prev`` (one stable partition per bit of ``prev``, ``O(n log n)`` vectorised NumPy; the
Fenwick-tree sweep of the classic algorithm is the same count taken sequentially). Consecutive
accesses to one line are merged first: they hit in any cache and leave every other distance alone.

**Set-associative** (``ways``-way, set = line mod sets, LRU per set): the same distances computed
per set on the stream stably grouped by set; an access misses iff its distance is ≥ ``ways``.
Bandwidth is misses × line size [DOC §3.5].
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ParameterError

COMPULSORY = -1
"""Stack distance of a line's first access: a miss in every cache."""


def merge_repeats(lines: np.ndarray) -> np.ndarray:
    """``lines`` without accesses to the line just accessed (hits in any cache)."""
    lines = np.asarray(lines)
    if len(lines) < 2:
        return lines
    return lines[np.r_[True, lines[1:] != lines[:-1]]]


def previous_access(lines: np.ndarray) -> np.ndarray:
    """Index of the previous access to the same line, −1 for a first access (int64)."""
    n = len(lines)
    by_line = np.argsort(lines, kind="stable")
    prev = np.full(n, -1, np.int64)
    same = lines[by_line][1:] == lines[by_line][:-1]
    prev[by_line[1:][same]] = by_line[:-1][same]
    return prev


def stack_distances(lines: np.ndarray, floor: int = 0) -> np.ndarray:
    """LRU stack distance of every access of ``lines`` (:data:`COMPULSORY` for first accesses).

    With ``floor`` > 0, an access whose reuse window (accesses since the previous one to its
    line) is shorter than ``floor`` gets that window length, an upper bound below ``floor``:
    misses are then exact for every capacity ≥ ``floor`` lines, and the count runs only for the
    other accesses."""
    lines = np.asarray(lines)
    n = len(lines)
    prev = previous_access(lines)
    value = (prev + 1).astype(np.int64)  # 0 = first access; values in [0, n]
    dist = np.full(n, COMPULSORY, np.int64)
    window = np.arange(n) - value  # accesses strictly between the previous one and this
    short = (value > 0) & (window < floor)
    dist[short] = window[short]
    asked = np.flatnonzero((value > 0) & ~short)
    if len(asked) == 0:
        return dist
    below = _count_earlier_below(value, asked, value[asked])
    dist[asked] = below - value[asked]
    return dist


def _count_earlier_below(seq: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``#{j < t_i : seq[j] < v_i}`` for every query ``i`` (wavelet matrix rank, MSB first)."""
    n = len(seq)
    itype = np.int32 if n < 2**31 - 1 else np.int64
    seq = seq.astype(itype)
    v = v.astype(itype)
    lo = np.zeros(len(t), itype)  # each query's interval [lo, hi) at the current level
    hi = t.astype(itype)
    count = np.zeros(len(t), itype)
    ones_before = np.zeros(n + 1, itype)
    position = np.arange(n, dtype=itype)
    for bit in range(max(int(seq.max()), int(v.max()), 1).bit_length() - 1, -1, -1):
        one = (seq >> bit) & 1
        np.cumsum(one, out=ones_before[1:])
        zeros = n - ones_before[n]
        olo, ohi = ones_before[lo], ones_before[hi]
        vbit = ((v >> bit) & 1).astype(bool)
        count += np.where(vbit, (hi - ohi) - (lo - olo), 0)
        lo = np.where(vbit, zeros + olo, lo - olo)
        hi = np.where(vbit, zeros + ohi, hi - ohi)
        target = np.where(one.astype(bool), zeros + ones_before[:-1], position - ones_before[:-1])
        shuffled = np.empty_like(seq)
        shuffled[target] = seq
        seq = shuffled
    return count


def misses(distances: np.ndarray, capacities) -> np.ndarray:
    """Fully associative LRU misses for each capacity (in lines) given the stack distances."""
    d = np.asarray(distances)
    compulsory = int(np.count_nonzero(d == COMPULSORY))
    sorted_d = np.sort(d[d != COMPULSORY])
    caps = np.asarray(capacities, np.int64)
    return compulsory + len(sorted_d) - np.searchsorted(sorted_d, caps, side="left")


def set_associative_misses(lines: np.ndarray, sets: int, ways: int) -> int:
    """Misses of a ``ways``-way set-associative LRU cache of ``sets`` sets (set = line mod sets)."""
    if sets < 1 or ways < 1:
        raise ParameterError(f"a cache needs >= 1 set and way, got {sets} sets of {ways} ways")
    lines = np.asarray(lines, np.int64)
    grouped = lines[np.argsort(lines % sets, kind="stable")]
    return int(misses(stack_distances(grouped, floor=ways), [ways])[0])


def parse_size(text: str | int) -> int:
    """Bytes of ``"128K"``, ``"1M"``, ``"64"`` (K/M = 1024/1024²)."""
    if isinstance(text, int | np.integer):
        size = int(text)
    else:
        s = str(text).strip().upper().removesuffix("B")
        scale = {"K": 1024, "M": 1024**2}.get(s[-1:], 1)
        try:
            size = int(float(s[:-1] if scale > 1 else s) * scale)
        except ValueError:
            size = 0
    if size <= 0:
        raise ParameterError(f"expected a size such as 128K, 1M or 128, got {text!r}")
    return size
