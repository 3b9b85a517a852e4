"""Photon tracing from the light G-buffer (Yao 2011 §3.1–3.2, Ch. 4; spec seed-004 §2.2, §2.4)."""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi


@dataclass
class ScreenPhotons:
    """The photon map of spec §2.4: ``W_L·H_L·B`` fixed slots (texel, bounce), flat arrays.

    ``pos``: hit point; ``nrm``: unit surface normal oriented toward the side the photon arrived
    from; ``power``: RGB power incident at the record point (watts); ``density``: the path density
    ρ_path = Π h_k (1 for diffuse-only paths; scales the splat radius r_p = clamp(r/√ρ_path, r/8,
    r)); ``valid``: the slot holds a photon (invalid slots have zero power).
    """

    pos: mi.Point3f
    nrm: mi.Normal3f
    power: mi.Color3f
    density: mi.Float
    valid: mi.Bool
