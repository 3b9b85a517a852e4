"""The ``photonmap`` command: render a scene with a method, render Mitsuba's own reference of the
same scene, compare two images, list the built-in scenes; on Ray workers, progressive passes
(``render --workers/--ray``) and frame sequences (``render-sequence``, :mod:`photonmap.cluster`).

Every argument is checked before any work starts (output paths, image size and its memory, the
``--set`` keys and values); each bad input is one line ``error: ...`` and exit status 2 (1 for a
failure outside the input, such as a full disk). Outputs are written atomically
(:func:`photonmap.core.image.write_bytes`). Ctrl-C is answered at the next safe point
(:mod:`photonmap.core.interrupt`): the image reached is written (a progressive render's) or
nothing, one line ``interrupted: ...`` says which, exit status 130. The CLI goes through the
package API only (:data:`photonmap.METHODS`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from contextlib import contextmanager, nullcontext
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


def _error(exc) -> typer.Exit:
    """Print a PhotonmapError on stderr (unwrapped, so keys are never split) → its exit status
    (2: bad input; 1: a failure outside the input, e.g. a full disk)."""
    from rich.text import Text

    console.print(Text.assemble(("error: ", "red"), str(exc)), soft_wrap=True)
    return typer.Exit(getattr(exc, "exit_code", 2))


def _root_cause(exc: BaseException) -> str:
    """The first line of the innermost cause of ``exc`` (Mitsuba wraps its errors)."""
    while (exc.__cause__ or exc.__context__) is not None:
        exc = exc.__cause__ or exc.__context__
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _say(text: str) -> None:
    console.print(text, soft_wrap=True, markup=False, highlight=False)


class _Run:
    """What a command wrote, for the line that ends it on Ctrl-C."""

    def __init__(self):
        self.written: list[str] = []
        self.note = ""  # what the written image holds (e.g. "5 iterations")
        self.summary = ""  # replaces the list of files (a sequence's "3 of 8 frames written")

    def write(self, outputs, image) -> None:
        """Write ``image`` to every output (atomically), saying so unless interrupted."""
        from .core import interrupt
        from .core.image import write_image

        for out in outputs:
            write_image(out, image)
            self.written.append(out)
            if not interrupt.requested():
                _say(f"wrote {out}")

    def describe(self) -> str:
        what = self.summary or (
            f"wrote {', '.join(self.written)}" if self.written else "nothing written"
        )
        return what + (f" ({self.note})" if self.note and (self.written or self.summary) else "")


@contextmanager
def _command(max_memory: str | None = None):
    """A command's work: a PhotonmapError is one line and its exit status; Ctrl-C is answered
    at the next safe point (:func:`photonmap.core.interrupt.check`) with one line saying what
    was written, exit status 130; running out of memory despite the estimates is one line."""
    from .core import interrupt
    from .core.errors import PhotonmapError
    from .core.memory import set_memory_limit

    run = _Run()
    with interrupt.deferred(force=True):
        try:
            set_memory_limit(max_memory)
            yield run
        except KeyboardInterrupt:
            interrupted = True
        except PhotonmapError as exc:
            raise _error(exc) from None
        except MemoryError as exc:
            _say(f"error: out of memory ({exc}); lower the photon budget or the image size")
            raise typer.Exit(1) from None
        else:
            interrupted = interrupt.requested()  # during the last writes: they completed
        finally:
            set_memory_limit(None)
    if interrupted:
        interrupt.answered()
        _say(f"interrupted: {run.describe()}")
        raise typer.Exit(130)


def _split_sets(items: list[str]) -> dict[str, str]:
    """``KEY=VALUE`` strings → {key: value text}."""
    from .core.errors import ParameterError

    out = {}
    for item in items:
        if "=" not in item:
            raise ParameterError(f"--set expects KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        out[key.strip()] = value
    return out


def _load(scene: str, sets: dict[str, str]):
    """``(mi_scene or None, builtin or None, remaining sets)``: a built-in is loaded by its
    pipeline (with its defaults); an XML file is loaded here, its ``$name`` parameters taken
    from ``sets``."""
    from .core.errors import SceneError
    from .scenes import SCENES, load_scene

    if scene in SCENES:
        return None, SCENES[scene], sets
    if not os.path.isfile(scene):
        raise SceneError(
            f"no built-in scene or scene file named {scene!r}; built-in scenes: "
            f"{', '.join(SCENES)} (or give the path of a Mitsuba 3 XML file)"
        )
    with open(scene, errors="replace") as f:
        text = f.read()
    xml = {k: v for k, v in sets.items() if f"${k}" in text}
    mi_scene, _ = load_scene(scene, **xml)
    return mi_scene, None, {k: v for k, v in sets.items() if k not in xml}


def _typed_params(method: str, sets: dict[str, str], builtin) -> dict:
    """The ``--set`` values as the types of the method's parameters (and, for a built-in, of
    its scene parameters); unknown keys list the valid ones."""
    from . import METHODS
    from .core.errors import ParameterError
    from .core.params import field_types, parameter_names, parse_field, parse_value

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


def _image_size(width, height, film_size) -> tuple[int, int]:
    """The image size: ``--width`` or ``--height`` alone keeps the scene's aspect ratio."""
    w0, h0 = (int(c) for c in film_size)
    if width and not height:
        height = max(1, round(width * h0 / w0))
    elif height and not width:
        width = max(1, round(height * w0 / h0))
    return int(width or w0), int(height or h0)


