"""The ``photonmap`` command: render scenes, list the built-ins, compare images."""

from __future__ import annotations

import dataclasses
from contextlib import nullcontext
from typing import Annotated

import typer
from rich.console import Console

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="Photon mapping on Mitsuba 3 + Dr.Jit."
)
console = Console(stderr=True)
METHODS = ("volume", "surface", "screen")
TRUE, FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def _error(exc) -> typer.Exit:
    """Print a PhotonmapError on stderr (unwrapped, so keys are never split) → exit status 2."""
    from rich.text import Text

    console.print(Text.assemble(("error: ", "red"), str(exc)), soft_wrap=True)
    return typer.Exit(2)


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
                word = value.strip().lower()
                if word not in TRUE + FALSE:
                    raise ValueError
                out[key] = word in TRUE
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
    method: Annotated[
        str | None,
        typer.Option(help="pipeline: volume | surface | screen (default: the scene's own)"),
    ] = None,
    width: Annotated[int | None, typer.Option(help="image width (default: the scene's)")] = None,
    height: Annotated[int | None, typer.Option(help="image height")] = None,
    spp: Annotated[
        int, typer.Option(help="camera samples per pixel (volume, surface; screen casts 1)")
    ] = 1,
    seed: Annotated[int, typer.Option(help="random seed")] = 0,
    set_: Annotated[
        list[str] | None, typer.Option("--set", help="KEY=VALUE pipeline parameter")
    ] = None,
    timings: Annotated[
        bool, typer.Option("--timings", help="print per-stage milliseconds")
    ] = False,
):
    """Render SCENE to OUT (.exr linear, .png tone-mapped to sRGB).

    Volume --set keys: grid, photons, eps, eps2, ds_min, ds_max, phase_k, sampler, fidelity, ...;
    surface: photons, caustic_photons, k, max_radius, fg_rays, structure, max_depth, lookup, ...;
    screen: bounces, light_res, radius, splat, subsample, shadows, isg_samples, light_size, ...
    (an unknown key lists them all). On a terminal the pipeline stages show as a progress bar."""
    from . import PhotonmapError
    from .core.image import write_image

    try:
        if method is None:
            from .scenes import SCENES

            method = SCENES[scene].pipeline if scene in SCENES else "volume"
        if method not in METHODS:
            raise PhotonmapError(f"unknown --method {method!r}; available: {', '.join(METHODS)}")
        for out in output:
            if not out.lower().endswith((".exr", ".png")):
                raise PhotonmapError(f"output {out!r} must end in .exr or .png")
        from .core.progress import interactive, stage_progress

        if method == "volume":
            from .volume.pipeline import STAGES, VolumeParams, VolumePipeline

            Pipeline, Params, extra = VolumePipeline, VolumeParams, {"grid": 128}
        elif method == "screen":
            from .screen.pipeline import STAGES, ScreenParams, ScreenPipeline

            Pipeline, Params, extra = ScreenPipeline, ScreenParams, {}
        else:
            from .surface.pipeline import STAGES, SurfaceParams, SurfacePipeline

            Pipeline, Params, extra = SurfacePipeline, SurfaceParams, {}
        fields = {f.name: getattr(Params(), f.name) for f in dataclasses.fields(Params)}
        params = _parse_sets(set_ or [], {**fields, **extra})
        if "spp" in fields:
            params.setdefault("spp", spp)
        elif spp != 1:
            raise PhotonmapError(
                f"--spp does not apply to the {method} method: it casts one primary ray per "
                f"pixel centre (got --spp {spp})"
            )
        params.setdefault("seed", seed)
        with console.status(f"loading {scene}") if interactive() else nullcontext():
            pipe = Pipeline(scene, **params)
            if width or height:
                pipe.set_camera(width=width, height=height)
        stages = getattr(pipe, "stages", STAGES)  # the volume pipeline's depend on emission
        with stage_progress(stages, f"rendering {scene}", console=console) as report:
            image = pipe.render(progress=report)
        for out in output:
            write_image(out, image)
            console.print(f"wrote {out}", soft_wrap=True, markup=False, highlight=False)
        if timings:  # a report the user asked for: on stdout
            out_console = Console()
            out_console.print(pipe.timer.table(f"{scene}: per-stage timings"))
            out_console.print(
                ", ".join(f"{k.replace('_', ' ')} {v:,}" for k, v in pipe.stats.items())
            )
    except PhotonmapError as exc:
        raise _error(exc) from None


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
        raise _error(exc) from None
    print(f"RMSE {m['rmse']:.6g}  relative RMSE {m['rel_rmse']:.6g}  PSNR {m['psnr']:.2f} dB")
