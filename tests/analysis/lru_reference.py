"""Brute-force LRU caches (one access at a time) for the cache simulator's tests."""

from __future__ import annotations

from collections import OrderedDict


def lru_misses(lines, capacity: int, sets: int = 1) -> int:
    """Misses of an LRU cache of ``capacity`` lines split into ``sets`` sets (line mod sets)."""
    ways = capacity // sets
    caches = [OrderedDict() for _ in range(sets)]
    missed = 0
    for line in lines:
        cache = caches[int(line) % sets]
        if line in cache:
            cache.move_to_end(line)
        else:
            missed += 1
            cache[line] = True
            if len(cache) > ways:
                cache.popitem(last=False)
    return missed
