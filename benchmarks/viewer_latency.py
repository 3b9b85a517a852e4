"""Update latency of ``photonmap view``: from a ``POST /api/update`` to
its new frame (``GET /api/frame.png`` returning the full-size PNG of that update), for a light
move and a camera move, on ``glass_sphere_fog`` (volume method) and ``cornell_ispm`` (screen
method) at their default sizes and settings, and on ``glass_sphere_fog`` with 512² photons.

The viewer is served by uvicorn on 127.0.0.1 and driven over real HTTP (httpx). Each move
alternates between two positions, so every update needs new work (the stage cache keeps one key
per stage). Per update it records the latency to the PNG, the latency to the frame's arrival on
the WebSocket stream (what the page waits for: a JPEG), the render thread's own time (applying
the change through the pipeline's setters, rendering, sRGB conversion and JPEG encoding) and
the stages that reran. A light drag is measured too: light moves sent as ``"preview": true``
updates at a new light position each (from the first position to the second, as a drag
moves it), timed to the first preview frame on the stream (¼ size, a reduced photon budget: the
frame's ``reduced``) and to the full-size frame that follows once updates stop (the viewer's
settle time, 0.25 s, included).
For scale, the same run times one frame of Mitsuba's own integrator on the same scene at 1 spp
(``volpath`` with fog, else ``path``): the ratio says how many such frames one update costs.

    .venv/bin/python benchmarks/viewer_latency.py [--runs 7] [--quick]

Writes ``results/viewer_latency.json`` and ``.md`` (``_quick`` with ``--quick``); the machine is
shared, so the load average is recorded and medians are reported.
"""

from __future__ import annotations

import json
import time

import httpx
from websockets.sync.client import connect

import photonmap
import report
import timing
from photonmap.core.reference import render_reference
from photonmap.scenes import load_scene
from photonmap.viewer import Background, Viewer

NAME = "viewer_latency"
SPHERE = ([0.3, 3.0, 0.5], [0.7, 3.0, 0.5]), ([1.8, 1.7, 2.2], [1.2, 1.8, 2.6])
CASES = {  # name → (scene, method, overrides, two light positions, two camera origins)
    "glass_sphere_fog": ("glass_sphere_fog", "volume", {}, *SPHERE),
    "cornell_ispm": ("cornell_ispm", "screen", {}, ([0.2, 0.53, 0.28], [0.35, 0.53, 0.28]),
                     ([0.2, 0.3, -0.8], [0.35, 0.25, -0.8])),
    # a smaller photon budget: 512² photons instead of the default 1024²
    "glass_sphere_fog, 512² photons": ("glass_sphere_fog", "volume", {"photons": 512**2},
                                        *SPHERE),
}  # fmt: skip


def streamed(ws, version: int, preview: bool = False) -> dict:
    """Read the frame stream up to the full-size (``preview``: the preview) frame of
    ``version``; returns its message."""
    while True:
        message = json.loads(ws.recv())
        if message["type"] == "error":
            raise RuntimeError(message["message"])
        ws.recv()  # the image
        if message["version"] >= version and message["preview"] == preview:
            return message


def measure(http: httpx.Client, ws, base: str, updates: list[dict]) -> list[dict]:
    out = []
    for update in updates:
        start = time.perf_counter()
        reply = http.post(base + "/api/update", json=update)
        reply.raise_for_status()
        meta = streamed(ws, reply.json()["version"])
        stream = 1e3 * (time.perf_counter() - start)
        frame = http.get(base + "/api/frame.png")
        frame.raise_for_status()
        latency = 1e3 * (time.perf_counter() - start)
        assert int(frame.headers["X-Frame-Version"]) == meta["version"] >= reply.json()["version"]
        out.append({"latency_ms": latency, "stream_ms": stream, "frame_ms": meta["ms"],
                    "apply_ms": meta["apply_ms"],
                    "render_ms": meta["render_ms"], "encode_ms": meta["encode_ms"],
                    "png_bytes": len(frame.content), "recomputed": meta["recomputed"],
                    "timings": meta["timings"]})  # fmt: skip
    return out


def step(a: list[float], b: list[float], t: float) -> list[float]:
    """The point a fraction ``t`` of the way from ``a`` to ``b``."""
    return [x + t * (y - x) for x, y in zip(a, b, strict=True)]


def measure_drag(http: httpx.Client, ws, base: str, updates: list[dict]) -> list[dict]:
    """Each update sent as a drag's (``"preview": true``): the times to its preview frame and to
    the full-size frame after it."""
    out = []
    for update in updates:
        start = time.perf_counter()
        reply = http.post(base + "/api/update", json={**update, "preview": True})
        reply.raise_for_status()
        version = reply.json()["version"]
        preview = streamed(ws, version, preview=True)
        preview_ms = 1e3 * (time.perf_counter() - start)
        full = streamed(ws, version)
        out.append({"preview_ms": preview_ms, "full_ms": 1e3 * (time.perf_counter() - start),
                    "preview_frame_ms": preview["ms"], "full_frame_ms": full["ms"],
                    "reduced": preview["reduced"], "size": [preview["width"], preview["height"]],
                    "recomputed": preview["recomputed"],
                    "timings": preview["timings"]})  # fmt: skip
    return out


