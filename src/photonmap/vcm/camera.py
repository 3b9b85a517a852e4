"""The camera pass of vertex connection and merging: ``spp`` camera subpaths per pixel, and at each of
its vertices every technique the mode uses, weighted by multiple importance sampling (Georgiev
et al. 2012 §5; Georgiev 2012, TR (37)–(45); SmallVCM's ``vertexcm.hxx``, the camera loop).

A camera subpath starts through its pixel (the film's filter importance-sampled,
:func:`photonmap.core.camera.pixel_rays`) with ``dVCM = N_L / (P p_cam) = 1 / W_e(ω)`` (the
sensor's importance over the crop of ``P = N_L`` pixels, TR (31): the density with which a camera
subpath of this pixel samples the direction, per pixel) and ``dVC = dVM = 0``. At each hit
(quantities completed as on the light side, :func:`.mis.after_hit`):

- **emission met**, weighted by ``1 / (1 + p_direct dVCM + p_e dVC)`` (TR (43); the emission
  seen directly is unweighted: no other technique makes it);
- at a vertex with a smooth lobe, within ``max_depth``:
  **next-event estimation** (TR (44)–(45)), **connection** to each vertex of the light subpath of
  the same index (TR (40)–(41); a shadow ray each), **merging** with the light vertices within
  ``r`` (TR (38)–(39), normalised by ``1 / (π r² N_L)``: photon mapping's density estimate;
  unweighted in ``ppm`` mode, which stops after it);
- the next segment by the BSDF sample (the quantities by :func:`.light.after_sample`) and
  Russian roulette on the throughput (Mitsuba's, with the η² of the refractions crossed).

In ``lt`` mode the camera subpaths only add the emission they see directly.

The subpaths are the transport core's eye paths (:func:`photonmap.core.eye_trace.trace_eye_paths`:
the flight, the BSDF sample, Russian roulette) with :class:`CameraVertexRule` as their vertex rule.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.camera import pixel_means, pixel_rays
from ..core.eye_trace import EyeRules, EyeVertexRule, trace_eye_paths
from ..core.hashgrid import HashGrid
from ..core.sampling import rng
from ..core.scene_info import SceneTraits
from ..core.settings import UNBOUNDED, PathSettings
from . import mis
from .light import IMPORTANCE, RADIANCE, Emitters, LightVertices, after_sample, reverse_pdf
from .mis import Techniques

RAY_EPSILON = 1500 * 2.0**-24  # Mitsuba's math::RayEpsilon<float>


@dataclass
class MergeGrid:
    """The light vertices in a hash grid of cell ``2r`` (a merge scans the 2 × 2 × 2 cells its
    radius can reach), with what a merge reads of them in the grid's storage order."""

    grid: HashGrid
    wi: mi.Vector3f  # towards the previous light vertex (world)
    beta: mi.Spectrum
    depth: mi.UInt32
    d_vcm: mi.Float
    d_vm: mi.Float

    @classmethod
    def build(cls, vertices: LightVertices, radius: float) -> MergeGrid | None:
        if vertices.count == 0:
            return None
        grid = HashGrid(vertices.si.p, cell_size=2.0 * radius)  # scanned 2 × 2 × 2
        si = vertices.si
        wi = si.to_world(si.wi)
        order = grid.order
        return cls(
            grid, dr.gather(mi.Vector3f, wi, order), dr.gather(mi.Spectrum, vertices.throughput,
            order), dr.gather(mi.UInt32, vertices.depth, order),
            dr.gather(mi.Float, vertices.d_vcm, order), dr.gather(mi.Float, vertices.d_vm, order),
        )  # fmt: skip


@dataclass
class _Subpath:
    """A camera subpath's MIS quantities and history: the extra state it carries through the
    core's loop."""

    d_vcm: mi.Float
    d_vc: mi.Float
    d_vm: mi.Float
    specular: mi.Bool  # every bounce so far a delta one
    prev: mi.Interaction3f  # the last vertex
    offset: mi.Float  # the camera's centre to the ray's origin (the near clip plane); then 0


