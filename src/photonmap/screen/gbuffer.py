"""G-buffers of the ``screen`` pipeline (Yao 2011 §3.1, Fig 3.1).

A :class:`GBuffer` holds one sample per pixel as flat Dr.Jit arrays in row-major order (pixel
``(x, y)`` at index ``y·width + x``, y = 0 the top row). Every image-space stage (splatting, soft
shadows, upsampling) reads it; the eye G-buffer is cast with Mitsuba rays (:func:`eye_gbuffer`:
primary rays, identical to Yao's rasterization up to sub-pixel position).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import to_jit
from ..core.bsdf import diffuse_albedo, intersect_visible, is_specular
from ..core.camera import pixel_means, pixel_rays

EMISSION_SAMPLES = 8
"""Sub-pixel samples per side (8 × 8) of the emission of pixels at a light's silhouette."""


@dataclass
class GBuffer:
    """Per-pixel surface samples seen from a pinhole camera.

    ``pos``: world-space hit point s; ``nrm``: unit shading normal, flipped to face the eye;
    ``depth``: eye-space depth Z_eye (distance along the camera's forward axis); ``albedo``: diffuse
    reflectance ρ(s) (the f(s) = ρ/π of Eq 1); ``valid``: a surface was hit (False on background,
    where the other channels are zero). ``eye``: camera position; ``forward``: unit view axis;
    ``f_px``: focal length in pixels, (H/2)/tan(fovy/2). ``emission``: radiance an area light
    emits toward the eye at s (0 elsewhere; None in G-buffers that do not carry it).
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
    emission: mi.Color3f | None = None


def focal_px(sensor: mi.Sensor) -> float:
    """Focal length in pixels of a perspective ``sensor``: (W/2)/tan(fov_x/2) (square pixels)."""
    width = int(sensor.film().size()[0])
    fov_x = float(np.array(mi.traverse(sensor)["x_fov"]).ravel()[0])
    return 0.5 * width / math.tan(math.radians(fov_x) / 2)


def eye_gbuffer(scene: mi.Scene, sensor: mi.Sensor) -> tuple[GBuffer, mi.Bool]:
    """The eye G-buffer (Yao 2011 §3.1), one primary ray per pixel centre (Fig 3.1; the pipeline
    applies the film's reconstruction filter to the finished image), and the mask of
    pixels that see a mirror or glass surface (their ``albedo`` is 0: no diffuse shading, no
    splats; :mod:`.composite` ray-traces them).

    ``depth`` is Z_eye = (s − e)·forward; normals are shading normals flipped to face the eye.
    Eye rays pass through ``null``-BSDF shapes (fog boxes are invisible); ``emission`` is the
    radiance of the area lights the eye sees (``emitter.eval``), antialiased at their silhouettes
    (:func:`_light_edges`).
    """
    w, h = (int(c) for c in sensor.film().crop_size())
    ray, _ = pixel_rays(sensor, dr.arange(mi.UInt32, w * h), mi.Point2f(0.5), filtered=False)
    si = intersect_visible(scene, ray)
    valid = si.is_valid()
    emission = dr.select(valid, si.emitter(scene).eval(si, valid), 0.0)
    bsdf = si.bsdf(ray)
    specular = is_specular(bsdf, valid)  # mirrors, glass: ray-traced (.composite)
    albedo = dr.select(valid & ~specular, diffuse_albedo(bsdf, si, valid), 0.0)
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
        emission=mi.Color3f(emission),
    )
    dr.eval(gbuf.pos, gbuf.nrm, gbuf.depth, gbuf.albedo, gbuf.valid, gbuf.emission, specular)
    gbuf.emission = _light_edges(scene, sensor, gbuf.emission)
    dr.eval(gbuf.emission)
    return gbuf, specular


def _light_edges(scene: mi.Scene, sensor: mi.Sensor, emission: mi.Color3f) -> mi.Color3f:
    """``emission`` with the pixels at a light's silhouette replaced by the mean of
    :data:`EMISSION_SAMPLES`² stratified sub-pixel rays: a light a few pixels tall covers as
    many pixels as in a pixel-filtered render (``mi.cornell_box()`` at 64 × 64: 20 pixel
    centres vs 23.6 pixels of area). A silhouette pixel is one whose neighbourhood holds pixels
    that see light and pixels that do not: 3 × 3 with a box filter; with another filter the
    neighbourhood reaches as far as the filter, and the sub-pixel rays importance-sample it
    (:func:`pixel_rays`), so that these pixels hold the film's filtered emission — the pipeline
    filters the rest of the image, not the emission (:mod:`photonmap.core.film_filter`)."""
    w, h = (int(c) for c in sensor.film().crop_size())
    emits = (dr.max(emission) > 0).numpy().reshape(h, w)
    if not emits.any():
        return emission
    rfilter = sensor.film().rfilter()
    box = rfilter.is_box_filter()
    m = 1 if box else int(rfilter.border_size()) + 1
    pad = np.pad(emits, m, mode="edge")
    edge = np.zeros_like(emits)
    for dy in range(2 * m + 1):
        for dx in range(2 * m + 1):
            edge |= pad[dy : dy + h, dx : dx + w] != emits
    index = np.flatnonzero(edge)
    k = EMISSION_SAMPLES if box else 2 * EMISSION_SAMPLES  # a filter reaches beyond the pixel
    sub = np.arange(k * k)
    # the strata's centres; a filter's tails lie beyond the outer strata's centres, so its
    # samples are jittered in their strata (a fixed hash: the same image every time)
    within = np.full((2, len(index) * k * k), 0.5)
    if not box:
        within = np.random.default_rng(0x5EED).random(within.shape)
    jitter = mi.Point2f(
        (np.tile(sub % k, len(index)) + within[0]) / k,
        (np.tile(sub // k, len(index)) + within[1]) / k,
    )
    ray, weight = pixel_rays(sensor, to_jit(mi.UInt32, np.repeat(index, k * k)), jitter)
    si = intersect_visible(scene, ray)
    seen = dr.select(si.is_valid(), si.emitter(scene).eval(si), 0.0)
    Le = pixel_means(seen if box else seen * weight, k * k)
    out = mi.Color3f(emission)
    dr.scatter(out, Le, mi.UInt32(index))
    return out
