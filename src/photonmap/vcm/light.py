"""The light pass of vertex connection and merging: ``spp`` light subpaths per pixel, their vertices
stored, and each vertex connected to the camera (light tracing) (Georgiev et al. 2012 §5;
Georgiev 2012, TR §5.3; SmallVCM's ``vertexcm.hxx``, ``GenerateLightSample`` and the light loop).

**Emission.** A light is picked with Mitsuba's emitter distribution (``scene.sample_emitter``:
its ``sampling_weight``\\s), a point on it with ``sample_position`` and a direction
cosine-distributed about its normal (area lights), uniform on the sphere (point lights) or in
the cone of the cutoff angle (spot lights; a positional delta light's intensity is read through
``sample_direction``). The subpath's throughput is ``L_e cos θ / p_e`` with ``p_e`` the emission
density per area and solid angle, the pick included (``emissionPdfW``, :class:`Emitters`), and
its MIS quantities start as TR (31)–(33): ``dVCM = p_direct / p_e``, ``dVC = cos θ / p_e`` (0
for delta lights), ``dVM = dVC / η_VCM``.

Next-event estimation samples a point on a sphere light from the cone it subtends, not
uniformly on its area, so ``p_direct`` depends on the point it lights: the first vertex's
``dVCM`` is computed there from Mitsuba's own ``pdf_emitter_direction`` (the densities of every
technique are then exactly those that sample them).

**Vertices.** At each surface hit the quantities are completed (TR (31)–(36): × d², ÷ |cos|);
a vertex with a smooth lobe is stored (its interaction, throughput, segments from the light and
the three quantities) and, in the modes that use light tracing, connected to the camera: the
contribution ``w · β f_s(→ camera) W_e / d²`` lands in the pixel the camera sees it in, weighted
by TR (46) (the camera's density is Mitsuba's sensor importance over the crop, per pixel). The
subpath goes on by the adjoint BSDF sample (``TransportMode.Importance``) and Russian roulette
on its throughput from ``rr_depth`` on; a vertex needs a segment to the camera, so the subpath
stops where one more would not fit ``max_depth``.

**Transport.** The subpaths are the core's light paths (:func:`photonmap.core.photon_trace.trace_light_paths`:
its chunked wavefront, BSDF sampling in importance mode and Russian roulette), with
:class:`LightVertexRule` as their vertex rule: the MIS quantities ride along as the paths'
extra state, a ``Null`` event counts as a delta vertex (``PhotonRules.null_counts``), and each
stored vertex is connected to the camera. At the end the vertices are sorted by subpath (each
carries its rank on it): the camera pass connects each camera vertex to the vertices of the
subpath with its pixel's index.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import concat, to_numpy
from ..core.emission import LightPaths
from ..core.photon_trace import PhotonRules, VertexRule, trace_light_paths
from ..core.sampling import rng
from ..core.scene_info import SceneTraits
from ..core.settings import PathSettings
from . import mis
from .mis import Techniques

IMPORTANCE = mi.BSDFContext(mi.TransportMode.Importance)
RADIANCE = mi.BSDFContext()
FOLLOWED_DELTA = mi.BSDFFlags.Delta | mi.BSDFFlags.Null  # sampled events with no density


@dataclass
class LightVertices:
    """The stored vertices of one iteration's light subpaths, sorted by subpath; subpath ``i``'s
    are ``start[i] … start[i + 1] − 1``."""

    si: mi.SurfaceInteraction3f  # ``wi``: towards the previous vertex (local)
    throughput: mi.Spectrum  # β from the light, without the 1/N_L
    depth: mi.UInt32  # segments from the light (s)
    d_vcm: mi.Float
    d_vc: mi.Float
    d_vm: mi.Float
    start: mi.UInt32  # N_L + 1 offsets

    @property
    def count(self) -> int:
        return dr.width(self.depth)


@dataclass
class LightPass:
    """What the light pass made: the vertices and the light-tracing image (H×W×3, float64,
    the crop's pixels, not yet filtered)."""

    vertices: LightVertices
    image: np.ndarray
    paths: int


@dataclass(frozen=True)
class Emitters:
    """What the emission densities need of a scene's emitters: the sum of their sampling weights
    (Mitsuba picks emitter ``e`` with ``w_e / Σ w``) and, per positional delta light, the density
    of its light subpaths' directions: uniform on the sphere (point lights) or in the cone of
    the cutoff angle (spot lights, as Mitsuba's ``sample_ray`` samples them); per area light,
    the density of its positions, ``1 / area`` (Mitsuba's shapes sample positions uniformly by
    area). Both are tables of constants, one entry per light: a call through a shape pointer
    (``pdf_position``) would trace every shape of the scene, and a ``shapegroup`` implements
    none."""

    total_weight: float
    cones: tuple  # (mi.EmitterPtr, direction density) per point or spot light
    areas: tuple  # (mi.EmitterPtr, 1 / area) per area light

    @classmethod
    def of(cls, scene: mi.Scene) -> Emitters:
        cones, areas = [], []
        for emitter in scene.emitters():
            if emitter.get_shape() is not None:
                areas.append((mi.EmitterPtr(emitter), 1.0 / emitter.get_shape().surface_area()[0]))
            if not mi.has_flag(emitter.flags(), mi.EmitterFlags.DeltaPosition):
                continue
            cutoff = mi.traverse(emitter).get("cutoff_angle")
            cos_max = -1.0 if cutoff is None else math.cos(math.radians(float(cutoff[0])))
            cones.append((mi.EmitterPtr(emitter), 1.0 / (2.0 * math.pi * (1.0 - cos_max))))
        weight = sum(e.sampling_weight() for e in scene.emitters())
        return cls(weight, tuple(cones), tuple(areas))

    def pick(self, emitter: mi.EmitterPtr) -> mi.Float:
        """The probability that ``scene.sample_emitter`` picks ``emitter``."""
        return emitter.sampling_weight() / self.total_weight

    @staticmethod
    def _lookup(table: tuple, emitter: mi.EmitterPtr) -> mi.Float:
        """The value of ``emitter`` in ``table`` (0 for an emitter not in it)."""
        value = dr.zeros(mi.Float, dr.width(emitter))
        for ptr, entry in table:  # a loop over the lights, not over lanes
            value = dr.select(emitter == ptr, entry, value)
        return value

    def cone(self, emitter: mi.EmitterPtr) -> mi.Float:
        """A delta light's direction density (0 for other emitters)."""
        return self._lookup(self.cones, emitter)

    def emitted(self, si_or_ds, emitter, cos_light, delta) -> mi.Float:
        """``p_e``: the density with which a light subpath starts at the point of ``si_or_ds``
        (a position sample on ``emitter``) towards a direction at ``cos_light`` from its normal,
        per area and solid angle (per solid angle for delta lights), the pick included."""
        area = self._lookup(self.areas, emitter)
        per_direction = dr.select(delta, self.cone(emitter), area * cos_light / math.pi)
        return self.pick(emitter) * per_direction


@dataclass
class _Subpath:
    """A light subpath's MIS quantities and stored vertices so far — the extra state it carries
    through the core's loop — and what its first vertex's ``dVCM`` needs of its emission."""

    d_vcm: mi.Float
    d_vc: mi.Float
    d_vm: mi.Float
    rank: mi.UInt32  # vertices stored so far
    light: mi.PositionSample3f  # where it left the light ...
    emitter: mi.EmitterPtr  # ... which one
    delta: mi.Bool  # a positional delta light
    p_e: mi.Float  # the emission density (module docstring)
    cos_light: mi.Float


def reverse_pdf(bsdf, ctx, si: mi.SurfaceInteraction3f, wo: mi.Vector3f, active) -> mi.Float:
    """The density of sampling ``si.wi`` from ``wo`` (the reverse of the forward sample)."""
    swapped = mi.SurfaceInteraction3f(si)
    swapped.wi = wo
    return bsdf.pdf(ctx, swapped, si.wi, active)


def after_sample(bsdf, ctx, si, bs, quantities, tech: Techniques, active):
    """The MIS quantities ``(dVCM, dVC, dVM)`` for the segment after the BSDF sample ``bs`` at
    ``si`` (TR (34)–(36), SmallVCM's ``SampleScattering``): after a delta (or ``Null``) event
    ``dVCM = 0`` and the other two are scaled by ``cos θ_o``; otherwise ``dVC = cos θ_o / p (dVC
    p_rev + dVCM + η)``, ``dVM = cos θ_o / p (dVM p_rev + dVCM / η + 1)``, ``dVCM = 1 / p``.
    Also returns whether it was a delta event."""
    d_vcm, d_vc, d_vm = quantities
    delta = mi.has_flag(bs.sampled_type, FOLLOWED_DELTA)
    cos_out = dr.abs(mi.Frame3f.cos_theta(bs.wo))
    p_rev = reverse_pdf(bsdf, ctx, si, bs.wo, active & ~delta)
    vm_factor, vc_factor = dr.opaque(mi.Float, tech.vm_factor), dr.opaque(mi.Float, tech.vc_factor)
    smooth = mis.after_bounce(d_vcm, d_vc, d_vm, cos_out, dr.maximum(bs.pdf, 1e-30), p_rev,
                              vm_factor, vc_factor)  # fmt: skip
    specular = mis.after_delta(d_vcm, d_vc, d_vm, cos_out)
    new_vcm, new_vc, new_vm = (dr.select(delta, a, b) for a, b in zip(specular, smooth,
                                                                        strict=True))
    if not tech.connect:  # no connections: the subpaths need dVC only for them (module docstring)
        new_vc = dr.zeros(mi.Float, dr.width(new_vc))
    return (new_vcm, new_vc, new_vm), delta


def _emit(scene: mi.Scene, n: int, gen, tech: Techniques, emitters: Emitters):
    """Emit ``n`` subpaths (module docstring): their rays and throughput as the core's
    :class:`~photonmap.core.emission.LightPaths`, and their :class:`_Subpath` state."""
    idx, _, _ = scene.sample_emitter(gen.next_float32())
    emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), idx)
    delta = mi.has_flag(emitter.flags(), mi.EmitterFlags.DeltaPosition)
    ps, _ = emitter.sample_position(0.0, mi.Point2f(gen.next_float32(), gen.next_float32()))
    u = mi.Point2f(gen.next_float32(), gen.next_float32())
    local = mi.warp.square_to_cosine_hemisphere(u)
    si0 = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
    si0.wi = local
    delta_ray, _ = emitter.sample_ray(0.0, 0.5, u, u, delta)  # point: sphere, spot: cone
    d = dr.select(delta, delta_ray.d, si0.to_world(local))
    cos_light = dr.select(delta, 1.0, mi.Frame3f.cos_theta(local))
    radiance = emitter.eval(si0, ~delta) * cos_light
    it = dr.zeros(mi.Interaction3f, n)
    it.p = ps.p + d
    _, intensity = emitter.sample_direction(it, mi.Point2f(0.5, 0.5), delta)  # I(d) / 1²
    p_e = emitters.emitted(ps, emitter, cos_light, delta)
    beta = dr.select(delta, intensity, radiance) / dr.maximum(p_e, 1e-30)
    ray = si0.spawn_ray(d)
    ray.o = dr.select(delta, ps.p, ray.o)  # a point light's rays leave from the point itself
    p_e = dr.maximum(p_e, 1e-30)
    d_vc, d_vm = mis.light_start(p_e, cos_light, dr.opaque(mi.Float, tech.vc_factor))
    d_vc, d_vm = (dr.select(delta, 0.0, v) for v in (d_vc, d_vm))
    if not tech.connect:
        d_vc = dr.zeros(mi.Float, n)
    zeros = dr.zeros(mi.UInt32, n)
    subpaths = _Subpath(dr.zeros(mi.Float, n), d_vc, d_vm, zeros, ps, emitter, delta, p_e,
                        cos_light)  # fmt: skip
    paths = LightPaths(ray, mi.Color3f(beta), dr.zeros(mi.MediumPtr, n), dr.zeros(mi.Bool, n),
                       dr.zeros(mi.Bool, n), np.zeros(3), 0)  # fmt: skip
    return paths, subpaths


