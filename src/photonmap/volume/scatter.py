"""Multiple scattering in the voxel radiance grid (our extension of Sun et
al. 2008): the sampling between the curved-ray steps (``step.py``), and the march of the orders.

Each photon order is marched as Sun marches it (S6/S7: deposits of the attenuated energy
``L̃ = W·T`` along the whole curved path, the expected-value estimator of that order's fluence);
on the way a **collision** is sampled against σ_t = κ with the density ``p̄(s) = ⅓ Σ_c κ_c T_c(s)``
(one channel chosen uniformly, its optical depth compared with ``−ln(1 − ξ)``: the spectral-MIS
free-flight sampling of Mitsuba's ``volpath`` for RGB media). When the order has left the grid
(or faded below ``10⁻³`` of its start, or hit the step cap), the photon restarts at the collision
with the phase-sampled direction and the weight

    W' = W ⊙ σ_s(x_c) ⊙ T(x_c) / p̄(x_c)        (= W·σ_s/σ_t in a grey medium)

— the collision density of the next order, estimated without bias. Orders beyond
:data:`RR_DEPTH` continue with Russian roulette on ``q = min(1, max W' / max W₀)`` (survivors
divide by ``q``). A photon stops after :data:`MAX_ORDERS` scattering events. Each order's
photons are marched in :func:`coherent_order`. A :class:`Collision` is searched along each
order's steps, and the photons still alive go from order to order as a :class:`Wavefront`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..core.grid import trilinear_packed
from .deposit import Deposits, Float64, Int64, radiance_tally, weight_tally
from .step import MarchGrids, MarchSettings, Scattering, Step, march_steps, sample_medium

SCATTERING = ("single", "multiple")
RR_DEPTH = 3  # scattering events before Russian roulette starts (the weights decay by albedo)
MAX_ORDERS = 256  # cap on scattering events per photon (iteration cap, DESIGN.md)


def schlick_cosine(k, xi):
    """Sample ``μ = cos θ`` between the incoming and the scattered propagation directions from the
    Schlick phase function ``p(μ) = (1 − k²) / (4π (1 − kμ)²)`` (Pfeuti §2.1.3) by inverting its
    CDF ``F(μ) = (1 − k²)/(2k) · (1/(1 − kμ) − 1/(1 + k))``: ``μ = (2ξ + k − 1)/(2kξ − k + 1)``
    (no division by k: isotropic ``μ = 2ξ − 1`` at k = 0)."""
    return dr.clip((2.0 * xi + k - 1.0) / (2.0 * k * xi - k + 1.0), -1.0, 1.0)


def schlick_direction(k, d: mi.Vector3f, xi: mi.Point2f) -> mi.Vector3f:
    """A direction scattered from the propagation direction ``d`` (unit) by Schlick's ``k``."""
    mu = schlick_cosine(k, xi.x)
    sin_theta = dr.safe_sqrt(1.0 - mu * mu)
    s, c = dr.sincos(2.0 * math.pi * xi.y)
    return mi.Frame3f(d).to_world(mi.Vector3f(sin_theta * c, sin_theta * s, mu))


def channel_of(value: mi.Color3f, channel: mi.UInt32) -> mi.Float:
    """``value[channel]`` per lane (channel ∈ {0, 1, 2})."""
    return dr.select(channel == 0, value.x, dr.select(channel == 1, value.y, value.z))


def free_flight(rng: mi.PCG32, active=True) -> tuple[mi.Float, mi.UInt32]:
    """The optical depth ``−ln(1 − ξ)`` at which the next collision happens, in the colour
    channel returned with it (uniform over R, G, B)."""
    depth = -dr.log(1.0 - rng.next_float32(active))
    channel = dr.minimum(mi.UInt32(rng.next_float32(active) * 3.0), 2)
    return depth, channel


