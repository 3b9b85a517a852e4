"""Voxel grids: the world box, texture sampling and separable filters (Dr.Jit).

Conventions (docs/DESIGN.md "Conventions"):

- The grid is a box of ``n_x × n_y × n_z`` cubic voxels of edge ``h`` (a *box
  grid*; ``n = max(n_x, n_y, n_z)`` voxels along its longest side of length ``size = n·h``), over
  the world box ``[lo, lo + h·dims]``; ``dims = (n_x, n_y, n_z)``. A cubic grid has
  ``dims = (n, n, n)``. Kernels work in **voxel units**: ``p = (x_world − lo) / h ∈ [0, dims)``;
  voxel ``(i, j, k)`` covers ``[i, i+1) × [j, j+1) × [k, k+1)`` and its centre is
  ``(i+½, j+½, k+½)``. Kernels take the grid's extent as ``dims`` (:func:`grid_dims`: an int ``n``
  means the cube ``(n, n, n)``).
- Grid arrays (NumPy or ``mi.TensorXf``) have shape ``(n_z, n_y, n_x)`` or ``(n_z, n_y, n_x, c)``
  and are indexed ``[z, y, x]`` (``[k, j, i]``), the order of ``dr.Texture3f``; the flat index of
  voxel ``(i, j, k)`` is ``(k·n_y + j)·n_x + i`` (:func:`flat_index`, :func:`voxel_of`).
- "Whenever we read data from a voxel grid we apply trilinear interpolation" (Pfeuti 2009 §3.1.1),
  with samples at voxel centres and clamp-to-edge addressing: :func:`trilinear_packed` (the
  semantics of ``dr.Texture3f`` with linear filtering and ``WrapMode.Clamp``, reading several
  channels with one index computation).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .arrays import to_jit
from .errors import ParameterError


def grid_dims(n) -> tuple:
    """The grid extent ``(n_x, n_y, n_z)`` of ``n``: a sequence of three, or one ``n`` (an int or
    a per-lane Dr.Jit array) for the cube ``(n, n, n)``."""
    if isinstance(n, tuple | list | np.ndarray):
        nx, ny, nz = n
        return nx, ny, nz
    return n, n, n


def grid_shape(n, *channels: int) -> tuple:
    """The tensor shape ``(n_z, n_y, n_x, *channels)`` of a grid of extent ``n`` (:func:`grid_dims`)."""
    nx, ny, nz = (int(c) for c in grid_dims(n))
    return (nz, ny, nx, *channels)


def grid_extent(n) -> mi.Point3f:
    """The grid's far corner ``(n_x, n_y, n_z)`` in voxel units (:func:`grid_dims`)."""
    return mi.Point3f(*(float(c) for c in grid_dims(n)))


def voxel_count(n) -> int:
    """``n_x · n_y · n_z``."""
    nx, ny, nz = (int(c) for c in grid_dims(n))
    return nx * ny * nz


def flat_index(i, j, k, n):
    """The flat index ``(k·n_y + j)·n_x + i`` of voxel ``(i, j, k)`` (layout [z, y, x])."""
    nx, ny, _ = grid_dims(n)
    return (k * ny + j) * nx + i