RECORD_FIELDS = {
    "si": mi.SurfaceInteraction3f, "throughput": mi.Spectrum, "depth": mi.UInt32,
    "d_vcm": mi.Float, "d_vc": mi.Float, "d_vm": mi.Float, "path": mi.UInt32, "rank": mi.UInt32,
    "pixel": mi.UInt32, "splat": mi.Spectrum,
}  # fmt: skip


def light_pass(
    scene: mi.Scene, sensor: mi.Sensor, seed: int, settings: PathSettings, tech: Techniques,
    emitters: Emitters,
) -> LightPass:
    """Trace ``tech.light_paths`` light subpaths (random numbers from ``seed``), store their
    vertices and, where light tracing is one of the techniques, their splats into the image
    (each splat × ``P / N_L = 1 / spp``: the estimate is the mean over the light subpaths)."""
    n = tech.light_paths
    w, h = (int(c) for c in sensor.film().crop_size())
    gen = rng(n, seed, 2)
    paths, subpaths = _emit(scene, n, gen, tech, emitters)
    rules = PhotonRules(settings, SceneTraits.of(scene), null_counts=True)
    rule = LightVertexRule(scene, sensor, tech, emitters, subpaths)
    records, _ = trace_light_paths(scene, paths, gen, rules, vertices=rule)
    image = np.zeros((h, w, 3))
    if tech.light_tracing and dr.width(records["pixel"]):
        pixel = records["pixel"].numpy()
        splat = to_numpy(records["splat"]).astype(np.float64)
        for c in range(3):  # a fixed order of summation: deterministic
            image[..., c] = np.bincount(pixel, splat[c], minlength=w * h + 1)[: w * h].reshape(h, w)
    image /= tech.spp
    return LightPass(_sorted(records, n), image, n)


