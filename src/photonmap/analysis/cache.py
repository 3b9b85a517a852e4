"""Cache simulator for photon-map memory traffic (Steinhurst 2007 §3.2, §3.5).

A stream of cache-line reads goes through a bank of caches at once, compiled with Numba:

- **fully associative LRU** caches of several capacities ``c_0 < … < c_{K−1}`` lines. LRU is a
  stack algorithm (Mattson et al. 1970): one recency list serves every capacity, cut into segments
  ``[c_{j−1}, c_j)`` by K markers. A read of a line in segment ``s`` misses in the caches ``j < s``
  and hits in the others; the line moves to the front, and the last line of each segment before
  ``s`` slides into the next one — ``O(s) ≤ K`` work per read, no search (lines past ``c_{K−1}``
  leave the list). One pass gives the Fig 3.9 curve;
- a ``ways``-way **set-associative** LRU cache (set = line mod sets, MRU-first tag rows);
- the **compulsory** misses (first reads of a line: the distinct lines read).

A read of the line read just before hits in every cache and changes nothing (the fast path of runs
of reads within one line). Bandwidth is misses × line size (Steinhurst 2007 §3.5). The full-scale
kd-tree streams feed these banks straight from the gathers (:mod:`.kdwalk`); :func:`simulate_lines`
takes an explicit stream.
"""

from __future__ import annotations

import numba
import numpy as np

from ..core.errors import ParameterError


@numba.njit(cache=True, nogil=True)
def feed_bank(lines, run, base, div, caches):
    """Reads of lines ``(lines[start : start + count] − base) // div``, ``run = (start, count)``,
    through one bank ``caches`` (:func:`bank`; see the module docstring): ``seg``/``prv``/``nxt``
    (lines,): each line's segment (K: evicted, K + 1: never read) and neighbours in the recency
    list; ``tail``/``size``/``segcap`` (K,): each segment's last line, its size and its capacity;
    ``tags`` (sets, ways): the set-associative cache, MRU first, −1 empty (0 sets: none);
    ``misses`` (K,); ``state``: most recent line, compulsory misses, set-associative misses."""
    start, count = run
    seg, prv, nxt, tail, size, segcap, tags, misses, state = caches
    K = segcap.shape[0]
    sets, ways = tags.shape
    head, compulsory, sa_misses = state[0], state[1], state[2]
    for r in range(start, start + count):
        x = (lines[r] - base) // div
        if x == head:
            continue  # the line just read: a hit in every cache
        s = seg[x]
        if s > K:
            compulsory += 1
            s = K
        for j in range(s):
            misses[j] += 1
        if s < K:  # unlink x from segment s
            p, n = prv[x], nxt[x]
            nxt[p] = n  # p ≥ 0: x is not the head
            if n >= 0:
                prv[n] = p
            if tail[s] == x:
                tail[s] = p  # x was not alone: the refill below brings p back otherwise
            size[s] -= 1
        nxt[x] = head
        prv[x] = -1
        if head >= 0:
            prv[head] = x
        head = x
        seg[x] = 0
        size[0] += 1
        if tail[0] < 0:
            tail[0] = x
        j = 0
        while j < K and size[j] > segcap[j]:  # the segment's last line slides into the next
            t = tail[j]
            before = prv[t]
            tail[j] = before
            size[j] -= 1
            if j + 1 < K:
                seg[t] = j + 1
                if tail[j + 1] < 0:
                    tail[j + 1] = t
                size[j + 1] += 1
            else:  # past the largest cache: leaves the list (its links are rewritten on return)
                seg[t] = K
            j += 1
        if sets > 0:
            row = x % sets
            at = ways - 1
            hit = False
            for w in range(ways):
                if tags[row, w] == x:
                    at = w
                    hit = True
                    break
            sa_misses += not hit
            for w in range(at, 0, -1):
                tags[row, w] = tags[row, w - 1]
            tags[row, 0] = x
    state[0], state[1], state[2] = head, compulsory, sa_misses


@numba.njit(cache=True, nogil=True)
def bank(lines, segcap, sets, ways):
    """Empty caches for :func:`feed_bank` over ``lines`` line ids, with segment capacities
    ``segcap`` (K,) and a ``ways``-way cache of ``sets`` sets (0: none)."""
    K = segcap.shape[0]
    return (
        np.full(lines, K + 1, np.int32),
        np.full(lines, -1, np.int32),
        np.full(lines, -1, np.int32),
        np.full(K, -1, np.int32),
        np.zeros(K, np.int64),
        segcap,
        np.full((sets, ways), -1, np.int64),
        np.zeros(K, np.int64),
        np.array([-1, 0, 0], np.int64),
    )


@numba.njit(cache=True, nogil=True)
def simulate_reads(order, offset, count, lines, segcap, sets, ways):
    """:func:`simulate_lines` of the stream made of the runs ``lines[offset[g] : offset[g] +
    count[g]]`` taken in ``order`` (each gather's stored reads, in a gather order)."""
    b = bank(lines.max() + 1 if len(lines) else 1, segcap, sets, ways)
    for g in order:
        feed_bank(lines, (offset[g], count[g]), 0, 1, b)
    return b[7], b[8][2], b[8][1]


@numba.njit(cache=True, nogil=True)
def simulate_lines(lines, segcap, sets, ways):
    """Misses of an explicit stream of line ids: ``(misses (K,), set-associative misses,
    compulsory)`` for the capacities with segment sizes ``segcap`` (K,) and a ``ways``-way cache
    of ``sets`` sets (0: none)."""
    b = bank(lines.max() + 1 if len(lines) else 1, segcap, sets, ways)
    feed_bank(lines, (0, len(lines)), 0, 1, b)
    return b[7], b[8][2], b[8][1]


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
