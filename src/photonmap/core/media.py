"""Participating media through Mitsuba's own ``Medium`` and ``PhaseFunction`` API — the medium
helpers of volumetric photon mapping (Jensen & Christensen 1998; spec beyond-seeds §4), shared by
the methods that trace rays through fog.

**Which medium a ray is in** follows Mitsuba's ``volpath`` exactly: a sensor ray starts in
``sensor.get_medium()``, a photon in ``emitter.get_medium()``; at a surface that is a medium
transition (a shape with an ``interior`` or ``exterior`` medium) the ray continues in
``si.target_medium(d)`` for its new direction ``d``, and at any other surface it keeps its medium.
``null``-BSDF surfaces (fog boxes) only switch the medium: the ray goes on unchanged.

**Free flight** (:func:`free_flight`): distances sampled by ``medium.sample_interaction`` in one
colour channel (chosen per lane, as ``volpath`` does), weighted by ``T / p`` from
``medium.transmittance_eval_pdf``; heterogeneous media sample against their majorant and reject
null collisions with probability ``σ_n / σ̄`` (delta tracking), so homogeneous and ``heterogeneous``
grid media take the same path. At a real collision the weight holds ``σ_s / p``: the scattering
albedo ``σ_s / σ_t`` for a grey medium.

**Transmittance** (:func:`transmittance`): along a finite ray through any number of ``null``
boundaries, ``exp(−σ_t d)`` in closed form in homogeneous media and ratio tracking
(``T ← T σ_n / σ̄`` at each tentative collision) in heterogeneous ones; any other surface on the
way blocks it (the visibility of :func:`photonmap.core.bsdf.occluded`, graded).

**The volume photon map** (:class:`VolumeMap`): photons stored at medium scattering events
(position, travel direction ω_p, scattered power Φ_p) in a :class:`~photonmap.core.hashgrid.HashGrid`
searched without a normal test; its radiance estimate (beyond-seeds §4)

    L_s(x, ω) ≈ Σ_p f_p(x, ω_p, ω) Φ_p / ((4/3) π r³)

is the in-scattered radiance per unit length, ``r`` the distance of the k-th photon or the maximum
radius where fewer were found (the sphere that was searched, as the surface gathers do).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .bsdf import is_null
from .hashgrid import HashGrid
from .knn import NO_PHOTON
from .sampling import rng

MAX_EVENTS = 256  # null collisions + boundary crossings in one free flight or transmittance ray


def scene_media(scene: mi.Scene) -> list:
    """The distinct ``mi.Medium`` objects of ``scene`` (shape interiors and exteriors, sensors,
    emitters)."""
    found = {}
    candidates = []
    for shape in scene.shapes():
        candidates += [shape.interior_medium(), shape.exterior_medium()]
    candidates += [s.get_medium() for s in scene.sensors()]
    candidates += [e.get_medium() for e in scene.emitters()]
    for medium in candidates:
        if medium is not None:
            found.setdefault(medium.ptr, medium)
    return list(found.values())


def channel(gen: mi.PCG32) -> mi.UInt32:
    """The colour channel that samples each lane's free-flight distances (``volpath``)."""
    n = dr.size_v(mi.Spectrum)
    return dr.minimum(mi.UInt32(gen.next_float32() * n), n - 1)


def pick(spectrum: mi.Spectrum, ch: mi.UInt32) -> mi.Float:
    """Component ``ch`` of ``spectrum`` per lane."""
    return dr.select(ch == 0, spectrum[0], dr.select(ch == 1, spectrum[1], spectrum[2]))


def enter(
    si: mi.SurfaceInteraction3f, d: mi.Vector3f, medium: mi.MediumPtr, active
) -> mi.MediumPtr:
    """The medium a ray leaving ``si`` along ``d`` travels in: ``si.target_medium(d)`` at a medium
    transition, else ``medium`` (``volpath``)."""
    change = active & si.is_valid() & si.is_medium_transition()
    return dr.select(change, si.target_medium(d), medium)


