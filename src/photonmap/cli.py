"""The ``photonmap`` command: render scenes, list the built-ins, compare images."""

from __future__ import annotations

import dataclasses
import sys
from contextlib import nullcontext
from typing import Annotated

import typer
from rich.console import Console

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="Photon mapping on Mitsuba 3 + Dr.Jit."
)
console = Console(stderr=True)
METHODS = ("volume",)


def _parse_sets(items: list[str], fields: dict) -> dict:
    """``KEY=VALUE`` strings → typed parameters; unknown keys list the valid ones."""
    from .core.errors import ParameterError

    out = {}
    for item in items:
        if "=" not in item:
            raise ParameterError(f"--set expects KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        key = key.strip()
        if key not in fields:
            raise ParameterError(
                f"unknown --set key {key!r}; valid keys: {', '.join(sorted(fields))}"
            )
        kind = type(fields[key])
        try:
            if kind is bool:
                out[key] = value.strip().lower() in ("1", "true", "yes", "on")
            elif kind is int:
                out[key] = int(float(value)) if "e" in value.lower() else int(value)
            else:
                out[key] = kind(value)
        except ValueError:
            raise ParameterError(f"--set {key}: cannot read {value!r} as {kind.__name__}") from None
    return out


@app.command()
def render(
    scene: Annotated[str, typer.Argument(help="Mitsuba XML file or built-in scene name")],
    output: Annotated[list[str], typer.Option("-o", "--output", help=".exr or .png (repeatable)")],
    method: Annotated[str, typer.Option(help="pipeline: volume")] = "volume",
    width: Annotated[int | None, typer.Option(help="image width (default: the scene's)")] = None,
    height: Annotated[int | None, typer.Option(help="image height")] = None,
    spp: Annotated[int, typer.Option(help="camera samples per pixel")] = 1,
    seed: Annotated[int, typer.Option(help="random seed")] = 0,
    set_: Annotated[
        list[str] | None, typer.Option("--set", help="KEY=VALUE pipeline parameter")
    ] = None,
    timings: Annotated[
        bool, typer.Option("--timings", help="print per-stage milliseconds")
    ] = False,
):
    """Render SCENE to OUT (.exr linear, .png tone-mapped to sRGB)."""
    from . import PhotonmapError
    from .core.image import write_image

    try:
        if method not in METHODS:
            raise PhotonmapError(f"unknown --method {method!r}; available: {', '.join(METHODS)}")
        for out in output:
            if not out.lower().endswith((".exr", ".png")):
                raise PhotonmapError(f"output {out!r} must end in .exr or .png")
        from .volume.pipeline import VolumeParams, VolumePipeline

        fields = {f.name: getattr(VolumeParams(), f.name) for f in dataclasses.fields(VolumeParams)}
        params = _parse_sets(set_ or [], {**fields, "grid": 128})
        grid = params.pop("grid", 128)
        params.setdefault("spp", spp)
        params.setdefault("seed", seed)
        with (
            console.status(f"loading {scene}", spinner="dots")
            if sys.stderr.isatty()
            else nullcontext()
        ):
            pipe = VolumePipeline(scene, grid=grid, **params)
            if width or height:
                pipe.set_camera(width=width, height=height)
        with console.status("rendering", spinner="dots") if sys.stderr.isatty() else nullcontext():
            image = pipe.render()
        for out in output:
            write_image(out, image)
            console.print(f"wrote {out}")
        if timings:
            console.print(pipe.timer.table(f"{scene}: per-stage timings"))
            console.print(
                f"photons propagated {pipe.stats['photons_propagated']:,}, "
                f"steps {pipe.stats['steps'] / 1e6:.2f} M"
            )
    except PhotonmapError as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from None


@app.command()
def scenes():
    """List the built-in scenes."""
    from rich.table import Table

    from .scenes import SCENES

    t = Table(title="built-in scenes")
    t.add_column("name")
    t.add_column("description")
    for name, builtin in SCENES.items():
        t.add_row(name, builtin.description)
    Console().print(t)


@app.command()
def compare(a: str, b: str):
    """Print RMSE, relative RMSE and PSNR of image A against reference B."""
    from . import PhotonmapError
    from .core.image import compare as compare_images
    from .core.image import read_image

    try:
        m = compare_images(read_image(a), read_image(b))
    except PhotonmapError as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from None
    print(f"RMSE {m['rmse']:.6g}  relative RMSE {m['rel_rmse']:.6g}  PSNR {m['psnr']:.2f} dB")