def collision_weight(sigma_s: mi.Color3f, kappa: mi.Color3f, depth: mi.Color3f) -> mi.Color3f:
    """``σ_s ⊙ T / p̄`` with ``T = exp(−depth)`` and ``p̄ = ⅓ Σ_c κ_c T_c`` (the pdf of the
    collision distance sampled by :func:`free_flight`), 0 where ``p̄ = 0``."""
    T = dr.exp(-depth)
    pdf = (kappa.x * T.x + kappa.y * T.y + kappa.z * T.z) / 3.0
    return dr.select(pdf > 0, sigma_s * T / dr.maximum(pdf, 1e-30), 0.0)


def roulette(weight: mi.Color3f, start: mi.Float, order: int, xi: mi.Float):
    """Russian roulette after :data:`RR_DEPTH` scattering events: survive with
    ``q = min(1, max weight / start)`` and return ``(survives, weight / q)``. The order is opaque
    to the kernel: one kernel serves every order. This is :func:`~photonmap.core.settings.survival`
    with the cap 1 instead of 0.95 and no η (the grid's photons cross no interface): a fog's
    photons scatter up to :data:`MAX_ORDERS` times, and a cap below 1 would end 5 % of them at
    every order, however bright they still are, where a surface path has a few bounces."""
    late = dr.opaque(mi.UInt32, order) >= RR_DEPTH
    q = dr.select(late, dr.minimum(dr.max(weight) / start, 1.0), 1.0)
    return (xi < q) & (q > 0), weight / dr.maximum(q, 1e-30)


def coherent_order(x: mi.Point3f, d: mi.Vector3f, subset: mi.UInt32, n: int) -> mi.UInt32:
    """The permutation of ``subset`` (indices into ``x``, ``d``) that lists photons by direction
    (96 bins: the cube-map face of ``d``, 4 × 4 cells on it), then in 3D Morton order of their
    position (8 bits per axis): SIMD neighbours then start near each other and travel alike, so
    their deposits share cache lines. The scattered photons come out of the compaction in their
    parents' order with random new directions; measured per photon at 128³ (glass_sphere_fog),
    the second order took 5× the time of the first in this order (unsorted: 8×; by octant and
    position: 6–7×; 1536 direction bins: 8×). ``n``: voxels along the grid's longest side."""
    p, d = dr.gather(mi.Point3f, x, subset), dr.gather(mi.Vector3f, d, subset)
    a = dr.abs(d)
    axis = dr.select((a.x >= a.y) & (a.x >= a.z), 0, dr.select(a.y >= a.z, 1, 2))
    major = dr.select(axis == 0, d.x, dr.select(axis == 1, d.y, d.z))
    u = dr.select(axis == 0, d.y, d.x) / dr.abs(major)  # the face coordinates, in [−1, 1]
    w = dr.select(axis == 2, d.y, d.z) / dr.abs(major)
    face = mi.UInt32(axis) * 2 + dr.select(major > 0, 1, 0)
    bu, bw = (mi.UInt32(dr.clip(2.0 * c + 2.0, 0.0, 3.0)) for c in (u, w))
    direction = (face * 4 + bu) * 4 + bw
    cell = mi.Vector3u(dr.clip(p * (256.0 / n), 0.0, 255.0))
    return dr.argsort(mi.math.morton_encode3(cell) | (direction << 24))


