"""Photon gathers per second of the hash grid and the kd-tree: the k-nearest-neighbour gathers of
photon mapping (Jensen 1996; Steinhurst 2007 §2.4, k = 100) on the two structures. 1M photons,
either uniform in the unit cube or on the walls of a Cornell box (floor, ceiling, back and side
walls, and the faces of two blocks; sampled by area); the gather points come from the same
distribution, in random order (Steinhurst's naive order) and sorted by grid cell (a spatially
coherent order). For k = 100, 50 and 10: exact k-nearest gathers per second of
:class:`photonmap.core.hashgrid.HashGrid` and :class:`photonmap.surface.kdtree.KDTree` (Dr.Jit
LLVM, all cores) and of ``scipy.spatial.cKDTree.query`` (``workers=2``) on the same points, after
one warm-up call (kernel compilation), median of ``--repeats`` timed calls.

Writes ``benchmarks/results/knn_throughput.json`` and ``.md`` (``--quick``: ``*_quick.*``, 100k
photons, 8192 gathers) and prints the markdown table.
``python benchmarks/knn_throughput.py [--quick] [--photons N] [--queries Q] [--repeats R]``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

import report
from photonmap.core.arrays import columns
from report import fmt, machine_info, markdown_table, publish, results_stem
from timing import summarize, timed

NAME = "knn_throughput"
KS = (100, 50, 10)


def uniform_points(count: int, rng: np.random.Generator) -> np.ndarray:
    return rng.random((count, 3)).astype(np.float32)


def cornell_points(count: int, rng: np.random.Generator) -> np.ndarray:
    """Points on the surfaces of a unit Cornell box (no front wall) and its two blocks."""
    quads = [  # corner, edge u, edge v
        ((0, 0, 0), (1, 0, 0), (0, 0, 1)),
        ((0, 1, 0), (1, 0, 0), (0, 0, 1)),
        ((0, 0, 0), (1, 0, 0), (0, 1, 0)),
        ((0, 0, 0), (0, 1, 0), (0, 0, 1)),
        ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    ]
    for x, z, w, h, d in ((0.15, 0.2, 0.3, 0.3, 0.3), (0.55, 0.45, 0.3, 0.6, 0.3)):
        quads += [
            ((x, h, z), (w, 0, 0), (0, 0, d)),
            ((x, 0, z), (w, 0, 0), (0, h, 0)),
            ((x, 0, z + d), (w, 0, 0), (0, h, 0)),
            ((x, 0, z), (0, h, 0), (0, 0, d)),
            ((x + w, 0, z), (0, h, 0), (0, 0, d)),
        ]
    corner, u, v = (np.array(c, np.float64) for c in zip(*quads, strict=True))
    area = np.linalg.norm(np.cross(u, v), axis=1)
    face = rng.choice(len(quads), count, p=area / area.sum())
    a, b = rng.random((2, count, 1))
    return (corner[face] + a * u[face] + b * v[face]).astype(np.float32)


POINT_SETS = {"uniform": uniform_points, "cornell": cornell_points}


def cell_order(queries: np.ndarray, cell: float) -> np.ndarray:
    """The permutation that sorts points by row-major grid cell (edge ``cell``)."""
    c = np.floor((queries - queries.min(axis=0)) / cell).astype(np.int64)
    return np.lexsort((c[:, 0], c[:, 1], c[:, 2]))


def rate(gather, count: int, repeats: int) -> dict:
    """Gathers per second (millions) of ``gather()``: one warm-up call, then ``repeats`` timed."""
    timed(gather)
    return summarize([count / timed(gather)[0] / 1e6 for _ in range(repeats)])


def main(argv=None) -> dict:
    parser = report.arguments(__doc__, "100k photons, 8192 gathers")
    parser.add_argument("--photons", type=int)
    parser.add_argument("--queries", type=int)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    photons = args.photons or (100_000 if args.quick else 1_000_000)
    queries = args.queries or (8192 if args.quick else 65536)

    import drjit as dr
    import mitsuba as mi
    from scipy.spatial import cKDTree

    import photonmap  # noqa: F401  (selects the variant)
    from photonmap.core.hashgrid import HashGrid
    from photonmap.surface.kdtree import KDTree

    def to_mi(a):
        return mi.Point3f(*columns(mi.Float, a))

    rows, results = [], []
    for name, generate in POINT_SETS.items():
        rng = np.random.default_rng(1)
        points, gathers = generate(photons, rng), generate(queries, rng)
        build = {}
        start = time.perf_counter()
        grid = HashGrid(to_mi(points))
        build["hash grid"] = time.perf_counter() - start
        start = time.perf_counter()
        tree = KDTree(to_mi(points))
        build["kd-tree"] = time.perf_counter() - start
        start = time.perf_counter()
        reference = cKDTree(points)
        build["cKDTree"] = time.perf_counter() - start
        sorted_gathers = gathers[cell_order(gathers, grid.cell_size)]
        for k in KS:
            entry = {"points": name, "k": k, "photons": photons, "queries": queries, "rates": {}}
            for label, structure in (("hash grid", grid), ("kd-tree", tree)):
                for order, g in (("random", gathers), ("cell order", sorted_gathers)):
                    batch = to_mi(g)
                    dr.eval(batch)

                    def gather(structure=structure, batch=batch, k=k):
                        found = structure.knn(batch, k=k)
                        dr.eval(found.index, found.count, found.radius2)

                    entry["rates"][f"{label}, {order}"] = rate(gather, queries, args.repeats)
            entry["rates"]["cKDTree, random"] = rate(
                lambda g=gathers, k=k, tree=reference: tree.query(g, k=k, workers=2),
                queries,
                args.repeats,
            )
            results.append(entry)
            r = {key: value["median"] for key, value in entry["rates"].items()}
            rows.append(
                [name, k]
                + [fmt(r[key], 3) for key in entry["rates"]]
                + [fmt(r["hash grid, random"] / r["cKDTree, random"], 1)]
            )
        results.append({"points": name, "build_s": build, "cell_size": grid.cell_size})

    headers = ["points", "k"] + [f"{key} (M/s)" for key in results[0]["rates"]] + ["hash / cKDTree"]
    table = markdown_table(headers, rows)
    machine = machine_info()
    builds = "; ".join(
        f"{r['points']}: " + ", ".join(f"{key} {s:.2f} s" for key, s in r["build_s"].items())
        for r in results
        if "build_s" in r
    )
    text = (
        f"# k-nearest photon gathers per second ({photons:,} photons, {queries:,} gathers)\n\n"
        f"{table}\n\nBuild times: {builds}.\n\n"
        f"Machine: {machine['cpu_model']}, {machine['cores']} cores, load "
        f"{machine.get('load_average')}; median of {args.repeats} runs after a warm-up.\n"
    )
    result = {"machine": machine, "photons": photons, "queries": queries, "results": results}
    return publish(results_stem(args.out_dir, NAME, args.quick), result, text)


if __name__ == "__main__":
    main(sys.argv[1:])
