"""Yao 2011 Tables 1 and 2 on this CPU: the ``screen`` pipeline's frame rate.

Reproduces the rows of the thesis's Table 1 (per scene: subsampling, bounces, photons, soft and
hard shadows) and Table 2 (quad vs icosahedron splats) that our built-in scenes cover, at the
thesis's 1024 × 768, with the thesis's GTX 480 numbers beside ours. The Happy Buddha and Chinese
dragon rows use ``cornell_mesh`` (a diffuse watertight torus-knot mesh) at the models' triangle
counts; the glass sphere row uses ``cornell_glass_sphere``. Photons = 100² × bounces; radius
0.045 × scene diagonal; ISG samples "4+5".

A *frame* is a full frame: every stage reruns except the fixed random map (both camera and light
moved, as in the thesis's dynamic scenes). Each configuration runs ``--warmup`` frames (kernel
compilation), then ``--frames`` timed frames; fps = 1000 / median frame ms. The per-stage ms are
medians over the timed frames. The headline setting is then timed again over 11 frames, and also
as a camera-move frame (photons kept) and an image-space-only frame (radius change). The machine
may be shared: the load average is recorded with every row.

Writes ``results/screen_table1.json`` (top-level ``headline.fps_cornell_1024x768``: Cornell box,
1024 × 768, 2 bounces, 20k photons, soft shadows, 8 × 8 subsampling, quads) and ``.md``.

    .venv/bin/python benchmarks/screen_table1.py [--quick] [--frames 5] [--warmup 2]
    .venv/bin/python benchmarks/screen_table1.py --images   # only the docs/screen_*.png figures
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path

import photonmap  # noqa: F401 - selects the Mitsuba variant
import report
import timing
from photonmap import ScreenPipeline
from photonmap.core.timer import StageTimer


class CPUStageTimer(StageTimer):
    """The stage timer, also recording each stage's process CPU ms (all threads) in ``cpu``:
    less sensitive than wall time to other work on a shared machine."""

    def __init__(self):
        super().__init__()
        self.cpu: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str):
        timing.sync()
        start = time.process_time()
        with super().__call__(stage):
            yield
        timing.sync()
        self.cpu[stage] = self.cpu.get(stage, 0.0) + 1e3 * (time.process_time() - start)

    def reset(self):
        super().reset()
        self.cpu = {}


NAME = "screen_table1"
W, H = 1024, 768
# (table, scene label, scene, scene params, subsample, bounces, thesis soft, thesis hard,
#  splat); Table 2 rows come in quad/icosahedron pairs
ROWS = [
    ("1", "Cornell box", "cornell_ispm", {}, 8, 1, 32, 107, "quad"),
    ("1", "Cornell box", "cornell_ispm", {}, 8, 2, 27, 85, "quad"),
    ("1", "Happy buddha (mesh 50,020)", "cornell_mesh", {"triangles": 50020}, 4, 1, 20, 40, "quad"),
    ("1", "Chinese dragon (mesh 26,082)", "cornell_mesh", {"triangles": 26082}, 4, 3, 23, 35,
     "quad"),
    ("1", "Glass sphere", "cornell_glass_sphere", {}, 4, 2, 34, 70, "quad"),
    ("sub", "Cornell box", "cornell_ispm", {}, 4, 2, None, None, "quad"),
    ("sub", "Cornell box", "cornell_ispm", {}, 2, 2, None, None, "quad"),
    ("2", "Cornell box", "cornell_ispm", {}, 8, 2, 22.0, 61.0, "quad"),
    ("2", "Cornell box", "cornell_ispm", {}, 8, 2, 21.0, 60.7, "icosahedron"),
    ("2", "Cornell box", "cornell_ispm", {}, 8, 3, 23.0, 61.4, "quad"),
    ("2", "Cornell box", "cornell_ispm", {}, 8, 3, 20.4, 54.0, "icosahedron"),
    ("2", "Happy buddha (mesh 50,020)", "cornell_mesh", {"triangles": 50020}, 8, 3, 11.7, 42.1,
     "quad"),
    ("2", "Happy buddha (mesh 50,020)", "cornell_mesh", {"triangles": 50020}, 8, 3, 11.3, 37.2,
     "icosahedron"),
    ("2", "Chinese dragon (mesh 26,082)", "cornell_mesh", {"triangles": 26082}, 8, 3, 21.2, 56.3,
     "quad"),
    ("2", "Chinese dragon (mesh 26,082)", "cornell_mesh", {"triangles": 26082}, 8, 3, 20.5, 50.9,
     "icosahedron"),
]  # fmt: skip
HEADLINE_FRAMES = 11


def time_frames(pipe: ScreenPipeline, frames: int, warmup: int, prepare) -> dict:
    """Render ``warmup`` + ``frames`` frames, calling ``prepare(pipe, i)`` before each; the wall
    ms, the process CPU ms (all threads; on a shared machine CPU ms / cores is what the frame
    would take with both cores to itself, if it scaled perfectly) and the per-stage ms of the
    timed ones."""
    totals, cpu, stages, stages_cpu = [], [], [], []
    if not isinstance(pipe.timer, CPUStageTimer):
        pipe.timer = CPUStageTimer()
    for i in range(warmup + frames):
        prepare(pipe, i)
        timing.sync()
        start, start_cpu = time.perf_counter(), time.process_time()
        pipe.render()
        timing.sync()
        if i >= warmup:
            totals.append(1e3 * (time.perf_counter() - start))
            cpu.append(1e3 * (time.process_time() - start_cpu))
            stages.append(dict(pipe.timer.ms))
            stages_cpu.append(dict(pipe.timer.cpu))
    ms = timing.summarize(totals)
    return {
        "frame_ms": ms,
        "fps": 1e3 / ms["median"],
        "cpu_ms": timing.summarize(cpu),
        "stages_ms": timing.stage_medians(stages),
        "stages_cpu_ms": timing.stage_medians(stages_cpu),
    }


def full_frame(pipe, i):
    pipe.invalidate()


def camera_move(pipe, i):
    # every frame moves the camera (frame 0 too: the headline frames leave it at x = 0.278)
    pipe.set_camera(origin=(0.278 + 0.01 * (i % 3 + 1), 0.273, -0.8))


def radius_change(pipe, i):
    pipe.set_params(radius=(0.045 + 0.001 * (i % 2 + 1)) * pipe.diagonal)  # never the headline's


def write_images(folder: Path = report.REPO / "docs", width: int = 512, height: int = 384):
    """The README figures: side-by-side comparisons on ``cornell_ispm`` (2 bounces, 40k photons
    per bounce, 4 × 4 subsampling unless varied) and the glass sphere's caustic."""
    import numpy as np

    from photonmap.core.image import write_image

    base = {"width": width, "height": height, "photons": 200**2, "subsample": 4}
    pipe = ScreenPipeline("cornell_ispm", **base)

    def shot(**params):
        pipe.set_params(**{"shadows": "soft", "bounces": 2, "splat": "quad", **params})
        return np.array(pipe.render())

    def pair(a, b):
        gap = np.ones((height, 4, 3), np.float32)
        return np.concatenate([a, gap, b], axis=1)

    write_image(str(folder / "screen_cornell.png"), shot())
    write_image(str(folder / "screen_shadows.png"), pair(shot(shadows="hard"), shot()))
    write_image(str(folder / "screen_bounces.png"), pair(shot(bounces=1), shot()))
    write_image(str(folder / "screen_splats.png"), pair(shot(), shot(splat="icosahedron")))
    glass = ScreenPipeline("cornell_glass_sphere", **base)
    write_image(str(folder / "screen_glass_sphere.png"), np.array(glass.render()))


