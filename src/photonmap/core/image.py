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


def check_output(path: str) -> str:
    """Raise a :class:`ParameterError` unless ``path`` ends in a known extension and lies in an
    existing, writable directory (checked before a render starts, not after)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise ParameterError(f"output {path!r} must end in .exr (linear) or .png (sRGB)")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise ParameterError(f"output {path!r}: the directory {folder!r} does not exist; create it")
    if os.path.isdir(path):
        raise ParameterError(f"output {path!r} is a directory; give a file name")
    target = path if os.path.exists(path) else folder
    if not os.access(target, os.W_OK):
        raise ParameterError(f"output {path!r} cannot be written here (permission denied)")
    return path


def write_image(path: str, image) -> str:
    """Write linear RGB radiance: ``.exr`` as float, ``.png`` tone-mapped to 8-bit sRGB (clamped).
    The directory must exist (:func:`check_output`)."""
    check_output(path)
    ext = os.path.splitext(path)[1].lower()
    rgb = as_rgb(image)
    if not np.all(np.isfinite(rgb)):
        raise ParameterError(f"refusing to write {path!r}: the image holds NaN or infinite values")
    bmp = mi.Bitmap(rgb, pixel_format=mi.Bitmap.PixelFormat.RGB)
    if ext == ".png":
        bmp = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    bmp.write(path)
    return path


def read_image(path: str) -> np.ndarray:
    """Read an EXR (linear) or PNG (sRGB, decoded to linear) as float32 (h, w, 3)."""
    if not os.path.isfile(path):
        raise ParameterError(f"no such image: {path!r}")
    try:
        bmp = mi.Bitmap(path).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False)
    except RuntimeError:
        raise ParameterError(
            f"{path!r} is not an image Mitsuba can read (EXR, PNG, JPEG, HDR, PFM, ...)"
        ) from None
    return as_rgb(np.array(bmp))


def block_means(image: np.ndarray, k: int = 4) -> np.ndarray:
    """Means of the image's k×k pixel blocks (the border rows and columns past a multiple of k
    are dropped)."""
    h, w = image.shape[0] // k * k, image.shape[1] // k * k
    return image[:h, :w].reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


def compare(a, b, block: int = 4) -> dict[str, float]:
    """Errors of image ``a`` against reference ``b``: RMSE, relative RMSE (RMSE / mean of ``b``),
    PSNR (peak = max of ``b``), the mean-brightness ratio, and the relative RMSE of
    ``block``×``block`` block means (``block_rel_rmse``: noise averages out within a block, a
    bias does not). A black reference has no relative error and is refused."""
    a, b = as_rgb(a).astype(np.float64), as_rgb(b).astype(np.float64)
    if a.shape != b.shape:
        raise ParameterError(f"images differ in size: {a.shape[:2]} vs {b.shape[:2]}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ParameterError("an image holds NaN or infinite values")
    mean = float(np.mean(np.abs(b)))
    if mean == 0:
        raise ParameterError(
            "the reference image is all zero (black): relative errors are undefined; check that "
            "the reference rendered (photonmap reference SCENE -o ref.exr)"
        )
    rmse = float(np.sqrt(np.mean((a - b) ** 2)))
    blocks = float(np.sqrt(np.mean((block_means(a, block) - block_means(b, block)) ** 2)))
    peak = float(np.max(np.abs(b)))
    return {
        "rmse": rmse,
        "rel_rmse": rmse / mean,
        "block_rel_rmse": blocks / mean,
        "brightness": float(np.mean(a)) / float(np.mean(b)),
        "psnr": 20 * np.log10(peak / rmse) if rmse > 0 else float("inf"),
    }
