"""``photonmap reference``, ``scenes``, ``compare``, ``view`` and ``analyze bandwidth``."""

from __future__ import annotations

import os
from typing import Annotated

import typer
from rich.console import Console

from .base import (
    MaxMemory,
    app,
    check_seconds,
    command,
    console,
    error_exit,
    image_size,
    root_cause,
    say,
    scene_request,
)


@app.command()
def reference(  # over 80 lines with its option declarations; the body is shorter
    scene: Annotated[str, typer.Argument(help="Mitsuba XML file or built-in scene name")],
    output: Annotated[list[str], typer.Option("-o", "--output", help=".exr or .png (repeatable)")],
    spp: Annotated[int, typer.Option(help="samples per pixel")] = 1024,
    time: Annotated[
        float | None, typer.Option(help="stop after the pass that crosses S seconds")
    ] = None,
    integrator: Annotated[
        str | None,
        typer.Option(help="path | volpath | ptracer (default: volpath with fog, else path)"),
    ] = None,
    max_depth: Annotated[
        int | None,
        typer.Option(
            help="Mitsuba's max_depth (-1 unbounded; 2 = direct light only; default: the file's)"
        ),
    ] = None,
    width: Annotated[int | None, typer.Option(help="image width, 1…16384")] = None,
    height: Annotated[int | None, typer.Option(help="image height, 1…16384")] = None,
    seed: Annotated[int, typer.Option(help="seed of the first pass")] = 0,
    set_: Annotated[
        list[str] | None, typer.Option("--set", help="KEY=VALUE: a scene parameter")
    ] = None,
):
    """Render SCENE with Mitsuba's own integrator, the ground truth for every method: the same
    file with its own max_depth, rr_depth and hide_emitters, in passes that bound memory, with a
    progress bar on a terminal."""
    from rich.progress import Progress

    from .. import mi
    from ..core import interrupt
    from ..core.errors import ParameterError, SceneError
    from ..core.image import check_output
    from ..core.memory import check_memory, check_side
    from ..core.progress import interactive
    from ..core.reference import BYTES_PER_SAMPLE, INTEGRATORS, render_reference
    from ..scenes import load_scene

    with command() as run:
        for out in output:
            check_output(out)
        check_side("--width", width)
        check_side("--height", height)
        if integrator is not None and integrator not in INTEGRATORS:
            raise ParameterError(
                f"unknown --integrator {integrator!r}; available: {', '.join(INTEGRATORS)}"
            )
        if spp < 1:
            raise ParameterError(f"--spp must be at least 1, got {spp}")
        if time is not None:
            check_seconds("--time", time)
        if not 0 <= seed < 2**32:
            raise ParameterError(f"--seed must lie in 0 … 2³²−1, got {seed}")
        request = scene_request(scene, set_)
        mi_scene, builtin, rest = request.scene, request.builtin, request.sets
        if builtin is not None:
            mi_scene, _ = load_scene(scene, **request.params(builtin.pipeline))
        elif rest:
            raise ParameterError(
                f"unknown --set key(s) {', '.join(rest)}: not $parameters of {scene}"
            )
        if not mi_scene.sensors():
            raise ParameterError("the scene has no sensor (camera) to render from")
        interrupt.check()
        film = mi_scene.sensors()[0].film().size()
        size = image_size(width, height, film)
        check_memory("reference", {"film and one pass": (BYTES_PER_SAMPLE + 64) * size[0] * size[1]},
                     "render a smaller image (--width, --height)")  # fmt: skip
        if size != tuple(int(c) for c in film):
            params = mi.traverse(mi_scene.sensors()[0])
            params["film.size"] = size
            params["film.crop_size"] = size
            params.update()

        def passed(done, total):  # after each pass: Ctrl-C stops here, nothing is written
            bar.update(task, completed=done)
            interrupt.check()

        with Progress(console=console, disable=not interactive()) as bar:
            task = bar.add_task(f"reference {scene}", total=spp)
            try:
                image, info = render_reference(
                    mi_scene,
                    spp,
                    integrator,
                    max_depth,
                    time,
                    seed,
                    progress=passed,
                    source=scene if builtin is None else None,
                )
            except (RuntimeError, TypeError) as exc:  # Mitsuba refused the scene or its film
                raise SceneError(f"Mitsuba could not render {scene!r}: {root_cause(exc)}") from None
        run.write(output, image)
        if not interrupt.requested():
            say(
                f"{info['integrator']}: {info['spp']} spp in {info['seconds']:.1f} s "
                f"({info['passes']} pass{'es' if info['passes'] > 1 else ''})"
            )


@app.command()
def scenes():
    """List the built-in scenes."""
    from rich.table import Table

    from ..scenes import SCENES

    with command():
        _scenes_table(Table, SCENES)


def _scenes_table(Table, SCENES) -> None:
    t = Table(title="built-in scenes")
    t.add_column("name")
    t.add_column("method")
    t.add_column("description")
    t.add_column("--set scene parameters")
    for name, builtin in SCENES.items():
        keys = [k for k in builtin.params if k not in ("width", "height")]
        t.add_row(name, builtin.pipeline, builtin.description, ", ".join(keys))
    Console().print(t)


@app.command()
def compare(
    a: Annotated[str, typer.Argument(help="image to measure")],
    b: Annotated[str, typer.Argument(help="reference image")],
):
    """Errors of image A against reference B: RMSE, relative RMSE, relative RMSE of 4×4-pixel
    block means (noise averages out, bias does not), brightness ratio and PSNR."""
    from ..core.image import compare as compare_images
    from ..core.image import read_image

    with command():
        m = compare_images(read_image(a), read_image(b))
    print(
        f"RMSE {m['rmse']:.6g}  relative RMSE {m['rel_rmse']:.6g}  "
        f"4x4-block relative RMSE {m['block_rel_rmse']:.6g}  brightness {m['brightness']:.4f}  "
        f"PSNR {m['psnr']:.2f} dB"
    )


