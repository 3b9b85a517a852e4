"""Photons aimed at specular objects — Jensen's projection maps (1996), generalised to area
lights (spec beyond-seeds §3; issue 12 item 2). Shared by the SPPM photon pass and the surface
method's caustic map.

**Aimed emission.** For an area emitter: sample a point ``y`` on it (``sample_position``, area
pdf ``p_A``), choose a specular shape ``S`` with probability ∝ the solid angle ``Ω_S`` its
bounding sphere subtends from ``y``, and a direction uniformly in that cone (the whole sphere of
directions where ``y`` lies inside it). Cones may overlap, so the direction's pdf is the mixture
``p(ω) = Σ_S P(S)·1[ω ∈ cone_S]/Ω_S = #{S: ω ∈ cone_S} / Σ_S Ω_S``, and the photon carries

    Φ = L_e(y, ω) |cos θ_y| / (p_A(y) · p(ω) · N_a)

for ``N_a`` aimed paths of that emitter: an unbiased estimate of the power it sends into the
cones. A *specular* shape has only delta lobes (:func:`~photonmap.core.bsdf.is_specular`:
mirrors, glass); ``null`` boundaries are not aimed at.

**Partition of light paths (unbiased).** Every path whose first surface interaction is on a
specular shape leaves its light inside that shape's cone, so it can be sampled aimed. A photon
budget is split per emitter: a fraction ``aim`` of an area emitter's paths is aimed and keeps only
the records of paths whose first interaction is specular (the *caustic* paths: ``L S …``); the
other paths are emitted as usual (:mod:`photonmap.core.photon_trace`) and keep only the records
of paths whose first interaction is smooth. Together they cover every path once. Other emitters
(points, spots, environment) keep all their paths unaimed. ``caustics_only`` tracing (the caustic
map) keeps only ``L S+ D`` records, which all start on a specular shape: there every path of an
area emitter is aimed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .bsdf import has_null_shapes, intersect_visible, is_specular
from .errors import ParameterError
from .photon_trace import (
    PhotonRecords,
    _check_power,
    _checked_powers,
    _sample_rays,
    _trace,
    split_paths,
)
from .sampling import rng

_LOBES = int(mi.BSDFFlags.All)
SURFACE_SAMPLES = 1 << 14  # points that bound a non-mesh shape (specular_spheres)


def specular_spheres(scene: mi.Scene) -> list[tuple[np.ndarray, float]]:
    """``(centre, radius)`` of a bounding sphere of every shape whose BSDF has only delta
    lobes (mirrors, glass; ``null`` boundaries and emitters excluded): centred on the shape's
    bounding box, through its farthest vertex (meshes) or 1% beyond the farthest of
    :data:`SURFACE_SAMPLES` points on it (spheres, disks, ...: their extremes are smooth, so the
    margin covers what the samples miss) — tighter than the box's own sphere."""
    spheres = []
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is None or shape.is_emitter():
            continue
        flags = bsdf.flags()
        if flags & int(mi.BSDFFlags.Smooth) or flags & _LOBES == int(mi.BSDFFlags.Null):
            continue
        box = shape.bbox()
        lo, hi = (np.array(c, dtype=np.float64).ravel() for c in (box.min, box.max))
        centre = (lo + hi) / 2
        if shape.is_mesh():
            points = np.array(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3)
            margin = 1.0001
        else:
            u = rng(SURFACE_SAMPLES, 0, 0)
            ps = shape.sample_position(0.0, mi.Point2f(u.next_float32(), u.next_float32()))
            points = np.array(ps.p, np.float64).reshape(3, -1).T
            margin = 1.01
        radius = margin * float(np.sqrt(((points - centre) ** 2).sum(axis=1).max()))
        spheres.append((centre, min(radius, 0.5001 * float(np.linalg.norm(hi - lo)))))
    return spheres


def aimable(scene: mi.Scene) -> np.ndarray:
    """Per emitter: whether its photons can be aimed (an area emitter on a shape)."""
    return np.array([e.get_shape() is not None for e in scene.emitters()], bool)


@dataclass
class AimedTrace:
    """Photon records of an aimed trace and what the aiming achieved."""

    records: PhotonRecords
    aimed_paths: int  # paths emitted towards specular shapes
    caustic_fraction: float  # of the aimed paths, those whose first interaction was specular


def _cones(y: mi.Point3f, spheres):
    """Per sphere: (unit axis from ``y``, cos θ_max, Ω, inside) as lane-wide arrays."""
    cones = []
    for centre, radius in spheres:
        to_c = mi.Point3f(*centre.tolist()) - y
        d2 = dr.squared_norm(to_c)
        inside = d2 <= radius**2
        cos_max = dr.select(inside, -1.0, dr.safe_sqrt(1.0 - radius**2 / dr.maximum(d2, 1e-30)))
        omega = 2.0 * math.pi * (1.0 - cos_max)
        cones.append((dr.normalize(to_c), cos_max, omega, inside))
    return cones


