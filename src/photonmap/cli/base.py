"""What every ``photonmap`` command shares: the Typer app, the one-line errors and exit
statuses, Ctrl-C answered at safe points (:func:`command`), and reading ``--set`` values and
scenes."""

from __future__ import annotations

import math
import os
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Annotated

import typer
from rich.console import Console

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="Photon mapping on Mitsuba 3 + Dr.Jit."
)
console = Console(stderr=True)
MaxMemory = Annotated[
    str | None,
    typer.Option(
        "--max-memory",
        help="memory the render may use, e.g. 8G (default: what the system has available)",
    ),
]


def main() -> None:
    """The console script: ``photonmap`` (also ``python -m photonmap``)."""
    app()


def error_exit(exc) -> typer.Exit:
    """Print a PhotonmapError on stderr (unwrapped, so keys are never split) → its exit status
    (2: bad input; 1: a failure outside the input, e.g. a full disk)."""
    from rich.text import Text

    console.print(Text.assemble(("error: ", "red"), str(exc)), soft_wrap=True)
    return typer.Exit(getattr(exc, "exit_code", 2))


def root_cause(exc: BaseException) -> str:
    """The first line of the innermost cause of ``exc`` (Mitsuba wraps its errors)."""
    while (exc.__cause__ or exc.__context__) is not None:
        exc = exc.__cause__ or exc.__context__
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


def count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def say(text: str) -> None:
    console.print(text, soft_wrap=True, markup=False, highlight=False)


class Run:
    """What a command wrote, for the line that ends it on Ctrl-C."""

    def __init__(self):
        self.written: list[str] = []
        self.note = ""  # what the written image holds (e.g. "5 iterations")
        self.summary = ""  # replaces the list of files (a sequence's "3 of 8 frames written")

    def write(self, outputs, image) -> None:
        """Write ``image`` to every output (atomically), saying so unless interrupted."""
        from ..core import interrupt
        from ..core.image import write_image

        for out in outputs:
            write_image(out, image)
            self.written.append(out)
            if not interrupt.requested():
                say(f"wrote {out}")

    def describe(self) -> str:
        what = self.summary or (
            f"wrote {', '.join(self.written)}" if self.written else "nothing written"
        )
        return what + (f" ({self.note})" if self.note and (self.written or self.summary) else "")


@contextmanager
def command(max_memory: str | None = None):
    """A command's work: a PhotonmapError is one line and its exit status; Ctrl-C is answered
    at the next safe point (:func:`photonmap.core.interrupt.check`) with one line saying what
    was written, exit status 130; running out of memory despite the estimates is one line."""
    from ..core import interrupt
    from ..core.errors import PhotonmapError
    from ..core.memory import set_memory_limit

    run = Run()
    with interrupt.deferred(force=True):
        try:
            set_memory_limit(max_memory)
            yield run
        except KeyboardInterrupt:
            interrupted = True
        except PhotonmapError as exc:
            raise error_exit(exc) from None
        except MemoryError as exc:
            say(f"error: out of memory ({exc}); lower the photon budget or the image size")
            raise typer.Exit(1) from None
        else:
            interrupted = interrupt.requested()  # during the last writes: they completed
        finally:
            set_memory_limit(None)
    if interrupted:
        interrupt.answered()
        say(f"interrupted: {run.describe()}")
        raise typer.Exit(130)


@dataclass
class SceneRequest:
    """SCENE and its ``--set KEY=VALUE`` pairs, split once (:func:`scene_request`): ``scene``, the
    file loaded with the pairs that name its ``$name`` parameters (``xml``), or None for a
    built-in (``builtin``: its pipeline loads it); ``sets``, the other pairs as text — the
    method's parameters and a built-in's own, typed by :meth:`params`."""

    scene: object  # mi.Scene, or None for a built-in
    builtin: object  # photonmap.scenes.Builtin, or None for a file
    xml: dict[str, str]
    sets: dict[str, str]

    def params(self, method: str) -> dict:
        """:attr:`sets` as the parameters of ``method`` (and of the built-in scene)."""
        return typed_params(method, self.sets, self.builtin)


def scene_request(scene: str, items: list[str] | None) -> SceneRequest:
    """The one way from a command line's SCENE and ``--set`` strings to a scene and its
    parameters: each ``KEY=VALUE`` is split once and goes to the file's ``$KEY`` if it has one,
    else to the method or the built-in scene (:meth:`SceneRequest.params`)."""
    from ..core.errors import ParameterError, SceneError
    from ..scenes import SCENES, load_scene

    sets = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError(f"--set expects KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        sets[key.strip()] = value
    if scene in SCENES:
        return SceneRequest(None, SCENES[scene], {}, sets)
    if not os.path.isfile(scene):
        raise SceneError(
            f"no built-in scene or scene file named {scene!r}; built-in scenes: "
            f"{', '.join(SCENES)} (or give the path of a Mitsuba 3 XML file)"
        )
    with open(scene, errors="replace") as f:
        text = f.read()
    xml = {k: v for k, v in sets.items() if f"${k}" in text}
    mi_scene, _ = load_scene(scene, **xml)
    return SceneRequest(mi_scene, None, xml, {k: v for k, v in sets.items() if k not in xml})


def typed_params(method: str, sets: dict[str, str], builtin) -> dict:
    """The ``--set`` values as the types of the method's parameters (and, for a built-in, of
    its scene parameters); unknown keys list the valid ones."""
    from .. import METHODS
    from ..core.errors import ParameterError
    from ..core.params import field_types, parameter_names, parse_field, parse_value

    params_type = METHODS[method].params
    kinds = field_types(params_type)
    names = parameter_names(params_type)
    scene_kinds = {}
    if builtin is not None:
        scene_kinds = {
            k: type(v) if v is not None else str
            for k, v in builtin.params.items()
            if k not in ("width", "height")  # --width and --height set the image size
        }
    out = {}
    for key, text in sets.items():
        if key in names:
            out[key] = parse_field(params_type, key, text)
        elif key in scene_kinds:
            out[key] = parse_value(key, text, scene_kinds[key])
        else:
            also = f"; scene parameters: {', '.join(sorted(scene_kinds))}" if scene_kinds else ""
            raise ParameterError(
                f"unknown --set key {key!r} for the {method} method; valid keys: "
                f"{', '.join(sorted(kinds))}{also}"
            )
    return out


def image_size(width, height, film_size) -> tuple[int, int]:
    """The image size: ``--width`` or ``--height`` alone keeps the scene's aspect ratio."""
    w0, h0 = (int(c) for c in film_size)
    if width and not height:
        height = max(1, round(width * h0 / w0))
    elif height and not width:
        width = max(1, round(height * w0 / h0))
    return int(width or w0), int(height or h0)


def check_seconds(name: str, value) -> None:
    """A time budget: a finite number of seconds > 0."""
    from ..core.errors import ParameterError

    if not (value > 0 and math.isfinite(value)):
        raise ParameterError(f"{name} must be a finite number of seconds > 0, got {value}")
