"""Where a test run's compile time goes: the Dr.Jit kernels each test module compiled (neither in
memory nor in the kernel cache on disk), their LLVM compile seconds, and the *near-duplicates* —
kernels whose code differs only in literals (a width, a radius, a seed written into the kernel),
which a warm cache cannot serve once the literal changes. Runs pytest (through
``scripts/test_suite.py``, on every core) with Dr.Jit's kernel history on, then prints a table a
module and the largest families of near-duplicates::

    .venv/bin/python scripts/kernel_census.py [PYTEST ARGS...]      # e.g. tests/sppm

With ``DRJIT_CACHE_DIR`` pointing at an empty folder the counts are those of a cold run; on a
second run they are the kernels compiled again every time.
"""

from __future__ import annotations

import collections
import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

RECORDS = "PHOTONMAP_KERNEL_CENSUS"  # the JSON-lines file the plugin appends to
NAME = re.compile(r"drjit_[0-9a-f]{32}")
LITERAL = re.compile(r"(?<![%@\w.])-?(0x[0-9A-Fa-f]+|\d+\.\d*(?:e[-+]?\d+)?|\d+)(?![\w])")


# ----------------------------------------------------------------------------- pytest plugin
def compiled_kernels() -> list[tuple[str, str, float]]:
    """``(hash, literal-free hash, compile ms)`` of the kernels compiled since the last call."""
    import drjit as dr

    out = []
    for k in dr.kernel_history():
        if k.get("type") != dr.KernelType.JIT or k.get("cache_hit") or k.get("cache_disk"):
            continue
        code = NAME.sub("drjit_K", k["ir"].getvalue() if "ir" in k else "")
        family = hashlib.md5(LITERAL.sub("#", code).encode()).hexdigest()[:16]
        ms = float(k.get("backend_time", 0)) + float(k.get("codegen_time", 0))
        out.append((k["hash"], family, round(ms, 2)))
    return out


def pytest_runtest_setup(item):
    import drjit as dr

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    compiled_kernels()  # drop what came before the test


def pytest_runtest_teardown(item):
    import drjit as dr

    kernels = compiled_kernels()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    with open(os.environ[RECORDS], "a") as f:
        f.write(json.dumps({"test": item.nodeid, "kernels": kernels}) + "\n")


# ----------------------------------------------------------------------------------- report
def report(lines: list[str], families: int = 10) -> str:
    records = [json.loads(line) for line in lines if line.strip()]
    modules = collections.defaultdict(lambda: [0, 0.0])
    members = collections.defaultdict(dict)  # family -> {hash: (ms, module)}
    for r in records:
        module = r["test"].split("::")[0]
        for h, family, ms in r["kernels"]:
            modules[module][0] += 1
            modules[module][1] += ms
            members[family].setdefault(h, (ms, module))
    repeated = {f: m for f, m in members.items() if len(m) > 1}
    extra = sum(len(m) - 1 for m in repeated.values())
    extra_s = sum(
        sum(ms for ms, _ in m.values()) * (len(m) - 1) / len(m) for m in repeated.values()
    )
    total = sum(n for n, _ in modules.values())
    seconds = sum(s for _, s in modules.values()) / 1e3
    out = [f"{total} kernels compiled, {seconds:.0f} s of compilation; {extra} of them "
           f"near-duplicates ({extra_s / 1e3:.0f} s) in {len(repeated)} families", "",
           f"{'kernels':>8} {'compile s':>10}  module"]  # fmt: skip
    for module, (n, ms) in sorted(modules.items(), key=lambda kv: -kv[1][1]):
        out.append(f"{n:8d} {ms / 1e3:10.1f}  {module}")
    out += ["", "largest near-duplicate families (kernels, compile s, modules):"]
    for family, m in sorted(repeated.items(), key=lambda kv: -sum(x for x, _ in kv[1].values()))[
        :families
    ]:
        where = sorted({module for _, module in m.values()})
        out.append(f"  {family}  {len(m):4d} {sum(x for x, _ in m.values()) / 1e3:6.1f}  "
                   f"{', '.join(where[:3])}")  # fmt: skip
    return "\n".join(out)


def main(args: list[str]) -> int:
    here = Path(__file__).resolve().parent
    with tempfile.TemporaryDirectory() as folder:
        records = Path(folder) / "kernels.jsonl"
        records.touch()
        path = os.pathsep.join(filter(None, [str(here), os.environ.get("PYTHONPATH")]))
        env = {**os.environ, RECORDS: str(records), "PYTHONPATH": path}
        code = subprocess.call(
            [sys.executable, str(here / "test_suite.py"), "-p", "kernel_census", *args], env=env
        )
        print(report(records.read_text().splitlines()))
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