def aimed_emission(scene: mi.Scene, emitter: mi.UInt32, counts: np.ndarray, spheres, seed: int):
    """Rays and powers of aimed photons leaving the area emitters ``emitter`` (per lane) towards
    ``spheres``; ``counts``: aimed paths per emitter (the ``N_a`` of the module docstring)."""
    n = dr.width(emitter)
    gen = rng(n, seed, stream=2)
    emitters = dr.gather(mi.EmitterPtr, scene.emitters_dr(), emitter)
    ps, _ = emitters.sample_position(0.0, mi.Point2f(gen.next_float32(), gen.next_float32()))
    cones = _cones(ps.p, spheres)
    total = sum(c[2] for c in cones)
    # choose a cone ∝ Ω, then a direction uniformly in it
    u, u_dir = gen.next_float32() * total, mi.Point2f(gen.next_float32(), gen.next_float32())
    d = mi.Vector3f(0.0)
    below = dr.zeros(mi.Float, n)
    chosen = dr.zeros(mi.Bool, n)
    for number, (axis, cos_max, omega, _) in enumerate(cones):
        pick = ~chosen & ((u < below + omega) | (number == len(cones) - 1))
        local = mi.warp.square_to_uniform_cone(u_dir, cos_max)
        d = dr.select(pick, mi.Frame3f(axis).to_world(local), d)
        chosen |= pick
        below += omega
    covering = dr.zeros(mi.Float, n)  # cones that contain d (overlaps: the mixed pdf)
    for axis, cos_max, _, inside in cones:
        covering += dr.select(inside | (dr.dot(d, axis) >= cos_max), 1.0, 0.0)
    pdf_dir = covering / total
    si = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
    si.wi = si.to_local(d)
    radiance = mi.Color3f(emitters.eval(si))
    cos_y = dr.maximum(dr.dot(ps.n, d), 0.0)
    per = dr.gather(mi.Float, mi.Float(np.maximum(counts, 1).astype(np.float32)), emitter)
    power = radiance * cos_y / dr.maximum(ps.pdf * pdf_dir * per, 1e-30)
    power = dr.select((ps.pdf > 0) & (pdf_dir > 0), power, 0.0)
    return si.spawn_ray(d), power


def _join(a, b):
    """Two 3-vectors (points, directions, colours) one after the other."""
    return type(a)(*(dr.concat([a[c], b[c]]) for c in range(3)))


def trace_aimed_photons(
    scene: mi.Scene,
    paths: int,
    aim: float,
    max_depth: int = 8,
    rr_depth: int = 3,
    seed: int = 0,
    caustics_only: bool = False,
) -> AimedTrace:
    """:func:`~photonmap.core.photon_trace.trace_photons` with the fraction ``aim`` of the area
    emitters' paths aimed at the specular shapes (``caustics_only``: all of them), partitioned as
    the module docstring says. Without specular shapes or area emitters, or with ``aim = 0``,
    it traces as ``trace_photons`` does (and keeps every record)."""
    if paths < 1:
        raise ParameterError(f"the number of photon paths must be at least 1, got {paths}")
    if not 0 <= aim < 1 and not (caustics_only and aim == 1):
        raise ParameterError(f"aim must lie in [0, 1), got {aim!r}: the fraction aimed")
    powers = _checked_powers(scene, seed)
    counts = split_paths(powers, paths)
    spheres = specular_spheres(scene)
    can = aimable(scene) & (counts >= (1 if caustics_only else 2))
    if not spheres or aim == 0:
        can[:] = False
    share = 1.0 if caustics_only else aim
    aimed = np.where(can, np.clip(np.round(counts * share), 1, counts - (not caustics_only)), 0)
    aimed = aimed.astype(np.int64)
    plain = counts - aimed
    index = np.arange(len(counts), dtype=np.uint32)
    n_plain, n_aimed = int(plain.sum()), int(aimed.sum())
    parts = []  # (ray, power, emitter) of the plain paths, then of the aimed ones
    if n_plain:
        plain_emitter = mi.UInt32(np.repeat(index, plain))
        ray, weight = _sample_rays(scene, plain_emitter, seed)
        per = dr.gather(mi.Float, mi.Float(np.maximum(plain, 1).astype(np.float32)), plain_emitter)
        parts.append((ray, weight / per, plain_emitter))
    fraction = 0.0
    if n_aimed:
        aimed_emitter = mi.UInt32(np.repeat(index, aimed))
        a_ray, a_power = aimed_emission(scene, aimed_emitter, aimed, spheres, seed)
        first = intersect_visible(scene, a_ray, True, has_null_shapes(scene))
        hits = is_specular(first.bsdf(a_ray), first.is_valid())
        fraction = float(dr.count(hits)[0]) / n_aimed
        parts.append((a_ray, a_power, aimed_emitter))
    if len(parts) == 2:
        (ray, power, emitter), (a_ray, a_power, a_emitter) = parts
        ray = mi.Ray3f(_join(ray.o, a_ray.o), _join(ray.d, a_ray.d))
        power, emitter = _join(power, a_power), dr.concat([emitter, a_emitter])
    else:
        ray, power, emitter = parts[0]
    emitted = np.array(dr.sum(mi.Color3d(power), axis=1)).ravel()
    records = _trace(
        scene, ray, power, rng(paths, seed, stream=1), max_depth, rr_depth, caustics_only,
        has_null_shapes(scene),
    )  # fmt: skip
    stored = records.pop("stored")
    slot = dr.compress(stored)
    if n_aimed and not caustics_only and dr.width(slot):
        path = slot % paths
        # a path's first interaction was smooth iff it left a record at depth 1
        depth = dr.gather(mi.UInt32, records["depth"], slot)
        smooth_first = dr.zeros(mi.Bool, paths)
        dr.scatter(smooth_first, True, path, depth == 1)
        em = dr.gather(mi.UInt32, emitter, path)
        partitioned = dr.gather(mi.Bool, mi.Bool(can), em)
        keep = ~partitioned | (dr.gather(mi.Bool, smooth_first, path) == (path < n_plain))
        slot = dr.gather(mi.UInt32, slot, dr.compress(keep))
    fields = {name: dr.gather(type(value), value, slot) for name, value in records.items()}
    dr.eval(fields)
    result = PhotonRecords(**fields, paths=paths, emitted_power=emitted)
    _check_power(result)
    return AimedTrace(result, n_aimed, fraction)