class LightVertexRule(VertexRule):
    """The light subpaths' vertex rule in the core's loop (module docstring): on arrival the MIS
    quantities are completed (the first vertex's ``dVCM`` from next-event estimation's density
    of its light point), each stored vertex carries them and its light-tracing splat, and after
    the BSDF sample they are updated for the next segment."""

    fields = RECORD_FIELDS

    def __init__(self, scene, sensor, tech: Techniques, emitters: Emitters, subpaths: _Subpath):
        self.scene, self.sensor, self.tech = scene, sensor, tech
        self.emitters, self.subpaths = emitters, subpaths
        self.size = tuple(int(c) for c in sensor.film().crop_size())

    def extra(self) -> _Subpath:
        return self.subpaths

    def arrive(self, state, si, on_surface) -> None:
        sub = state.extra
        first = on_surface & (state.depth == 0)
        cos_in = dr.maximum(dr.abs(mi.Frame3f.cos_theta(si.wi)), 1e-12)
        dist2 = dr.square(si.t)
        ds = mi.DirectionSample3f(sub.light)
        ds.d = dr.normalize(sub.light.p - si.p)
        ds.dist = si.t
        ds.emitter = sub.emitter
        pick = self.emitters.pick(sub.emitter)
        p_direct = dr.select(  # next-event estimation's density of the light point, per area
            sub.delta, pick,
            self.scene.pdf_emitter_direction(mi.Interaction3f(si), ds, first & ~sub.delta)
            * sub.cos_light / dist2,
        )  # fmt: skip
        d_vcm, d_vc, d_vm = mis.after_hit(sub.d_vcm, sub.d_vc, sub.d_vm, dist2, cos_in)
        d_vcm = dr.select(first, mis.first_light_hit(p_direct, sub.p_e, dist2, cos_in), d_vcm)
        sub.d_vcm[on_surface] = d_vcm
        sub.d_vc[on_surface] = d_vc
        sub.d_vm[on_surface] = d_vm

    def record(self, state, si, bsdf, store, caustic) -> tuple:
        sub = state.extra
        pixel, splat = self._to_camera(si, bsdf, state.power, (sub.d_vcm, sub.d_vc), store)
        rank = mi.UInt32(sub.rank)  # a copy: the masked update below is in place
        sub.rank[store] += 1
        return (si, state.power, state.depth + 1, sub.d_vcm, sub.d_vc, sub.d_vm, state.path,
                rank, pixel, splat)  # fmt: skip

    def bounced(self, state, si, bsdf, bs, bounced) -> None:
        sub = state.extra
        quantities = (sub.d_vcm, sub.d_vc, sub.d_vm)
        (d_vcm, d_vc, d_vm), _ = after_sample(bsdf, IMPORTANCE, si, bs, quantities, self.tech,
                                              bounced)  # fmt: skip
        sub.d_vcm[bounced] = d_vcm
        sub.d_vc[bounced] = d_vc
        sub.d_vm[bounced] = d_vm

    def result(self, records: dict, light: LightPaths, rays: int) -> dict:
        return records

    def _to_camera(self, si, bsdf, beta, light, active):
        """Light tracing at a stored vertex: its pixel (``w · h`` where it misses the crop) and
        the splat ``w_LT · β f_s W_e / d²`` (TR (46): ``w_light = p_cam (η + dVCM + dVC
        p_rev)``, ``light = (dVCM, dVC)``; the only technique in ``lt`` mode)."""
        scene, sensor, tech = self.scene, self.sensor, self.tech
        w, h = self.size
        miss = dr.full(mi.UInt32, w * h, dr.width(active))
        if not tech.light_tracing:
            return miss, dr.zeros(mi.Spectrum, dr.width(active))
        ds, importance = sensor.sample_direction(si, mi.Point2f(0.5, 0.5), active)
        wo = si.to_local(ds.d)
        seen = active & (ds.pdf > 0) & dr.any(importance > 0)
        f = bsdf.eval(IMPORTANCE, si, wo, seen)
        seen &= dr.any(f != 0.0) & ~scene.ray_test(si.spawn_ray_to(ds.p), seen)
        x, y = mi.UInt32(dr.floor(ds.uv.x)), mi.UInt32(dr.floor(ds.uv.y))
        seen &= (ds.uv.x >= 0) & (ds.uv.y >= 0) & (x < w) & (y < h)
        weight = dr.ones(mi.Float, dr.width(active))
        if tech.mode != "lt":
            p_rev = reverse_pdf(bsdf, IMPORTANCE, si, wo, seen)
            p_camera = importance.x * dr.abs(mi.Frame3f.cos_theta(wo))  # × P / N_L = 1
            weight = mis.light_tracing_weight(*light, p_camera, p_rev,
                                              dr.opaque(mi.Float, tech.vm_factor))  # fmt: skip
        splat = dr.select(seen, weight * beta * f * importance, 0.0)
        return dr.select(seen, y * w + x, miss), splat


def _sorted(records: dict, n: int) -> LightVertices:
    """The records sorted by subpath: subpath ``i``'s vertex of rank ``k`` goes to
    ``start[i] + k`` (integer counts and an exclusive prefix sum: deterministic)."""
    count = dr.width(records["depth"])
    counts = dr.zeros(mi.UInt32, n)
    if count:
        dr.scatter_reduce(dr.ReduceOp.Add, counts, 1, records["path"])
    start = dr.prefix_sum(counts)  # exclusive
    start = concat([start, dr.opaque(mi.UInt32, count)]) if n else mi.UInt32([0])
    keys = ("si", "throughput", "depth", "d_vcm", "d_vc", "d_vm")
    if not count:
        return LightVertices(*(records[k] for k in keys), start)
    target = dr.gather(mi.UInt32, start, records["path"]) + records["rank"]
    out = []
    for k in keys:
        value = dr.zeros(RECORD_FIELDS[k], count)
        dr.scatter(value, records[k], target)
        out.append(value)
    dr.eval(*out)
    return LightVertices(*out, start)