def main(argv=None) -> dict:
    ap = report.arguments(__doc__, "headline rows only, 3 frames")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--images", action="store_true", help="write the docs/ figures and stop")
    ap.add_argument("--width", type=int, default=W)
    ap.add_argument("--height", type=int, default=H)
    args = ap.parse_args(argv)
    if args.images:
        write_images()
        return {}
    rows = ROWS if not args.quick else [ROWS[1], ROWS[8]]
    frames = min(args.frames, 3) if args.quick else args.frames
    results, pipes = [], {}
    for table, label, scene, scene_params, s, bounces, t_soft, t_hard, splat in rows:
        key = (scene, tuple(sorted(scene_params.items())))
        if key not in pipes:
            pipes[key] = ScreenPipeline(scene, width=args.width, height=args.height, **scene_params)
        pipe = pipes[key]
        row = {"table": table, "scene": label, "builtin": scene, "triangles": _triangles(pipe),
               "subsample": s, "bounces": bounces, "photons": 100**2 * bounces, "splat": splat,
               "thesis_fps_soft": t_soft, "thesis_fps_hard": t_hard}  # fmt: skip
        row["load_average_before"] = report.load_average()
        for shadows in ("soft", "hard"):
            pipe.set_params(subsample=s, bounces=bounces, splat=splat, shadows=shadows,
                            photons=100**2, radius=0)  # fmt: skip
            row[shadows] = time_frames(pipe, frames, args.warmup, full_frame)
            print(f"{label:30s} s={s} B={bounces} {splat:11s} {shadows}: "
                  f"{row[shadows]['fps']:.2f} fps", flush=True)  # fmt: skip
        results.append(row)
    # the headline: a dedicated run with more frames (the machine may be shared: the load
    # average is recorded beside every measurement)
    pipe = pipes[("cornell_ispm", ())]
    pipe.set_params(subsample=8, bounces=2, splat="quad", shadows="soft", radius=0,
                    photons=100**2)  # fmt: skip
    pipe.set_camera(origin=(0.278, 0.273, -0.8))
    load = report.load_average()
    head_frames = HEADLINE_FRAMES if not args.quick else frames
    head = time_frames(pipe, head_frames, args.warmup, full_frame)
    more = frames if args.quick else max(frames, 5)
    camera = time_frames(pipe, more, args.warmup, camera_move)
    image_space = time_frames(pipe, more, args.warmup, radius_change)
    headline = {
        "fps_cornell_1024x768": head["fps"],
        "setting": "cornell_ispm, 1024x768, 2 bounces, 20k photons, soft shadows (4+5), 8x8 "
        "subsampling, quads, full frame (all stages but the random map)",
        "frame_ms_median": head["frame_ms"]["median"],
        "frame_ms": head["frame_ms"],
        "cpu_ms_median": head["cpu_ms"]["median"],
        "frames_timed": len(head["frame_ms"]["samples"]),
        "stages_ms": head["stages_ms"],
        "stages_cpu_ms": head["stages_cpu_ms"],
        "load_average_before": load,
        "load_average_after": report.load_average(),
        "fps_camera_move": camera["fps"],
        "camera_move_stages_ms": camera["stages_ms"],
        "fps_image_space_change": image_space["fps"],
        "target_fps": 4.0,
        "thesis_fps_gtx480": 27,
    }
    data = {"machine": report.machine_info(), "resolution": [args.width, args.height],
            "headline": headline,
            "rows": results, "frames": frames, "warmup": args.warmup}  # fmt: skip
    return report.publish(report.results_stem(args.out_dir, NAME, args.quick), data, markdown(data))


