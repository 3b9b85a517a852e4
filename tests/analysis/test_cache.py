"""The LRU cache simulator (spec seed-001 §2.6; oracles O4, O20) against one-access-at-a-time
LRU caches."""

from __future__ import annotations

import numpy as np
import pytest
from lru_reference import lru_misses

from photonmap import ParameterError
from photonmap.analysis.cache import (
    merge_repeats,
    misses,
    parse_size,
    set_associative_misses,
    stack_distances,
)


def _streams():
    rng = np.random.default_rng(7)
    for trial in range(12):
        n, lines = int(rng.integers(1, 3000)), int(rng.integers(1, 200))
        if trial % 2:
            yield rng.integers(0, lines, n)
        else:  # a random walk: the reuse of a traversal
            yield np.cumsum(rng.integers(-3, 4, n)) % lines


CAPACITIES = [1, 2, 3, 8, 16, 64, 256]


def test_stack_distances_give_lru_misses_of_every_capacity():
    """One pass gives the misses of every fully associative LRU capacity (Mattson et al.)."""
    for lines in _streams():
        d = stack_distances(merge_repeats(lines))
        assert list(misses(d, CAPACITIES)) == [lru_misses(lines, c) for c in CAPACITIES]
        bounded = stack_distances(merge_repeats(lines), floor=8)
        assert list(misses(bounded, CAPACITIES[3:])) == [
            lru_misses(lines, c) for c in CAPACITIES[3:]
        ]


def test_set_associative_matches_per_set_lru():
    for lines in _streams():
        merged = merge_repeats(lines)
        for sets in (1, 2, 4, 16):
            assert set_associative_misses(merged, sets, 8) == lru_misses(lines, 8 * sets, sets)


def test_inclusion_and_compulsory_misses():
    """O4: misses never grow with the capacity; they never fall below the distinct lines, and
    equal them once the cache holds the footprint."""
    for lines in _streams():
        curve = misses(stack_distances(merge_repeats(lines)), [1, 4, 16, 64, 256, 1024])
        assert np.all(np.diff(curve) <= 0)
        distinct = len(np.unique(lines))
        assert curve.min() >= distinct
        if distinct <= 1024:
            assert curve[-1] == distinct


def test_parse_size():
    assert parse_size("128K") == 131072 and parse_size("1M") == 1 << 20
    assert parse_size("64") == 64 and parse_size("2kb") == 2048
    for bad in ("", "big", "-1K", "0"):
        with pytest.raises(ParameterError, match="size"):
            parse_size(bad)
    with pytest.raises(ParameterError, match="set"):
        set_associative_misses(np.arange(4), 0, 8)
