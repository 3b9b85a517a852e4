"""Stage S1: fractional inside coverage of a closed shape on the voxel grid.

Sun et al. 2008 §4.1; Pfeuti 2009 §3.1.2, Listing A.1.

The inside test is the parity of surface crossings along +z (the XOR bit-slice voxelization of
Eisemann & Décoret 2008 that Pfeuti uses), computed with Mitsuba's own ray tracer: for each
column of sample centres, rays along +z collect every crossing ``z₁ < z₂ < …`` of the surface, and
a sample at height ``z`` is inside iff an odd number of crossings lie below it (a crossing exactly
at a sample's height counts as above it). Columns are shifted by a fixed irrational fraction of a
voxel (:data:`COLUMN_JITTER`) so that they do not run exactly through the edges or vertices of
meshes built on simple rational coordinates, nor graze a face.

Coverage (Sun §4.1):

- ``B[v]``: inside test at the centre of voxel ``v``;
- ``v`` is a *border* voxel iff ``B`` is not uniform over its 3×3×3 neighbourhood (clamped);
- ``cov[v] = B[v]`` off the border, and on the border the mean of the ``s×s×s`` sub-samples at
  ``(i + (a+½)/s, j + (b+½)/s, k + (c+½)/s)`` (``s = 4``: multiples of 1/64).

``full_supersample=True`` supersamples every voxel (the papers: the border only): it also catches
features thinner than a voxel that the centre samples miss (a thin plate), and agrees with the
default for smooth objects.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.bsdf import shape_box
from ..core.errors import ParameterError, SceneError
from ..core.grid import GridBox, filter_separable

COLUMN_JITTER = ((np.sqrt(2.0) - 1.0) * 1e-3, (np.sqrt(5.0) - 2.0) * 1e-3)
"""Offset of every sample column in voxel units (x, y): breaks ties with edges and grazing faces."""

MAX_CROSSINGS = 4096
"""Iteration cap of the ray loop: the most surface crossings one column may have."""


def check_closed(shape: mi.Shape, name: str) -> None:
    """Raise :class:`SceneError` unless ``shape`` bounds a volume.

    Spheres are closed; a mesh is closed when, after welding vertices at equal positions, every
    edge of a non-degenerate triangle is shared by exactly two triangles. Other shape types
    (rectangle, disk, cylinder, ...) are open surfaces.
    """
    kind = mi.ShapeType(shape.shape_type())
    if kind == mi.ShapeType.Sphere:
        return
    if kind != mi.ShapeType.Mesh:
        raise SceneError(
            f"shape {name!r} is a {kind.name}, an open surface: refractive objects and the shapes "
            "bounding a medium must be closed (a 'sphere', a 'cube' or a watertight mesh)"
        )
    positions = shape.vertex_positions_buffer().numpy().reshape(-1, 3)
    faces = shape.faces_buffer().numpy().reshape(-1, 3)
    _, weld = np.unique(positions, axis=0, return_inverse=True)
    faces = weld.reshape(-1)[faces]
    a, b, c = faces.T
    faces = faces[(a != b) & (b != c) & (c != a)]  # without triangles that welding collapsed
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges[:, 0] * np.int64(len(positions)) + edges[:, 1], return_counts=True)
    open_edges = np.count_nonzero(uses != 2)
    if len(faces) == 0 or open_edges:
        raise SceneError(
            f"mesh {name!r} is not watertight: {open_edges} of {len(uses)} edges are not shared by "
            "exactly two triangles. Close its holes (and remove duplicate faces) so that it "
            "bounds a volume"
        )


@dr.syntax
def _trace_columns(scene, x, y, z, eps, limit, store=None):
    """Cast rays along +z from ``(x, y, z)`` (world units) and count at most ``limit`` surface
    crossings per column. With ``store = (heights, start, lo_z, 1/h)``, also write the crossing
    heights in voxel units to ``heights[start + 0, 1, ...]``."""
    count = dr.zeros(mi.UInt32, dr.width(x))
    active = count < limit
    while active:
        ray = mi.Ray3f(mi.Point3f(x, y, z), mi.Vector3f(0, 0, 1))
        si = scene.ray_intersect_preliminary(ray, coherent=False, active=active)
        active &= si.is_valid()
        z_hit = z + si.t
        if store is not None:
            heights, start, lo_z, inv_h = store
            dr.scatter(heights, (z_hit - lo_z) * inv_h, start + count, active)
        count = dr.select(active, count + 1, count)
        z = dr.select(active, z_hit + eps, z)
        active &= count < limit
    return count


def _column_crossings(scene, box: GridBox, columns: mi.UInt32, s: int, z0: float):
    """Crossings of the ``s×s`` sample columns under each coarse column (``j·n_x + i``).

    Column ``slot·s² + b·s + a`` passes through ``(i + (a+½)/s, j + (b+½)/s)`` (plus the jitter),
    where ``columns[slot] = j·n_x + i``. Returns ``(start, count, heights)``: column ``c`` crosses the
    surface at the heights (voxel units, ascending) ``heights[start[c] : start[c] + count[c]]``.
    """
    nx, h = box.dims[0], box.h
    index = dr.arange(mi.UInt32, dr.width(columns) * s * s)
    coarse = dr.gather(mi.UInt32, columns, index // (s * s))
    sub = index % (s * s)
    lo = [dr.opaque(mi.Float, c) for c in box.lo]
    x = lo[0] + h * (mi.Float(coarse % nx) + (mi.Float(sub % s) + 0.5) / s + COLUMN_JITTER[0])
    y = lo[1] + h * (mi.Float(coarse // nx) + (mi.Float(sub // s) + 0.5) / s + COLUMN_JITTER[1])
    scale = max(float(np.max(np.abs(box.lo))), float(np.max(np.abs(box.hi))), abs(z0))
    eps = dr.opaque(mi.Float, max(1e-4 * h / s, 4e-6 * scale))
    z_start = dr.opaque(mi.Float, z0, dr.width(index))
    count = _trace_columns(scene, x, y, z_start, eps, dr.opaque(mi.UInt32, MAX_CROSSINGS))
    dr.eval(count)
    if dr.any(count >= MAX_CROSSINGS):
        raise SceneError(f"a grid column crosses the surface {MAX_CROSSINGS} times or more")
    start = dr.prefix_sum(count)
    heights = dr.zeros(mi.Float, max(int(dr.sum(count)[0]), 1))
    store = (heights, start, lo[2], dr.opaque(mi.Float, 1.0 / h))
    _trace_columns(scene, x, y, z_start, eps, count, store)
    return start, count, heights


@dr.syntax
def _mean_inside(voxels: mi.UInt32, slots: mi.UInt32, crossings, layer_size: int, s: int):
    """Fraction of the ``s³`` sub-samples of each voxel that are inside (crossing parity).

    ``slots[v]`` is the slot of the voxel's coarse column in :func:`_column_crossings`;
    ``layer_size = n_x·n_y`` voxels per z layer. The
    parities of the ``s`` samples of a sub-column are the low bits of one integer: a crossing at
    height ``z`` lies below samples ``c ≥ c₀ = ⌊(z − k)·s + ½⌋`` and toggles their bits.
    """
    start, count, heights = crossings
    layer = mi.Float(voxels // layer_size)
    all_bits = (1 << s) - 1
    inside = dr.zeros(mi.UInt32, dr.width(voxels))
    sub = dr.zeros(mi.UInt32, dr.width(voxels))
    while sub < s * s:
        column = slots * (s * s) + sub
        hit = dr.gather(mi.UInt32, start, column)
        end = hit + dr.gather(mi.UInt32, count, column)
        parity = dr.zeros(mi.UInt32, dr.width(voxels))
        while hit < end:
            z = dr.gather(mi.Float, heights, hit)
            c0 = mi.UInt32(dr.clip(dr.floor((z - layer) * s + 0.5), 0, s))
            parity ^= all_bits ^ ((1 << c0) - 1)
            hit += 1
        inside += dr.popcnt(parity)
        sub += 1
    return mi.Float(inside) / s**3


def voxelize(
    shape: mi.Shape, box: GridBox, supersample: int = 4, full_supersample: bool = False
) -> mi.TensorXf:
    """Fractional inside coverage of the closed ``shape`` on the grid of ``box``: a tensor
    (n_z, n_y, n_x) indexed [z, y, x] with values in [0, 1], multiples of ``1/supersample³`` on
    the border.

    ``supersample = 1`` returns the binary centre-sample grid ``B``. The shape must be closed
    (see :func:`check_closed`); an open one gives meaningless parities.
    """
    if not (isinstance(supersample, int | np.integer) and 1 <= supersample <= 8):
        raise ParameterError(f"supersample must be an integer in 1..8, got {supersample!r}")
    shape3, layer = box.shape, box.dims[0] * box.dims[1]
    scene = mi.load_dict({"type": "scene", "shape": shape})
    z0 = min(shape_box(shape).min.z, float(box.lo[2])) - box.h

    voxels = dr.arange(mi.UInt32, box.voxels)
    centres = _column_crossings(scene, box, dr.arange(mi.UInt32, layer), 1, z0)
    coverage = _mean_inside(voxels, voxels % layer, centres, layer, 1)
    if supersample == 1:
        return mi.TensorXf(coverage, shape3)

    if full_supersample:
        border = voxels
    else:
        # Off the border, the sum of B over the clamped 3×3×3 neighbourhood is 0 or 27.
        neighbours = filter_separable(mi.TensorXf(coverage, shape3), [1.0, 1.0, 1.0]).array
        border = dr.compress((neighbours > 0.5) & (neighbours < 26.5))
    if dr.width(border) > 0:
        used = dr.zeros(mi.UInt32, layer)
        dr.scatter(used, 1, border % layer)
        columns = dr.compress(used == 1)
        slot_of = dr.zeros(mi.UInt32, layer)
        dr.scatter(slot_of, dr.arange(mi.UInt32, dr.width(columns)), columns)
        samples = _column_crossings(scene, box, columns, supersample, z0)
        slots = dr.gather(mi.UInt32, slot_of, border % layer)
        dr.scatter(coverage, _mean_inside(border, slots, samples, layer, supersample), border)
    return mi.TensorXf(coverage, shape3)
