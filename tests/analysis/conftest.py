"""Helpers of these tests: the brute-force references here and ``tests/benchmarks_import.py``."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).parents[1]))
