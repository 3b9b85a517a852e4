"""The volume method (Sun et al. 2008) on box grids fitted to the fog against the cube grid.

``examples/glass_sphere_long_fog_box.xml``: a glass sphere in a 10 × 5 × 4 box of fog under a
sphere light outside the box, and the same box without the sphere. The volume method renders it
on the cube grid around the fog box (``grid_bbox`` = that cube: the layout before box grids, the
fog in a fifth of the voxels) and on the box grid fitted to the fog box, at the same voxel size
(``grid`` N for both) and at equal memory (the box grid's N chosen so that N_x·N_y·N_z ≈ N³).
Errors against ``volpath`` (the file's own integrator, ``--reference-spp``, cached in
``results/cache/``, not in git): the brightness ratio mean(ours)/mean(volpath), the relative RMSE
of 4×4-block means and per pixel (:func:`photonmap.compare`); render times are medians of
``--repeats`` full renders (every stage), with the load average (the machine is shared). Writes
``results/volume_box_grid.json`` and ``.md`` (``_quick`` with ``--quick``).

    PYTHONPATH=src .venv/bin/python benchmarks/volume_box_grid.py            # ~10 min
    PYTHONPATH=src .venv/bin/python benchmarks/volume_box_grid.py --quick    # ~1 min
"""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

import mitsuba as mi
import numpy as np

import report
from accuracy import cached_image
from photonmap import VolumePipeline
from photonmap.core.image import compare
from photonmap.core.reference import render_reference
from photonmap.volume.params import memory_estimate
from timing import summarize

NAME = "volume_box_grid"
SCENE = report.REPO / "examples" / "glass_sphere_long_fog_box.xml"
CUBE = ([-5.0] * 3, [5.0] * 3)  # the cube around the 10 × 5 × 4 fog box


def scene_text(ball: bool, width: int, height: int) -> str:
    """The example at ``width`` × ``height``, with or without its glass sphere."""
    text = SCENE.read_text().replace('value="320"', f'value="{width}"')
    text = text.replace('value="240"', f'value="{height}"')
    if not ball:
        start = text.index('<shape type="sphere" id="ball">')
        text = text[:start] + text[text.index("</shape>", start) + len("</shape>") :]
    return text


def reference(name: str, text: str, spp: int, cache: Path) -> np.ndarray:
    """The file's own integrator at ``spp`` (cached, keyed by the scene text)."""
    digest = hashlib.sha1(text.encode()).hexdigest()[:10]

    def render():
        image, info = render_reference(mi.load_string(text), spp=spp, seed=7)
        print(f"reference {name}: {info['seconds']:.1f} s", flush=True)
        return image

    return cached_image(cache / f"{NAME}_{name}_{spp}spp_{digest}.exr", render)


def equal_memory_grid(n: int, extent=(10.0, 5.0, 4.0)) -> int:
    """The box grid's N whose N_x·N_y·N_z is closest to N³ (cubic voxels fitted to ``extent``)."""
    fraction = np.prod(np.asarray(extent) / max(extent))
    return int(round(n / fraction ** (1 / 3)))


def run(args) -> dict:
    rows = []
    for name in ("fog", "ball"):
        text = scene_text(name == "ball", args.width, args.height)
        ref = reference(name, text, args.reference_spp, args.out_dir / "cache")
        layouts = [("cube", args.grid, CUBE), ("box", args.grid, None)]
        layouts.append(("box, equal memory", equal_memory_grid(args.grid), None))
        for layout, grid, bbox in layouts:
            times, image, pipe = [], None, None
            for _ in range(args.repeats):
                pipe = VolumePipeline(
                    mi.load_string(text), grid=grid, grid_bbox=bbox, photons=args.photons,
                    phase_k=0.0, table=0.0, spp=4,
                )  # fmt: skip
                start = time.perf_counter()
                image = np.asarray(pipe.render())
                times.append(time.perf_counter() - start)
            errors = compare(image, ref)
            box = pipe.world.box
            row = {
                "scene": name,
                "layout": layout,
                "grid": grid,
                "dims": list(box.dims),
                "voxels": box.voxels,
                "memory_bytes": memory_estimate(box.dims, 1, args.photons)[0],
                "ratio": float(image.mean() / ref.mean()),
                "block_rel_rmse": errors["block_rel_rmse"],
                "rel_rmse": errors["rel_rmse"],
                "render_s": summarize(times),
                "loadavg": os.getloadavg(),
            }
            rows.append(row)
            print(
                f"{name:5s} {layout:18s} {'×'.join(map(str, box.dims)):12s} ratio "
                f"{row['ratio']:.4f}  block {row['block_rel_rmse']:.4f}  pixel "
                f"{row['rel_rmse']:.4f}  {row['render_s']['median']:.2f} s",
                flush=True,
            )
    return {
        "benchmark": NAME,
        "machine": report.machine_info(),
        "git": report.git_revision(),
        "config": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "rows": rows,
    }


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "grid 24, 48×36, 256-spp reference")
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--photons", type=int, default=2**18)
    parser.add_argument("--width", type=int, default=96)
    parser.add_argument("--height", type=int, default=72)
    parser.add_argument("--reference-spp", type=int, default=8192)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    if args.quick:
        args.grid, args.photons, args.width, args.height = 24, 2**14, 48, 36
        args.reference_spp, args.repeats = 256, 1
    result = run(args)
    table = report.records_table(
        result["rows"],
        [
            ("scene", "scene", None),
            ("layout", "layout", None),
            ("voxels", lambda r: "×".join(map(str, r["dims"])), None),
            ("ratio", "ratio", 4),
            ("block rel. RMSE", "block_rel_rmse", 4),
            ("pixel rel. RMSE", "rel_rmse", 4),
            ("s", lambda r: r["render_s"]["median"], 2),
        ],
    )
    return report.publish(report.results_stem(args.out_dir, NAME, args.quick), result, table + "\n")


if __name__ == "__main__":
    main()