def mitsuba_frame_ms(scene: str, runs: int) -> dict:
    """One 1-spp frame of Mitsuba's own integrator on the same scene (after a warm-up)."""
    mi_scene, _ = load_scene(scene)
    samples = []
    for i in range(runs + 1):
        start = time.perf_counter()
        render_reference(mi_scene, spp=1, seed=i)
        samples.append(1e3 * (time.perf_counter() - start))
    return timing.summarize(samples[1:])


def run_case(name: str, runs: int) -> dict:
    scene, method, overrides, lights, origins = CASES[name]
    background = Background(Viewer(scene, method, dict(overrides)))
    base = background.url.rstrip("/")
    try:
        with httpx.Client(timeout=600, headers=background.headers) as http:  # the token
            start = time.perf_counter()
            first = http.get(base + "/api/frame.png")
            first.raise_for_status()
            first_ms = 1e3 * (time.perf_counter() - start)
            state = http.get(base + "/api/state").json()
            stream = f"{base.replace('http', 'ws')}/api/stream?token={background.viewer.token}"
            with connect(stream, max_size=None) as ws:
                streamed(ws, 0)
                light = measure(http, ws, base, [
                    {"lights": [{"position": lights[i % 2]}]} for i in range(runs + 1)
                ])[1:]  # fmt: skip
                drag = measure_drag(http, ws, base, [  # a new position each time, as a drag
                    {"lights": [{"position": step(*lights, i / runs)}]} for i in range(runs + 1)
                ])[1:]  # fmt: skip
                camera = measure(http, ws, base, [
                    {"camera": {"origin": origins[i % 2]}} for i in range(runs + 1)
                ])[1:]  # fmt: skip
    finally:
        background.stop()
    size = (state["camera"]["width"], state["camera"]["height"])
    mitsuba = mitsuba_frame_ms(scene, max(2, runs // 2))
    result = {"method": method, "size": size, "params": state["params"], "first_frame_ms": first_ms,
              "mitsuba_1spp_frame_ms": mitsuba}  # fmt: skip
    for name, samples in (("light", light), ("camera", camera)):
        result[name] = {
            "latency_ms": timing.summarize([s["latency_ms"] for s in samples]),
            **{
                key: timing.summarize([s[key] for s in samples])
                for key in ("stream_ms", "frame_ms", "apply_ms", "render_ms", "encode_ms")
            },
            "stages_ms": timing.stage_medians([s["timings"] for s in samples]),
            "recomputed": samples[-1]["recomputed"],
            "png_bytes": samples[-1]["png_bytes"],
            "latency_over_mitsuba_1spp": timing.median(s["latency_ms"] for s in samples)
            / mitsuba["median"],
        }
    result["light_drag"] = {
        **{key: timing.summarize([s[key] for s in drag])
           for key in ("preview_ms", "full_ms", "preview_frame_ms", "full_frame_ms")},
        "preview_size": drag[-1]["size"], "reduced": drag[-1]["reduced"],
        "preview_stages_ms": timing.stage_medians([s["timings"] for s in drag]),
        "preview_recomputed": drag[-1]["recomputed"],
    }  # fmt: skip
    return result


def drag_cells(drag: dict) -> list[str]:
    """The light drag's table cells: to the preview frame, to the full frame, the budget."""
    budget = ", ".join(f"{k} {v:,}" for k, v in drag["reduced"].items()) or "full"
    return [report.fmt(drag["preview_ms"]["median"]), report.fmt(drag["full_ms"]["median"]),
            f"{budget} at {drag['preview_size'][0]}×{drag['preview_size'][1]}"]  # fmt: skip


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "3 runs")
    parser.add_argument("--runs", type=int, default=7, help="timed updates per kind of move")
    args = parser.parse_args(argv)
    runs = 3 if args.quick else args.runs
    results = {"machine": report.machine_info(), "runs": runs,
               "cases": {name: run_case(name, runs) for name in CASES}}  # fmt: skip
    results["machine"]["load_average_end"] = report.load_average()
    rows = []
    for scene, r in results["cases"].items():
        for move in ("light", "camera"):
            m = r[move]
            rows.append([
                scene, r["method"], f"{r['size'][0]}×{r['size'][1]}", move,
                report.fmt(m["latency_ms"]["median"]), report.fmt(m["stream_ms"]["median"]),
                *(drag_cells(r["light_drag"]) if move == "light" else ["–"] * 3),
                report.fmt(m["apply_ms"]["median"]),
                report.fmt(m["render_ms"]["median"]), report.fmt(m["encode_ms"]["median"]),
                report.fmt(r["mitsuba_1spp_frame_ms"]["median"]),
                report.fmt(m["latency_over_mitsuba_1spp"], 2), ", ".join(m["recomputed"]),
            ])  # fmt: skip
    table = report.markdown_table(
        ["scene", "method", "size", "move", "latency ms (PNG)", "stream ms",
         "drag: preview ms", "drag: full ms", "preview budget", "apply ms",
         "render ms", "encode ms", "Mitsuba 1 spp ms", "latency / Mitsuba frame",
         "stages rerun"], rows, "llllrrrrlrrrrrl",
    )  # fmt: skip
    load = results["machine"].get("load_average")
    text = (f"# photonmap view: update latency (POST /api/update → new frame)\n\n{table}\n\n"
            f"Medians of {runs} updates each; load average {load} at the start, "
            f"{results['machine']['load_average_end']} at the end.\n")  # fmt: skip
    return report.publish(report.results_stem(args.out_dir, NAME, args.quick), results, text)


if __name__ == "__main__":
    photonmap.set_device("cpu")
    main()