@app.command()
def view(
    scene: Annotated[str, typer.Argument(help="Mitsuba XML file or built-in scene name")],
    method: Annotated[
        str | None,
        typer.Option(help="volume | screen | surface | sppm | vcm; default as render"),
    ] = None,
    port: Annotated[int, typer.Option(help="TCP port of the local web server")] = 8000,
    host: Annotated[str, typer.Option(help="address to bind (default: this machine only)")] = (
        "127.0.0.1"
    ),
    no_browser: Annotated[
        bool, typer.Option("--no-browser", help="do not open the page in a browser (a flag)")
    ] = False,
    width: Annotated[int | None, typer.Option(help="image width (alone: keeps the aspect)")] = None,
    height: Annotated[int | None, typer.Option(help="image height")] = None,
    volumes: Annotated[
        str | None,
        typer.Option(help=".npz of volume frames to play: n, sigma_s, kappa, shape (F, N, N, N)"),
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option("--set", help="KEY=VALUE: a method or scene parameter (repeatable)"),
    ] = None,
    max_memory: MaxMemory = None,
):
    """Interactive relighting in the browser: drag the light, orbit the camera, change the
    glass and the fog, paint the volume; per-stage timings of each change. docs/viewer.md
    documents the page and its HTTP API. The page's URL carries a token the server
    requires (only that page drives the viewer)."""
    from .. import METHODS, PhotonmapError
    from ..core import interrupt
    from ..core.errors import ParameterError
    from ..core.memory import check_side
    from ..core.scene_info import pick_method

    try:
        from ..viewer import Viewer, page_url, serve
    except ImportError as exc:
        raise error_exit(
            PhotonmapError(
                f"the viewer needs the 'viewer' extra ({exc.name} is missing): "
                "pip install 'photonmap[viewer]'"
            )
        ) from None
    with command(max_memory) as run:
        check_side("--width", width)
        check_side("--height", height)
        if not 1 <= port <= 65535:
            raise ParameterError(f"--port must lie in 1…65535, got {port}")
        if method is not None and method not in METHODS:
            raise ParameterError(f"unknown --method {method!r}; available: {', '.join(METHODS)}")
        request = scene_request(scene, set_)
        mi_scene, builtin = request.scene, request.builtin
        if method is None:
            method = builtin.pipeline if builtin is not None else pick_method(mi_scene)
        params = request.params(method)
        frames = None
        if volumes is not None:
            import numpy as np

            if not os.path.isfile(volumes):
                raise ParameterError(f"--volumes: no such file {volumes!r}")
            with np.load(volumes) as data:
                frames = {k: data[k] for k in data.files}
        size = None
        if width or height:
            from ..scenes import load_scene

            probe = mi_scene if mi_scene is not None else load_scene(scene)[0]
            size = image_size(width, height, probe.sensors()[0].film().size())
        interrupt.check()
        say(f"loading {scene} ({method})")
        viewer = Viewer(mi_scene if mi_scene is not None else scene, method, params, size,
                        frames, name=scene)  # fmt: skip
        run.summary = "the viewer stopped, nothing written"
        try:
            interrupt.check()
            say(f"photonmap view: {page_url(viewer, host, port)}  (Ctrl-C stops)")
            serve(viewer, host, port, open_browser=not no_browser)
        finally:
            viewer.close()


analyze_app = typer.Typer(
    no_args_is_help=True, help="Study a render rather than make one (Steinhurst 2007 Ch. 3)."
)
app.add_typer(analyze_app, name="analyze")


@analyze_app.command("bandwidth")
def analyze_bandwidth(
    scene: Annotated[str, typer.Argument(help="Mitsuba XML file or built-in scene name")],
    order: Annotated[
        list[str] | None, typer.Option(help="gather order (repeatable; default: all seven)")
    ] = None,
    cache: Annotated[str, typer.Option(help="cache size, e.g. 128K")] = "128K",
    line: Annotated[str, typer.Option(help="cache line size in bytes")] = "128",
    tile: Annotated[int, typer.Option(help="tile edge in pixels")] = 16,
    sweep: Annotated[str | None, typer.Option(help="tile | cache | line: print curves")] = None,
    plot: Annotated[str | None, typer.Option(help="PNG of the sweep's curves")] = None,
    structure: Annotated[
        str, typer.Option(help="photon map layout: kdtree | kdbtree | blockhash (Ch. 4)")
    ] = "kdtree",
    size: Annotated[int, typer.Option(help="image side of a built-in scene")] = 512,
    crop: Annotated[
        str | None, typer.Option(help="X,Y,W,H: trace only this window of a built-in's image")
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option("--set", help="KEY=VALUE: a surface-method or scene parameter"),
    ] = None,
):
    """Photon-map memory traffic of SCENE's final gathers per gather order: exact k-NN gathers
    on the heap-order kd-tree, a fully associative LRU cache (and 8-way set-associative), bytes
    per image against the dissertation's uncached 20 bytes per visited node."""
    from ..analysis.report import CacheModel, bandwidth_report

    with command():
        request = scene_request(scene, set_)
        builtin, params = request.builtin, request.params("surface")
        model = CacheModel(order, cache, line, tile, structure, sweep, plot)
        text = bandwidth_report(scene, builtin, params, size, crop, model)
        Console().print(text, markup=False, highlight=False, soft_wrap=True)
