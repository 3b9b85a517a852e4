"""Photons aimed at specular objects — Jensen's projection maps (1996), generalised to area lights
(ours: a mixture of cones over the specular shapes, below): the geometry of aiming. Used by the
emission of every method's photon paths (:func:`photonmap.core.emission.emit`), which partitions
each aimed emitter's paths so that every light path is counted once.

**Aimed emission.** For an area emitter: sample a point ``y`` on it (``sample_position``, area
pdf ``p_A``), choose a specular shape ``S`` with probability ∝ the solid angle ``Ω_S`` its
bounding sphere subtends from ``y``, and a direction uniformly in that cone (the whole sphere of
directions where ``y`` lies inside it). Cones may overlap, so the direction's pdf is the mixture
``p(ω) = Σ_S P(S)·1[ω ∈ cone_S]/Ω_S = #{S: ω ∈ cone_S} / Σ_S Ω_S``, and the photon carries

    Φ = L_e(y, ω) |cos θ_y| / (p_A(y) · p(ω) · N_a)

for ``N_a`` aimed paths of that emitter: an unbiased estimate of the power it sends into the
cones. A *specular* shape has only delta lobes (:func:`~photonmap.core.bsdf.is_specular`:
mirrors, glass, thin glass), or is rough glass where the caller follows it
(:func:`~photonmap.core.bsdf.is_rough_glass`); ``null`` boundaries are not aimed at. Every path whose first
interaction is on a specular shape left its light inside that shape's cone, so it can be sampled
aimed.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from .arrays import to_jit
from .bsdf import instanced_shapes, rough_glass_flags, shape_box
from .sampling import rng

_LOBES = int(mi.BSDFFlags.All)
SURFACE_SAMPLES = 1 << 14  # points that bound a non-mesh shape (specular_spheres)


def specular_spheres(scene: mi.Scene, rough_glass: bool = False) -> list[tuple[np.ndarray, float]]:
    """``(centre, radius)`` of a bounding sphere of every shape whose BSDF has only delta
    lobes (mirrors, glass; ``null`` boundaries and emitters excluded), with ``rough_glass`` also
    of every rough glass shape: centred on the shape's
    bounding box, through its farthest vertex (meshes) or 1% beyond the farthest of
    :data:`SURFACE_SAMPLES` points on it (spheres, disks, ...: their extremes are smooth, so the
    margin covers what the samples miss) — tighter than the box's own sphere. An ``instance``
    whose group holds such a shape is aimed at as a whole: the sphere of its box."""
    spheres = []
    groups = {instance.ptr: shapes for instance, shapes in instanced_shapes(scene)}
    for shape in scene.shapes():
        if shape.ptr in groups:  # an instance: aimed at as a whole if its group holds glass
            if any(_aimed(s, rough_glass) for s in groups[shape.ptr]):
                box = shape_box(shape)
                lo, hi = (np.array(c, dtype=np.float64).ravel() for c in (box.min, box.max))
                spheres.append(((lo + hi) / 2, 0.5001 * float(np.linalg.norm(hi - lo))))
            continue
        if not _aimed(shape, rough_glass):
            continue
        box = shape_box(shape)
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


def _aimed(shape: mi.Shape, rough_glass: bool) -> bool:
    """Whether photons are aimed at ``shape`` (:func:`specular_spheres`)."""
    bsdf = shape.bsdf()
    if bsdf is None or shape.is_emitter():
        return False
    flags = bsdf.flags()
    rough = rough_glass and rough_glass_flags(flags)
    null = flags & _LOBES == int(mi.BSDFFlags.Null)
    return not ((flags & int(mi.BSDFFlags.Smooth) and not rough) or null)


def aimable(scene: mi.Scene) -> np.ndarray:
    """Per emitter: whether its photons can be aimed (an area emitter on a shape)."""
    return np.array([e.get_shape() is not None for e in scene.emitters()], bool)


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
    per = dr.gather(mi.Float, to_jit(mi.Float, np.maximum(counts, 1)), emitter)
    power = radiance * cos_y / dr.maximum(ps.pdf * pdf_dir * per, 1e-30)
    power = dr.select((ps.pdf > 0) & (pdf_dir > 0), power, 0.0)
    return si.spawn_ray(d), power