def broadcast(medium: mi.Medium | None, n: int) -> mi.MediumPtr:
    """``medium`` (a scene's medium or None) in every one of ``n`` lanes."""
    return dr.gather(mi.MediumPtr, mi.MediumPtr(medium), dr.zeros(mi.UInt32, n))


def full_width(ray: mi.Ray3f, n: int) -> mi.Ray3f:
    """A copy of ``ray`` with every field ``n`` lanes wide (loop variables must be full width)."""
    zero = dr.zeros(mi.Float, n)
    return mi.Ray3f(ray.o + zero, ray.d + zero, ray.maxt + zero, ray.time + zero, ray.wavelengths)


def interaction(
    p: mi.Point3f, d: mi.Vector3f, t: mi.Float, medium: mi.MediumPtr
) -> mi.MediumInteraction3f:
    """A medium interaction at ``p`` on a ray travelling along ``d`` (``wi = −d``, as
    ``sample_interaction`` sets it), for phase-function and coefficient queries."""
    mei = dr.zeros(mi.MediumInteraction3f, dr.width(p))
    mei.p = mi.Point3f(p)
    mei.wi = -mi.Vector3f(d)
    mei.sh_frame = mi.Frame3f(mei.wi)
    mei.t = mi.Float(t)
    mei.medium = mi.MediumPtr(medium)
    return mei


ESCAPE_FREE_PATHS = 10.0  # an escaping ray is marched this many mean free paths beyond the scene


def escape_length(
    scene: mi.Scene, ray: mi.Ray3f, medium: mi.MediumPtr, active: mi.Bool
) -> mi.Float:
    """How far to march ``ray`` when it leaves the scene inside ``medium`` (e.g. the sensor's
    medium around everything): to the exit of the medium's bounding box where it has one
    (a grid volume), else to the exit of the scene's bounding box and then
    :data:`ESCAPE_FREE_PATHS` mean free paths (σ_t at the ray's origin) further, beyond which
    less than e⁻¹⁰ of the light remains."""
    _, _, medium_exit = medium.intersect_aabb(ray)
    box = scene.bbox()
    lo, hi = mi.Point3f(box.min), mi.Point3f(box.max)
    inv = dr.rcp(ray.d)
    far = dr.maximum((lo - ray.o) * inv, (hi - ray.o) * inv)
    scene_exit = dr.maximum(dr.min(far), 0.0)
    _, _, sigma_t = medium.get_scattering_coefficients(
        interaction(ray.o, ray.d, 0.0, medium), active
    )
    beyond = ESCAPE_FREE_PATHS / dr.maximum(dr.mean(sigma_t), 1e-6)
    return dr.select(dr.isfinite(medium_exit), medium_exit, scene_exit + beyond)


@dataclass
class Flight:
    """Result of :func:`free_flight` per lane: ``scattered`` — a real collision at ``mei``;
    otherwise the ray ended at ``si`` (a surface that is not ``null``, or an invalid hit: it
    escaped). ``weight``: ``T/p`` along the flight (``σ_s T / p`` where it scattered);
    ``medium``: the medium at the end (where ``si`` is hit)."""

    si: mi.SurfaceInteraction3f
    mei: mi.MediumInteraction3f
    weight: mi.Spectrum
    scattered: mi.Bool
    medium: mi.MediumPtr


