"""Stage S4: the octree over n as a dense level array, built from a min/max pyramid.

Sun et al. 2008 §4.2 (Fig 4) and §5.3 ("Modified Octree Construction"); Pfeuti 2009 §3.1.3,
Listings 3.1–3.3 and A.2.

A level-k node is an aligned cube of ``2^k`` voxels; level 0 is one voxel, level K the whole
``2^K`` grid. With the range ``r_k(v)`` = max − min of n over the level-k node holding v (from the
min/max pyramid, built bottom-up), every voxel is labelled top-down with the first, i.e. largest,
level whose node is uniform (strict ``<``, as both papers):

    level(v) = max{k ∈ 0..K : r_k(v) < ε'}
    Δs_max(v) = ∞ if r_level(v)(v) < ε else L                (Sun §5.3; ∞ everywhere if ε' = ε)

The defaults are those of Sun §5.3: ε = 0.005, ε' = 0.02, L = 8 voxels. A grid whose side is not a
power of two is padded to the next ``2^K`` by edge replication, for the pyramid only (the papers
assume a ``2^K`` cube); a box grid (``n_x × n_y × n_z``) is padded the same way to the cube ``2^K``
of its longest side, so its nodes are the same aligned cubes. Optionally (both papers ignore κ here)
a node must also have an extinction range below ``eps_kappa`` in every channel.

Bounded fog: a node must also lie wholly inside or wholly outside every fog volume, one voxel of
trilinear support included (the coverage uniform over the node grown by one voxel, tested on the
3×3×3 box sum of the coverage). The marcher samples κ at the start of a step as long as the node (eq
6), so a node across the fog's boundary would carry photons through the fog unattenuated, or
attenuate them in vacuum; next to the boundary steps are then one voxel, and a photon entering the
fog misses about half a voxel of its optical depth. Fog that fills the grid splits nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import reduce

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.errors import ParameterError
from ..core.grid import (
    filter_separable,
    flat_index,
    grid_shape,
    voxel_count,
    voxel_of,
)


@dataclass
class Octree:
    """Per voxel (tensors (n_z, n_y, n_x, 1) indexed [z, y, x]): ``level`` of the leaf node (0..K) and
    ``step_limit`` Δs_max (+inf, or ``ds_max`` voxels where the node only passes ε')."""

    level: mi.TensorXf
    step_limit: mi.TensorXf


def _range_pyramid(values: mi.TensorXf, size: int) -> list[mi.Float]:
    """Per-channel range (max − min) of a grid (n_z, n_y, n_x, c) over the nodes of every level,
    after padding it to ``size³`` by edge replication.

    Entry k has flat index ``((z·m + y)·m + x)·c + channel`` with ``m = size / 2^k``.
    """
    nz, ny, nx, c = values.shape
    dims = (nx, ny, nz)
    index = dr.arange(mi.UInt32, size**3 * c)
    cell, channel = index // c, index % c
    x, y, z = (dr.minimum(a, e - 1) for a, e in zip(voxel_of(cell, size), dims, strict=True))
    lo = hi = dr.gather(mi.Float, values.array, flat_index(x, y, z, dims) * c + channel)
    ranges = [dr.zeros(mi.Float, dr.width(index))]
    channels = dr.opaque(mi.UInt32, c)
    while size > 1:
        size //= 2
        index = dr.arange(mi.UInt32, size**3 * c)
        m = dr.opaque(mi.UInt32, size)  # one kernel for every level (literals would make one each)
        cell, channel = index // channels, index % channels
        x, y, z = 2 * (cell % m), 2 * ((cell // m) % m), 2 * (cell // (m * m))
        children = [
            ((z + (i >> 2)) * 2 * m + y + ((i >> 1) & 1)) * 2 * m + x + (i & 1) for i in range(8)
        ]
        lo = reduce(dr.minimum, [dr.gather(mi.Float, lo, j * channels + channel) for j in children])
        hi = reduce(dr.maximum, [dr.gather(mi.Float, hi, j * channels + channel) for j in children])
        ranges.append(hi - lo)
        dr.eval(lo, hi, ranges[-1])
    return ranges


def build_octree(
    ior: mi.TensorXf,
    eps: float = 0.005,
    eps2: float | None = 0.02,
    ds_max: float = 8.0,
    kappa: mi.TensorXf | None = None,
    eps_kappa: float = np.inf,
    boundaries: mi.TensorXf | None = None,
) -> Octree:
    """Octree levels and step limits of the index grid ``ior`` (n_z, n_y, n_x[, 1]).

    ``eps2=None`` (or ``eps2 == eps``) builds the basic octree of Sun §4.2, with no step limit.
    ``kappa`` (n_z, n_y, n_x, c) with a finite ``eps_kappa`` also splits nodes whose extinction
    varies. ``boundaries`` (n_z, n_y, n_x, c): the coverages of the fog volumes (S1); nodes where
    one varies at all within one voxel of the node are split.
    """
    if len(ior.shape) not in (3, 4):
        raise ParameterError(f"the octree needs a scalar grid, got shape {ior.shape}")
    dims = tuple(int(c) for c in ior.shape[:3])[::-1]
    shape, count = grid_shape(dims), voxel_count(dims)
    eps2 = eps if eps2 is None else eps2
    if dr.width(ior.array) != count:
        raise ParameterError(f"the octree needs a scalar grid, got shape {ior.shape}")
    if not (0 < eps <= eps2 < np.inf):
        raise ParameterError(f"octree tolerances need 0 < eps <= eps2 < inf, got {eps}, {eps2}")
    if not (ds_max > 0 and eps_kappa > 0):
        raise ParameterError(f"ds_max and eps_kappa must be positive, got {ds_max}, {eps_kappa}")
    channels = 0
    if kappa is not None:
        channels = dr.width(kappa.array) // count
        if tuple(kappa.shape[:3]) != shape or dr.width(kappa.array) != channels * count:
            raise ParameterError(f"kappa has shape {kappa.shape}, expected {shape} + (c,)")

    walls = 0
    if boundaries is not None:
        walls = dr.width(boundaries.array) // count
        if tuple(boundaries.shape[:3]) != shape or dr.width(boundaries.array) != walls * count:
            raise ParameterError(f"boundaries have shape {boundaries.shape}, expected {shape}")

    depth = int(np.ceil(np.log2(max(dims))))
    size = 2**depth
    ior_ranges = _range_pyramid(mi.TensorXf(ior.array, (*shape, 1)), size)
    if kappa is not None:
        kappa_ranges = _range_pyramid(mi.TensorXf(kappa.array, (*shape, channels)), size)
    if walls:
        support = filter_separable(mi.TensorXf(boundaries.array, (*shape, walls)), [1.0] * 3)
        wall_ranges = _range_pyramid(support, size)
    x, y, z = voxel_of(dr.arange(mi.UInt32, count), dims)
    tolerances = (dr.opaque(mi.Float, eps), dr.opaque(mi.Float, eps2))
    level = [dr.zeros(mi.Float, count), dr.zeros(mi.Float, count)]
    labelled = [dr.zeros(mi.Bool, count), dr.zeros(mi.Bool, count)]
    for k in range(depth, -1, -1):
        m = size >> k
        cell = ((z >> k) * m + (y >> k)) * m + (x >> k)
        ior_range = dr.gather(mi.Float, ior_ranges[k], cell)
        kappa_uniform = True
        for c in range(channels):
            kappa_range = dr.gather(mi.Float, kappa_ranges[k], cell * channels + c)
            kappa_uniform &= kappa_range < dr.opaque(mi.Float, eps_kappa)
        for c in range(walls):
            kappa_uniform &= dr.gather(mi.Float, wall_ranges[k], cell * walls + c) == 0
        for i, tolerance in enumerate(tolerances):
            uniform = ~labelled[i] & (ior_range < tolerance) & kappa_uniform
            level[i] = dr.select(uniform, k, level[i])
            labelled[i] |= uniform
    step_limit = dr.select(level[0] == level[1], dr.inf, dr.opaque(mi.Float, ds_max))
    return Octree(mi.TensorXf(level[1], (*shape, 1)), mi.TensorXf(step_limit, (*shape, 1)))