def camera_pass(
    scene: mi.Scene,
    sensor: mi.Sensor,
    seed: int,
    settings: PathSettings,
    tech: Techniques,
    vertices: LightVertices | None,
    grid: MergeGrid | None,
    emitters: Emitters,
) -> mi.Spectrum:
    """The radiance per pixel of the crop (row-major): the mean of ``tech.spp`` camera subpaths
    (adjacent lanes; lane ``i`` connects to light subpath ``i``), with every technique of
    ``tech`` (module docstring)."""
    w, h = (int(c) for c in sensor.film().crop_size())
    n = w * h * tech.spp
    gen = rng(n, seed, 3)
    pixel = dr.arange(mi.UInt32, n) // tech.spp
    ray, weight = pixel_rays(sensor, pixel, mi.Point2f(gen.next_float32(), gen.next_float32()))
    # the camera's density of this direction, per pixel: W_e at a point at unit distance,
    # read at a point between the clip planes (Mitsuba's importance is 0 outside them; at unit
    # distance an oblique ray is nearer than a near clip of 1) and scaled by its distance²
    # (opaque: a literal would compile a new kernel for every camera)
    params = mi.traverse(sensor)
    depth = dr.opaque(mi.Float, math.sqrt(float(params["near_clip"]) * float(params["far_clip"])))
    local_z = (sensor.world_transform().inverse() @ ray.d).z
    distance = depth / dr.maximum(local_z, 1e-6)
    centre = mi.Point3f(sensor.world_transform().translation())
    dr.make_opaque(centre)
    at = dr.zeros(mi.Interaction3f, n)
    at.p = centre + ray.d * distance
    _, importance = sensor.sample_direction(at, mi.Point2f(0.5, 0.5))
    importance = importance.x * dr.square(distance)
    d_vcm = dr.select(importance > 0, dr.rcp(importance), 0.0)
    zero = dr.zeros(mi.Float, n)
    subpaths = _Subpath(d_vcm, zero, zero, dr.full(mi.Bool, True, n),
                        dr.zeros(mi.Interaction3f, n), dr.norm(ray.o - centre))  # fmt: skip
    if tech.mode == "lt":  # the camera subpaths add the emission they see and stop
        settings = dataclasses.replace(settings, max_depth=1)
    limit = 2**31 - 1 if settings.max_depth == UNBOUNDED else settings.max_depth
    limit = dr.opaque(mi.UInt32, limit)
    vm_factor = dr.opaque(mi.Float, tech.vm_factor)
    path = dr.arange(mi.UInt32, n)

    def techniques(si, bsdf, gen, t, d_vcm, d_vc, d_vm, active):
        """The techniques at a smooth vertex: next-event estimation, connections, merges."""
        total = dr.zeros(mi.Spectrum, n)
        if tech.nee:
            total += _next_event(scene, si, bsdf, gen, d_vcm, d_vc, vm_factor, tech, emitters,
                                 active)  # fmt: skip
        if tech.connect and vertices is not None:
            total += _connect(scene, si, bsdf, path, t, d_vcm, d_vc, vertices, vm_factor, limit,
                              active)  # fmt: skip
        if tech.merge and grid is not None:
            total += _merge(grid, si, bsdf, t, d_vcm, d_vm, tech, limit, active)
        return total

    rule = CameraVertexRule(scene, tech, emitters, settings.hide_emitters, techniques, subpaths)
    rules = EyeRules(settings, SceneTraits.of(scene), media_mode="transmit", vertex=rule)
    eye = trace_eye_paths(scene, (ray, mi.Spectrum(weight), dr.zeros(mi.MediumPtr, n)), gen,
                          rules)  # fmt: skip
    return pixel_means(eye.radiance, tech.spp)


class CameraVertexRule(EyeVertexRule):
    """The camera subpaths' vertex rule in the core's eye loop (module docstring): on arrival the
    MIS quantities completed and the emission met weighted, at a smooth vertex the ``techniques``
    (next-event estimation, connections, merges), after the BSDF sample the quantities updated
    (``ppm`` mode: only delta samples go on, the path merged at its first smooth vertex)."""

    def __init__(self, scene, tech: Techniques, emitters: Emitters, hide: bool, techniques,
                 subpaths: _Subpath):  # fmt: skip
        self.scene, self.tech, self.emitters, self.hide = scene, tech, emitters, hide
        self.techniques, self.subpaths = techniques, subpaths

    def extra(self) -> _Subpath:
        return self.subpaths

    def arrive(self, walk, si, arrived, hit) -> None:
        sub = walk.extra
        cos_in = dr.maximum(dr.abs(mi.Frame3f.cos_theta(si.wi)), 1e-12)
        dist2 = dr.square(si.t + sub.offset)  # the first segment's from the camera's centre
        d_vcm, d_vc, d_vm = mis.after_hit(sub.d_vcm, sub.d_vc, sub.d_vm, dist2, cos_in)
        sub.d_vcm[hit] = d_vcm
        sub.d_vc[hit] = d_vc
        sub.d_vm[hit] = d_vm
        walk.radiance[hit] += walk.beta * _emission(
            self.scene, si, arrived, d_vcm, d_vc, sub.specular, sub.prev, self.tech,
            self.emitters, self.hide, hit,
        )  # fmt: skip

    def at_vertex(self, walk, si, bsdf, gen, arrived, here) -> mi.Spectrum:
        sub = walk.extra
        return self.techniques(si, bsdf, gen, arrived, sub.d_vcm, sub.d_vc, sub.d_vm, here)

    def bounced(self, walk, si, bsdf, bs, go_on) -> mi.Bool:
        sub = walk.extra
        quantities = (sub.d_vcm, sub.d_vc, sub.d_vm)
        (d_vcm, d_vc, d_vm), delta = after_sample(bsdf, RADIANCE, si, bs, quantities, self.tech,
                                                  go_on)  # fmt: skip
        if self.tech.mode == "ppm":
            go_on &= delta  # merged at the first smooth vertex; its delta lobes go on
        sub.specular[go_on] &= delta
        sub.prev[go_on] = mi.Interaction3f(si)
        sub.d_vcm[go_on] = d_vcm
        sub.d_vc[go_on] = d_vc
        sub.d_vm[go_on] = d_vm
        sub.offset[go_on] = 0.0
        return go_on