@dr.syntax
def free_flight(
    scene: mi.Scene,
    ray: mi.Ray3f,
    medium: mi.MediumPtr,
    gen: mi.PCG32,
    ch: mi.UInt32,
    active: mi.Bool,
) -> Flight:
    """Sample where ``ray`` (unit direction) next interacts: a real collision in a medium or the
    next non-``null`` surface (module docstring). ``ch``: the sampling channel per lane
    (:func:`channel`)."""
    n = dr.width(active)
    ray = full_width(ray, n)
    medium = mi.MediumPtr(medium)
    weight = dr.full(mi.Spectrum, 1.0, n)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    mei = dr.zeros(mi.MediumInteraction3f, n)
    scattered = dr.zeros(mi.Bool, n)
    going = mi.Bool(active)
    needs_hit = mi.Bool(active)
    events = dr.zeros(mi.UInt32, n)
    while going & (events < MAX_EVENTS):
        si_next = scene.ray_intersect(ray, going & needs_hit)
        si[going & needs_hit] = si_next
        needs_hit = dr.zeros(mi.Bool, n)
        in_medium = going & (medium != None)  # noqa: E711 (Dr.Jit pointer test)
        segment = mi.Ray3f(ray)
        segment.maxt = dr.minimum(ray.maxt, si.t)
        m = medium.sample_interaction(segment, gen.next_float32(), ch, in_medium)
        collide = in_medium & m.is_valid() & (m.t < segment.maxt)
        m.t = dr.select(collide, m.t, dr.inf)
        ends = mi.SurfaceInteraction3f(si)
        ends.t = segment.maxt
        tr, pdf = medium.transmittance_eval_pdf(m, ends, in_medium)
        p_ch = pick(pdf, ch)
        weight[in_medium] *= dr.select(p_ch > 0, tr / p_ch, 0.0)
        real_p = dr.select(
            collide, dr.mean(m.sigma_t / dr.maximum(m.combined_extinction, 1e-30)), 1.0
        )
        real = collide & (gen.next_float32() < real_p)
        null_hit = collide & ~real
        weight[null_hit] *= m.sigma_n / dr.maximum(1.0 - real_p, 1e-30)
        weight[real] *= m.sigma_s / real_p
        scattered |= real
        mei[real] = m
        ray.o[null_hit] = m.p
        ray.maxt[null_hit] = ray.maxt - m.t
        si.t[null_hit] = si.t - m.t
        # the surface at the end of the segment: a null boundary switches the medium only
        surface = going & ~collide & si.is_valid()
        cross = surface & is_null(si.bsdf(ray), surface) & (si.emitter(scene) == None)  # noqa: E711
        medium = enter(si, ray.d, medium, cross)
        crossed = si.spawn_ray(ray.d)
        crossed.maxt = ray.maxt - si.t
        ray[cross] = crossed
        needs_hit |= cross
        going = (null_hit | cross) & dr.any(weight != 0.0)
        events += 1
    return Flight(si, mei, weight, scattered, medium)


@dr.syntax
def segment_transmittance(
    ray: mi.Ray3f,
    length: mi.Float,
    medium: mi.MediumPtr,
    gen: mi.PCG32,
    ch: mi.UInt32,
    active: mi.Bool,
) -> mi.Spectrum:
    """Transmittance of ``medium`` over ``[0, length]`` of ``ray`` (unit direction; no surface on
    the way): ``exp(−σ_t length)`` in a homogeneous medium, ratio tracking (``T ← T σ_n / σ̄`` at
    each tentative collision against the majorant σ̄, in channel ``ch``) in a heterogeneous one;
    1 in vacuum (``medium`` None)."""
    n = dr.width(active)
    ray = full_width(ray, n)
    ray.maxt = dr.select(active, length, 0.0)
    in_medium = active & (medium != None)  # noqa: E711
    homogeneous = in_medium & medium.is_homogeneous()
    _, _, sigma_t = medium.get_scattering_coefficients(
        interaction(ray.o, ray.d, 0.0, medium), homogeneous
    )
    T = dr.full(mi.Spectrum, 1.0, n)
    T[homogeneous] = dr.exp(-sigma_t * length)
    tracking = in_medium & ~homogeneous
    events = dr.zeros(mi.UInt32, n)
    while tracking & (events < MAX_EVENTS):
        m = medium.sample_interaction(ray, gen.next_float32(), ch, tracking)
        collide = tracking & m.is_valid() & (m.t < ray.maxt)
        dist = dr.select(collide, m.t, ray.maxt) - m.mint
        tr = dr.exp(-dist * m.combined_extinction)
        pdf = pick(dr.select(collide, tr * m.combined_extinction, tr), ch)
        T[tracking] *= dr.select(pdf > 0, tr / pdf, 0.0)
        T[collide] *= m.sigma_n
        ray.o[collide] = m.p
        ray.maxt[collide] = ray.maxt - m.t
        tracking = collide & dr.any(T != 0.0)
        events += 1
    return T


