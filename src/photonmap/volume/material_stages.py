"""S1 voxelization and S2 material grids of the volume pipeline (Sun et al. 2008 §4, §6) as cached
stages: the grids of n, σ_s and κ, from the scene's shapes and media or from grids given directly
(``set_volume``), under keys that keep n, κ and σ_s apart — painting σ_s with κ unchanged reruns the
viewing pass alone — and the fog volumes' coverages that the octree splits its nodes at."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.stages import StageCache, cache_key
from .materials import MaterialGrids, Perturbation, from_arrays, material_grids
from .params import VolumeParams
from .scene import VolumeScene
from .voxelize import voxelize


def voxelized_materials(
    cache: StageCache, s: VolumeScene, p: VolumeParams, geometry_version: int
) -> tuple[MaterialGrids, tuple, tuple, tuple]:
    """S1 + S2 in ``cache``; returns the grids and the cache keys of n, κ and σ_s separately.
    ``geometry_version`` counts the shapes replaced so far (a new shape reruns S1)."""
    box = s.box
    if s.grids is not None:
        # separate keys, so that painting σ_s with κ unchanged reruns S9 only (Sun et al. 2008 §6)
        ior_key = ("grids", cache_key(s.grids["n"]), cache_key(box))
        kappa_key = ("grids", cache_key(s.grids["kappa"]), cache_key(box))
        key = (ior_key, kappa_key, cache_key(s.grids["sigma_s"]))
        mats = cache.stage("materials", key, lambda: from_arrays(s.grids, box))
        return mats, ior_key, kappa_key, key
    shapes = [o.shape for o in s.objects] + [v.shape for v in s.fog_volumes]
    geo = (
        geometry_version,
        tuple(id(shape) for shape in shapes),
        cache_key(box),
        p.supersample,
    )
    covs = cache.stage(
        "voxelization", geo, lambda: [voxelize(shape, box, p.supersample) for shape in shapes]
    )
    k = len(s.objects)
    surrounding, fog_media = s.surrounding, [v.medium for v in s.fog_volumes]
    noise = (p.ior_noise, p.sigma_s_noise, p.noise_scale, p.seed)
    key = (
        geo,
        cache_key(surrounding),
        cache_key(fog_media),
        cache_key([o.medium for o in s.objects]),
        p.blur_all,
        noise,
    )
    mats = cache.stage(
        "materials",
        key,
        lambda: material_grids(
            list(zip(covs[:k], [o.medium for o in s.objects], strict=True)),
            surrounding,
            box,
            blur_all=p.blur_all,
            noise=Perturbation(p.ior_noise, p.sigma_s_noise, p.noise_scale, p.seed),
            media=list(zip(covs[k:], fog_media, strict=True)),
        ),
    )
    ior_key = (
        geo,
        surrounding.ior,
        tuple(o.medium.ior for o in s.objects),
        p.ior_noise,
        p.noise_scale,
        p.seed,
    )
    kappa_key = (
        geo,
        cache_key(surrounding.extinction_key),
        cache_key([m.extinction_key for m in fog_media]),
        cache_key([o.medium.extinction_key for o in s.objects]),
        p.blur_all,
        noise,
    )
    return mats, ior_key, kappa_key, key


def fog_boundaries(cache: StageCache, s: VolumeScene) -> mi.TensorXf | None:
    """The coverages of the fog volumes (n_z, n_y, n_x, V) from the cached voxelization, for
    the octree (which splits its nodes at their boundaries); None without fog volumes."""
    if s.grids is not None or not s.fog_volumes:
        return None
    covs = cache.get("voxelization")[len(s.objects) :]
    voxels, count = s.box.voxels, len(covs)
    out = dr.zeros(mi.Float, voxels * count)
    index = dr.arange(mi.UInt32, voxels) * count
    for c, coverage in enumerate(covs):
        dr.scatter(out, coverage.array, index + c)
    return mi.TensorXf(out, (*s.box.shape, count))
