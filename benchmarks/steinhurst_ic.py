"""Steinhurst 2007's irradiance caching (Ch. 5, Table 5.1, Fig 5.5) measured on our renders, for
``steinhurst_ic_cis.py``: the bare Cornell box and the box with two and with six "bushes"
(clusters of small diffuse cubes, Fig 5.5's role), full final gather against Ward's whole-image
cache and the tiled cache (oracles O22–O24): hit rate R_IC, gathers saved, photon-map gathers
per image, image error and the tile-seam ratio; the final gather's time with per-ray k-NN
gathers; R_avg precomputed at photons against cast at each hit.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from accuracy import masked_errors
from photonmap.core.camera import pixel_rays
from photonmap.scenes import cornell
from photonmap.scenes.meshes import to_mitsuba_mesh
from photonmap.surface.irradiance_cache import (
    RAVG_RAYS,
    TILE,
    cache_order,
    harmonic_mean_distance,
    plan_cache,
    precompute_ravg,
    ravg_limits,
)
from photonmap.surface.pipeline import SurfacePipeline
from report import records_table

IC_COLUMNS = [
    ("scene", "scene", None),
    ("cache", "mode", None),
    ("ε_max", "ic_error", 3),
    ("R_IC", "hit_rate", 3),
    ("gathers saved", "gathers_saved", 3),
    ("photon gathers vs none", "gathers_vs_none", 3),
    ("rel. RMSE", "rel_rmse", 4),
    ("seam ratio", "seam_ratio", 3),
    ("FG ms", "final_gather_ms", 0),
]
RAVG_COLUMNS = [
    ("scene", "scene", None),
    ("median R_pre/R_direct", "median_ratio_precomputed_over_direct", 3),
    ("median abs(log ratio)", "median_abs_log_ratio", 3),
    ("R_IC pre", "hit_rate_precomputed", 3),
    ("R_IC direct", "hit_rate_direct", 3),
    ("same decision", "same_decision", 3),
]


def first_hits(pipe: SurfacePipeline):
    """Eye-ray hits through the pixel centres (masks, the R_avg comparison)."""
    w, h = (int(c) for c in pipe.sensor.film().crop_size())
    n = w * h
    ray, _ = pixel_rays(pipe.sensor, dr.arange(mi.UInt32, n), mi.Point2f(0.5, 0.5))
    si = pipe.scene.ray_intersect(ray)
    return si, w, h


def shape_hits(pipe: SurfacePipeline) -> np.ndarray:
    """Pixels whose centre sees a shape (flat)."""
    si, _, _ = first_hits(pipe)
    return si.is_valid().numpy()


def render(pipe: SurfacePipeline, **params) -> tuple[np.ndarray, float]:
    """Set ``params``, render: the image and the final gather's milliseconds."""
    pipe.set_params(**params)
    image = np.array(pipe.render())
    return image, pipe.timer.ms.get("final gather", 0.0)


def bushes(count: int, leaves: int = 250, seed: int = 7) -> mi.Mesh:
    """``count`` bushes on the floor: clusters of ``leaves`` randomly turned 2.5 cm cubes."""
    rng = np.random.default_rng(seed)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * 0.0125
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    cube_faces = np.array([[a, b, c] for a, b, c, d in quads] + [[a, c, d] for a, b, c, d in quads])
    centres = np.column_stack(
        [
            rng.uniform(0.1, cornell.WIDTH - 0.1, count),
            np.full(count, 0.09),
            rng.uniform(0.1, cornell.DEPTH - 0.15, count),
        ]
    )
    vertices, faces = [], []
    for b in range(count):
        q, _ = np.linalg.qr(rng.normal(size=(leaves, 3, 3)))
        offset = centres[b] + rng.normal(scale=0.045, size=(leaves, 3))
        offset[:, 1] = np.clip(offset[:, 1], 0.02, None)
        vertices.append(np.einsum("lij,vj->lvi", q, corners) + offset[:, None])
        faces.append(cube_faces[None] + 8 * (b * leaves + np.arange(leaves))[:, None, None])
    bsdf = mi.load_dict(
        {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.15]}}
    )
    return to_mitsuba_mesh(
        "bushes",
        np.concatenate(vertices).reshape(-1, 3),
        np.concatenate(faces).reshape(-1, 3),
        bsdf=bsdf,
    )


def bare_box(size: int, bush_count: int = 0) -> dict:
    """The Cornell box of Fig 1.2 without its two spheres, with ``bush_count`` bushes."""
    scene = cornell.cornell_steinhurst(size, size)
    for name in ("mirror_sphere", "glass_sphere"):
        del scene[name]
    if bush_count:
        scene["bushes"] = bushes(bush_count)
    return scene


def seam_ratio(image: np.ndarray, mask: np.ndarray) -> float:
    """Mean |step| between neighbouring pixels across tile borders / elsewhere (within ``mask``,
    the pixels without the light)."""
    lum = image.mean(axis=2)
    ratios = []
    for axis in (0, 1):
        step = np.abs(np.diff(lum, axis=axis))
        ok = np.diff(mask.astype(int), axis=axis) == 0
        ok &= np.take(mask, range(step.shape[axis]), axis=axis)
        border = np.zeros(step.shape[axis], bool)
        border[TILE - 1 :: TILE] = True
        border = border[:, None] if axis == 0 else border[None, :]
        border = np.broadcast_to(border, step.shape)
        ratios.append(step[ok & border].mean() / step[ok & ~border].mean())
    return float(np.mean(ratios))