@dr.syntax
def transmittance(
    scene: mi.Scene,
    ray: mi.Ray3f,
    medium: mi.MediumPtr,
    gen: mi.PCG32,
    ch: mi.UInt32,
    active: mi.Bool,
) -> mi.Spectrum:
    """Transmittance along the finite ``ray`` (unit direction, length ``ray.maxt``) starting in
    ``medium``: zero where a surface other than a ``null`` boundary lies on it, else the product of
    the media's transmittances between the boundaries (:func:`segment_transmittance`)."""
    n = dr.width(active)
    ray = full_width(ray, n)
    medium = mi.MediumPtr(medium)
    T = dr.full(mi.Spectrum, 1.0, n)
    T[~active] = 0.0
    going = mi.Bool(active)
    crossings = dr.zeros(mi.UInt32, n)
    while going & (crossings < MAX_EVENTS):
        si = scene.ray_intersect(ray, going)
        end = dr.minimum(si.t, ray.maxt)
        T[going] *= segment_transmittance(ray, end, medium, gen, ch, going)
        surface = going & si.is_valid()
        cross = surface & is_null(si.bsdf(ray), surface) & (si.emitter(scene) == None)  # noqa: E711
        T[surface & ~cross] = 0.0
        medium = enter(si, ray.d, medium, cross)
        crossed = si.spawn_ray(ray.d)
        crossed.maxt = ray.maxt - si.t
        ray[cross] = crossed
        going = cross & dr.any(T != 0.0)
        crossings += 1
    return T


def shadow_ray(origin: mi.Interaction3f, target: mi.Point3f) -> mi.Ray3f:
    """A unit-direction ray from ``origin`` (offset off its surface, if any) that stops short of
    ``target`` by Mitsuba's shadow epsilon (``spawn_ray_to``)."""
    return origin.spawn_ray_to(target)


@dataclass
class VolumePhotons:
    """Photons stored at medium scattering events: position, travel direction ω_p before the
    event, the power scattered there Φ_p (the arriving power times ``σ_s/σ_t``), and ``direct``:
    the photon came straight from the emitter (no scattering or surface bounce before, ``null``
    crossings aside) — the first-event photons that :func:`photonmap.surface` replaces by ray
    marching with shadow rays."""

    position: mi.Point3f
    direction: mi.Vector3f
    power: mi.Color3f
    direct: mi.Bool

    @property
    def count(self) -> int:
        return dr.width(self.direct)

    def select(self, mask: mi.Bool) -> VolumePhotons:
        index = dr.compress(mask)
        fields = (self.position, self.direction, self.power, self.direct)
        return VolumePhotons(*(dr.gather(type(f), f, index) for f in fields))


VOLUME_RADIUS = 0.1  # automatic volume gather radius, × scene diagonal
STEP_SAMPLES = 4096  # volume photons whose k-NN radius sets the automatic march step


