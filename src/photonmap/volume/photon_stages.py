"""S5–S8 of the volume pipeline, uniform or adaptive: photons emitted from each light's photon
plane, marched through the march grids (``march.py``), and their radiance grids C and D
smoothed (uniform emission; Sun et al. 2008 §4.3–4.5) or filtered from mipmaps (adaptive
emission: Pfeuti 2009 §3.2, pilot photons A1–A2, the photon-plane pdf A3, importance photons
with weights A4–A5, mipmaps and the level-selecting filter A6–A7).

Each function runs its stages through the pipeline's :class:`~photonmap.core.stages.StageCache`
under keys of exactly their inputs, and returns ``(C, D, key, surface photons, stats)``: the
grids, the key of the last stage (what the viewing stages depend on), the photons recorded on
opaque surfaces and the counters of :attr:`VolumePipeline.stats`.
"""

from __future__ import annotations

from ..core.arrays import concat
from ..core.grid import filter_separable
from ..core.stages import StageCache, cache_key
from . import adaptive, emit, march, mipmap, pilot
from .params import VolumeParams
from .scene import VolumeScene
from .smooth import BINOMIAL, smooth
from .surface_stages import emission, surface_key


def uniform_photons(
    cache: StageCache, s: VolumeScene, p: VolumeParams, march_grids, octree_keys, scatter,
    scatter_key,
):  # fmt: skip
    """S5–S8: uniform photons on the photon plane, marched and smoothed."""
    octree_key, kappa_key = octree_keys
    light_key = (cache_key(s.lights), cache_key(s.box), p.photons, p.sampler, p.seed, p.fidelity)
    spread = emission(s, scatter is not None)
    light_key += (surface_key(s), spread["scene_bounds"] is not None)
    photons = cache.stage("photon generation", light_key, lambda: emit.emit_lights(
        s.lights, s.box, p.photons, p.sampler, p.seed, p.fidelity, **spread))  # fmt: skip
    march_key = (light_key, octree_key, kappa_key, p.ds_min, p.fidelity, scatter_key)
    march_key += (s.refracted_ior,)
    traced = cache.stage("photon tracing", march_key, lambda: march.march(
        photons, march_grids, march.Marching(p.ds_min, fidelity=p.fidelity), s.box.h,
        scattering=scatter, surfaces=s.surfaces, iso=s.refracted_ior,
    ))  # fmt: skip
    smooth_key = (march_key, p.smoothing)
    C, D = cache.stage("smoothing", smooth_key, lambda: smooth(traced.C, traced.D, p.smoothing))
    stats = {
        "photons_generated": len(s.lights) * p.photons,
        "photons_propagated": photons.count,
        "steps": traced.steps,
        "scatterings": traced.scatterings,
        "surface_photons": traced.surface.count if traced.surface else 0,
    }
    return C, D, smooth_key, traced.surface, stats


def _pilot_samplers(cache: StageCache, s: VolumeScene, p: VolumeParams, march_grids, octree_keys):
    """A1–A3: pilot photons per light, marched, and the photon-plane pdf each gives; with the
    pdf's stage key, the pilots and their march grids (for the counters)."""
    octree_key, kappa_key = octree_keys
    box, lights = s.box, s.lights
    pilot_key = (cache_key(lights), cache_key(box), p.pilot_photons, p.seed, p.fidelity)
    pilots = cache.stage("pilot photon generation", pilot_key, lambda: [
        pilot.emit_pilot(li, box, p.pilot_photons, p.seed, p.fidelity) for li in lights
    ])  # fmt: skip
    pilot_march_key = (pilot_key, octree_key, kappa_key, p.ds_min)
    pilot_grids = cache.stage("pilot photon marching", pilot_march_key, lambda: [
        pilot.march_pilot(b, march_grids, p.ds_min, p.fidelity) for b in pilots
    ])  # fmt: skip
    pdf_key = (pilot_march_key, p.grad_threshold, p.rad_threshold, p.background, p.placement)
    samplers = cache.stage("photon distribution", pdf_key, lambda: [
        adaptive.plane_sampler(g, p.grad_threshold, p.rad_threshold, p.background, p.placement)
        for g in pilot_grids
    ])  # fmt: skip
    return samplers, pdf_key, pilots, pilot_grids


def adaptive_photons(
    cache: StageCache, s: VolumeScene, p: VolumeParams, march_grids, octree_keys, scatter,
    scatter_key,
):  # fmt: skip
    """A1–A7 (Pfeuti §3.2): pilot photons → photon-plane pdf per light → importance photons
    marched with their weights → mipmaps → level-selecting filter."""
    octree_key, kappa_key = octree_keys
    box, lights = s.box, s.lights
    samplers, pdf_key, pilots, pilot_grids = _pilot_samplers(cache, s, p, march_grids, octree_keys)
    gen_key = (pdf_key, p.photons, p.sampler)
    count = p.photons - p.pilot_photons

    def generate():
        batches = [
            adaptive.emit_importance(li, box, smp, count, p.sampler, p.seed, p.fidelity)
            for li, smp in zip(lights, samplers, strict=True)
        ]
        return emit.concat([b[0] for b in batches]), concat([b[1] for b in batches])

    photons, weights = cache.stage("photon generation", gen_key, generate)
    march_key = (gen_key, octree_key, kappa_key, p.ds_min, scatter_key)
    march_key += (surface_key(s), s.refracted_ior)
    traced = cache.stage("photon tracing", march_key, lambda: march.march(
        photons, march_grids, march.Marching(p.ds_min, fidelity=p.fidelity), box.h,
        weights=weights, scattering=scatter, surfaces=s.surfaces, iso=s.refracted_ior,
    ))  # fmt: skip
    mip_key = (march_key, p.smoothing)

    def mipmaps():  # S8 on C only: the directions stay as marched (mipmap.py notes)
        C = filter_separable(traced.C, BINOMIAL) if p.smoothing else traced.C
        return mipmap.build_pyramid(C, traced.D, traced.count, traced.weight)

    pyramid = cache.stage("mipmap generation", mip_key, mipmaps)
    filter_key = (mip_key, p.delta_weight, p.mip_block, p.mip_blend)

    def reconstruct():
        step = mipmap.weight_step(p.delta_weight, count, box.n)
        C, D, level = mipmap.reconstruct(pyramid, step, p.mip_block, p.mip_blend)
        return (*smooth(C, D, enabled=False), level)

    C, D, _ = cache.stage("filtering", filter_key, reconstruct)
    stats = {
        "photons_generated": len(lights) * p.photons,
        "photons_propagated": photons.count + sum(b.count for b in pilots),
        "pilot_photons_propagated": sum(b.count for b in pilots),
        "steps": traced.steps + sum(g.steps for g in pilot_grids),
        "scatterings": traced.scatterings,
    }
    return C, D, filter_key, traced.surface, stats
