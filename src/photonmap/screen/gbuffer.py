"""G-buffers of the ``screen`` pipeline (Yao 2011 §3.1, Fig 3.1; spec seed-004 §2.1).

A :class:`GBuffer` holds one sample per pixel as flat Dr.Jit arrays in row-major order (pixel
``(x, y)`` at index ``y·width + x``, y = 0 the top row). Every image-space stage (splatting, soft
shadows, upsampling) reads it; the eye G-buffer is cast with Mitsuba rays (:func:`eye_gbuffer`;
spec §7: "G-buffers come from primary rays", identical to rasterization up to sub-pixel position).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.camera import pixel_rays
from ..surface.trace import is_specular


@dataclass
class GBuffer:
    """Per-pixel surface samples seen from a pinhole camera.

    ``pos``: world-space hit point s; ``nrm``: unit shading normal, flipped to face the eye;
    ``depth``: eye-space depth Z_eye (distance along the camera's forward axis); ``albedo``: diffuse
    reflectance ρ(s) (the f(s) = ρ/π of Eq 1); ``valid``: a surface was hit (False on background,
    where the other channels are zero). ``eye``: camera position; ``forward``: unit view axis;
    ``f_px``: focal length in pixels, (H/2)/tan(fovy/2).
    """

    width: int
    height: int
    pos: mi.Point3f
    nrm: mi.Normal3f
    depth: mi.Float
    albedo: mi.Color3f
    valid: mi.Bool
    eye: mi.ScalarPoint3f
    forward: mi.ScalarVector3f
    f_px: float


def focal_px(sensor: mi.Sensor) -> float:
    """Focal length in pixels of a perspective ``sensor``: (W/2)/tan(fov_x/2) (square pixels)."""
    width = int(sensor.film().size()[0])
    fov_x = float(np.array(mi.traverse(sensor)["x_fov"]).ravel()[0])
    return 0.5 * width / math.tan(math.radians(fov_x) / 2)


def eye_gbuffer(scene: mi.Scene, sensor: mi.Sensor) -> tuple[GBuffer, mi.Bool]:
    """The eye G-buffer of spec §2.1, one primary ray per pixel centre (Fig 3.1), and the mask of
    pixels that see a mirror or glass surface (their ``albedo`` is 0: no diffuse shading, no
    splats; :mod:`.composite` ray-traces them).

    ``depth`` is Z_eye = (s − e)·forward; normals are shading normals flipped to face the eye.
    """
    w, h = (int(c) for c in sensor.film().crop_size())
    ray, _ = pixel_rays(sensor, dr.arange(mi.UInt32, w * h), mi.Point2f(0.5))
    flags = mi.RayFlags.Minimal | mi.RayFlags.UV | mi.RayFlags.ShadingFrame  # UV: textures
    si = scene.ray_intersect(ray, flags, True)
    valid = si.is_valid()
    bsdf = si.bsdf(ray)
    specular = is_specular(bsdf, valid)  # mirrors, glass: ray-traced (spec §2.9, A27)
    albedo = dr.select(valid & ~specular, bsdf.eval_diffuse_reflectance(si, valid), 0.0)
    n = mi.Normal3f(si.sh_frame.n)
    n = dr.select(dr.dot(n, ray.d) > 0, -n, n)
    m = np.array(sensor.world_transform().matrix, dtype=np.float64)[..., 0]
    eye, forward = m[:3, 3], m[:3, 2] / np.linalg.norm(m[:3, 2])
    p = dr.select(valid, si.p, 0.0)
    depth = dr.select(
        valid, dr.dot(p - mi.Point3f(*eye.tolist()), mi.Vector3f(*forward.tolist())), 0.0
    )
    gbuf = GBuffer(
        width=w,
        height=h,
        pos=mi.Point3f(p),
        nrm=dr.select(valid, n, 0.0),
        depth=depth,
        albedo=mi.Color3f(albedo),
        valid=valid,
        eye=mi.ScalarPoint3f(*eye.tolist()),
        forward=mi.ScalarVector3f(*forward.tolist()),
        f_px=focal_px(sensor),
    )
    dr.eval(gbuf.pos, gbuf.nrm, gbuf.depth, gbuf.albedo, gbuf.valid, specular)
    return gbuf, specular
