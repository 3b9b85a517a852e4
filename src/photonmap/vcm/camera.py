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
from ..core.eye_rules import EyeRules, EyeVertexRule
from ..core.eye_trace import trace_eye_paths
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
    rule = CameraVertexRule(scene, tech, emitters, settings, (vertices, grid), subpaths)
    rules = EyeRules(settings, SceneTraits.of(scene), media_mode="transmit", vertex=rule)
    eye = trace_eye_paths(scene, (ray, mi.Spectrum(weight), dr.zeros(mi.MediumPtr, n)), gen,
                          rules)  # fmt: skip
    return pixel_means(eye.radiance, tech.spp)


class CameraVertexRule(EyeVertexRule):
    """The camera subpaths' vertex rule in the core's eye loop (module docstring): on arrival the
    MIS quantities completed and the emission met weighted, at a smooth vertex next-event
    estimation, connections and merges, after the BSDF sample the quantities updated (``ppm``
    mode: only delta samples go on, the path merged at its first smooth vertex). ``light``: the
    light pass's ``(vertices, grid)`` (None where the mode uses neither)."""

    def __init__(self, scene, tech: Techniques, emitters: Emitters, settings: PathSettings,
                 light: tuple, subpaths: _Subpath):  # fmt: skip
        self.scene, self.tech, self.emitters, self.subpaths = scene, tech, emitters, subpaths
        self.hide = settings.hide_emitters
        self.vertices, self.grid = light
        limit = 2**31 - 1 if settings.max_depth == UNBOUNDED else settings.max_depth
        self.limit = dr.opaque(mi.UInt32, limit)
        self.vm_factor = dr.opaque(mi.Float, tech.vm_factor)
        self.paths = dr.width(subpaths.d_vcm)

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
        walk.radiance[hit] += walk.beta * self._emission(si, arrived, (d_vcm, d_vc), sub, hit)

    def at_vertex(self, walk, si, bsdf, gen, arrived, here) -> mi.Spectrum:
        sub, tech = walk.extra, self.tech
        total = dr.zeros(mi.Spectrum, self.paths)
        if tech.nee:
            total += self._next_event(si, bsdf, gen, (sub.d_vcm, sub.d_vc), here)
        if tech.connect and self.vertices is not None:
            total += self._connect(si, bsdf, arrived, (sub.d_vcm, sub.d_vc), here)
        if tech.merge and self.grid is not None:
            total += self._merge(si, bsdf, arrived, (sub.d_vcm, sub.d_vm), here)
        return total

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

    def _emission(self, si, t, camera, sub: _Subpath, active):
        """``w L_e`` of an emitter met (TR (43): ``w = 1 / (1 + p_direct dVCM + p_e dVC)``,
        ``camera = (dVCM, dVC)``, with ``p_direct`` next-event estimation's density of the point
        from the previous vertex; 1 for the emission seen directly; in ``ppm`` mode 1 along
        purely specular paths and 0 otherwise, in ``lt`` mode only the emission seen
        directly)."""
        scene, tech = self.scene, self.tech
        emitter = si.emitter(scene, active)
        met = active & (emitter != None)  # noqa: E711 (Dr.Jit pointer test)
        radiance = emitter.eval(si, met)
        first = t == 1
        if tech.mode == "ppm":
            weight = dr.select(first | sub.specular, 1.0, 0.0)
        elif tech.mode == "lt":
            weight = dr.select(first, 1.0, 0.0)
        else:
            later = met & ~first
            ds = mi.DirectionSample3f(scene, si, sub.prev)
            cos_light = dr.abs(mi.Frame3f.cos_theta(si.wi))
            p_direct = scene.pdf_emitter_direction(sub.prev, ds, later)
            p_direct_area = p_direct * cos_light / dr.square(si.t)
            p_e = self.emitters.emitted(si, emitter, cos_light, dr.zeros(mi.Bool, dr.width(t)))
            weight = dr.select(first, 1.0, mis.emission_weight(*camera, p_direct_area, p_e))
        if self.hide:
            weight = dr.select(first, 0.0, weight)
        return dr.select(met, weight * radiance, 0.0)

    def _next_event(self, si, bsdf, gen, camera, active):
        """Next-event estimation weighted by TR (44)–(45), ``camera = (dVCM, dVC)`` (``pt``
        mode: against the BSDF sample alone)."""
        scene, tech = self.scene, self.tech
        u = mi.Point2f(gen.next_float32(), gen.next_float32())
        ds, em_weight = scene.sample_emitter_direction(si, u, False, active)
        lit = active & (ds.pdf > 0)  # a new mask: ``&=`` would change the caller's
        wo = si.to_local(ds.d)
        f, p_forward = bsdf.eval_pdf(RADIANCE, si, wo, lit)
        cos_light = dr.select(ds.delta, 1.0, dr.abs(dr.dot(ds.n, ds.d)))
        p_direct = dr.select(ds.delta, ds.pdf * dr.square(ds.dist), ds.pdf)  # per solid angle
        p_forward = dr.select(ds.delta, 0.0, p_forward)  # no BSDF sample finds a delta light
        if tech.mode == "pt":  # against the BSDF sample alone
            weight = dr.rcp(1.0 + p_forward / p_direct)
        else:
            p_rev = reverse_pdf(bsdf, RADIANCE, si, wo, lit)
            p_e = self.emitters.emitted(ds, ds.emitter, cos_light, ds.delta)
            here = (*camera, p_forward, p_rev, dr.abs(mi.Frame3f.cos_theta(wo)))
            weight = mis.next_event_weight(here, (p_direct, p_e, cos_light), self.vm_factor)
        lit &= dr.any(f != 0.0)
        lit &= ~scene.ray_test(si.spawn_ray_to(ds.p), lit)
        return dr.select(lit, weight * f * em_weight, 0.0)

    def _connect(self, si, bsdf, t, camera, active):
        """Σ over the vertices of the light subpath of the same lane (TR (40)–(41)), ``camera =
        (dVCM, dVC)``: :func:`_connect`."""
        path = dr.arange(mi.UInt32, self.paths)
        return _connect(self.scene, (si, bsdf, path, t), camera, self.vertices,
                        (self.vm_factor, self.limit), active)  # fmt: skip

    def _merge(self, si, bsdf, t, camera, active):
        """``1/(π r² N_L) Σ w f_s β_L`` over the light vertices within ``r`` whose path fits
        ``max_depth`` (TR (38)–(39): ``w_light = dVCM_L / η + dVM_L p``, ``w_camera = dVCM / η
        + dVM p_rev``, ``camera = (dVCM, dVM)``; ``w = 1`` in ``ppm`` mode), ``f_s`` without its
        cosine."""
        tech, grid, limit = self.tech, self.grid, self.limit
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
                light = (dr.gather(mi.Float, grid.d_vcm, j, ok),
                         dr.gather(mi.Float, grid.d_vm, j, ok))  # fmt: skip
                weight = mis.merge_weight(light, camera, p, p_rev, vc_factor)
            return dr.select(ok, weight * f * dr.gather(mi.Spectrum, grid.beta, j, ok), 0.0)

        zero = dr.zeros(mi.Spectrum, dr.width(t))
        radius2 = dr.opaque(mi.Float, tech.radius**2)
        total = grid.grid.sum_within(si.p, radius2, term, zero, active, span=2)
        return total * dr.opaque(mi.Float, tech.merge_normalization)


@dr.syntax
def _connect(scene, vertex, camera, vertices: LightVertices, constants, active):
    """Σ over the vertices of the light subpath ``path`` at the camera ``vertex = (si, bsdf,
    path, t)``: ``w β_L f_L f_C / d²`` with TR (40)–(41) ``w_light = p_C→L (η + dVCM_L + dVC_L
    p_L,rev)``, ``w_camera = p_L→C (η + dVCM + dVC p_C,rev)`` (``camera = (dVCM, dVC)``), the
    densities per area; a shadow ray each. ``constants = (η_VCM, max_depth)``."""
    si, bsdf, path, t = vertex
    vm_factor, limit = constants
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
        light_end = (
            dr.gather(mi.Float, vertices.d_vcm, k), dr.gather(mi.Float, vertices.d_vc, k),
            p_light, p_light_rev, dr.abs(mi.Frame3f.cos_theta(wo_light)),
        )  # fmt: skip
        camera_end = (*camera, p, p_rev, dr.abs(mi.Frame3f.cos_theta(wo)))
        weight = mis.connection_weight(light_end, camera_end, dist2, vm_factor)
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
