"""G-buffers of the ``screen`` pipeline (Yao 2011 §3.1, Fig 3.1; spec seed-004 §2.1).

A :class:`GBuffer` holds one sample per pixel as flat Dr.Jit arrays in row-major order (pixel
``(x, y)`` at index ``y·width + x``, y = 0 the top row). Every image-space stage (splatting, soft
shadows, upsampling) reads it; the eye G-buffer is cast with Mitsuba rays.
"""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi


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
