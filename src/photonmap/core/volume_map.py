"""The volume photon map (Jensen & Christensen 1998): photons stored where
they scattered in a medium, and their radiance estimates.

A volume photon holds its position, its travel direction ω_p before the event, the power it
scattered there Φ_p (the arriving power times ``σ_s/σ_t``), its depth (the path's segments from
the light, this one included) and whether its history is a pure specular chain (``caustic``:
only mirror and glass bounces before it — a volume caustic, which eye paths cannot find by
next-event estimation). The in-scattered radiance per unit length at ``x`` towards ``ω`` is

    L_s(x, ω) ≈ Σ_p f_p(x, ω_p, ω) Φ_p / ((4/3) π r³)

over the photons in a sphere of radius ``r``: the ``k`` nearest (:func:`inscattered`, ``r`` the
distance of the k-th or the searched radius where fewer lie within it) or all within a fixed
radius (:meth:`VolumeMap.phase_sum`, a fused scan usable inside an eye-path loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .hashgrid import HashGrid
from .knn import NO_PHOTON, neighbour_sum

LOOKUP_PER_CELL = 2.0  # ScatteredDensity: points per occupied cell of its lookup grid
CHUNK = 1 << 18  # k-NN estimates evaluated at a time (k indices each)


@dataclass
class VolumePhotons:
    """Photons stored at medium scattering events (module docstring)."""

    position: mi.Point3f
    direction: mi.Vector3f
    power: mi.Color3f
    depth: mi.UInt32
    caustic: mi.Bool

    @property
    def count(self) -> int:
        return dr.width(self.depth)

    @property
    def direct(self) -> mi.Bool:
        """The photon came straight from its emitter (its first scattering event)."""
        return self.depth == 1

    def select(self, mask: mi.Bool) -> VolumePhotons:
        index = dr.compress(mi.Bool(mask))
        fields = (self.position, self.direction, self.power, self.depth, self.caustic)
        return VolumePhotons(*(dr.gather(type(f), f, index) for f in fields))


@dataclass
class VolumeMap:
    """Volume photons and a hash grid over their positions (no normal test in a volume)."""

    photons: VolumePhotons
    grid: HashGrid | None

    @classmethod
    def build(cls, photons: VolumePhotons, cell_size: float | None = None) -> VolumeMap:
        """The map of ``photons``; ``cell_size``: the grid's cell edge (at least the radius of
        :meth:`phase_sum`), automatic by default."""
        grid = HashGrid(photons.position, cell_size=cell_size) if photons.count else None
        return cls(photons, grid)

    @property
    def size(self) -> int:
        return self.photons.count

    def stored(self):
        """Power, direction and depth in the grid's storage order (for :meth:`phase_sum`)."""
        order = self.grid.order
        p = self.photons
        return (
            dr.gather(mi.Color3f, p.power, order),
            dr.gather(mi.Vector3f, p.direction, order),
            dr.gather(mi.UInt32, p.depth, order),
        )

    def phase_sum(
        self, stored, mei: mi.MediumInteraction3f, radius: float, depth_left, active
    ) -> mi.Spectrum:
        """``Σ f_p(ω_p, ω) Φ_p / ((4/3) π r³)`` over the photons within ``radius`` (at most the
        grid's cell size) of ``mei.p`` whose depth is at most ``depth_left`` (per lane; the
        eye path's remaining segments), ``stored``: :meth:`stored`. Lazy: fuses into the caller's
        kernel (an eye-path loop)."""
        power, direction, depth = stored
        phase = mei.medium.phase_function()
        ctx = mi.PhaseFunctionContext(None)

        def share(j, near):
            ok = near & (dr.gather(mi.UInt32, depth, j, near) <= depth_left)
            wo = -dr.gather(mi.Vector3f, direction, j, ok)
            f, _ = phase.eval_pdf(ctx, mei, wo, ok)
            return dr.select(ok, f * dr.gather(mi.Color3f, power, j, ok), 0.0)

        zero = dr.zeros(mi.Spectrum, dr.width(mei.p))
        total = self.grid.sum_within(mei.p, dr.opaque(mi.Float, radius**2), share, zero, active)
        return total * dr.opaque(mi.Float, 1.0 / ((4.0 / 3.0) * math.pi * radius**3))