@app.command()
def render(
    scene: Annotated[str, typer.Argument(help="Mitsuba XML file or built-in scene name")],
    output: Annotated[list[str], typer.Option("-o", "--output", help=".exr or .png (repeatable)")],
    method: Annotated[
        str | None,
        typer.Option(
            help="volume | surface | screen | sppm (default: a built-in's own; for a file, sppm, "
            "which renders everything in it)"
        ),
    ] = None,
    width: Annotated[
        int | None, typer.Option(help="image width, 1…16384 (alone: keeps the aspect ratio)")
    ] = None,
    height: Annotated[int | None, typer.Option(help="image height, 1…16384")] = None,
    spp: Annotated[
        int, typer.Option(help="camera samples per pixel (volume, surface; screen casts 1)")
    ] = 1,
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
        float | None, typer.Option(help="sppm: iterate for SECONDS (Ctrl-C stops early)")
    ] = None,
    preview_every: Annotated[
        float | None, typer.Option(help="sppm: rewrite the output every SECONDS while iterating")
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
    fidelity, ...; surface: photons, caustic_photons, k, max_radius, fg_rays, structure,
    max_depth, lookup, ...; screen: bounces, light_res, radius, splat, subsample, shadows,
    isg_samples, light_size, ...; a built-in scene's own parameters (photonmap scenes); an XML
    file's $name parameters (an unknown key lists them all). On a terminal the pipeline stages
    show as a progress bar."""
    from . import METHODS, PhotonmapError
    from .core import interrupt
    from .core.image import check_output
    from .core.memory import check_side
    from .core.progress import interactive, stage_progress
    from .core.scene_info import pick_method

    with _command(max_memory) as run:
        for out in output:
            check_output(out)
        check_side("--width", width)
        check_side("--height", height)
        if spp < 1:
            raise PhotonmapError(f"--spp must be at least 1, got {spp}")
        if method is not None and method not in METHODS:
            raise PhotonmapError(f"unknown --method {method!r}; available: {', '.join(METHODS)}")
        with console.status(f"loading {scene}") if interactive() else nullcontext():
            mi_scene, builtin, sets = _load(scene, _split_sets(set_ or []))
        interrupt.check()
        if method is None and builtin is not None:
            method = builtin.pipeline  # the method the built-in scene is made for
        elif method is None:
            method = pick_method(mi_scene)
            _say(f"method: {method} (renders everything in a Mitsuba file; choose with --method)")
        Pipeline, Params, _ = METHODS[method]
        _check_progressive(method, Pipeline.progressive, time, preview_every)
        if (workers is not None or ray_address is not None) and not Pipeline.progressive:
            raise PhotonmapError(
                "--workers/--ray distribute a progressive method's iterations (--method sppm); "
                "for many frames of any method use 'photonmap render-sequence'"
            )
        params = _typed_params(method, sets, builtin)
        fields = {f.name for f in dataclasses.fields(Params)}
        if "spp" in fields:
            params.setdefault("spp", spp)
        elif spp != 1:
            raise PhotonmapError(
                f"--spp does not apply to the {method} method: it casts one primary ray per "
                f"pixel centre (got --spp {spp})"
            )
        params.setdefault("seed", seed)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with console.status(f"loading {scene}") if interactive() else nullcontext():
                pipe = Pipeline(mi_scene if mi_scene is not None else scene, **params)
            interrupt.check()
            film = pipe.sensor.film().size()
            size = _image_size(width, height, film)
            pipe.check_memory(size=size)  # the method's own estimate, before any allocation
            if size != tuple(int(c) for c in film):
                pipe.set_camera(width=size[0], height=size[1])
            if workers is not None or ray_address is not None:
                xml = {k: v for k, v in _split_sets(set_ or []).items() if k not in sets}
                job = _job(scene, method, params, xml, size)
                image = _distribute(job, output, time, preview_every, workers, ray_address, run)
            elif pipe.progressive:
                image = _iterate(pipe, scene, output, time, "iterations" in params,
                                 preview_every, run)  # fmt: skip
            else:
                with stage_progress(pipe.stages, f"rendering {scene}", console=console) as bar:

                    def report(stage):
                        interrupt.check()  # Ctrl-C: stop between stages, write nothing
                        if bar is not None:
                            bar(stage)

                    image = pipe.render(progress=report)
        if not interrupt.requested():
            for w in {str(w.message): w for w in caught}.values():
                _say(f"warning: {w.message}")
        if image is not None:
            run.write(output, image)
        if timings and not interrupt.requested():  # a report the user asked for: on stdout
            out_console = Console()
            out_console.print(pipe.timer.table(f"{scene}: per-stage timings"))
            out_console.print(
                ", ".join(f"{k.replace('_', ' ')} {v:,}" for k, v in pipe.stats.items())
            )


def _check_seconds(name: str, value) -> None:
    """A time budget: a finite number of seconds > 0."""
    from .core.errors import ParameterError

    if not (value > 0 and math.isfinite(value)):
        raise ParameterError(f"{name} must be a finite number of seconds > 0, got {value}")


def _check_progressive(method, progressive: bool, seconds, preview_every) -> None:
    """``--time`` and ``--preview-every`` are a progressive method's (positive seconds)."""
    from .core.errors import ParameterError

    for name, value in (("--time", seconds), ("--preview-every", preview_every)):
        if value is None:
            continue
        if not progressive:
            raise ParameterError(
                f"{name} applies to a progressive method (--method sppm), not to {method}"
            )
        _check_seconds(name, value)


def _iterate(pipe, scene, outputs, seconds, iterations_set, preview_every, run):
    """Run the progressive pipeline for ``--time`` seconds (and/or ``--set iterations=N``) with
    a progress bar of iterations and the mean radius; ``--preview-every`` rewrites the outputs
    during the run; Ctrl-C ends it with the image of the whole iterations reached so far (None:
    not one finished)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from .core import interrupt
    from .core.image import write_image
    from .core.progress import interactive

    iterations = pipe.params.iterations if seconds is None or iterations_set else None
    total = float(seconds) if iterations is None else float(iterations)
    columns = (TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console, transient=True, disable=not interactive()) as bar:
        task = bar.add_task(f"{pipe.method} {scene}", total=total)

        def progress(i, elapsed, radius):
            done = elapsed if iterations is None else i
            bar.update(task, completed=done, description=f"{pipe.method}: {i} iterations, r {radius:.4g}")
            interrupt.check()  # Ctrl-C: stop after this whole iteration

        def preview(image):
            for out in outputs:
                write_image(out, image)

        try:
            interrupt.check()
            pipe.run(seconds, iterations, progress, preview, preview_every or float("inf"))
        except KeyboardInterrupt:
            run.note = f"the image of {_count(pipe.iterations, 'iteration')}"
            return pipe.image() if pipe.iterations else None
    _say(f"{pipe.method}: {pipe.iterations} iterations, mean radius {pipe.mean_radius:.4g}")
    return pipe.image()


def _job(scene, method, params, scene_params, size):
    from .cluster.job import SceneJob

    return SceneJob(scene, method, params, scene_params, *size)


def _distribute(job, outputs, seconds, preview_every, workers, address, run):
    """``render --workers/--ray``: memoryless iterations in blocks on Ray workers
    (:mod:`photonmap.cluster.progressive`), previews as blocks arrive, Ctrl-C keeps the merge
    (None: no block finished)."""
    from rich.progress import Progress

    from .cluster.progressive import render_progressive
    from .core.errors import PhotonmapError
    from .core.image import write_image
    from .core.progress import interactive

    iterations = job.params.get("iterations", 64 if seconds is None else None)

    def preview(image):
        for out in outputs:
            write_image(out, image)

    with Progress(console=console, transient=True, disable=not interactive()) as bar:
        task = bar.add_task("sppm on Ray workers", total=iterations or seconds)

        def on_block(done, info):
            bar.update(task, completed=done if iterations else min(seconds, info["seconds"]),
                       description=f"sppm: {done} iterations merged")

        res = render_progressive(
            job, iterations, seconds, workers, address, preview=preview,
            preview_every=preview_every or float("inf"), on_block=on_block,
        )  # fmt: skip
    if res.interrupted:
        run.note = f"the image of {_count(res.iterations, 'iteration')}"
        return None if res.sums is None else res.sums.image()
    for text in res.warnings():
        _say(f"warning: {text}")
    if res.sums is None:
        raise PhotonmapError("no block of iterations finished: no image")
    pids = {(b["node"], b["pid"]) for b in res.blocks}
    _say(f"sppm: {res.iterations} iterations in {len(res.blocks)} blocks on {len(pids)} "
         f"worker(s), {res.seconds:.1f} s")
    return res.sums.image()


@app.command("render-sequence")
def render_sequence(
    scene: Annotated[str, typer.Argument(help="Mitsuba XML file or built-in scene name")],
    frames: Annotated[str, typer.Option(help="frame spec (JSON): a camera or light path, or a "
                                              "list of parameter sets (docs/cluster.md)")],
    output: Annotated[
        list[str], typer.Option("-o", "--output", help="out/%04d.png or .exr (repeatable)")
    ],
    workers: Annotated[int | None, typer.Option(help="N local Ray workers (default: one per core)")]
    = None,
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
    from . import METHODS, PhotonmapError
    from .cluster.frames import load_frames
    from .cluster.job import check_frames
    from .cluster.sequence import check_outputs
    from .cluster.sequence import render_sequence as run_frames
    from .core import interrupt
    from .core.memory import check_side
    from .core.scene_info import pick_method

    with _command(max_memory) as run:
        check_outputs(output)
        check_side("--width", width)
        check_side("--height", height)
        spec = load_frames(frames)
        mi_scene, builtin, _ = _load(scene, {})
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
                _say(f"warning: {text}")
            seen |= set(info["warnings"])
            reran = info["recomputed"]
            reran = "" if reran is None else f", reran {len(reran)} stage(s)"
            _say(f"wrote {', '.join(paths)} (frame {index}, {done}/{len(todo)}; worker "
                 f"{info['node']}:{info['pid']}, {info['seconds']:.2f} s{reran})")


def _sequence_job(scene, method, spec, width, height):
    """The job (settings equal in every frame go to the pipeline's constructor) and the frames
    with only what changes between them."""
    import dataclasses as dc

    from .cluster.job import SceneJob

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


@app.command()
def reference(
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

    from . import mi
    from .core import interrupt
    from .core.errors import ParameterError, SceneError
    from .core.image import check_output
    from .core.memory import check_memory, check_side
    from .core.progress import interactive
    from .core.reference import BYTES_PER_SAMPLE, INTEGRATORS, render_reference
    from .scenes import load_scene

    with _command() as run:
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
            _check_seconds("--time", time)
        if not 0 <= seed < 2**32:
            raise ParameterError(f"--seed must lie in 0 … 2³²−1, got {seed}")
        sets = _split_sets(set_ or [])
        mi_scene, builtin, rest = _load(scene, sets)
        if builtin is not None:
            mi_scene, _ = load_scene(scene, **_typed_params(builtin.pipeline, rest, builtin))
        elif rest:
            raise ParameterError(
                f"unknown --set key(s) {', '.join(rest)}: not $parameters of {scene}"
            )
        if not mi_scene.sensors():
            raise ParameterError("the scene has no sensor (camera) to render from")
        interrupt.check()
        film = mi_scene.sensors()[0].film().size()
        size = _image_size(width, height, film)
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
                    mi_scene, spp, integrator, max_depth, time, seed, progress=passed,
                    source=scene if builtin is None else None,
                )
            except (RuntimeError, TypeError) as exc:  # Mitsuba refused the scene or its film
                raise SceneError(f"Mitsuba could not render {scene!r}: {_root_cause(exc)}") from None
        run.write(output, image)
        if not interrupt.requested():
            _say(
                f"{info['integrator']}: {info['spp']} spp in {info['seconds']:.1f} s "
                f"({info['passes']} pass{'es' if info['passes'] > 1 else ''})"
            )


@app.command()
def scenes():
    """List the built-in scenes."""
    from rich.table import Table

    from .scenes import SCENES

    with _command():
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
    from .core.image import compare as compare_images
    from .core.image import read_image

    with _command():
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
        typer.Option(help="volume | screen | surface (sppm where installed); default as render"),
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
    from . import METHODS, PhotonmapError
    from .core import interrupt
    from .core.errors import ParameterError
    from .core.memory import check_side
    from .core.scene_info import pick_method

    try:
        from .viewer import Viewer, page_url, serve
    except ImportError as exc:
        raise _error(PhotonmapError(
            f"the viewer needs the 'viewer' extra ({exc.name} is missing): "
            "pip install 'photonmap[viewer]'"
        )) from None
    with _command(max_memory) as run:
        check_side("--width", width)
        check_side("--height", height)
        if not 1 <= port <= 65535:
            raise ParameterError(f"--port must lie in 1…65535, got {port}")
        if method is not None and method not in METHODS:
            raise ParameterError(f"unknown --method {method!r}; available: {', '.join(METHODS)}")
        mi_scene, builtin, sets = _load(scene, _split_sets(set_ or []))
        if method is None:
            method = builtin.pipeline if builtin is not None else pick_method(mi_scene)
        params = _typed_params(method, sets, builtin)
        frames = None
        if volumes is not None:
            import numpy as np

            if not os.path.isfile(volumes):
                raise ParameterError(f"--volumes: no such file {volumes!r}")
            with np.load(volumes) as data:
                frames = {k: data[k] for k in data.files}
        size = None
        if width or height:
            from .scenes import load_scene

            probe = mi_scene if mi_scene is not None else load_scene(scene)[0]
            size = _image_size(width, height, probe.sensors()[0].film().size())
        interrupt.check()
        _say(f"loading {scene} ({method})")
        viewer = Viewer(mi_scene if mi_scene is not None else scene, method, params, size,
                        frames, name=scene)  # fmt: skip
        run.summary = "the viewer stopped, nothing written"
        try:
            interrupt.check()
            _say(f"photonmap view: {page_url(viewer, host, port)}  (Ctrl-C stops)")
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
    from .analysis.report import bandwidth_report

    with _command():
        mi_scene, builtin, sets = _load(scene, _split_sets(set_ or []))
        params = _typed_params("surface", sets, builtin)
        text = bandwidth_report(
            scene, builtin, order, cache, line, tile, sweep, plot, size, crop, params, structure
        )
        Console().print(text, markup=False, highlight=False, soft_wrap=True)