def voxel_of(index, n) -> tuple:
    """The voxel ``(i, j, k)`` of flat index ``index`` (the inverse of :func:`flat_index`)."""
    nx, ny, _ = grid_dims(n)
    return index % nx, (index // nx) % ny, index // (nx * ny)


@dataclass(frozen=True)
class GridBox:
    """A world box of ``dims = (n_x, n_y, n_z)`` cubic voxels of edge ``h = size / n`` from the
    corner ``lo``: ``n`` voxels along its longest side, of length ``size``. ``dims`` None (the
    default) is the cube ``[lo, lo + size]³`` of ``n³`` voxels."""

    lo: tuple[float, float, float]
    size: float
    n: int
    dims: tuple[int, int, int] | None = None

    def __post_init__(self):
        if not (isinstance(self.n, int | np.integer) and self.n >= 4):
            raise ParameterError(f"grid resolution must be an integer >= 4, got {self.n!r}")
        dims = (self.n,) * 3 if self.dims is None else tuple(self.dims)
        if not (
            len(dims) == 3
            and all(isinstance(c, int | np.integer) and 4 <= c <= self.n for c in dims)
            and max(dims) == self.n
        ):
            raise ParameterError(
                f"grid dims must be three integers in 4..n with the largest = n = {self.n}, "
                f"got {self.dims!r}"
            )
        object.__setattr__(self, "dims", tuple(int(c) for c in dims))
        if not (np.isfinite(self.size) and self.size > 0):
            raise ParameterError(f"grid box size must be positive and finite, got {self.size!r}")
        if not np.all(np.isfinite(self.lo)):
            raise ParameterError(f"grid box corner must be finite, got {self.lo!r}")

    @property
    def h(self) -> float:
        """Voxel edge length in world units."""
        return self.size / self.n

    @property
    def extent(self) -> np.ndarray:
        """The box's side lengths (world units, xyz): ``size·dims/n``."""
        return self.size * (np.asarray(self.dims, dtype=np.float64) / self.n)

    @property
    def hi(self) -> np.ndarray:
        return np.asarray(self.lo, dtype=np.float64) + self.extent

    @property
    def center(self) -> np.ndarray:
        return np.asarray(self.lo, dtype=np.float64) + 0.5 * self.extent

    @property
    def shape(self) -> tuple[int, int, int]:
        """The tensor shape ``(n_z, n_y, n_x)`` of the grid's arrays."""
        return grid_shape(self.dims)

    @property
    def voxels(self) -> int:
        """``n_x · n_y · n_z``."""
        return voxel_count(self.dims)

    def to_voxel(self, x):
        """World position(s) → voxel coordinates (NumPy, last axis xyz)."""
        return (np.asarray(x, dtype=np.float64) - np.asarray(self.lo)) / self.h

    def to_world(self, p):
        """Voxel coordinates → world position(s) (NumPy, last axis xyz)."""
        return np.asarray(p, dtype=np.float64) * self.h + np.asarray(self.lo)

    @staticmethod
    def around(bbox_min, bbox_max, n: int, margin: float = 6.0) -> GridBox:
        """The cube centred on a bounding box that holds it with ``margin`` voxels on every side.

        The 9³ blur of the materials (Pfeuti 2009 §3.1.2) needs ≥ 5 voxels of margin around
        objects.
        """
        bmin = np.asarray(bbox_min, dtype=np.float64)
        bmax = np.asarray(bbox_max, dtype=np.float64)
        extent = float(np.max(bmax - bmin))
        if not np.isfinite(extent) or extent <= 0:
            raise ParameterError(f"cannot build a grid around an empty box {bmin} .. {bmax}")
        size = extent * n / max(n - 2.0 * margin, 1.0)
        lo = 0.5 * (bmin + bmax) - 0.5 * size
        return GridBox(tuple(float(c) for c in lo), size, n)

    @staticmethod
    def fitted(bbox_min, bbox_max, n: int, margin: float = 6.0) -> GridBox:
        """The box grid centred on a bounding box that holds it with ``margin``
        voxels on every side: ``n`` voxels along the longest side (voxel edge
        ``h = extent/(n − 2·margin)``, as :meth:`around`), and along each other axis the fewest
        voxels that hold its extent and margins (at least 4). A cubic bounding box gives
        :meth:`around`'s cube."""
        cube = GridBox.around(bbox_min, bbox_max, n, margin)
        span = np.asarray(bbox_max, dtype=np.float64) - np.asarray(bbox_min, dtype=np.float64)
        need = np.ceil(span / cube.h + 2.0 * margin - 1e-6)
        dims = tuple(int(c) for c in np.clip(need, 4, n))
        centre = 0.5 * (np.asarray(bbox_min, np.float64) + np.asarray(bbox_max, np.float64))
        lo = centre - 0.5 * cube.size * (np.asarray(dims, dtype=np.float64) / n)
        return GridBox(tuple(float(c) for c in lo), cube.size, n, dims)


def to_tensor(values, n=None) -> mi.TensorXf:
    """A NumPy grid (n_z, n_y, n_x[, c]) or a tensor → ``mi.TensorXf`` of shape
    (n_z, n_y, n_x, c); ``n`` (:func:`grid_dims`), if given, is the extent it must have."""
    if isinstance(values, mi.TensorXf):
        t = values
    else:
        t = to_jit(mi.TensorXf, np.asarray(values, np.float32))
    if len(t.shape) == 3:
        t = mi.TensorXf(t.array, (*t.shape, 1))
    if n is not None and tuple(t.shape[:3]) != grid_shape(n):
        raise ParameterError(f"grid has shape {tuple(t.shape[:3])}, expected {grid_shape(n)}")
    return t


def gaussian_taps(radius: int, sigma: float) -> np.ndarray:
    """Normalised 1D Gaussian taps at offsets −radius..radius."""
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def filter_axis(t: mi.TensorXf, taps, axis: int) -> mi.TensorXf:
    """Convolve a grid tensor (nz, ny, nx, c) along ``axis`` (0 = z, 1 = y, 2 = x) with ``taps``
    centred on the middle tap, clamping indices at the edges (neither paper states the boundary
    rule: clamp-to-edge, as the trilinear lookups). The stride and extent are opaque: one kernel
    serves every axis and grid size."""
    shape = tuple(t.shape)
    taps = np.asarray(taps, dtype=np.float64)
    r = (len(taps) - 1) // 2
    size = int(np.prod(shape))
    stride = dr.opaque(mi.UInt32, int(np.prod(shape[axis + 1 :])))
    extent = dr.opaque(mi.Int32, shape[axis])
    idx = dr.arange(mi.UInt32, size)
    coord = mi.Int32((idx // stride) % extent)
    base = idx - mi.UInt32(coord) * stride
    out = dr.zeros(mi.Float, size)
    for o, w in zip(range(-r, r + 1), taps, strict=True):
        if w == 0.0:
            continue
        c = dr.clip(coord + o, 0, extent - 1)
        out += float(w) * dr.gather(mi.Float, t.array, base + mi.UInt32(c) * stride)
    return mi.TensorXf(out, shape)


def filter_separable(t: mi.TensorXf, taps, axes=(0, 1, 2)) -> mi.TensorXf:
    """Apply the same 1D filter along each of ``axes`` (a separable 3D filter)."""
    for axis in axes:
        t = filter_axis(t, taps, axis)
        dr.eval(t)
    return t


def pack(channels: list, n) -> mi.Float:
    """Interleave per-voxel channels (tensors or NumPy grids (n_z, n_y, n_x[, c]) of extent ``n``,
    :func:`grid_dims`) into one flat array of ``4·k`` floats per voxel (zero-padded), the layout
    :func:`trilinear_packed` reads."""
    tensors = [to_tensor(c, n) for c in channels]
    sources = [(t, k) for t in tensors for k in range(t.shape[3])]
    packets = (len(sources) + 3) // 4
    count = voxel_count(n)
    voxel = dr.arange(mi.UInt32, count)
    out = dr.zeros(mi.Float, count * 4 * packets)
    for p in range(packets):
        values = [
            dr.gather(mi.Float, t.array, voxel * t.shape[3] + k)
            for t, k in sources[4 * p : 4 * p + 4]
        ]
        values += [dr.zeros(mi.Float, count)] * (4 - len(values))
        dr.scatter(out, mi.Vector4f(*values), voxel * packets + p)
    dr.eval(out)
    return out


def trilinear_packed(
    data: mi.Float, n, packets: int, p: mi.Point3f, base=0, active: mi.Bool | bool = True
) -> list:
    """Trilinear sample at voxel coordinates ``p`` of a grid packed by :func:`pack` with
    ``4·packets`` channels: one list entry (``mi.Vector4f``) per packet of four channels. The
    grid has extent ``n`` (:func:`grid_dims`: ``(n_x, n_y, n_z)``, or one ``n`` per axis) and
    starts at cell ``base`` of ``data`` — both may vary per lane (the levels of a mipmap pyramid
    stored one after another).

    Samples sit at voxel centres with clamp-to-edge addressing (Pfeuti §3.1.1: "whenever we read
    data from a voxel grid we apply trilinear interpolation" — a CUDA 3D texture's semantics). The
    eight corners share one index computation and each reads whole packets (vector gathers).
    """
    q = p - 0.5
    f = dr.floor(q)
    w = q - f
    i0 = mi.Point3i(f)
    nx, ny, nz = grid_dims(n)
    top = mi.Point3i(nx - 1, ny - 1, nz - 1)
    lo = dr.clip(i0, 0, top)
    hi = dr.clip(i0 + 1, 0, top)
    out = [dr.zeros(mi.Vector4f, dr.width(p)) for _ in range(packets)]
    for dz in (0, 1):
        z, wz = (hi.z, w.z) if dz else (lo.z, 1.0 - w.z)
        for dy in (0, 1):
            y, wy = (hi.y, w.y) if dy else (lo.y, 1.0 - w.y)
            row = (z * ny + y) * nx
            for dx in (0, 1):
                x, wx = (hi.x, w.x) if dx else (lo.x, 1.0 - w.x)
                cell = (base + mi.UInt32(row + x)) * packets
                weight = wx * wy * wz
                for k in range(packets):
                    out[k] += weight * dr.gather(mi.Vector4f, data, cell + k, active)
    return out
