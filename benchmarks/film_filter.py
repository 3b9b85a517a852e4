"""The film's reconstruction filter: every method on ``mi.cornell_box()`` unchanged (256², Mitsuba's
default gaussian filter, path max_depth 8) against Mitsuba's ``path`` per pixel.

References: ``path`` at 2048 spp on the gaussian film and on the same film with a box filter
(cached in ``results/cache/``, not in git); a second gaussian reference with another seed gives
the references' own noise. Each method renders the gaussian film (the filter honoured:
importance-sampled eye rays, or the filtered image of the pixel centres) and the box film. The
box film's image is exactly what the methods computed for the gaussian film before they read the
film's filter (the box filter's rays are unchanged bit for bit), so "ignoring the filter" is the
box image against the gaussian reference; "box film" is that image against the box reference,
the method's own floor. Errors: relative RMSE per pixel and of 4×4-pixel block means
(:func:`photonmap.core.image.compare`).

Writes ``results/film_filter.json`` and ``.md`` (``_quick`` with ``--quick``).

    .venv/bin/python benchmarks/film_filter.py [--quick]
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np

import report
from accuracy import cached_image
from photonmap import METHODS
from photonmap.core.image import compare
from photonmap.core.reference import render_reference
from timing import timed

NAME = "film_filter"
RUNS = [
    ("surface", {"spp": 4}),
    ("surface", {"spp": 16}),
    ("sppm", {"iterations": 64}),
    ("sppm", {"iterations": 256}),
    ("screen", {}),
]


def scene(rfilter: str, size: int) -> mi.Scene:
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=size, height=size)
    if rfilter != "gaussian":
        d["sensor"]["film"]["rfilter"] = {"type": rfilter}
    return mi.load_dict(d)


def reference(rfilter: str, size: int, spp: int, seed: int, cache: Path) -> np.ndarray:
    """``path`` at ``spp`` on the ``rfilter`` film (cached)."""
    return cached_image(
        cache / f"film_filter_{rfilter}_{size}_{spp}_{seed}.npy",
        lambda: render_reference(scene(rfilter, size), spp=spp, seed=seed)[0],
    )


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "64², 256 spp references, 3 runs")
    args = parser.parse_args(argv)
    size, spp = (64, 256) if args.quick else (256, 2048)
    runs = RUNS[::2] if args.quick else RUNS
    cache = args.out_dir / "cache"
    ref = {f: reference(f, size, spp, 0, cache) for f in ("gaussian", "box")}
    floor = compare(reference("gaussian", size, spp, 1, cache), ref["gaussian"])
    rows, records = [], []
    for method, params in runs:
        images, seconds = {}, {}
        for rfilter in ("gaussian", "box"):
            pipe = METHODS[method].pipeline(scene(rfilter, size), **params)
            seconds[rfilter], image = timed(pipe.render)
            images[rfilter] = np.array(image, dtype=np.float64)
        honoured = compare(images["gaussian"], ref["gaussian"])
        ignored = compare(images["box"], ref["gaussian"])
        box = compare(images["box"], ref["box"])
        records.append({"method": method, "params": params, "seconds": seconds,
                        "ignoring_the_filter": ignored, "filter_honoured": honoured,
                        "box_film": box})  # fmt: skip
        setting = ", ".join(f"{k} {v}" for k, v in params.items()) or "defaults"
        rows.append([
            method, setting,
            f"{ignored['rel_rmse']:.3f} / {ignored['block_rel_rmse']:.3f}",
            f"{honoured['rel_rmse']:.3f} / {honoured['block_rel_rmse']:.3f}",
            f"{box['rel_rmse']:.3f} / {box['block_rel_rmse']:.3f}",
            f"{seconds['gaussian']:.1f} / {seconds['box']:.1f}",
        ])  # fmt: skip
        print(rows[-1], flush=True)
    headers = ["method", "settings", "ignoring the filter", "filter honoured", "box film",
               "seconds (gaussian / box)"]  # fmt: skip
    machine = report.machine_info()
    text = (
        f"# The film's reconstruction filter: mi.cornell_box() ({size}², gaussian) vs path\n\n"
        f"Relative RMSE per pixel / of 4×4 block means, against `path` at {spp} spp on the same "
        "film. *ignoring the filter*: the method's image as before it read the film's filter "
        "(= its box-film image) against the gaussian reference; *filter honoured*: the gaussian "
        "film's image; *box film*: the box-film image against the box reference (the method's "
        f"own floor). The references' own noise: {floor['rel_rmse']:.3f} / "
        f"{floor['block_rel_rmse']:.3f}.\n\n"
        + report.markdown_table(headers, rows)
        + f"\n\nMachine: {machine.get('cpu_model', '')}, load average "
        f"{machine.get('load_average')} (shared cores: times vary by up to ~4x).\n"
    )
    result = {"machine": machine, "git": report.git_revision(), "size": size,
              "reference_spp": spp, "reference_noise": floor, "runs": records}  # fmt: skip
    return report.publish(report.results_stem(args.out_dir, NAME, args.quick), result, text)


if __name__ == "__main__":
    main()
