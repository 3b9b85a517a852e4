"""The LRU cache simulator (spec seed-001 §2.6; oracles O4, O20) against one-access-at-a-time
LRU caches."""

from __future__ import annotations

import numpy as np
import pytest
from lru_reference import lru_misses

from photonmap import ParameterError
from photonmap.analysis.cache import parse_size, simulate_lines


def _streams():
    rng = np.random.default_rng(7)
    for trial in range(12):
        n, lines = int(rng.integers(1, 3000)), int(rng.integers(1, 200))
        if trial % 2:
            yield rng.integers(0, lines, n)
        else:  # a random walk: the reuse of a traversal
            yield np.cumsum(rng.integers(-3, 4, n)) % lines


CAPACITIES = [1, 2, 3, 8, 16, 64, 256]


def _misses(lines, capacities, sets=0, ways=8):
    return simulate_lines(np.asarray(lines, np.int64), np.diff(capacities, prepend=0), sets, ways)


def test_one_pass_gives_lru_misses_of_every_capacity():
    """One pass gives the misses of every fully associative LRU capacity (Mattson et al.)."""
    for lines in _streams():
        missed, _, _ = _misses(lines, CAPACITIES)
        assert list(missed) == [lru_misses(lines, c) for c in CAPACITIES]
        missed, _, _ = _misses(lines, CAPACITIES[3:5])  # a bank of two capacities only
        assert list(missed) == [lru_misses(lines, c) for c in CAPACITIES[3:5]]


def test_set_associative_matches_per_set_lru():
    for lines in _streams():
        for sets in (1, 2, 4, 16):
            _, missed, _ = _misses(lines, [8 * sets], sets, 8)
            assert missed == lru_misses(lines, 8 * sets, sets)


def test_inclusion_and_compulsory_misses():
    """O4: misses never grow with the capacity; they never fall below the distinct lines, and
    equal them once the cache holds the footprint."""
    for lines in _streams():
        curve, _, compulsory = _misses(lines, [1, 4, 16, 64, 256, 1024])
        assert np.all(np.diff(curve) <= 0)
        distinct = len(np.unique(lines))
        assert compulsory == distinct and curve.min() >= distinct
        if distinct <= 1024:
            assert curve[-1] == distinct


def test_parse_size():
    assert parse_size("128K") == 131072 and parse_size("1M") == 1 << 20
    assert parse_size("64") == 64 and parse_size("2kb") == 2048
    for bad in ("", "big", "-1K", "0"):
        with pytest.raises(ParameterError, match="size"):
            parse_size(bad)