@dataclass
class VolumeMap:
    """Volume photons and a hash grid over their positions (k-NN without the normal test)."""

    photons: VolumePhotons
    grid: HashGrid | None

    @classmethod
    def build(cls, photons: VolumePhotons) -> VolumeMap:
        return cls(photons, HashGrid(photons.position) if photons.count else None)

    @property
    def size(self) -> int:
        return self.photons.count

    def march_step(self, k: int, radius: float, samples: int = STEP_SAMPLES) -> float:
        """An automatic ray-marching step: half the median distance of the ``k``-th nearest
        photon (``radius`` where fewer lie within it) over up to ``samples`` of the photons —
        the step follows the photon density, as the radius of the estimate does."""
        if self.size == 0:
            return radius
        every = max(1, self.size // samples)
        index = dr.arange(mi.UInt32, 0, self.size, every)
        at = dr.gather(mi.Point3f, self.photons.position, index)
        found = self.grid.knn(at, k=k, max_radius=radius)
        r2 = dr.select(found.count < k, radius**2, found.radius2)
        return 0.5 * float(np.sqrt(np.median(r2.numpy())))


def inscattered(
    vmap: VolumeMap, mei: mi.MediumInteraction3f, k: int, max_radius: float, active: mi.Bool
) -> mi.Spectrum:
    """``L_s(x, ω) ≈ Σ f_p(x, ω_p, ω) Φ_p / ((4/3) π r³)`` at ``mei.p`` towards ``mei.wi``
    (beyond-seeds §4) from the ``k`` nearest volume photons within ``max_radius``; the phase
    function is the one of ``mei.medium``."""
    count = dr.width(mei.p)
    if vmap.size == 0:
        return dr.zeros(mi.Spectrum, count)
    active = active & dr.full(mi.Bool, True, count)
    nb = vmap.grid.knn(mei.p, k=k, max_radius=max_radius)
    return _phase_sum(vmap, mei, nb, k, max_radius, active)


@dr.syntax
def _phase_sum(vmap, mei, nb, k, max_radius, active):
    """The sum of :func:`inscattered` over the neighbours ``nb``, divided by the sphere."""
    count = dr.width(mei.p)
    phase = mei.medium.phase_function()
    ctx = mi.PhaseFunctionContext(None)
    base = dr.arange(mi.UInt32, count) * k
    L = dr.zeros(mi.Spectrum, count)
    j = dr.zeros(mi.UInt32, count)
    while active & (j < nb.count):
        idx = dr.gather(mi.UInt32, nb.index, base + j)
        power = dr.gather(mi.Color3f, vmap.photons.power, idx, active)
        wo = -dr.gather(mi.Vector3f, vmap.photons.direction, idx, active)
        f, _ = phase.eval_pdf(ctx, mei, wo, active)
        L += f * power
        j += 1
    return dr.select(active & (nb.count > 0), L / _sphere(nb, k, max_radius), 0.0)


@dataclass
class ScatteredDensity:
    """The volume map's scattered power density ``S = Σ Φ_p / ((4/3) π r³)`` precomputed at every
    ``every``-th volume photon (the volume analogue of Christensen 1999's precomputed irradiance,
    :mod:`photonmap.surface.irradiance`): in an isotropic medium ``L_s = S / (4π)`` wherever the
    nearest precomputed point (one cell edge of its hash grid at most) is read — a lazy lookup
    that fuses into the caller's kernel instead of a k-NN gather per point."""

    position: mi.Point3f
    density: mi.Color3f
    grid: HashGrid

    @classmethod
    def build(cls, vmap: VolumeMap, every: int, k: int, max_radius: float) -> ScatteredDensity:
        index = dr.arange(mi.UInt32, 0, vmap.size, every)
        position = dr.gather(mi.Point3f, vmap.photons.position, index)
        dr.eval(position)
        density = dr.zeros(mi.Color3f, dr.width(index))
        for first in range(0, dr.width(index), CHUNK):
            chunk = dr.arange(mi.UInt32, first, min(dr.width(index), first + CHUNK))
            at = dr.gather(mi.Point3f, position, chunk)
            nb = vmap.grid.knn(at, k=k, max_radius=max_radius)
            dr.scatter(density, _power_sum(vmap, nb, k, max_radius), chunk)
            dr.eval(density)
        return cls(position, density, HashGrid(position))

    def inscattered(self, p: mi.Point3f, active) -> mi.Spectrum:
        """``L_s = S / (4π)`` at ``p`` from the nearest precomputed point (isotropic media)."""
        index, _ = self.grid.nearest(p, self.grid.cell_size, active=active)
        found = active & (index != NO_PHOTON)
        density = dr.gather(mi.Color3f, self.density, index, found)
        return dr.select(found, density / (4.0 * math.pi), 0.0)


@dr.syntax
def _power_sum(vmap, nb, k, max_radius):
    """``Σ Φ_p / ((4/3) π r³)`` over the neighbours ``nb`` of each query."""
    count = dr.width(nb.count)
    base = dr.arange(mi.UInt32, count) * k
    S = dr.zeros(mi.Color3f, count)
    j = dr.zeros(mi.UInt32, count)
    while j < nb.count:
        S += dr.gather(mi.Color3f, vmap.photons.power, dr.gather(mi.UInt32, nb.index, base + j))
        j += 1
    return S / _sphere(nb, k, max_radius)


def _sphere(nb, k: int, max_radius: float) -> mi.Float:
    """``(4/3) π r³``: r the distance of the k-th photon, or ``max_radius`` where fewer were
    found (the sphere that was searched); at least a tiny positive volume."""
    r2 = dr.select(nb.count < k, dr.opaque(mi.Float, max_radius**2), nb.radius2)
    return dr.maximum((4.0 / 3.0) * math.pi * r2 * dr.sqrt(r2), 1e-30)


def isotropic(scene: mi.Scene) -> bool:
    """Whether every medium of ``scene`` has an isotropic phase function."""
    return all(
        mi.has_flag(m.phase_function().flags(), mi.PhaseFunctionFlags.Isotropic)
        for m in scene_media(scene)
    )


def within_extent(mei: mi.MediumInteraction3f) -> mi.Bool:
    """Whether ``mei.p`` lies where ``mei.medium`` exists: inside a grid volume's bounding box
    (Mitsuba's heterogeneous medium has interactions only there, while its grid lookups clamp
    to the border values outside it), everywhere for a homogeneous medium."""
    hit, mint, maxt = mei.medium.intersect_aabb(mi.Ray3f(mei.p, mi.Vector3f(0, 0, 1)))
    return hit & (mint <= 0) & (maxt >= 0)


def direct_inscattered(
    scene: mi.Scene,
    mei: mi.MediumInteraction3f,
    u: mi.Point2f,
    gen: mi.PCG32,
    ch: mi.UInt32,
    active: mi.Bool,
) -> mi.Spectrum:
    """Single scattering of direct light at ``mei`` towards ``mei.wi`` per unit length,
    ``σ_s f_p L_e T / p``: one emitter sample (``u``) and a transmittance shadow ray (Jensen &
    Christensen 1998: the eye pass marches with shadow rays for the direct term)."""
    ds, em_weight = scene.sample_emitter_direction(mi.Interaction3f(mei), u, False, active)
    lit = active & (ds.pdf != 0)
    T = transmittance(scene, shadow_ray(mi.Interaction3f(mei), ds.p), mei.medium, gen, ch, lit)
    sigma_s, _, _ = mei.medium.get_scattering_coefficients(mei, lit)
    f, _ = mei.medium.phase_function().eval_pdf(mi.PhaseFunctionContext(None), mei, ds.d, lit)
    return dr.select(lit, sigma_s * f * em_weight * T, 0.0)


MAX_STEPS = 256  # ray-marching steps per medium segment (longer segments take longer steps)
CHUNK = 1 << 18  # in-scattering estimates evaluated at a time (k indices each)


@dataclass
class Segments:
    """Pieces of eye rays inside media, to be marched (:meth:`Inscatter.march`): origin, unit
    direction, length, medium, the path throughput at the origin and the lane (eye sample) that
    owns it."""

    origin: mi.Point3f
    direction: mi.Vector3f
    length: mi.Float
    medium: mi.MediumPtr
    weight: mi.Spectrum
    lane: mi.UInt32

    @property
    def count(self) -> int:
        return dr.width(self.lane)


@dataclass
class Inscatter:
    """The in-scattered radiance of the eye pass (Jensen & Christensen 1998; beyond-seeds §4):
    at a point of a medium, per unit length towards ``mei.wi``, single scattering of direct light
    by a shadow ray (:func:`direct_inscattered`) plus the volume map's estimate of the rest
    (:func:`inscattered`, ``k`` photons within ``max_radius``, or the precomputed ``density`` in
    isotropic media); ``step``: the ray-marching step. Both take batches of points (a wavefront:
    the k-NN gathers cannot run inside a loop)."""

    scene: mi.Scene
    vmap: VolumeMap
    k: int
    max_radius: float
    step: float
    density: ScatteredDensity | None = None  # precomputed (isotropic media), else k-NN gathers
    seed: int = 0

    def at(self, mei: mi.MediumInteraction3f, active, stream: int) -> mi.Spectrum:
        """``L_s(x, ω)`` at each ``mei`` (radiance per unit length): direct and map terms."""
        return self._chunked(mei, active, stream, direct=True, photons=True)

    def _chunked(self, mei, active, stream: int, direct: bool, photons: bool) -> mi.Spectrum:
        """The ``direct`` and/or ``photons`` (volume map) terms of :meth:`at`, in chunks of
        :data:`CHUNK` points; ``stream``: the random stream of the shadow rays' emitter samples."""
        count = dr.width(mei.p)
        out = dr.zeros(mi.Spectrum, count)
        if count == 0:
            return out
        active = mi.Bool(active) & dr.full(mi.Bool, True, count)
        for first in range(0, count, CHUNK):
            index = dr.arange(mi.UInt32, first, min(count, first + CHUNK))
            m = dr.gather(mi.MediumInteraction3f, mei, index)
            ok = dr.gather(mi.Bool, active, index) & within_extent(m)
            L = dr.zeros(mi.Spectrum, dr.width(index))
            if direct:
                gen = rng(dr.width(index), self.seed, stream + first)
                u = mi.Point2f(gen.next_float32(), gen.next_float32())
                L += direct_inscattered(self.scene, m, u, gen, channel(gen), ok)
            if photons and self.density is not None:
                L += self.density.inscattered(m.p, ok)
            elif photons:
                L += inscattered(self.vmap, m, self.k, self.max_radius, ok)
            dr.scatter(out, L, index)
            dr.eval(out)
        return out

    def march(self, segments: Segments, lanes: int, stream: int) -> mi.Spectrum:
        """Ray marching (beyond-seeds §4): per lane, ``Σ w T(x) L_s(x) / p(x)`` over its
        segments, ``w`` the segment's throughput and ``T(x)`` the transmittance from the segment's
        origin (:func:`segment_transmittance`: exact when homogeneous, ratio tracking otherwise).
        Each segment of length ``ℓ`` gets ``N = ⌈ℓ / step⌉`` points (at most :data:`MAX_STEPS`)
        for each term of ``L_s``, stratified with one uniform offset ``u`` per segment:

        - the volume map's smooth estimate at ``x_k = (k + u) ℓ/N`` (``1/p = ℓ/N``: a jittered
          step of the photon radius' size);
        - single scattering of direct light at equiangular points (Kulla & Fajardo 2012) about a
          point sampled on the emitters from the segment's middle: ``t = Δ + D tan θ``, ``θ``
          stratified between the angles of the segment's ends, ``p(t) = D / ((θ_b − θ_a)
          (D² + (t − Δ)²))`` — the ``1/r²`` peak of a point or spot light near the ray is
          sampled in proportion, where uniform steps would miss or hit it.

        Both are unbiased estimates of their integrals for any step. The points are evaluated
        for runs of whole segments of at most :data:`CHUNK` points each, and their terms summed
        per lane in a fixed order (``np.bincount``), so the result does not depend on the order
        of threads (atomic float additions would: SPPM's iterations must repeat exactly)."""
        if segments.count == 0:
            return dr.zeros(mi.Spectrum, lanes)
        L = np.zeros((3, lanes))
        steps = np.clip(np.ceil(segments.length.numpy() / self.step), 1, MAX_STEPS)
        steps = steps.astype(np.int64)
        gen = rng(segments.count, self.seed, stream)
        jitter = gen.next_float32()
        middle = dr.zeros(mi.Interaction3f, segments.count)
        middle.p = segments.origin + segments.direction * (0.5 * segments.length)
        u = mi.Point2f(gen.next_float32(), gen.next_float32())
        centre = self.scene.sample_emitter_direction(middle, u, False, True)[0].p
        dr.eval(jitter, centre)
        ends = np.cumsum(steps)
        first = 0
        while first < segments.count:  # runs of whole segments, at most CHUNK points each
            base = ends[first - 1] if first else 0
            last = max(first + 1, int(np.searchsorted(ends, base + CHUNK, side="right")))
            run = np.arange(first, last)
            seg = mi.UInt32(np.repeat(run, steps[run]).astype(np.uint32))
            k = np.arange(ends[last - 1] - base) - np.repeat(
                ends[run] - steps[run] - base, steps[run]
            )
            self._march_run(
                segments,
                seg,
                mi.Float(k.astype(np.float32)),
                mi.Float(steps.astype(np.float32)),
                jitter,
                centre,
                L,
                stream + 4 * first,
            )
            first = last
        return mi.Spectrum(*(mi.Float(c.astype(np.float32)) for c in L))

    def _march_run(self, segments, seg, k, steps, jitter, centre, L, stream: int) -> None:
        """:meth:`march` at the points ``k`` (0 … N−1) of the segments ``seg``, added to ``L``
        (NumPy, 3 × lanes)."""
        origin = dr.gather(mi.Point3f, segments.origin, seg)
        d = dr.gather(mi.Vector3f, segments.direction, seg)
        medium = dr.gather(mi.MediumPtr, segments.medium, seg)
        weight = dr.gather(mi.Spectrum, segments.weight, seg)
        lane = dr.gather(mi.UInt32, segments.lane, seg)
        ell = dr.gather(mi.Float, segments.length, seg)
        n = dr.gather(mi.Float, steps, seg)
        u = dr.gather(mi.Float, jitter, seg)

        # equiangular points about the point on the emitters
        c = dr.gather(mi.Point3f, centre, seg)
        delta = dr.dot(c - origin, d)
        D = dr.maximum(dr.norm(c - origin - delta * d), 1e-6 * dr.maximum(ell, 1e-6))
        theta_a = dr.atan2(-delta, D)
        theta_b = dr.atan2(ell - delta, D)
        theta = theta_a + (k + u) / n * (theta_b - theta_a)
        t_direct = dr.clip(delta + D * dr.tan(theta), 0.0, ell)
        pdf = D / ((theta_b - theta_a) * (dr.square(D) + dr.square(t_direct - delta)))
        inv_pdf = dr.select(pdf > 0, 1.0 / (n * pdf), 0.0)
        terms = self._term(origin, d, t_direct, medium, weight * inv_pdf, stream + 1, True)
        if self.vmap.size:
            t_map = (k + u) * ell / n
            terms += self._term(origin, d, t_map, medium, weight * ell / n, stream + 2, False)
        index = lane.numpy()
        for c, value in enumerate(np.asarray(terms, np.float64).reshape(3, -1)):
            L[c] += np.bincount(index, value, minlength=L.shape[1])

    def _term(self, origin, d, t, medium, weight, stream: int, direct: bool) -> mi.Spectrum:
        """``weight · T(t) · L_s(t)`` (its direct or its volume-map term) at ``origin + t d``."""
        ray = mi.Ray3f(origin, d)
        gen = rng(dr.width(t), self.seed, stream)
        T = segment_transmittance(ray, t, medium, gen, channel(gen), True)
        mei = interaction(ray(t), d, t, medium)
        value = weight * T
        dr.eval(value, mei)
        return value * self._chunked(mei, True, stream + (1 << 20), direct, not direct)