def run_ic(
    size: int, photons: int, fg_rays: int, ref_rays: int, errors: list[float], ward: list[float]
) -> dict:
    """Full final gather, Ward's cache at ``ward`` and the tiled cache at ``errors`` (ε_max) on
    the bare box and the boxes with two and six bushes, against a ``ref_rays`` final gather."""
    rows = []
    ravg = []
    for label, count in (("bare box", 0), ("two bushes", 2), ("six bushes", 6)):
        pipe = SurfacePipeline(
            bare_box(size, count), photons=photons, caustic_photons=0, emitter_spp=0
        )
        ref, _ = render(pipe, fg_rays=ref_rays, irradiance_cache="none")
        mask = ref.max(axis=2) < 1.0  # not the light
        full, full_ms = render(pipe, fg_rays=fg_rays, irradiance_cache="none")
        hits = int(np.count_nonzero(shape_hits(pipe)))
        full_gathers = hits * fg_rays
        base = {
            "scene": label,
            "mode": "none",
            "ic_error": None,
            "hit_rate": 0.0,
            "final_gathers": hits,
            "gathers_saved": 0.0,
            "photon_gathers": full_gathers,
            "gathers_vs_none": 1.0,
            "rel_rmse": masked_errors(full, ref, mask)["rel_rmse"],
            "seam_ratio": seam_ratio(full, mask),
            "final_gather_ms": full_ms,
        }
        rows.append(base)
        for mode, error in [("ward", e) for e in ward] + [("tiled", e) for e in errors]:
            image, ms = render(pipe, fg_rays=fg_rays, irradiance_cache=mode, ic_error=error)
            st = pipe.stats
            gathers = st["ic_final_gathers"] * fg_rays + (hits if mode == "tiled" else 0)
            rows.append(
                {
                    "scene": label,
                    "mode": mode,
                    "ic_error": error,
                    "hit_rate": st["ic_hit_rate"],
                    "final_gathers": st["ic_final_gathers"],
                    "gathers_saved": 1 - st["ic_final_gathers"] / hits,
                    "photon_gathers": gathers,
                    "gathers_vs_none": gathers / full_gathers,
                    "rel_rmse": masked_errors(image, ref, mask)["rel_rmse"],
                    "seam_ratio": seam_ratio(image, mask),
                    "final_gather_ms": ms,
                }
            )
        ravg.append({"scene": label, **precomputed_vs_direct(pipe, 0.05)})
    return {
        "image": [size, size],
        "photons": photons,
        "fg_rays": fg_rays,
        "rows": rows,
        "ravg": ravg,
        "knn_wall_time": knn_wall_time(size, photons, fg_rays),
    }


def knn_wall_time(size: int, photons: int, fg_rays: int) -> dict:
    """Final-gather stage time on the bare box with the dissertation's per-ray k-NN gathers
    (``lookup="knn"``), without a cache and with the tiled one at ε_max = 0.05 — where a gather
    is expensive, the gathers saved are time saved."""
    pipe = SurfacePipeline(
        bare_box(size), photons=photons, caustic_photons=0, emitter_spp=0, lookup="knn"
    )
    out = {}
    for mode in ("none", "tiled"):
        _, ms = render(pipe, fg_rays=fg_rays, irradiance_cache=mode, ic_error=0.05)
        out[mode] = {"final_gather_ms": ms}
    out["speedup"] = out["none"]["final_gather_ms"] / out["tiled"]["final_gather_ms"]
    return out


def precomputed_vs_direct(pipe: SurfacePipeline, error: float) -> dict:
    """O24 at the pixel-centre hits: R_avg read at the nearest precomputed photon vs cast at the
    hit, and the tiled cache's decisions with each."""
    si, w, h = first_hits(pipe)
    found = si.is_valid()
    limits = ravg_limits(pipe.scene)
    points = precompute_ravg(pipe.scene, pipe.photon_maps()[0], 0)
    pre = points.lookup(si, found, pipe.radii()[1], limits[0]).numpy()
    direct = harmonic_mean_distance(pipe.scene, si.p, si.sh_frame.n, RAVG_RAYS, 1, limits).numpy()
    order, cache = cache_order("tiled", w, h, 1)
    position = si.p.numpy().reshape(3, -1).T.astype(np.float64)
    normal = si.sh_frame.n.numpy().reshape(3, -1).T.astype(np.float64)
    ok = found.numpy()
    plans = {
        name: plan_cache(position, normal, R.astype(np.float64), ok, ok, order, cache, error)
        for name, R in (("precomputed", pre), ("direct", direct))
    }
    interp = {k: set(p.interpolate) for k, p in plans.items()}
    same = 1 - len(interp["precomputed"] ^ interp["direct"]) / max(int(ok.sum()), 1)
    ratio = pre[ok] / direct[ok]
    return {
        "ic_error": error,
        "median_ratio_precomputed_over_direct": float(np.median(ratio)),
        "median_abs_log_ratio": float(np.median(np.abs(np.log(ratio)))),
        "hit_rate_precomputed": plans["precomputed"].hit_rate,
        "hit_rate_direct": plans["direct"].hit_rate,
        "same_decision": same,
    }


def ic_markdown(ic: dict) -> list[str]:
    """Table 5.1's measurements, the k-NN timing and the R_avg comparison."""
    knn = ic["knn_wall_time"]
    return [
        "",
        "## Table 5.1 / O22–O24: irradiance caching",
        "",
        records_table(ic["rows"], IC_COLUMNS),
        "",
        "With per-ray k-NN gathers (`lookup=knn`), bare box: final gather "
        f"{knn['none']['final_gather_ms']:.0f} ms without a cache, "
        f"{knn['tiled']['final_gather_ms']:.0f} ms with the tiled cache at ε_max = 0.05 "
        f"({knn['speedup']:.2f}×).",
        "",
        "R_avg precomputed at photons vs cast at the hit (tiled cache, ε_max = 0.05):",
        "",
        records_table(ic["ravg"], RAVG_COLUMNS),
        "",
    ]
