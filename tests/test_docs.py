"""Every code block of README.md and docs/ runs here, at small sizes, so the documentation cannot
go stale; the parameter tables of docs/methods/ are checked against the ``*Params`` dataclasses.

How a fenced block runs (the block's text is what runs):

- ``python``: executed in a fresh namespace with the working directory at the page's temporary
  directory, which holds a link ``examples`` to the repository's ``examples/`` (the documented
  relative paths resolve; every output lands in the temporary directory). The blocks of one
  page run in order in the same directory, so a later block may read an earlier one's files.
- ``sh`` / ``bash`` / ``console``: one command per line (a trailing backslash continues it, ``#``
  starts a comment; in ``console`` only the lines after ``$ `` are commands). A ``photonmap ...``
  command runs in this process through the CLI, with the size reduction below appended; any
  other command runs in ``bash`` with this interpreter's ``bin/`` first on ``PATH``. Every
  command must exit with status 0.
- ``json``: a frame spec of ``photonmap render-sequence``, read by
  :func:`photonmap.cluster.frames.parse_frames`.
- A block preceded by ``<!-- docs-test: skip (reason) -->`` does not run; the reason is
  required. No other block language is allowed, and a ``photonmap`` command that cannot run
  here (the viewer's server, Ray workers) fails until its block is marked.

The size reduction (:func:`reduced`) only appends options: the CLI takes the last value of an
option and of a ``--set`` key, and a cap leaves a value the line already sets lower alone.

========================  =====================================================================
command                   appended
========================  =====================================================================
``render``                ``--width 32 --height 24``, ``--spp`` ≤ 4, and by method (``--method``,
                          else the built-in scene's own, else ``sppm``): volume ``grid`` ≤ 32,
                          ``photons`` ≤ 4096, ``pilot_photons`` ≤ 256; surface ``photons``,
                          ``caustic_photons`` ≤ 2000; sppm ``iterations`` ≤ 2,
                          ``photons`` ≤ 2000; vcm ``iterations`` ≤ 2; screen ``photons`` ≤ 1024
                          (a 32 × 32 light G-buffer)
``reference``             ``--width 32 --height 24``, ``--spp`` ≤ 16
``analyze bandwidth``     ``--size 64`` (a ``--crop`` window scaled by 64 / the line's size),
                          ``photons``, ``caustic_photons`` ≤ 2000, ``fg_rays`` ≤ 4
others                    nothing
========================  =====================================================================
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

import photonmap
from photonmap.cli import app
from photonmap.cluster.frames import parse_frames
from photonmap.scenes import SCENES

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
SKIP = re.compile(r"<!--\s*docs-test:\s*skip\s*(?:\((?P<reason>[^)]*)\))?\s*-->")
FENCE = re.compile(r"^(?P<fence>```+|~~~+)\s*(?P<lang>[\w+-]*)\s*$")
SHELL = ("sh", "bash", "console")
LANGUAGES = ("python", "json", *SHELL)

WIDTH, HEIGHT = 32, 24
RENDER_CAPS = {
    "volume": {"grid": 32, "photons": 4096, "pilot_photons": 256},
    "surface": {"photons": 2000, "caustic_photons": 2000},
    "sppm": {"iterations": 2, "photons": 2000},
    "vcm": {"iterations": 2},
    "screen": {"photons": 1024},
}
ANALYZE_CAPS = {"photons": 2000, "caustic_photons": 2000, "fg_rays": 4}
ANALYZE_SIZE = 64
NOT_HERE = {
    "view": "starts the viewer's web server",
    "render-sequence": "starts Ray workers",
    "--workers": "starts Ray workers",
    "--ray": "joins a Ray cluster",
}


@dataclasses.dataclass
class Block:
    page: Path
    line: int  # of the opening fence, 1-based
    lang: str
    text: str
    skip: str | None  # the reason, "" when the marker gives none; None: the block runs

    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def blocks(page: Path) -> list[Block]:
    """The fenced blocks of ``page`` with their languages and skip markers (the marker is the
    last non-blank line before the fence)."""
    lines = page.read_text().splitlines()
    out, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        end = next((j for j in range(i + 1, len(lines)) if lines[j].strip() == m["fence"]), None)
        assert end is not None, f"{page.relative_to(ROOT)}:{i + 1}: unclosed code block"
        before = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        marker = SKIP.fullmatch(before.strip())
        skip = (marker["reason"] or "").strip() if marker else None
        out.append(Block(page, i + 1, m["lang"], "\n".join(lines[i + 1 : end]) + "\n", skip))
        i = end + 1
    return out


def commands(block: Block) -> list[str]:
    """The command lines of a shell block: continuations joined, console output left out."""
    out, pending = [], ""
    for raw in block.text.splitlines():
        line = raw.rstrip()
        if block.lang == "console" and not pending:
            if not line.startswith("$ "):
                continue  # output shown after a command
            line = line[2:]
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        line, pending = pending + line, ""
        if shlex.split(line, comments=True):
            out.append(line)
    assert not pending, f"{block.where()}: a command ends in a backslash"
    return out


# ------------------------------------------------------------------------------------------------
# the size reduction


def _last(argv: list[str], option: str) -> str | None:
    """The last value given to ``option`` (``--opt V`` or ``--opt=V``)."""
    value = None
    for i, arg in enumerate(argv):
        if arg == option and i + 1 < len(argv):
            value = argv[i + 1]
        elif arg.startswith(option + "="):
            value = arg.split("=", 1)[1]
    return value


def _sets(argv: list[str]) -> dict[str, str]:
    values = [argv[i + 1] for i in range(len(argv) - 1) if argv[i] == "--set"]
    values += [a.split("=", 1)[1] for a in argv if a.startswith("--set=")]
    return dict(v.split("=", 1) for v in values if "=" in v)


def _capped(argv: list[str], caps: dict[str, float]) -> list[str]:
    """``--set key=cap`` for each key the line leaves unset or sets higher."""
    sets, out = _sets(argv), []
    for key, cap in caps.items():
        try:
            low = key in sets and float(sets[key]) <= cap
        except ValueError:
            low = False
        if not low:
            out += ["--set", f"{key}={cap}"]
    return out


def _option_cap(argv: list[str], option: str, cap: int, default: int) -> list[str]:
    value = _last(argv, option)
    return [] if int(value if value is not None else default) <= cap else [option, str(cap)]


def method_of(argv: list[str]) -> str:
    """The method ``photonmap render`` picks: ``--method``, a built-in's own, else sppm."""
    method = _last(argv, "--method")
    if method is None:
        scene = argv[1] if len(argv) > 1 else ""
        method = SCENES[scene].pipeline if scene in SCENES else "sppm"
    return method


