"""Voxel grids: the world box, texture sampling and separable filters (Dr.Jit).

Conventions (DESIGN.md, spec seed-000-002 §0.2):

- The grid is a cube of ``n³`` voxels over the world box ``[lo, lo + size]³``, voxel edge
  ``h = size / n``. Kernels work in **voxel units**: ``p = (x_world − lo) / h ∈ [0, n)³``; voxel
  ``(i, j, k)`` covers ``[i, i+1) × [j, j+1) × [k, k+1)`` and its centre is ``(i+½, j+½, k+½)``.
- Grid arrays (NumPy or ``mi.TensorXf``) have shape ``(n, n, n)`` or ``(n, n, n, c)`` and are indexed
  ``[z, y, x]`` (``[k, j, i]``), the order of ``dr.Texture3f``; the flat index of voxel ``(i, j, k)``
  is ``(k·n + j)·n + i``.
- "Whenever we read data from a voxel grid we apply trilinear interpolation" [Pf §3.1.1], with
  samples at voxel centres and clamp-to-edge addressing: :func:`trilinear_packed` (the semantics of
  ``dr.Texture3f`` with linear filtering and ``WrapMode.Clamp``, reading several channels with one
  index computation).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .errors import ParameterError


@dataclass(frozen=True)
class GridBox:
    """A cubic world box ``[lo, lo + size]³`` divided into ``n³`` voxels."""

    lo: tuple[float, float, float]
    size: float
    n: int

    def __post_init__(self):
        if not (isinstance(self.n, int | np.integer) and self.n >= 4):
            raise ParameterError(f"grid resolution must be an integer >= 4, got {self.n!r}")
        if not (np.isfinite(self.size) and self.size > 0):
            raise ParameterError(f"grid box size must be positive and finite, got {self.size!r}")
        if not np.all(np.isfinite(self.lo)):
            raise ParameterError(f"grid box corner must be finite, got {self.lo!r}")

    @property
    def h(self) -> float:
        """Voxel edge length in world units."""
        return self.size / self.n

    @property
    def hi(self) -> np.ndarray:
        return np.asarray(self.lo, dtype=np.float64) + self.size

    @property
    def center(self) -> np.ndarray:
        return np.asarray(self.lo, dtype=np.float64) + 0.5 * self.size

    def to_voxel(self, x):
        """World position(s) → voxel coordinates (NumPy, last axis xyz)."""
        return (np.asarray(x, dtype=np.float64) - np.asarray(self.lo)) / self.h

    def to_world(self, p):
        """Voxel coordinates → world position(s) (NumPy, last axis xyz)."""
        return np.asarray(p, dtype=np.float64) * self.h + np.asarray(self.lo)

    @staticmethod
    def around(bbox_min, bbox_max, n: int, margin: float = 6.0) -> GridBox:
        """The cube centred on a bounding box that holds it with ``margin`` voxels on every side.

        Spec A4: the 9³ blur needs ≥ 5 voxels of margin around objects.
        """
        bmin = np.asarray(bbox_min, dtype=np.float64)
        bmax = np.asarray(bbox_max, dtype=np.float64)
        extent = float(np.max(bmax - bmin))
        if not np.isfinite(extent) or extent <= 0:
            raise ParameterError(f"cannot build a grid around an empty box {bmin} .. {bmax}")
        size = extent * n / max(n - 2.0 * margin, 1.0)
        lo = 0.5 * (bmin + bmax) - 0.5 * size
        return GridBox(tuple(float(c) for c in lo), size, n)


def to_tensor(values, n: int | None = None) -> mi.TensorXf:
    """A NumPy grid (n, n, n[, c]) or a tensor → ``mi.TensorXf`` of shape (n, n, n, c)."""
    if isinstance(values, mi.TensorXf):
        t = values
    else:
        t = mi.TensorXf(np.ascontiguousarray(values, dtype=np.float32))
    if len(t.shape) == 3:
        t = mi.TensorXf(t.array, (*t.shape, 1))
    if n is not None and tuple(t.shape[:3]) != (n, n, n):
        raise ParameterError(f"grid has shape {tuple(t.shape[:3])}, expected {(n, n, n)}")
    return t


def gaussian_taps(radius: int, sigma: float) -> np.ndarray:
    """Normalised 1D Gaussian taps at offsets −radius..radius."""
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def filter_axis(t: mi.TensorXf, taps, axis: int) -> mi.TensorXf:
    """Convolve a grid tensor (nz, ny, nx, c) along ``axis`` (0 = z, 1 = y, 2 = x) with ``taps``
    centred on the middle tap, clamping indices at the edges (spec A4)."""
    shape = tuple(t.shape)
    taps = np.asarray(taps, dtype=np.float64)
    r = (len(taps) - 1) // 2
    size = int(np.prod(shape))
    stride = int(np.prod(shape[axis + 1 :]))
    extent = shape[axis]
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


def pack(channels: list, n: int) -> mi.Float:
    """Interleave per-voxel channels (tensors or NumPy grids (n, n, n[, c])) into one flat array of
    ``4·k`` floats per voxel (zero-padded), the layout :func:`trilinear_packed` reads."""
    tensors = [to_tensor(c, n) for c in channels]
    sources = [(t, k) for t in tensors for k in range(t.shape[3])]
    packets = (len(sources) + 3) // 4
    voxel = dr.arange(mi.UInt32, n**3)
    out = dr.zeros(mi.Float, n**3 * 4 * packets)
    for p in range(packets):
        values = [
            dr.gather(mi.Float, t.array, voxel * t.shape[3] + k)
            for t, k in sources[4 * p : 4 * p + 4]
        ]
        values += [dr.zeros(mi.Float, n**3)] * (4 - len(values))
        dr.scatter(out, mi.Vector4f(*values), voxel * packets + p)
    dr.eval(out)
    return out


def trilinear_packed(
    data: mi.Float, n, packets: int, p: mi.Point3f, base=0, active: mi.Bool | bool = True
) -> list:
    """Trilinear sample at voxel coordinates ``p`` of a grid packed by :func:`pack` with
    ``4·packets`` channels: one list entry (``mi.Vector4f``) per packet of four channels. The
    grid has ``n`` cells per axis and starts at cell ``base`` of ``data`` — both may vary per lane
    (the levels of a mipmap pyramid stored one after another).

    Samples sit at voxel centres with clamp-to-edge addressing (Pfeuti §3.1.1: "whenever we read
    data from a voxel grid we apply trilinear interpolation" — a CUDA 3D texture's semantics). The
    eight corners share one index computation and each reads whole packets (vector gathers).
    """
    q = p - 0.5
    f = dr.floor(q)
    w = q - f
    i0 = mi.Point3i(f)
    lo = dr.clip(i0, 0, n - 1)
    hi = dr.clip(i0 + 1, 0, n - 1)
    out = [dr.zeros(mi.Vector4f, dr.width(p)) for _ in range(packets)]
    for dz in (0, 1):
        z, wz = (hi.z, w.z) if dz else (lo.z, 1.0 - w.z)
        for dy in (0, 1):
            y, wy = (hi.y, w.y) if dy else (lo.y, 1.0 - w.y)
            row = (z * n + y) * n
            for dx in (0, 1):
                x, wx = (hi.x, w.x) if dx else (lo.x, 1.0 - w.x)
                cell = (base + mi.UInt32(row + x)) * packets
                weight = wx * wy * wz
                for k in range(packets):
                    out[k] += weight * dr.gather(mi.Vector4f, data, cell + k, active)
    return out
