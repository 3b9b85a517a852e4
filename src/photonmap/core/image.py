"""Image output, tone mapping and image comparison.

Every file photonmap writes goes through :func:`write_bytes`: the data goes to a temporary file
in the target's directory, is flushed to the disk and renamed over the target (atomic on POSIX),
so a failed or interrupted write leaves the previous file as it was and never a partial one.
"""

from __future__ import annotations

import errno
import os
import secrets
import stat

import mitsuba as mi
import numpy as np

from . import interrupt
from .errors import OutputError, ParameterError, WriteError

FORMATS = (".exr", ".png")


def as_rgb(image) -> np.ndarray:
    """A TensorXf / Bitmap / array of shape (h, w, 3) → float32 NumPy (h, w, 3)."""
    a = np.asarray(image, dtype=np.float32)
    if a.ndim != 3 or a.shape[2] < 3:
        raise ParameterError(f"expected an RGB image of shape (h, w, 3), got {a.shape}")
    return np.ascontiguousarray(a[..., :3])


def check_output(path: str, formats=FORMATS) -> str:
    """Raise an :class:`OutputError` unless ``path`` ends in a known extension and names a
    regular file (or nothing yet) in an existing, writable directory (checked before a render
    starts, not after). A symbolic link counts as the file it points to."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in formats:
        if formats == FORMATS:
            raise OutputError(f"output {path!r} must end in .exr (linear) or .png (sRGB)")
        raise OutputError(f"output {path!r} must end in {' or '.join(formats)}")
    real = os.path.realpath(path)
    folder = os.path.dirname(real)
    if not os.path.isdir(folder):
        folder = os.path.dirname(os.path.abspath(path))
        raise OutputError(f"output {path!r}: the directory {folder!r} does not exist; create it")
    if os.path.isdir(real):
        raise OutputError(f"output {path!r} is a directory; give a file name")
    if os.path.exists(real) and not os.path.isfile(real):
        raise OutputError(
            f"output {path!r} is not a regular file (a device, pipe or socket): give a file path"
        )
    for target in (folder, real) if os.path.exists(real) else (folder,):
        if not os.access(target, os.W_OK):
            raise OutputError(f"output {path!r} cannot be written here (permission denied)")
    return path


# errors of a write that the path cannot fix: exit status 1 (WriteError), else 2 (OutputError)
IO_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EFBIG}


def write_bytes(path: str, data: bytes) -> str:
    """Write ``data`` to ``path`` atomically: a temporary file in the same directory, flushed to
    the disk, renamed over ``path`` (a symbolic link's target is replaced, the link kept; an
    existing file's permissions are kept). On failure the temporary file is removed and the
    previous file is untouched: a :class:`WriteError` (disk full, I/O error) or an
    :class:`OutputError` (the path: permission, missing directory)."""
    real = os.path.realpath(path)
    if os.path.exists(real) and not os.path.isfile(real):  # never rename over a device
        raise OutputError(
            f"output {path!r} is not a regular file (a device, pipe or socket): give a file path"
        )
    folder, name = os.path.split(real)
    temp = os.path.join(folder, f".{name}.{secrets.token_hex(4)}.tmp")
    interrupt.pending_files.add(temp)
    try:
        fd = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
        try:
            _write_all(fd, data)
            os.fsync(fd)
            if os.path.isfile(real):
                os.chmod(temp, stat.S_IMODE(os.stat(real).st_mode))
        finally:
            os.close(fd)
        os.replace(temp, real)
    except OSError as exc:
        try:
            os.unlink(temp)
        except OSError:
            pass
        why = exc.strerror or type(exc).__name__
        if exc.errno in IO_ERRORS:
            raise WriteError(
                f"could not write {path!r}: {why}; the previous file (if any) is unchanged"
            ) from None
        raise OutputError(f"could not write {path!r}: {why}; choose another path") from None
    finally:
        interrupt.pending_files.discard(temp)
    _sync_directory(folder)
    return path


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _sync_directory(folder: str) -> None:
    """Flush the directory entry of a rename to the disk (where the system allows it)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def encode_image(image, ext: str) -> bytes:
    """Linear RGB radiance as the bytes of an ``.exr`` (float) or ``.png`` (8-bit sRGB, clamped)
    file."""
    rgb = as_rgb(image)
    bmp = mi.Bitmap(rgb, pixel_format=mi.Bitmap.PixelFormat.RGB)
    if ext == ".png":
        bmp = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
        fmt = mi.Bitmap.FileFormat.PNG
    else:
        fmt = mi.Bitmap.FileFormat.OpenEXR
    stream = mi.MemoryStream()
    bmp.write(stream, fmt)
    stream.seek(0)
    return stream.read(stream.size())


def write_image(path: str, image) -> str:
    """Write linear RGB radiance: ``.exr`` as float, ``.png`` tone-mapped to 8-bit sRGB (clamped),
    atomically (:func:`write_bytes`). The directory must exist (:func:`check_output`)."""
    check_output(path)
    ext = os.path.splitext(path)[1].lower()
    rgb = as_rgb(image)
    if not np.all(np.isfinite(rgb)):
        raise ParameterError(f"refusing to write {path!r}: the image holds NaN or infinite values")
    return write_bytes(path, encode_image(rgb, ext))


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