@dataclass
class Collision:
    """The collision of each photon in one scattering order: where the optical depth of colour
    ``channel`` since the order's start reaches the sampled ``target`` (κ constant over a step, as
    in eq (6)). Updated step by step inside a marching loop (:meth:`search`)."""

    target: mi.Float  # the sampled optical depth (:func:`free_flight`)
    channel: mi.UInt32  # the colour it is sampled in
    found: mi.Bool
    x: mi.Point3f  # the collision point
    start: mi.Point3f  # the start of the step it lies in (where σ_s is read, like κ)
    direction: mi.Vector3f  # the photon's direction there
    ratio: mi.Color3f  # T/p̄ there (:func:`.scatter.collision_weight` without σ_s)
    depth: mi.Color3f  # optical depth since the order's start (RGB)

    @staticmethod
    def none(count: int, target: mi.Float, channel: mi.UInt32) -> Collision:
        """No collision yet, at optical depth 0, to be found at optical depth ``target`` of
        colour ``channel``."""
        return Collision(
            target,
            channel,
            dr.zeros(mi.Bool, count),
            dr.zeros(mi.Point3f, count),
            dr.zeros(mi.Point3f, count),
            dr.zeros(mi.Vector3f, count),
            dr.zeros(mi.Color3f, count),
            dr.zeros(mi.Color3f, count),
        )

    def search(self, x: mi.Point3f, step: Step) -> None:
        """Record the collision of the photons whose ``target`` lies within ``step`` from ``x``
        and add the step's optical depth."""
        target = self.target
        depth_new = self.depth + step.kappa * step.length
        before = channel_of(self.depth, self.channel)
        after = channel_of(depth_new, self.channel)
        hit = ~self.found & (after >= target) & (after > before)
        f = (target - before) / dr.maximum(after - before, 1e-30)  # where in the step
        self.x = dr.select(hit, dr.lerp(x, step.x, f), self.x)
        self.start = dr.select(hit, x, self.start)
        turned = dr.normalize(dr.lerp(step.direction, step.new_direction, f))
        self.direction = dr.select(hit, turned, self.direction)
        depth_f = self.depth + step.kappa * (f * step.length)
        self.ratio = dr.select(hit, collision_weight(1.0, step.kappa, depth_f), self.ratio)
        self.found |= hit
        self.depth = depth_new

    def sigma_s(self, medium: MarchGrids) -> mi.Color3f:
        """σ_s at the collisions (read where κ was, at the start of the step)."""
        packed = trilinear_packed(medium.scatter, medium.dims, 1, self.start, active=self.found)
        return mi.Color3f(packed[0].xyz)


@dataclass
class Wavefront:
    """The photons of multiple scattering, marched one order (or leg) at a time: the live ones
    are compacted after each order, so SIMD lanes do not wait for a neighbour's further orders.
    Photon ``i`` draws from PCG32 stream ``i`` of the seed."""

    ids: mi.UInt32  # each live photon's index among the emitted ones
    start: mi.Float  # its emitted power (max over RGB), Russian roulette's reference
    rng: mi.PCG32
    tally: object  # the deposit tally; a weighted one follows its photons (weight_tally)
    final: list  # per emitted photon: x, v (or d), L̃ where it stopped, its last order
    steps: int = 0  # marching steps of all orders

    @staticmethod
    def emitted(x, v, L, seed: int, tally) -> Wavefront:
        """The emitted photons at ``x`` with ``v`` (or ``d``) and power ``L``."""
        count = dr.width(L)
        rng = mi.PCG32(count, dr.opaque(mi.UInt64, seed), dr.arange(mi.UInt64, count))
        start = dr.max(L)
        dr.make_opaque(rng, start)  # in memory, as after a compaction: every order, one kernel
        final = [mi.Point3f(x), mi.Vector3f(v), mi.Color3f(L), dr.zeros(mi.UInt32, count)]
        return Wavefront(dr.arange(mi.UInt32, count), start, rng, tally, final)

    def record(self, order: int, steps: mi.UInt32, x, v, L) -> None:
        """Where the live photons stopped in ``order`` (evaluated), and its steps."""
        values = (x, v, L, dr.opaque(mi.UInt32, order))
        for array, value in zip(self.final, values, strict=True):
            dr.scatter(array, value, self.ids)
        self.steps += int(dr.sum(Float64(steps))[0])

    def compact(self, alive: mi.UInt32, x, omega, W, n: int):
        """Keep the photons ``alive`` (indices), reordered for coherence
        (:func:`.scatter.coherent_order`): their ``(x, ω, W)`` and their bookkeeping."""
        alive = dr.gather(mi.UInt32, alive, coherent_order(x, omega, alive, n))
        x = dr.gather(mi.Point3f, x, alive)
        omega = dr.gather(mi.Vector3f, omega, alive)
        W = dr.gather(mi.Color3f, W, alive)
        self.ids = dr.gather(mi.UInt32, self.ids, alive)
        self.start = dr.gather(mi.Float, self.start, alive)
        self.rng.state = dr.gather(mi.UInt64, self.rng.state, alive)
        self.rng.inc = dr.gather(mi.UInt64, self.rng.inc, alive)
        weights = getattr(self.tally, "weights", None)
        if weights is not None:
            weights = dr.gather(mi.Float, weights, alive)
        # in memory, as the first order's photons are: every later order runs one kernel
        dr.eval(x, omega, W, self.ids, self.start, self.rng, weights)
        if weights is not None:
            self.tally = weight_tally(weights)
        return x, omega, W


