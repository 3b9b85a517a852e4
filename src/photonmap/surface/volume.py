"""The surface method's light in participating media (Jensen & Christensen 1998):
the in-scattered radiance per unit length along the eye paths,

    L_s(x, ω) = σ_s f_p L_e T / p  (single scattering of direct light, a shadow ray)
              + Σ_p f_p Φ_p / ((4/3) π r³)  (the volume map: everything else),

the map's term from the ``volume_k`` nearest photons within ``volume_radius`` (in isotropic media
the density precomputed at the photons, :class:`~photonmap.core.volume_map.ScatteredDensity`).

- **Eye rays** are marched (:meth:`MediumLight.march`): the transport core's eye-path loop
  attenuates them through the media and records each piece
  (``media_mode="march"``, :func:`photonmap.core.eye_trace.trace_eye_paths`); each piece is
  integrated by stratified points — equiangular ones for the direct term (Kulla & Fajardo 2012),
  uniform ones of the photon radius's size for the map's term.
- **Final-gather rays** sample free flights and end at a collision ``x`` (``media_mode="end"``)
  with a throughput that already holds ``σ_s T / p``: they read ``L_s(x, ω) / σ_s(x)``
  (:meth:`MediumLight.at`).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import to_jit
from ..core.direct import equiangular, inscattered_direct
from ..core.media import Segments, channel, interaction, segment_transmittance, within_extent
from ..core.sampling import rng
from ..core.volume_map import CHUNK, ScatteredDensity, VolumeMap, density_radius, inscattered

MAX_STEPS = 256  # ray-marching steps per medium piece (longer pieces take longer steps)


@dataclass
class MediumLight:
    """The in-scattered light of the volume map and the emitters (module docstring):
    :meth:`at` collisions of free flights, :meth:`march` along recorded pieces."""

    scene: mi.Scene
    vmap: VolumeMap
    k: int
    radius: float
    density: ScatteredDensity | None = None  # precomputed (isotropic media), else k-NN gathers
    seed: int = 0
    step: float = 0.0  # ray-marching step of :meth:`march`

    def at(self, mei: mi.MediumInteraction3f, active, stream: int) -> mi.Spectrum:
        """``L_s(x, ω) / σ_s(x)`` at each collision ``mei`` (module docstring); ``stream``: the
        random stream of the shadow rays."""
        L_s = self._chunked(mei, active, stream, direct=True, photons=True)
        sigma_s = mi.Spectrum(mei.sigma_s)
        return dr.select(sigma_s > 0, L_s / dr.maximum(sigma_s, 1e-30), 0.0)

    def _chunked(self, mei, active, stream: int, direct: bool, photons: bool) -> mi.Spectrum:
        """The ``direct`` and/or ``photons`` (volume map) terms of ``L_s`` per unit length at each
        ``mei``, in chunks of :data:`CHUNK` points; ``stream``: the random stream of the shadow
        rays' emitter samples."""
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
                L += inscattered_direct(self.scene, m, u, gen, channel(gen), ok)
            if photons and self.density is not None:
                L += self.density.inscattered(m.p, ok)
            elif photons and self.vmap.size:
                L += inscattered(self.vmap, m, self.k, self.radius, ok)
            dr.scatter(out, L, index)
            dr.eval(out)
        return out

    def march(self, segments: Segments, lanes: int, stream: int) -> mi.Spectrum:
        """Ray marching (Jensen & Christensen 1998): per lane, ``Σ w T(x) L_s(x) / p(x)`` over its
        segments, ``w`` the segment's throughput and ``T(x)`` the transmittance from the segment's
        origin (:func:`~photonmap.core.media.segment_transmittance`: exact when homogeneous,
        ratio tracking otherwise).
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
            seg = to_jit(mi.UInt32, np.repeat(run, steps[run]))
            k = np.arange(ends[last - 1] - base) - np.repeat(
                ends[run] - steps[run] - base, steps[run]
            )
            self._march_run(
                segments,
                seg,
                to_jit(mi.Float, k),
                to_jit(mi.Float, steps),
                jitter,
                centre,
                L,
                stream + 4 * first,
            )
            first = last
        return mi.Spectrum(*(to_jit(mi.Float, c) for c in L))

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

        # equiangular points about the point on the emitters, stratified
        c = dr.gather(mi.Point3f, centre, seg)
        t_direct, pdf = equiangular(mi.Ray3f(origin, d), ell, c, (k + u) / n)
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


def march_step(vmap: VolumeMap, k: int, radius: float) -> float:
    """An automatic ray-marching step: half the radius of the spheres that hold ``k`` photons
    (:func:`~photonmap.core.volume_map.density_radius`) — the step follows the photon density,
    as the radius of the estimate does."""
    return 0.5 * density_radius(vmap.photons.position, k, radius)