def density_radius(
    position: mi.Point3f, k: int, bound: float, samples: int = 4096, grid: HashGrid | None = None
) -> float:
    """The radius of a sphere that holds about ``k`` of the points ``position``: the median
    distance of the ``k``-th nearest over up to ``samples`` of them (``bound`` where fewer lie
    within it, and at most; ``bound`` where there are fewer than ``k`` points: with one point,
    its nearest is itself, at distance 0). ``grid``: a hash grid over ``position`` to search,
    if one exists."""
    count = dr.width(position)
    if count < k:
        return bound
    grid = grid or HashGrid(position)
    at = dr.gather(mi.Point3f, position, dr.arange(mi.UInt32, 0, count, max(1, count // samples)))
    found = grid.knn(at, k=k, max_radius=bound)
    r2 = dr.select(found.count < k, bound**2, found.radius2)
    return min(bound, float(np.sqrt(np.median(r2.numpy()))))


def inscattered(
    vmap: VolumeMap, mei: mi.MediumInteraction3f, k: int, max_radius: float, active: mi.Bool
) -> mi.Spectrum:
    """``L_s(x, ω)`` at ``mei.p`` towards ``mei.wi`` from the ``k`` nearest volume photons within
    ``max_radius`` (module docstring); the phase function is the one of ``mei.medium``."""
    count = dr.width(mei.p)
    out = dr.zeros(mi.Spectrum, count)
    if vmap.size == 0 or count == 0:
        return out
    active = mi.Bool(active) & dr.full(mi.Bool, True, count)
    for first in range(0, count, CHUNK):
        index = dr.arange(mi.UInt32, first, min(count, first + CHUNK))
        m = dr.gather(mi.MediumInteraction3f, mei, index)
        ok = dr.gather(mi.Bool, active, index)
        nb = vmap.grid.knn(m.p, k=k, max_radius=max_radius)
        dr.scatter(out, _phase_sum(vmap, m, nb, k, max_radius, ok), index)
        dr.eval(out)
    return out


def _phase_sum(vmap, mei, nb, k, max_radius, active):
    """The sum of :func:`inscattered` over the neighbours ``nb``, divided by the sphere."""
    phase = mei.medium.phase_function()
    ctx = mi.PhaseFunctionContext(None)

    def phase_value(arriving, active):
        return phase.eval_pdf(ctx, mei, arriving, active)[0]

    photons = vmap.photons
    L = neighbour_sum(nb, photons.power, photons.direction, phase_value, active)
    return dr.select(active & (nb.count > 0), L / _sphere(nb, k, max_radius), 0.0)


@dataclass
class ScatteredDensity:
    """The volume map's scattered power density ``S = Σ Φ_p / ((4/3) π r³)`` precomputed at every
    ``every``-th volume photon (the volume analogue of Christensen 1999's precomputed irradiance,
    :mod:`photonmap.surface.irradiance`): in an isotropic medium ``L_s = S / (4π)`` wherever the
    nearest precomputed point (one cell edge of its hash grid at most) is read — a lazy lookup
    that fuses into the caller's kernel instead of a k-NN gather per point. The grid holds
    about :data:`LOOKUP_PER_CELL` points per occupied cell: with the hash grid's usual 8 the
    cells where the points cluster (near a lamp) hold hundreds, each scanned at every step of
    every eye path through the fog."""

    position: mi.Point3f
    density: mi.Color3f
    grid: HashGrid

    @classmethod
    def build(cls, vmap: VolumeMap, every: int, k: int, max_radius: float) -> ScatteredDensity:
        """The density at every ``every``-th photon from its ``k`` nearest within ``max_radius``.
        The queries lie where the photons are densest, so they search a grid whose cell edge is
        the typical ``k``-NN radius there (:func:`density_radius`), not the map's (sized for
        the mean occupied cell: on a room of fog lit by one lamp, 6× slower)."""
        index = dr.arange(mi.UInt32, 0, vmap.size, every)
        position = dr.gather(mi.Point3f, vmap.photons.position, index)
        dr.eval(position)
        cell = density_radius(vmap.photons.position, k, max_radius, grid=vmap.grid)
        grid = HashGrid(vmap.photons.position, cell_size=cell)
        density = dr.zeros(mi.Color3f, dr.width(index))
        for first in range(0, dr.width(index), CHUNK):
            chunk = dr.arange(mi.UInt32, first, min(dr.width(index), first + CHUNK))
            at = dr.gather(mi.Point3f, position, chunk)
            nb = grid.knn(at, k=k, max_radius=max_radius)
            dr.scatter(density, _power_sum(vmap, nb, k, max_radius), chunk)
            dr.eval(density)
        return cls(position, density, HashGrid(position, photons_per_cell=LOOKUP_PER_CELL))

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
