"""``photonmap render`` (any method; a progressive method iterates for ``--time``, on Ray
workers with ``--workers``/``--ray``) and ``photonmap render-sequence`` (frames on Ray)."""

from __future__ import annotations

import dataclasses
import os
import warnings
from contextlib import nullcontext
from typing import Annotated

import typer
from rich.console import Console

from .base import (
    MaxMemory,
    app,
    check_seconds,
    command,
    console,
    count,
    image_size,
    say,
    scene_request,
)


@app.command()
def render(  # over 80 lines with its option declarations; the body is shorter
    scene: Annotated[str, typer.Argument(help="Mitsuba XML file or built-in scene name")],
    output: Annotated[list[str], typer.Option("-o", "--output", help=".exr or .png (repeatable)")],
    method: Annotated[
        str | None,
        typer.Option(
            help="volume | surface | screen | sppm | vcm (default: a built-in's own; for a file, "
            "sppm, which renders everything in it)"
        ),
    ] = None,
    width: Annotated[
        int | None, typer.Option(help="image width, 1…16384 (alone: keeps the aspect ratio)")
    ] = None,
    height: Annotated[int | None, typer.Option(help="image height, 1…16384")] = None,
    spp: Annotated[
        int | None,
        typer.Option(help="camera samples per pixel (default: the method's own; screen casts 1)"),
    ] = None,
    seed: Annotated[int, typer.Option(help="random seed, 0 … 2³²−1")] = 0,
    set_: Annotated[
        list[str] | None,
        typer.Option("--set", help="KEY=VALUE: a method or scene parameter (repeatable)"),
    ] = None,
    timings: Annotated[
        bool,
        typer.Option(
            "--timings/--no-timings", metavar=" ", help="print per-stage milliseconds (a flag)"
        ),
    ] = False,
    time: Annotated[
        float | None, typer.Option(help="sppm, vcm: iterate for SECONDS (Ctrl-C stops early)")
    ] = None,
    preview_every: Annotated[
        float | None, typer.Option(help="sppm, vcm: rewrite the output every SECONDS while iterating")
    ] = None,
    workers: Annotated[
        int | None, typer.Option(help="sppm: iterate on N local Ray workers (one per core)")
    ] = None,
    ray_address: Annotated[
        str | None, typer.Option("--ray", help="sppm: iterate on the Ray cluster at HOST:PORT")
    ] = None,
    max_memory: MaxMemory = None,
):
    """Render SCENE to OUT (.exr linear, .png tone-mapped to sRGB).

    Volume --set keys: grid, grid_bbox, photons, eps, eps2, ds_min, ds_max, phase_k, sampler,
    fidelity, ...; surface: photons, caustic_photons, k, radius, fg_rays, structure,
    max_depth, lookup, ...; screen: bounces, photons, radius, splat, subsample, shadows,
    isg_samples, light_size, ...; a built-in scene's own parameters (photonmap scenes); an XML
    file's $name parameters (an unknown key lists them all). On a terminal the pipeline stages
    show as a progress bar."""
    from .. import METHODS, PhotonmapError
    from ..core import interrupt
    from ..core.image import check_output
    from ..core.memory import check_side
    from ..core.progress import interactive
    from ..core.scene_info import pick_method

    with command(max_memory) as run:
        for out in output:
            check_output(out)
        check_side("--width", width)
        check_side("--height", height)
        if spp is not None and spp < 1:
            raise PhotonmapError(f"--spp must be at least 1, got {spp}")
        if method is not None and method not in METHODS:
            raise PhotonmapError(f"unknown --method {method!r}; available: {', '.join(METHODS)}")
        with console.status(f"loading {scene}") if interactive() else nullcontext():
            request = scene_request(scene, set_)
            mi_scene, builtin = request.scene, request.builtin
        interrupt.check()
        if method is None and builtin is not None:
            method = builtin.pipeline  # the method the built-in scene is made for
        elif method is None:
            method = pick_method(mi_scene)
            say(f"method: {method} (renders everything in a Mitsuba file; choose with --method)")
        Pipeline = METHODS[method].pipeline
        _check_progressive(method, Pipeline.progressive, time, preview_every)
        if (workers is not None or ray_address is not None) and not Pipeline.progressive:
            raise PhotonmapError(
                "--workers/--ray distribute a progressive method's iterations (--method sppm); "
                "for many frames of any method use 'photonmap render-sequence'"
            )
        params = _method_params(method, request, spp, seed)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with console.status(f"loading {scene}") if interactive() else nullcontext():
                pipe = Pipeline(mi_scene if mi_scene is not None else scene, **params)
            interrupt.check()
            size = _sized(pipe, width, height)
            if workers is not None or ray_address is not None:
                job = _job(scene, method, params, request.xml, size)
                image = _distribute(job, output, time, preview_every, workers, ray_address, run)
            elif pipe.progressive:
                image = _iterate(pipe, scene, output, time, "iterations" in params,
                                 preview_every, run)  # fmt: skip
            else:
                image = _staged(pipe, scene)
        if not interrupt.requested():
            for w in {str(w.message): w for w in caught}.values():
                say(f"warning: {w.message}")
        if image is not None:
            run.write(output, image)
        if timings and not interrupt.requested():  # a report the user asked for: on stdout
            out_console = Console()
            out_console.print(pipe.timer.table(f"{scene}: per-stage timings"))
            out_console.print(
                ", ".join(f"{k.replace('_', ' ')} {v:,}" for k, v in pipe.stats.items())
            )


