"""Perspective cameras as Mitsuba sensors: move, re-aim or resize an existing one; cast a
wavefront of pixel samples."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .params import check_fov, check_view


def moved_sensor(
    old, focus_hint, origin=None, target=None, up=(0, 1, 0), fov=None, width=None, height=None
):
    """A perspective sensor like ``old`` with the given changes. Without a new ``target`` the camera
    keeps looking at the point of its old view axis nearest ``focus_hint`` (e.g. the scene centre);
    ``fov`` is horizontal, in degrees; unspecified values are kept."""
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
    size = old.film().size()
    fov = float(fov if fov is not None else np.array(mi.traverse(old)["x_fov"])[0])
    return mi.load_dict(
        {
            "type": "perspective",
            "fov": fov,
            "to_world": to_world,
            "film": {
                "type": "hdrfilm",
                "width": int(width or size[0]),
                "height": int(height or size[1]),
                "rfilter": {"type": "box"},
            },
        }
    )


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


def pixel_rays(sensor, pixel: mi.UInt32, jitter: mi.Point2f) -> tuple[mi.Ray3f, mi.Spectrum]:
    """Camera rays through the given pixels of the sensor's film crop (index ``y · width + x``),
    each placed in its pixel by ``jitter`` (a point in [0, 1)² per ray). Returns the rays and their
    importance weights."""
    film = sensor.film()
    w = int(film.crop_size()[0])
    ox, oy = (int(c) for c in film.crop_offset())
    full = film.size()
    pos = mi.Point2f(
        (mi.Float(pixel % w + ox) + jitter.x) / float(full[0]),
        (mi.Float(pixel // w + oy) + jitter.y) / float(full[1]),
    )
    ray, weight = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    return ray, mi.Spectrum(weight)


def pixel_means(L: mi.Spectrum, spp: int) -> mi.Spectrum:
    """The mean of each pixel's ``spp`` adjacent samples. ``L`` is evaluated first: a block
    reduction of each channel of a lazy ``L`` would rerun the kernel that computes it."""
    dr.eval(L)
    return mi.Spectrum(*[dr.block_reduce(dr.ReduceOp.Add, c, spp) for c in L]) / spp
