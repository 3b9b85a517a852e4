"""Final gather (Steinhurst 2007 §2.6.2.1, Eq 2.5; Jensen): indirect light at the eye-ray hit x as
a Monte Carlo integral over the hemisphere::

    L_indirect(x, ω_o) = (1/N) Σ_i f_r(x, ω_i, ω_o) · L(y_i → x) · (ω_i · n) / p(ω_i)

Each of the N_FG rays leaves x by BSDF sampling (smooth lobes, ``sampling="bsdf"``), cosine-weighted
(``"cosine"``) or uniform (``"uniform"``, the naive algorithm's "visible hemisphere uniformly",
Steinhurst §3.1) hemisphere sampling, or from a per-point tabular pdf — Jensen's photon-map pdf or
Steinhurst's combined importance sampling (``"jensen"``, ``"cis"``: Ch. 6, :mod:`.cis`) — the N_FG
directions of a point warped from a randomly shifted Hammersley set
(:func:`~photonmap.core.sampling.rotated_hammersley`) — passes through purely specular surfaces and
reads the photon map at the first non-specular hit y_i — emitters met on the way add nothing (direct
light and caustics at x are computed separately). ``L(y_i → x)`` comes from irradiance precomputed
at photon positions (default) or from an exact k-NN radiance estimate at y_i (the dissertation's
naive algorithm, ``lookup="knn"``).

With the precomputed irradiance the whole batch — BSDF sampling, the eye-path loop and the
nearest-point lookup (:meth:`photonmap.core.hashgrid.HashGrid.nearest`) — is one fused kernel; no
interaction at y is materialised in memory. A k-NN lookup runs its own kernels over the evaluated
hits (``fused=False``).

The rays are issued in explicit batches of photon-map queries — as many final-gather rays of every
query point at a time as fit in ``BATCH_RAYS`` (2²¹) rays per batch — the unit that gather
reordering works on. With a ``layout`` (:class:`~.gather_batch.RequestLayout`) the k-NN lookups of
a batch run as a :class:`~.gather_batch.GatherBatch` of the hits, in one of Steinhurst's gather
orders (Ch. 3); each ray's result goes back to its lane before the per-pixel sums, so the image is
bit-identical in every order (tested).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.arrays import to_numpy
from ..core.eye_rules import EyeRules
from ..core.eye_trace import trace_eye_paths
from ..core.media import enter
from ..core.sampling import rng, rotated_hammersley
from ..core.scene_info import SceneTraits
from ..core.settings import PathSettings
from .cis import sample_table
from .gather_batch import RequestLayout, gather_order
from .volume import MediumLight

FG_STREAM = 1 << 16  # RNG streams of the final-gather batches start here
BATCH_RAYS = 1 << 21  # final-gather rays traced per batch


@dataclass
class GatherPoints:
    """The points x gathered at: the eye-ray hits ``si`` where ``active``, the eye path's
    segments to each (``depth``), the medium there (None in vacuum) and where the irradiance
    cache wants irradiance rather than radiance (``irradiance``, None without it)."""

    si: mi.SurfaceInteraction3f
    active: mi.Bool
    depth: mi.UInt32
    medium: mi.MediumPtr | None = None
    irradiance: mi.Bool | None = None


@dataclass(frozen=True)
class GatherRays:
    """How the rays leave x: ``rays`` per point, random numbers from ``seed``, directions by
    ``sampling`` (``table``: the per-point tabular pdf of ``"jensen"``/``"cis"``), followed by the
    path ``settings`` in a scene of ``traits``."""

    rays: int
    seed: int
    settings: PathSettings
    traits: SceneTraits
    sampling: str = "bsdf"
    table: mi.Float | None = None


@dataclass(frozen=True)
class GatherReading:
    """How a ray's end y is read: ``lookup(si_y, bsdf_y, active)`` returns the radiance leaving
    y towards x (lazily if ``fused``); ``layout`` (k-NN lookups, ``fused=False``) issues each
    batch's gathers in ``layout.order``; ``medium_light`` is the light at a collision in a
    medium (:mod:`.volume`)."""

    lookup: Callable
    fused: bool = True
    layout: RequestLayout | None = None
    medium_light: MediumLight | None = None


def final_gather(
    scene: mi.Scene, points: GatherPoints, cast: GatherRays, reading: GatherReading
) -> mi.Spectrum:
    """Average of ``cast.rays`` final-gather estimates at each of the ``points``. The rays are
    followed by the transport core's eye-path loop
    (:func:`~photonmap.core.eye_trace.trace_eye_paths`: mirrors, glass, ``null`` boundaries,
    media); in a scene with participating media a ray that collides in a medium reads the light
    there (``reading.medium_light``)."""
    si, active, depth, medium, irradiance = (
        points.si, points.active, points.depth, points.medium, points.irradiance,
    )  # fmt: skip
    rays, seed, settings, traits = cast.rays, cast.seed, cast.settings, cast.traits
    lookup, fused, layout, medium_light = (
        reading.lookup, reading.fused, reading.layout, reading.medium_light,
    )  # fmt: skip
    count = dr.width(active)
    per_batch = max(1, min(rays, BATCH_RAYS // max(count, 1)))
    total = dr.zeros(mi.Spectrum, count)
    shifts = rng(count, seed, FG_STREAM - 1)
    shift = mi.Point2f(shifts.next_float32(), shifts.next_float32())
    media = medium is not None and traits.media
    for first in range(0, rays, per_batch):
        m = min(per_batch, rays - first)
        query = dr.arange(mi.UInt32, count * m) // m  # m rays of each query point, adjacent
        x = dr.gather(mi.SurfaceInteraction3f, si, query)
        ok = dr.gather(mi.Bool, active, query)
        bsdf = x.bsdf()
        gen = rng(count * m, seed, FG_STREAM + first)
        i = first + dr.arange(mi.UInt32, count * m) % m
        u = rotated_hammersley(rays, i, dr.gather(mi.Point2f, shift, query))
        wo, pdf, weight, ok = _sample_direction(cast.sampling, x, bsdf, gen, u, ok, cast.table,
                                                query)  # fmt: skip
        if irradiance is not None:
            cos_pdf = mi.Spectrum(dr.maximum(wo.z, 0.0) / dr.maximum(pdf, 1e-12))
            weight = dr.select(dr.gather(mi.Bool, irradiance, query), cos_pdf, weight)
        ray = x.spawn_ray(x.to_world(wo))
        medium_x = dr.zeros(mi.MediumPtr, count * m)
        if media:
            medium_x = enter(x, ray.d, dr.gather(mi.MediumPtr, medium, query), ok)
        rules = EyeRules(settings, traits, emission=False, media_mode="end", rough_glass=True)
        y = trace_eye_paths(
            scene, (ray, dr.select(ok, weight, 0.0), medium_x), gen, rules,
            start_depth=dr.gather(mi.UInt32, depth, query), active=ok,
        )  # fmt: skip
        si_y, throughput, found = y.si, y.beta, y.found & settings.allows(y.depth + 1)
        L_medium = 0.0
        if media and medium_light is not None:
            L_medium = y.beta * medium_light.at(y.mei, y.in_medium, FG_STREAM + (1 << 20) + first)
        if not fused:
            dr.eval(si_y, throughput, found)  # the k-NN gathers run several kernels over these
        if layout is None or fused:
            L_y = lookup(si_y, si_y.bsdf(), found)
        else:
            L_y = _ordered_lookup(lookup, layout, si_y, found, query, i, ray.d)
        L = dr.select(found, throughput * L_y, 0.0) + L_medium
        dr.eval(L)  # once: each channel's block sum below would otherwise rerun the kernel
        total += mi.Spectrum(*[dr.block_reduce(dr.ReduceOp.Add, c, m) for c in L])
        dr.eval(total)
    return total / rays


def _sample_direction(sampling: str, x, bsdf, gen, u: mi.Point2f, ok, table, query):
    """A final-gather direction at ``x`` from the 2D sample ``u``: ``(wo, pdf, weight, ok)``,
    ``weight = f cos / pdf`` of the smooth lobes (delta and ``Null`` samples count nothing), by
    BSDF sampling, cosine or uniform hemisphere sampling, or from the per-query tabular pdf
    ``table`` (:func:`~.cis.sample_table`: ``jensen``, ``cis``)."""
    ctx = mi.BSDFContext()
    if sampling == "bsdf":
        bs, weight = bsdf.sample(ctx, x, gen.next_float32(), u, ok)
        smooth = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Smooth)
        return bs.wo, bs.pdf, weight, ok & (bs.pdf > 0) & smooth
    if sampling == "cosine":
        wo = mi.warp.square_to_cosine_hemisphere(u)
        pdf = mi.warp.square_to_cosine_hemisphere_pdf(wo)
    elif sampling == "uniform":
        wo = mi.warp.square_to_uniform_hemisphere(u)
        pdf = mi.warp.square_to_uniform_hemisphere_pdf(wo)
    else:
        wo, pdf = sample_table(table, query, u)
    weight = bsdf.eval(ctx, x, wo, ok) / dr.maximum(pdf, 1e-12)
    return wo, pdf, weight, ok & (pdf > 0)


def _ordered_lookup(lookup, layout: RequestLayout, si_y, found, query, i, direction) -> mi.Spectrum:
    """``lookup`` at the found hits as a request batch in ``layout.order``; the results are
    scattered back to their lanes (Steinhurst §3.2: a reordering changes only the order)."""
    lanes = dr.compress(found)
    dr.eval(lanes)
    host = lanes.numpy()
    if len(host) == 0:
        return dr.zeros(mi.Spectrum, dr.width(found))
    batch = layout.batch(
        query.numpy()[host],
        i.numpy()[host],
        to_numpy(si_y.p).T[host],
        to_numpy(si_y.sh_frame.n).T[host],
        to_numpy(direction).T[host],
    )
    if layout.keep:
        layout.batches.append(batch)
    if layout.record_only:
        return dr.zeros(mi.Spectrum, dr.width(found))
    issued = dr.gather(
        mi.UInt32, lanes, mi.UInt32(gather_order(batch, layout.order, layout.params))
    )
    si = dr.gather(mi.SurfaceInteraction3f, si_y, issued)
    L = dr.zeros(mi.Spectrum, dr.width(found))
    dr.scatter(L, lookup(si, si.bsdf(), dr.full(mi.Bool, True, dr.width(issued))), issued)
    return L