def _method_params(method: str, request, spp: int | None, seed: int) -> dict:
    """The ``--set`` values as the method's (and the built-in scene's) parameters, with ``--spp``
    (when given; else the method's own default) and ``--seed``; ``--spp`` other than 1 for a
    method without ``spp`` is refused."""
    from .. import METHODS, PhotonmapError

    params = request.params(method)
    if spp is not None and "spp" in {f.name for f in dataclasses.fields(METHODS[method].params)}:
        params.setdefault("spp", spp)
    elif spp not in (None, 1):
        raise PhotonmapError(
            f"--spp does not apply to the {method} method: it casts one primary ray per "
            f"pixel centre (got --spp {spp})"
        )
    params.setdefault("seed", seed)
    return params


def _sized(pipe, width, height) -> tuple[int, int]:
    """Give the pipeline's camera the ``--width``/``--height`` size (checked against the
    method's memory estimate before any allocation); return the size."""
    film = pipe.sensor.film().size()
    size = image_size(width, height, film)
    pipe.check_memory(size=size)
    if size != tuple(int(c) for c in film):
        pipe.set_camera(width=size[0], height=size[1])
    return size


def _staged(pipe, scene: str):
    """A staged method's image, with a progress bar of its stages; Ctrl-C stops between them."""
    from ..core import interrupt
    from ..core.progress import stage_progress

    with stage_progress(pipe.stages, f"rendering {scene}", console=console) as bar:

        def report(stage):
            interrupt.check()  # Ctrl-C: stop between stages, write nothing
            if bar is not None:
                bar(stage)

        return pipe.render(progress=report)


def _check_progressive(method, progressive: bool, seconds, preview_every) -> None:
    """``--time`` and ``--preview-every`` are a progressive method's (positive seconds)."""
    from ..core.errors import ParameterError

    for name, value in (("--time", seconds), ("--preview-every", preview_every)):
        if value is None:
            continue
        if not progressive:
            raise ParameterError(
                f"{name} applies to a progressive method (--method sppm or vcm), not to {method}"
            )
        check_seconds(name, value)