def reduced(argv: list[str]) -> list[str]:
    """``photonmap`` arguments (without the program name) with the size reduction appended."""
    command = argv[0] if argv else ""
    size = ["--width", str(WIDTH), "--height", str(HEIGHT)]
    if command == "render":
        extra = size + _option_cap(argv, "--spp", 4, 1)
        return argv + extra + _capped(argv, RENDER_CAPS[method_of(argv)])
    if command == "reference":
        return argv + size + _option_cap(argv, "--spp", 16, 1024)
    if command == "analyze" and argv[1:2] == ["bandwidth"]:
        extra = ["--size", str(ANALYZE_SIZE)]
        crop = _last(argv, "--crop")
        if crop is not None:
            scale = ANALYZE_SIZE / int(_last(argv, "--size") or 512)
            x, y, w, h = (int(c) for c in crop.split(","))
            window = (round(x * scale), round(y * scale), max(1, round(w * scale)),
                      max(1, round(h * scale)))  # fmt: skip
            extra += ["--crop", ",".join(str(c) for c in window)]
        return argv + extra + _capped(argv, ANALYZE_CAPS)
    return argv


def test_reduction_appends_caps_and_keeps_lower_values():
    line = "render glass_sphere_fog -o a.png --set photons=1000 --set grid=96".split()
    out = reduced(line)
    assert out[: len(line)] == line
    assert _sets(out) == {"photons": "1000", "grid": "32", "pilot_photons": "256"}
    assert _last(out, "--width") == "32" and _last(out, "--height") == "24"
    assert method_of("render examples/cornell_box.xml -o x.png".split()) == "sppm"
    assert method_of("render cornell_ispm -o x.png".split()) == "screen"
    assert "photons=1024" in reduced("render x.xml -o y.png --method=screen".split())
    crop = reduced("analyze bandwidth cornell_steinhurst --crop 192,288,64,32".split())
    assert _last(crop, "--crop") == "24,36,8,4" and _last(crop, "--size") == "64"
    assert reduced(["compare", "a.exr", "b.exr"]) == ["compare", "a.exr", "b.exr"]


# ------------------------------------------------------------------------------------------------
# running the blocks

runner = CliRunner()


def run_photonmap(block: Block, line: str) -> None:
    argv = shlex.split(line, comments=True)[1:]
    for word, why in NOT_HERE.items():
        assert word not in argv, (
            f"{block.where()}: `{line}` {why}, which this test cannot do: mark the block "
            "<!-- docs-test: skip (reason) -->"
        )
    args = reduced(argv)
    result = runner.invoke(app, args)
    assert result.exit_code == 0, (
        f"{block.where()}: `photonmap {' '.join(args)}` exited with {result.exit_code}:\n"
        f"{result.output}{result.exception!r}"
    )


def run_shell(block: Block, line: str) -> None:
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
           "PYTHONPATH": str(ROOT / "src")}  # fmt: skip
    done = subprocess.run(["bash", "-c", line], env=env, capture_output=True, text=True)
    assert done.returncode == 0, (
        f"{block.where()}: `{line}` exited with {done.returncode}:\n{done.stdout}{done.stderr}"
    )


