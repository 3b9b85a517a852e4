"""Image output, tone mapping and image comparison."""

from __future__ import annotations

import os

import mitsuba as mi
import numpy as np

from .errors import ParameterError

FORMATS = (".exr", ".png")


def as_rgb(image) -> np.ndarray:
    """A TensorXf / Bitmap / array of shape (h, w, 3) → float32 NumPy (h, w, 3)."""
    a = np.asarray(image, dtype=np.float32)
    if a.ndim != 3 or a.shape[2] < 3:
        raise ParameterError(f"expected an RGB image of shape (h, w, 3), got {a.shape}")
    return np.ascontiguousarray(a[..., :3])


def write_image(path: str, image) -> str:
    """Write linear RGB radiance: ``.exr`` as float, ``.png`` tone-mapped to 8-bit sRGB (clamped)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise ParameterError(f"output {path!r} must end in .exr or .png")
    rgb = as_rgb(image)
    if not np.all(np.isfinite(rgb)):
        raise ParameterError(f"refusing to write {path!r}: the image holds NaN or infinite values")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    bmp = mi.Bitmap(rgb, pixel_format=mi.Bitmap.PixelFormat.RGB)
    if ext == ".png":
        bmp = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    bmp.write(path)
    return path


def read_image(path: str) -> np.ndarray:
    """Read an EXR (linear) or PNG (sRGB, decoded to linear) as float32 (h, w, 3)."""
    if not os.path.exists(path):
        raise ParameterError(f"no such image: {path!r}")
    bmp = mi.Bitmap(path).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False)
    return as_rgb(np.array(bmp))


def compare(a, b) -> dict[str, float]:
    """RMSE, relative RMSE (RMSE / mean of ``b``) and PSNR (peak = max of ``b``) of two images."""
    a, b = as_rgb(a).astype(np.float64), as_rgb(b).astype(np.float64)
    if a.shape != b.shape:
        raise ParameterError(f"images differ in size: {a.shape[:2]} vs {b.shape[:2]}")
    rmse = float(np.sqrt(np.mean((a - b) ** 2)))
    mean = float(np.mean(np.abs(b)))
    peak = float(np.max(np.abs(b)))
    return {
        "rmse": rmse,
        "rel_rmse": rmse / mean if mean > 0 else float("inf"),
        "psnr": 20 * np.log10(peak / rmse) if rmse > 0 and peak > 0 else float("inf"),
    }