def _triangles(pipe) -> int:
    return int(sum(s.face_count() for s in pipe.scene.shapes() if hasattr(s, "face_count")))


def markdown(data: dict) -> str:
    h = data["headline"]
    stages = sorted({k for r in data["rows"] for k in r["soft"]["stages_ms"]},
                    key=list(data["rows"][0]["soft"]["stages_ms"]).index)  # fmt: skip
    head = ["table", "scene", "tris", "sub", "B", "photons", "splat", "fps soft (hard)",
            "thesis GTX 480"] + [f"{s} ms" for s in stages]  # fmt: skip
    rows = []
    for r in data["rows"]:
        thesis = (f"{r['thesis_fps_soft']} ({r['thesis_fps_hard']})"
                  if r["thesis_fps_soft"] is not None else "–")  # fmt: skip
        rows.append([r["table"], r["scene"], f"{r['triangles']:,}", f"{r['subsample']}x"
                     f"{r['subsample']}", r["bounces"], f"{r['photons'] // 1000}k", r["splat"],
                     f"{r['soft']['fps']:.1f} ({r['hard']['fps']:.1f})", thesis]
                    + [report.fmt(r["soft"]["stages_ms"].get(s)) for s in stages])  # fmt: skip
    m = data["machine"]
    return (
        f"# Yao 2011 Tables 1 and 2 on {m['cpu_model']} ({m['cores_usable']} cores), "
        f"{data['resolution'][0]}x{data['resolution'][1]}\n\n"
        f"**Headline** ({h['setting']}): **{h['fps_cornell_1024x768']:.2f} fps** "
        f"({h['frame_ms_median']:.0f} ms wall, median of {h['frames_timed']} frames; "
        f"{h['cpu_ms_median']:.0f} ms of process CPU time per frame; target ≥ 4; "
        f"thesis 27 on a GTX 480). Camera move (photons kept): {h['fps_camera_move']:.2f} fps; "
        f"image-space change only (radius): {h['fps_image_space_change']:.2f} fps.\n\n"
        "Per-stage wall ms (CPU ms) of the headline frame: "
        + ", ".join(
            f"{k} {v:.1f} ({h['stages_cpu_ms'].get(k, 0):.1f})" for k, v in h["stages_ms"].items()
        )
        + f"\n\nfps = 1000 / median full-frame ms ({data['frames']} frames after "
        f"{data['warmup']} warm-up) per row, rows in the order run; stage columns: soft-shadow "
        "frames. The machine is shared with other work: "
        f"load average (1, 5, 15 min) {h['load_average_before']} before the headline run, "
        f"{h['load_average_after']} after (2 cores).\n\n"
        + report.markdown_table(head, rows, "lllrrrlrr" + "r" * len(stages))
        + "\n"
    )


if __name__ == "__main__":
    main()