def run_block(block: Block) -> None:
    if block.lang == "python":
        code = compile(block.text, block.where(), "exec")
        exec(code, {"__name__": "__docs__"})  # a fresh namespace per block
    elif block.lang == "json":
        parse_frames(json.loads(block.text), where=block.where())
    else:
        for line in commands(block):
            if shlex.split(line, comments=True)[0] == "photonmap":
                run_photonmap(block, line)
            else:
                run_shell(block, line)


def test_blocks_are_read_with_their_markers(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "text\n\n<!-- docs-test: skip (needs a server) -->\n\n```sh\nphotonmap view x\n```\n"
        "<!-- docs-test: skip -->\n```python\npass\n```\n"
        "```console\n$ photonmap scenes \\\n  # a comment\nan output line\n```\n"
    )
    first, second, third = blocks(page)
    assert (first.lang, first.skip, first.text) == ("sh", "needs a server", "photonmap view x\n")
    assert (second.lang, second.skip) == ("python", "")  # a marker without its reason
    assert third.skip is None
    assert [shlex.split(c, comments=True) for c in commands(third)] == [["photonmap", "scenes"]]


ALL = [b for page in PAGES for b in blocks(page)]


def test_every_block_runs_or_is_marked_with_a_reason():
    assert len(PAGES) > 10 and ALL
    for block in ALL:
        if block.skip is not None:
            assert block.skip, f"{block.where()}: a skip marker needs a reason: skip (why)"
        else:
            assert block.lang in LANGUAGES, (
                f"{block.where()}: a ```{block.lang or '(no language)'} block cannot run; use one "
                f"of {', '.join(LANGUAGES)} or mark it <!-- docs-test: skip (reason) -->"
            )
    for page in PAGES:  # a marker must stand right before a block
        markers = page.read_text().count("<!-- docs-test")
        marked = sum(b.skip is not None for b in ALL if b.page == page)
        assert markers == marked, f"{page.relative_to(ROOT)}: a docs-test marker before no block"


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_page_blocks_run(page, tmp_path, monkeypatch):
    todo = [b for b in blocks(page) if b.skip is None]
    if not todo:
        return  # a page without code
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    monkeypatch.chdir(tmp_path)
    for block in todo:
        run_block(block)


# ------------------------------------------------------------------------------------------------
# what the pages state


def test_readme_is_a_front_door():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 210, f"README.md has {len(lines)} lines; the reference goes in docs/"
    first = blocks(ROOT / "README.md")[0]
    assert [c.split("#")[0].split() for c in commands(first)] == [
        ["make", "demo"],
        ["make", "test"],
    ]


LINK = re.compile(r"\]\((?P<target>[^)\s]+)\)|src=\"(?P<src>[^\"]+)\"")


def test_relative_links_resolve():
    for page in PAGES:
        for m in LINK.finditer(page.read_text()):
            target = (m["target"] or m["src"]).split("#")[0]
            if not target or re.match(r"[a-z]+:", target):
                continue  # an anchor on the page, or a web address
            path = (page.parent / target).resolve()
            assert path.exists(), f"{page.relative_to(ROOT)}: link to a missing {target}"


PARAM_PAGES = {
    "volume": (ROOT / "docs/methods/volume.md", {"grid", "grid_bbox"}),
    "surface": (ROOT / "docs/methods/surface.md", set()),
    "sppm": (ROOT / "docs/methods/sppm.md", set()),
    "vcm": (ROOT / "docs/methods/vcm.md", set()),
    "screen": (ROOT / "docs/methods/screen.md", set()),
}


def parameter_table(page: Path) -> dict[str, str]:
    """The rows of the table headed ``| key | default | meaning |``: key → default text."""
    rows, inside = {}, False
    for line in page.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells[:2] == ["key", "default"]:
            inside = True
        elif inside and line.startswith("|"):
            if set(cells[0]) <= set("-: "):
                continue
            rows[cells[0].strip("`")] = cells[1].strip("`")
        elif inside:
            break
    return rows


@pytest.mark.parametrize("method", list(PARAM_PAGES))
def test_parameter_tables_match_the_dataclasses(method):
    """Each method page lists every field of its ``*Params`` with the default as a Python value,
    and nothing else (besides the pipeline's own arguments)."""
    page, extra = PARAM_PAGES[method]
    table = parameter_table(page)
    fields = {f.name: f for f in dataclasses.fields(photonmap.METHODS[method].params)}
    assert set(table) == set(fields) | extra, (
        f"{page.relative_to(ROOT)}: missing {sorted((set(fields) | extra) - set(table))}, "
        f"not parameters {sorted(set(table) - set(fields) - extra)}"
    )
    for name, field in fields.items():
        default = eval(table[name], {"__builtins__": {}})  # e.g. 1024**2, 2/3, "hash", None
        assert default == field.default, (
            f"{page.relative_to(ROOT)}: {name} defaults to "
            f"{field.default!r}, the table says {table[name]}"
        )
