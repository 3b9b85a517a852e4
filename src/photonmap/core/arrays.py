"""Joining Dr.Jit arrays, copying them to NumPy and making them from NumPy without compiling a
kernel per width or per allocation.

Dr.Jit turns a Python number used in a kernel into a literal of its code, so a kernel that
depends on a width — ``dr.concat`` (each part's offset), ``.numpy()`` of a ``Point3f`` or
``Color3f`` (the components' offsets), ``dr.arange(n) + offset``, ``dr.mean(colour, axis=0)``
(it multiplies by the width and divides by three times it) — is compiled anew for every width a
render produces: photon counts, compacted wavefronts, the chunks of a path loop. These helpers
pass the offsets as opaque values (``dr.opaque``), copy component by component or average without
the width, so one compiled kernel serves every width.

Dr.Jit also maps a NumPy array's memory without copying it (``mi.Float(array)``), and reads a
buffer that is not aligned to its vector width (64 bytes: 16 float32 lanes) with unaligned loads:
another kernel, with another hash, chosen by where ``malloc`` happened to put the array, so a
warm kernel cache missed it on the next run. A constructor that must cast (a float64 array into
``mi.Float``) maps a fresh temporary, aligned or not. :func:`to_jit` casts first and gives the
array an aligned home (:func:`aligned`).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

ALIGNMENT = 64  # bytes: Dr.Jit's widest vector load (16 lanes of 4 bytes)


def aligned(array, dtype=None) -> np.ndarray:
    """``array`` as a C-contiguous NumPy array of ``dtype`` (default: its own) whose memory starts
    on a :data:`ALIGNMENT`-byte boundary (itself when it already does)."""
    array = np.ascontiguousarray(array, dtype)
    if array.ctypes.data % ALIGNMENT == 0:
        return array
    buffer = np.empty(array.nbytes + ALIGNMENT, np.uint8)
    start = -buffer.ctypes.data % ALIGNMENT
    out = buffer[start : start + array.nbytes].view(array.dtype).reshape(array.shape)
    out[...] = array
    return out


DTYPES = {
    dr.VarType.Float32: np.float32, dr.VarType.Float64: np.float64, dr.VarType.UInt32: np.uint32,
    dr.VarType.Int32: np.int32, dr.VarType.UInt64: np.uint64, dr.VarType.Int64: np.int64,
    dr.VarType.Bool: np.bool_,
}  # fmt: skip


def to_jit(kind, array):
    """``kind(array)`` for a Dr.Jit type (``mi.Float``, ``mi.UInt32``, ``mi.TensorXf``, …): the
    NumPy array cast to the type's element and :func:`aligned` first. Dr.Jit maps NumPy memory
    into its kernels and writes the pointer's alignment into their code; an unaligned array, or a
    cast inside the constructor (which maps a fresh temporary), would make the kernel — and
    whether Dr.Jit's kernel cache serves it — depend on where ``malloc`` put the memory."""
    return kind(aligned(array, DTYPES[dr.type_v(kind)]))


def columns(kind, array) -> list:
    """The columns of an ``(N, k)`` NumPy array as ``k`` arrays of the Dr.Jit type ``kind``
    (:func:`to_jit`): ``mi.Point3f(*columns(mi.Float, points))``."""
    return [to_jit(kind, column) for column in np.asarray(array).T]


def concat(parts: list):
    """The arrays (or Mitsuba structs) of ``parts`` one after the other, as ``dr.concat``."""
    parts = [p for p in parts if dr.width(p)] or parts[:1]
    if len(parts) == 1:
        return parts[0]
    out = dr.zeros(type(parts[0]), sum(dr.width(p) for p in parts))
    offset = 0
    for part in parts:
        width = dr.width(part)
        dr.scatter(out, part, dr.arange(mi.UInt32, width) + dr.opaque(mi.UInt32, offset))
        offset += width
    return out


def channel_mean(value):
    """The mean of a colour's channels (``Color3f``, ``Spectrum``), lane by lane: what
    ``dr.mean(value, axis=0)`` computes, without its width literal."""
    return dr.sum(value, axis=0) / len(value)


def to_numpy(value) -> np.ndarray:
    """``value`` as NumPy: shape ``(n,)`` for a flat array, ``(components, n)`` for a nested one
    (``Point3f``, ``Color3f``, …), the layout of ``value.numpy()``."""
    if not dr.depth_v(value) > 1:
        return np.array(value)
    dr.eval(value)
    n = dr.width(value)
    return np.stack([np.broadcast_to(np.array(value[i]), (n,)) for i in range(len(value))])
