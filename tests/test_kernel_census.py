"""``scripts/kernel_census.py``: the report counts the kernels and compile seconds of each module
and finds the near-duplicates (the same code but for a literal), on records with known answers;
the literal-free hash groups kernels that differ only in a number."""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import kernel_census  # noqa: E402


def test_report_counts_modules_and_near_duplicates():
    lines = [
        json.dumps({"test": "tests/a.py::t1", "kernels": [["h1", "F", 100.0], ["h2", "F", 300.0]]}),
        json.dumps({"test": "tests/a.py::t2", "kernels": [["h3", "G", 50.0]]}),
        json.dumps({"test": "tests/b.py::t", "kernels": [["h4", "F", 200.0], ["h1", "F", 100.0]]}),
    ]
    text = kernel_census.report(lines)
    # F holds h1, h2, h4 (h1 twice: one kernel); two of the three are near-duplicates
    assert text.splitlines()[0] == (
        "5 kernels compiled, 1 s of compilation; 2 of them near-duplicates (0 s) in 1 families"
    )
    assert "       3        0.5  tests/a.py" in text and "       2        0.3  tests/b.py" in text
    assert "  F     3    0.6  tests/a.py, tests/b.py" in text


def test_a_literal_does_not_change_the_family():
    def family(code: str) -> str:
        return kernel_census.LITERAL.sub("#", kernel_census.NAME.sub("drjit_K", code))

    a = "define void @drjit_0123456789abcdef0123456789abcdef() { %r1 = mul i32 %r0, 4096 }"
    b = a.replace("4096", "512").replace("0123456789abcdef", "fedcba9876543210")
    assert family(a) == family(b)
    assert family(a) != family(a.replace("mul", "add"))