def _emission(scene, si, t, d_vcm, d_vc, specular, prev, tech: Techniques, emitters: Emitters,
              hide: bool, active):  # fmt: skip
    """``w L_e`` of an emitter met (TR (43): ``w = 1 / (1 + p_direct dVCM + p_e dVC)``, with
    ``p_direct`` next-event estimation's density of the point from the previous vertex; 1 for
    the emission seen directly; in ``ppm`` mode 1 along purely specular paths and 0 otherwise,
    in ``lt`` mode only the emission seen directly)."""
    emitter = si.emitter(scene, active)
    met = active & (emitter != None)  # noqa: E711 (Dr.Jit pointer test)
    radiance = emitter.eval(si, met)
    first = t == 1
    if tech.mode == "ppm":
        weight = dr.select(first | specular, 1.0, 0.0)
    elif tech.mode == "lt":
        weight = dr.select(first, 1.0, 0.0)
    else:
        later = met & ~first
        ds = mi.DirectionSample3f(scene, si, prev)
        cos_light = dr.abs(mi.Frame3f.cos_theta(si.wi))
        p_direct = scene.pdf_emitter_direction(prev, ds, later)
        p_direct_area = p_direct * cos_light / dr.square(si.t)
        p_e = emitters.emitted(si, emitter, cos_light, dr.zeros(mi.Bool, dr.width(t)))
        weight = dr.select(first, 1.0, mis.emission_weight(d_vcm, d_vc, p_direct_area, p_e))
    if hide:
        weight = dr.select(first, 0.0, weight)
    return dr.select(met, weight * radiance, 0.0)


def _next_event(scene, si, bsdf, gen, d_vcm, d_vc, vm_factor, tech: Techniques,
                emitters: Emitters, active):  # fmt: skip
    """Next-event estimation weighted by TR (44)–(45) (``pt`` mode: against the BSDF sample
    alone)."""
    u = mi.Point2f(gen.next_float32(), gen.next_float32())
    ds, em_weight = scene.sample_emitter_direction(si, u, False, active)
    lit = active & (ds.pdf > 0)  # a new mask: ``&=`` would change the caller's
    wo = si.to_local(ds.d)
    f, p_forward = bsdf.eval_pdf(RADIANCE, si, wo, lit)
    cos_light = dr.select(ds.delta, 1.0, dr.abs(dr.dot(ds.n, ds.d)))
    p_direct = dr.select(ds.delta, ds.pdf * dr.square(ds.dist), ds.pdf)  # per solid angle here
    p_forward = dr.select(ds.delta, 0.0, p_forward)  # no BSDF sample finds a delta light
    if tech.mode == "pt":  # against the BSDF sample alone
        weight = dr.rcp(1.0 + p_forward / p_direct)
    else:
        p_rev = reverse_pdf(bsdf, RADIANCE, si, wo, lit)
        p_e = emitters.emitted(ds, ds.emitter, cos_light, ds.delta)
        weight = mis.next_event_weight(d_vcm, d_vc, p_forward, p_direct, p_e,
                                       dr.abs(mi.Frame3f.cos_theta(wo)), cos_light, p_rev,
                                       vm_factor)  # fmt: skip
    lit &= dr.any(f != 0.0)
    lit &= ~scene.ray_test(si.spawn_ray_to(ds.p), lit)
    return dr.select(lit, weight * f * em_weight, 0.0)