def _iterate(pipe, scene, outputs, seconds, iterations_set, preview_every, run):
    """Run the progressive pipeline for ``--time`` seconds (and/or ``--set iterations=N``) with
    a progress bar of iterations and the mean radius; ``--preview-every`` rewrites the outputs
    during the run; Ctrl-C ends it with the image of the whole iterations reached so far (None:
    not one finished)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ..core import interrupt
    from ..core.image import write_image
    from ..core.progress import interactive

    iterations = pipe.params.iterations if seconds is None or iterations_set else None
    total = float(seconds) if iterations is None else float(iterations)
    columns = (TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console, transient=True, disable=not interactive()) as bar:
        task = bar.add_task(f"{pipe.method} {scene}", total=total)

        def progress(i, elapsed, radius):
            done = elapsed if iterations is None else i
            bar.update(
                task, completed=done, description=f"{pipe.method}: {i} iterations, r {radius:.4g}"
            )
            interrupt.check()  # Ctrl-C: stop after this whole iteration

        def preview(image):
            for out in outputs:
                write_image(out, image)

        try:
            interrupt.check()
            pipe.run(seconds, iterations, progress, preview, preview_every or float("inf"))
        except KeyboardInterrupt:
            run.note = f"the image of {count(pipe.iterations, 'iteration')}"
            return pipe.image() if pipe.iterations else None
    say(f"{pipe.method}: {pipe.iterations} iterations, mean radius {pipe.mean_radius:.4g}")
    return pipe.image()


def _job(scene, method, params, scene_params, size):
    from ..cluster.job import SceneJob

    return SceneJob(scene, method, params, scene_params, *size)


def _distribute(job, outputs, seconds, preview_every, workers, address, run):
    """``render --workers/--ray``: memoryless iterations in blocks on Ray workers
    (:mod:`photonmap.cluster.progressive`), previews as blocks arrive, Ctrl-C keeps the merge
    (None: no block finished)."""
    from rich.progress import Progress

    from ..cluster.progressive import Watch, render_progressive
    from ..core.errors import PhotonmapError
    from ..core.image import write_image
    from ..core.progress import interactive

    iterations = job.params.get("iterations", 64 if seconds is None else None)

    def preview(image):
        for out in outputs:
            write_image(out, image)

    with Progress(console=console, transient=True, disable=not interactive()) as bar:
        task = bar.add_task("sppm on Ray workers", total=iterations or seconds)

        def on_block(done, info):
            bar.update(
                task,
                completed=done if iterations else min(seconds, info["seconds"]),
                description=f"sppm: {done} iterations merged",
            )

        watch = Watch(preview, preview_every or float("inf"), on_block)
        res = render_progressive(job, iterations, seconds, workers, address, watch=watch)
    if res.interrupted:
        run.note = f"the image of {count(res.iterations, 'iteration')}"
        return None if res.sums is None else res.sums.image()
    for text in res.warnings():
        say(f"warning: {text}")
    if res.sums is None:
        raise PhotonmapError("no block of iterations finished: no image")
    pids = {(b["node"], b["pid"]) for b in res.blocks}
    say(
        f"sppm: {res.iterations} iterations in {len(res.blocks)} blocks on {len(pids)} "
        f"worker(s), {res.seconds:.1f} s"
    )
    return res.sums.image()


@app.command("render-sequence")
def render_sequence(
    scene: Annotated[str, typer.Argument(help="Mitsuba XML file or built-in scene name")],
    frames: Annotated[
        str,
        typer.Option(
            help="frame spec (JSON): a camera or light path, or a "
            "list of parameter sets (docs/cluster.md)"
        ),
    ],
    output: Annotated[
        list[str], typer.Option("-o", "--output", help="out/%04d.png or .exr (repeatable)")
    ],
    workers: Annotated[
        int | None, typer.Option(help="N local Ray workers (default: one per core)")
    ] = None,
    ray_address: Annotated[
        str | None, typer.Option("--ray", help="the Ray cluster at HOST:PORT")
    ] = None,
    width: Annotated[int | None, typer.Option(help="image width (overrides the spec's)")] = None,
    height: Annotated[int | None, typer.Option(help="image height (overrides the spec's)")] = None,
    skip_existing: Annotated[
        bool, typer.Option("--skip-existing", help="leave out frames already written (resume)")
    ] = False,
    max_memory: MaxMemory = None,
):
    """Render a sequence of frames of SCENE, one Ray task per frame, each frame written as it
    finishes; every worker keeps its pipeline's cached stages between the frames it renders.
    Every frame's settings and memory are checked here before the first frame starts."""
    from .. import METHODS, PhotonmapError
    from ..cluster.frames import load_frames
    from ..cluster.job import check_frames
    from ..cluster.sequence import check_outputs
    from ..cluster.sequence import render_sequence as run_frames
    from ..core import interrupt
    from ..core.memory import check_side
    from ..core.scene_info import pick_method

    with command(max_memory) as run:
        check_outputs(output)
        check_side("--width", width)
        check_side("--height", height)
        spec = load_frames(frames)
        request = scene_request(scene, [])
        mi_scene, builtin = request.scene, request.builtin
        method = spec.method or (builtin.pipeline if builtin else pick_method(mi_scene))
        if method not in METHODS:
            raise PhotonmapError(f"unknown method {method!r}; available: {', '.join(METHODS)}")
        job, todo = _sequence_job(scene, method, spec, width, height)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the workers report them
            check_frames(job, todo)  # every frame's settings and memory, before any work
        interrupt.check()
        done, seen = 0, set()
        run.summary = f"0 of {len(todo)} frames written"
        for index, paths, info in run_frames(job, todo, output, workers, ray_address,
                                             skip_existing):  # fmt: skip
            done += 1
            run.summary = f"{done} of {len(todo)} frames written"
            if interrupt.requested():
                continue  # the frame is on disk; the line that ends the command says so
            for text in set(info["warnings"]) - seen:
                say(f"warning: {text}")
            seen |= set(info["warnings"])
            reran = info["recomputed"]
            reran = "" if reran is None else f", reran {len(reran)} stage(s)"
            say(
                f"wrote {', '.join(paths)} (frame {index}, {done}/{len(todo)}; worker "
                f"{info['node']}:{info['pid']}, {info['seconds']:.2f} s{reran})"
            )


def _sequence_job(scene, method, spec, width, height):
    """The job (settings equal in every frame go to the pipeline's constructor) and the frames
    with only what changes between them."""
    import dataclasses as dc

    from ..cluster.job import SceneJob

    first = spec.frames[0].set
    fixed = {k: v for k, v in first.items() if all(f.set.get(k) == v for f in spec.frames)}
    xml = {}
    if os.path.isfile(scene):
        with open(scene, errors="replace") as f:
            text = f.read()
        xml = {k: str(v) for k, v in fixed.items() if f"${k}" in text}
    params = {k: v for k, v in fixed.items() if k not in xml}
    job = SceneJob(scene, method, params, xml, width or spec.width, height or spec.height)
    frames = [
        dc.replace(f, set={k: v for k, v in f.set.items() if k not in fixed}) for f in spec.frames
    ]
    return job, frames