def march_order(
    into: Deposits,
    medium: MarchGrids,
    photon: tuple,
    march: MarchSettings,
    flight: tuple[mi.Float, mi.UInt32],
):
    """One scattering order of every ``photon = (x, v = n dx/ds, L̃)`` (module docstring),
    depositing ``into``: :func:`.step.march_steps`, which also finds the :class:`Collision`
    where the optical depth of the colour ``channel`` reaches ``target`` (``flight = (target,
    channel)``). Returns the steps, the final ``(x, v, L̃)`` and the collision."""
    collision = Collision.none(dr.width(photon[2]), *flight)
    steps, x, v, L = march_steps(into, medium, photon, march, collision)
    return steps, x, v, L, collision


def march_multiple(
    accumulators: tuple[Int64, Int64],
    medium: MarchGrids,
    rays: tuple,
    march: MarchSettings,
    scattering: Scattering,
    tally=radiance_tally,
    shift: int = 0,
):
    """``march.py``'s march with multiple scattering of the photons ``rays = (x, d, L)``, one
    order at a time over the photons still alive (a :class:`Wavefront`). The collision of each
    order starts the next there, in a Schlick-sampled direction, with weight ``W ⊙ σ_s ⊙ T/p̄``
    and Russian roulette (:func:`roulette`). The first order deposits into ``acc`` as
    ``march.py`` does; the scattered orders deposit with atomics into ``atomic``
    (``accumulators = (acc, atomic)``, the same layout, summed by the caller): one reduction
    mode per array, one ``Expand`` launch (see :func:`.deposit.reduce_mode`).
    Returns the total steps and, per photon, the final ``(x, v, L̃)`` and its scattering events.
    """
    acc, atomic = accumulators
    x, d, L = rays
    k = dr.opaque(mi.Float, scattering.phase_k)
    v = sample_medium(medium, x)[0] * d  # v₀ = n(x₀)·d₀
    photons = Wavefront.emitted(x, v, L, scattering.seed, tally)
    rng = photons.rng
    for order in range(MAX_ORDERS + 1):
        into = Deposits(acc if order == 0 else atomic, photons.tally, shift, order == 0)
        n_steps, x, v, L_end, collision = march_order(
            into, medium, (x, v, L), march, free_flight(rng)
        )
        dr.eval(into.acc, n_steps, x, v, L_end, collision)  # one launch per order
        photons.record(order, n_steps, x, v, L_end)
        if order == MAX_ORDERS:
            break
        # the next order starts at the collisions
        W = L * collision.sigma_s(medium) * collision.ratio
        survives, W = roulette(W, photons.start, order, rng.next_float32())
        omega = schlick_direction(
            k, collision.direction, mi.Point2f(rng.next_float32(), rng.next_float32())
        )
        going = collision.found & survives & (dr.max(W) > 0)  # not absorbed
        dr.eval(going, W, omega, rng)  # one kernel: the compaction gathers them per channel
        alive = dr.compress(going)
        if dr.width(alive) == 0:
            break
        x, omega, L = photons.compact(alive, collision.x, omega, W, medium.n)
        v = sample_medium(medium, x)[0] * omega
    return photons.steps, *photons.final