@dr.syntax
def _connect(scene, si, bsdf, path, t, d_vcm, d_vc, vertices: LightVertices, vm_factor, limit,
             active):  # fmt: skip
    """Σ over the vertices of the light subpath ``path``: ``w β_L f_L f_C / d²`` with TR (40)–(41)
    ``w_light = p_C→L (η + dVCM_L + dVC_L p_L,rev)``, ``w_camera = p_L→C (η + dVCM + dVC
    p_C,rev)``, the densities per area; a shadow ray each."""
    k = dr.gather(mi.UInt32, vertices.start, path, active)
    end = dr.gather(mi.UInt32, vertices.start, path + 1, active)
    total = dr.zeros(mi.Spectrum, dr.width(path))
    while dr.hint(active & (k < end), exclude=[vertices]):  # read, not loop state
        light = dr.gather(mi.SurfaceInteraction3f, vertices.si, k)
        s = dr.gather(mi.UInt32, vertices.depth, k)
        ok = active & (k < end) & (s + 1 + t <= limit)
        d = light.p - si.p
        dist2 = dr.squared_norm(d)
        direction = d * dr.rsqrt(dist2)
        wo = si.to_local(direction)
        f, p = bsdf.eval_pdf(RADIANCE, si, wo, ok)
        p_rev = reverse_pdf(bsdf, RADIANCE, si, wo, ok)
        light_bsdf = light.bsdf()
        wo_light = light.to_local(-direction)
        f_light, p_light = light_bsdf.eval_pdf(IMPORTANCE, light, wo_light, ok)
        p_light_rev = reverse_pdf(light_bsdf, IMPORTANCE, light, wo_light, ok)
        weight = mis.connection_weight(
            (dr.gather(mi.Float, vertices.d_vcm, k), dr.gather(mi.Float, vertices.d_vc, k)),
            (d_vcm, d_vc), p, p_rev, p_light, p_light_rev, dr.abs(mi.Frame3f.cos_theta(wo)),
            dr.abs(mi.Frame3f.cos_theta(wo_light)), dist2, vm_factor,
        )  # fmt: skip
        value = f * f_light * dr.gather(mi.Spectrum, vertices.throughput, k) / dist2
        ok &= dr.any(value != 0.0)
        ok &= ~scene.ray_test(si.spawn_ray_to(_lifted(light, -direction)), ok)
        total[ok] += weight * value
        k += 1
    return total


def _lifted(si: mi.SurfaceInteraction3f, d: mi.Vector3f) -> mi.Point3f:
    """``si.p`` moved off its surface towards ``d`` as Mitsuba offsets a ray's origin (the far end
    of a shadow ray between two surface points must not hit its own surface)."""
    lift = (1.0 + dr.max(dr.abs(si.p))) * RAY_EPSILON
    return si.p + dr.mulsign(si.n * lift, dr.dot(si.n, d))


def _merge(grid: MergeGrid, si, bsdf, t, d_vcm, d_vm, tech: Techniques, limit, active):
    """``1/(π r² N_L) Σ w f_s β_L`` over the light vertices within ``r`` whose path fits
    ``max_depth`` (TR (38)–(39): ``w_light = dVCM_L / η + dVM_L p``, ``w_camera = dVCM / η +
    dVM p_rev``; ``w = 1`` in ``ppm`` mode), ``f_s`` without its cosine."""
    vc_factor = dr.opaque(mi.Float, tech.vc_factor)
    weighted = tech.mode != "ppm"

    def term(j, near):
        ok = near & (dr.gather(mi.UInt32, grid.depth, j, near) + t <= limit)
        wo = si.to_local(dr.gather(mi.Vector3f, grid.wi, j, ok))
        f, p = bsdf.eval_pdf(RADIANCE, si, wo, ok)
        f = f / dr.maximum(dr.abs(mi.Frame3f.cos_theta(wo)), 1e-4)
        weight = dr.ones(mi.Float, dr.width(t))
        if weighted:
            p_rev = reverse_pdf(bsdf, RADIANCE, si, wo, ok)
            light = (dr.gather(mi.Float, grid.d_vcm, j, ok), dr.gather(mi.Float, grid.d_vm, j, ok))
            weight = mis.merge_weight(light, (d_vcm, d_vm), p, p_rev, vc_factor)
        return dr.select(ok, weight * f * dr.gather(mi.Spectrum, grid.beta, j, ok), 0.0)

    zero = dr.zeros(mi.Spectrum, dr.width(t))
    radius2 = dr.opaque(mi.Float, tech.radius**2)
    total = grid.grid.sum_within(si.p, radius2, term, zero, active, span=2)
    return total * dr.opaque(mi.Float, tech.merge_normalization)
