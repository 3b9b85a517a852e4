"""Perspective cameras as Mitsuba sensors: move, re-aim or resize an existing one; cast a
wavefront of pixel samples."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .film_filter import sample_offsets
from .params import check_fov, check_view


def moved_sensor(
    old, focus_hint, origin=None, target=None, up=(0, 1, 0), fov=None, width=None, height=None
):
    """A perspective sensor like ``old`` with the given changes. Without a new ``target`` the camera
    keeps looking at the point of its old view axis nearest ``focus_hint`` (e.g. the scene centre);
    ``fov`` is horizontal, in degrees; unspecified values are kept: the film's reconstruction
    filter and ``sample_border`` always, its crop window while the size stays."""
    check_fov(fov)
    matrix = np.array(old.world_transform().matrix, dtype=np.float64)[..., 0]
    to_world = mi.ScalarTransform4f(matrix)
    if origin is not None or target is not None:
        o_old, forward = matrix[:3, 3], matrix[:3, 2]
        focus = o_old + max(np.dot(np.asarray(focus_hint) - o_old, forward), 1e-6) * forward
        o = origin if origin is not None else o_old
        t = target if target is not None else focus
        check_view(o, t, up)  # a degenerate placement would render black
        o, t = np.asarray(o, dtype=np.float64), np.asarray(t, dtype=np.float64)
        to_world = mi.ScalarTransform4f().look_at(
            origin=o.tolist(), target=t.tolist(), up=np.asarray(up, float).tolist()
        )
    film = old.film()
    size = film.size()
    fov = float(fov if fov is not None else np.array(mi.traverse(old)["x_fov"])[0])
    new_film = {
        "type": "hdrfilm",
        "width": int(width or size[0]),
        "height": int(height or size[1]),
        "rfilter": film.rfilter(),  # the film's reconstruction filter is kept
        "sample_border": bool(film.sample_border()),
    }
    if (new_film["width"], new_film["height"]) == tuple(int(c) for c in size):
        (ox, oy), (cw, ch) = (
            tuple(int(c) for c in v) for v in (film.crop_offset(), film.crop_size())
        )
        new_film.update(crop_offset_x=ox, crop_offset_y=oy, crop_width=cw, crop_height=ch)
    return mi.load_dict({"type": "perspective", "fov": fov, "to_world": to_world, "film": new_film})


def scene_bounds(scene: mi.Scene) -> tuple[np.ndarray, float]:
    """The centre and the diagonal length of the scene's bounding box."""
    box = scene.bbox()
    lo, hi = (np.array(c, dtype=np.float64).ravel() for c in (box.min, box.max))
    return (lo + hi) / 2, float(np.linalg.norm(hi - lo))


class MovableCamera:
    """``set_camera`` for a pipeline holding a Mitsuba ``scene`` and its current ``sensor``."""

    scene: mi.Scene
    sensor: mi.Sensor

    def set_camera(
        self, origin=None, target=None, up=(0, 1, 0), fov=None, width=None, height=None, sensor=None
    ) -> None:
        """Move, re-aim or resize the camera (``fov`` horizontal, degrees), or pass a Mitsuba
        ``sensor``; the photons are kept. Without a new ``target`` the camera keeps looking at the
        point of its view axis nearest the scene's centre."""
        if sensor is None:
            centre, _ = scene_bounds(self.scene)
            sensor = moved_sensor(self.sensor, centre, origin, target, up, fov, width, height)
        self.sensor = sensor


def pixel_rays(
    sensor, pixel: mi.UInt32, jitter: mi.Point2f, filtered: bool = True
) -> tuple[mi.Ray3f, mi.Spectrum]:
    """Camera rays through the given pixels of the sensor's film crop (index ``y · width + x`` of
    the crop; the sensor maps the crop window to its sample space), each placed in its pixel by
    ``jitter`` (a point in [0, 1)² per ray). Returns the rays and their
    importance weights.

    The film's reconstruction filter is importance-sampled (:mod:`.film_filter`, Ernst et al.
    2006): ``jitter`` goes through the inverse cumulative filter of the pixel, so the mean of a
    pixel's weighted samples converges to the film's filtered pixel, as Mitsuba's splatting
    does; the weight carries the filter's sign and normalisation where it has negative lobes.
    The integer part of a ``jitter`` beyond [0, 1) shifts the ray by whole pixels. A box filter,
    or ``filtered=False`` (passes of one ray per pixel centre, which filter their image with
    :func:`.film_filter.filter_image`), places the ray uniformly in the pixel."""
    film = sensor.film()
    w, h = (int(c) for c in film.crop_size())
    rfilter = film.rfilter()
    # the sensor's sample space [0, 1]² spans the crop window (Mitsuba's sample_to_camera)
    if not filtered or rfilter.is_box_filter():
        pos = mi.Point2f(
            (mi.Float(pixel % w) + jitter.x) / float(w),
            (mi.Float(pixel // w) + jitter.y) / float(h),
        )
        ray, weight = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
        return ray, mi.Spectrum(weight)
    column, row = pixel % w, pixel // w
    offset, filter_weight = sample_offsets(
        rfilter, (w, h), film.sample_border(), column, row, jitter
    )
    pos = mi.Point2f(
        (mi.Float(column) + (0.5 + offset.x)) / float(w),
        (mi.Float(row) + (0.5 + offset.y)) / float(h),
    )
    ray, weight = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    if filter_weight is None:
        return ray, mi.Spectrum(weight)
    return ray, mi.Spectrum(weight) * filter_weight


def pixel_means(L: mi.Spectrum, spp: int) -> mi.Spectrum:
    """The mean of each pixel's ``spp`` adjacent samples. ``L`` is evaluated first: a block
    reduction of each channel of a lazy ``L`` would rerun the kernel that computes it."""
    dr.eval(L)
    return mi.Spectrum(*[dr.block_reduce(dr.ReduceOp.Add, c, spp) for c in L]) / spp


def footprint_radius(scene: mi.Scene, sensor: mi.Sensor, pixels: float) -> float:
    """``pixels`` pixel footprints at the median distance from the camera of the first surfaces
    the camera rays through the pixel centres meet (a gather radius that looks the same size in
    every image; the distance from the camera's position, not the ray's origin, which Mitsuba
    puts on the near clipping plane); 10⁻³ of the scene's diagonal if they meet none."""
    w, h = (int(c) for c in sensor.film().crop_size())
    pixel = dr.arange(mi.UInt32, w * h)
    ray, _ = pixel_rays(sensor, pixel, mi.Point2f(0.5, 0.5))
    side, _ = pixel_rays(sensor, pixel, mi.Point2f(1.5, 0.5))
    angle = dr.safe_acos(dr.dot(ray.d, side.d))
    si = scene.ray_intersect(ray)
    origin = np.array(sensor.world_transform().matrix, dtype=np.float64)[:3, 3, 0]
    eye = mi.Point3f(*(float(c) for c in origin))
    footprint = (dr.norm(si.p - eye) * angle).numpy()[si.is_valid().numpy()]
    if footprint.size:
        return pixels * float(np.median(footprint))
    return 1e-3 * scene_bounds(scene)[1]
