"""A clone of the repository is all the tests, benchmarks and examples need: nothing under
``tests/``, ``benchmarks/`` or ``examples/`` names a path that leaves the repository, however the
path is built — ``Path(__file__).parents[N]`` or ``.parent`` chains or nested
``os.path.dirname`` calls that climb above the root, a string with ``..`` components that climbs
out of the file's folder or of the root (where the tests run), a file name in a Mitsuba XML file
that climbs out of that file's folder, the project's sibling folder ``shared/`` by name, or an
absolute path into a home or work directory. What the benchmarks wrote (``results/``) is not
scanned, nor this file, whose snippets check the scanner: a scanner that finds nothing fails."""

from __future__ import annotations

import re
from pathlib import Path, PurePosixPath

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("tests", "benchmarks", "examples")
SUFFIXES = {".py", ".xml", ".json", ".md", ".sh", ".toml", ".cfg", ".txt", ".yaml", ".yml"}

PARENTS = re.compile(r"__file__\)?(?:\.resolve\(\))?\.parents\[(\d+)\]")
PARENT_CHAIN = re.compile(r"__file__\)?(?:\.resolve\(\))?((?:\.parent\b)+)")
DIRNAME = re.compile(r"((?:os\.path\.dirname\(\s*)+)(?:os\.path\.(?:abs|real)path\(\s*)?__file__")
STRING = re.compile(r"""(["'])((?:(?!\1).)*?\.\.(?:/|\\)(?:(?!\1).)*?)\1""")
XML_FILENAME = re.compile(r"""name=["']filename["']\s+value=["']([^"']+)["']""")
OUTSIDE = "shared"  # the project's sibling folder (named once: this file reads nothing there)
SIBLING = re.compile(rf"(?<![\w.]){OUTSIDE}/(?:tools|seeds|spec)\b|\.\./{OUTSIDE}\b")
ABSOLUTE = re.compile(r"""["'](?:/(?:work|home|root|Users|mnt|srv)/)""")


def climbs_out(start: PurePosixPath, relative: str) -> bool:
    """Whether ``relative`` (``..`` and names), joined to the repository-relative folder
    ``start``, leaves the repository."""
    depth = len(start.parts)
    for part in re.split(r"[/\\]", relative):
        if part == "..":
            depth -= 1
            if depth < 0:
                return True
        elif part not in ("", "."):
            depth += 1
    return False


def escapes(rel: PurePosixPath, text: str) -> list[str]:
    """What in ``text`` (the file at repository-relative path ``rel``) names a path outside the
    repository, one line each."""
    found = []
    folder = rel.parent  # Path(__file__).parent
    above = len(rel.parts) - 1  # parents[above] is the repository root
    for match in PARENTS.finditer(text):
        if int(match.group(1)) > above:
            found.append(f"{match.group(0)} climbs above the repository root")
    for match in PARENT_CHAIN.finditer(text):
        if match.group(1).count(".parent") - 1 > above:
            found.append(f"{match.group(0)} climbs above the repository root")
    for match in DIRNAME.finditer(text):
        if match.group(1).count("dirname") - 1 > above:
            found.append(f"{match.group(0)} climbs above the repository root")
    for match in STRING.finditer(text) if rel.suffix != ".xml" else ():
        path = match.group(2)
        if climbs_out(folder, path) or climbs_out(PurePosixPath(), path):
            found.append(f"{path!r} climbs out of the repository")
    if rel.suffix == ".xml":
        for match in XML_FILENAME.finditer(text):
            if climbs_out(folder, match.group(1)):
                found.append(f"filename {match.group(1)!r} climbs out of the repository")
    for match in SIBLING.finditer(text):
        found.append(f"{match.group(0)!r} names the folder beside the repository")
    for match in ABSOLUTE.finditer(text):
        found.append(f"{match.group(0)!r}… is an absolute path outside the repository")
    return found


@pytest.mark.parametrize(
    "rel, text, bad",
    [
        ("tests/screen/t.py", f'Path(__file__).resolve().parents[3] / "{OUTSIDE}/tools/x.xml"', 2),
        ("tests/screen/t.py", 'Path(__file__).resolve().parents[2] / "examples/a.xml"', 0),
        ("tests/t.py", "Path(__file__).parents[2]", 1),
        ("tests/t.py", "Path(__file__).parents[1]", 0),
        ("tests/t.py", "Path(__file__).resolve().parent.parent.parent", 1),
        ("tests/t.py", "Path(__file__).resolve().parent.parent", 0),
        ("tests/t.py", "os.path.dirname(os.path.dirname(os.path.dirname(__file__)))", 1),
        ("tests/t.py", "os.path.dirname(os.path.dirname(os.path.abspath(__file__)))", 0),
        ("tests/t.py", 'open("../scenes/a.xml")', 1),  # from the root, where the tests run
        ("tests/t.py", 'open("tests/../examples/a.xml")', 0),
        ("examples/a.xml", '<string name="filename" value="../../meshes/b.obj"/>', 1),
        ("examples/a.xml", '<string name="filename" value="meshes/b.obj"/>', 0),
        ("benchmarks/b.py", f"# see ../{OUTSIDE}/tools/scenes", 1),
        ("benchmarks/b.py", f'Path("/work/{OUTSIDE}/tools/scenes")', 2),
        ("benchmarks/b.py", "shared_cache = 1  # the shared cores", 0),
    ],
)
def test_the_scanner_finds_what_leaves(rel, text, bad):
    assert len(escapes(PurePosixPath(rel), text)) == bad, escapes(PurePosixPath(rel), text)


def test_nothing_reads_outside_the_repository():
    found = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*")):
            if path.suffix not in SUFFIXES or not path.is_file() or path == Path(__file__):
                continue
            if {"results", "cache"} & set(path.parts):  # what the benchmarks wrote, not read
                continue
            rel = PurePosixPath(path.relative_to(ROOT).as_posix())
            found += [f"{rel}: {what}" for what in escapes(rel, path.read_text(errors="replace"))]
    assert not found, "paths outside the repository:\n" + "\n".join(found)


def test_the_modules_run_first_exist():
    """``conftest.LONGEST_FIRST`` names test modules that exist (a renamed one would silently
    lose its place at the front)."""
    text = (ROOT / "tests" / "conftest.py").read_text()
    listed = re.search(r"LONGEST_FIRST = \((.*?)\n\)", text, re.S).group(1)
    paths = re.findall(r'"([^"]+)"', listed)
    assert len(paths) >= 5 and [p for p in paths if not (ROOT / p).is_file()] == []
