"""Photon tracing from the light G-buffer (Yao 2011 §3.1–3.2, Ch. 4; spec seed-004 §2.2, §2.4,
A1–A9).

Every light G-buffer texel (i, j) starts one path at its first hit x₁ with the incident power
Φ_ij. The path scatters B times; scattering event k draws its random numbers from the **fixed
random map** (PRM, §2.4, A4): one 32-bit seed per texel made once from ``seed``, hashed with
(k, m) by TEA, u = hash(seed_ij, k, m) ∈ [0, 1), so bounces are uncorrelated and frames are
temporally stable. Hit k + 1 (k = 1 … B) goes to the fixed slot ``(k − 1)·W_L·H_L + texel`` (A1:
the map holds W_L·H_L·B records); hit 1 is never stored, direct light covers it (A2).

Scattering rules (§2.4 table), through Mitsuba's BSDFs in importance mode:

| surface | direction | power | path density h |
|---|---|---|---|
| diffuse | cosine-weighted hemisphere (A5) | Φ·ρ_d | 1 |
| mirror | ω_i − 2(ω_i·n)n | Φ·ρ_s | 4 |
| glossy | ``"yao_average"``: normalize(ω_d + ω_r) (A6); ``"bsdf"``: Mitsuba's lobe sample | Φ·ρ_g | 2 |
| glass | reflect with probability F, else refract; TIR reflects (A7) | Φ | 4 |

Glass uses the exact unpolarized dielectric Fresnel F with η from the BSDF (1.5 in the built-in
scenes).

Mitsuba's ``diffuse``, ``conductor`` and ``dielectric`` samplers are exactly these rules (the
dielectric chooses reflection iff u < F). No Russian roulette (A8). Photons are stored only on
surfaces with a diffuse or glossy lobe; a mirror or glass hit uses up its bounce and leaves its slot
invalid (A3). ρ_path = Π h_k scales the splat radius (A9). Photons pass through ``null``-BSDF
shapes (fog boxes): crossing one is no bounce.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.bsdf import has_null_shapes, intersect_visible, is_specular
from ..core.errors import ParameterError, SceneError
from .light_gbuffer import LightGBuffer

GLOSSY_MODES = ("yao_average", "bsdf")


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


def random_map(width: int, height: int, seed: int = 0) -> mi.UInt32:
    """The precomputed random map (PRM, §2.4): one 32-bit seed per light G-buffer texel."""
    i = dr.arange(mi.UInt32, width * height)
    s0, _ = mi.sample_tea_32(i, dr.opaque(mi.UInt32, int(np.uint32(seed & 0xFFFFFFFF))), 4)
    dr.eval(s0)
    return s0


def prm_float(prm: mi.UInt32, bounce: int, dim: int) -> mi.Float:
    """u = hash(seed_ij, k, m) ∈ [0, 1) — the PRM number of bounce ``k``, dimension ``m``."""
    key = dr.opaque(mi.UInt32, (bounce * 16 + dim) & 0xFFFFFFFF)
    return mi.sample_tea_float32(prm, key + dr.zeros(mi.UInt32, dr.width(prm)), 4)


def trace_photons(
    scene: mi.Scene,
    lgb: LightGBuffer,
    prm: mi.UInt32,
    bounces: int,
    glossy: str = "yao_average",
) -> ScreenPhotons:
    """The photon map of ``bounces`` recorded bounces per light G-buffer texel (spec §2.4)."""
    if not isinstance(bounces, int) or bounces < 1:
        raise ParameterError(f"bounces must be an integer >= 1, got {bounces!r}")
    if glossy not in GLOSSY_MODES:
        raise ParameterError(f"glossy must be one of {', '.join(GLOSSY_MODES)}, got {glossy!r}")
    n = lgb.width * lgb.height
    if dr.width(prm) != n:
        raise ParameterError(f"the random map has {dr.width(prm)} seeds for {n} texels")
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    si, active = lgb.si, mi.Bool(lgb.valid)
    power = mi.Color3f(lgb.flux)
    density = dr.ones(mi.Float, n)
    null_shapes = has_null_shapes(scene)
    parts = []
    for k in range(1, bounces + 1):  # B ≤ a few: one kernel per bounce, fixed slots
        bsdf = si.bsdf()
        u1, u2, u3 = (prm_float(prm, k, m) for m in range(3))
        bs, weight = bsdf.sample(ctx, si, u1, mi.Point2f(u2, u3), active)
        wo = bs.wo
        lobe = bs.sampled_type
        is_glossy = mi.has_flag(lobe, mi.BSDFFlags.Glossy)
        if glossy == "yao_average":  # normalize(ω_d + ω_r), ω_d cosine-distributed (A6)
            w_d = mi.warp.square_to_cosine_hemisphere(
                mi.Point2f(prm_float(prm, k, 3), prm_float(prm, k, 4))
            )
            w_d = dr.mulsign(w_d, mi.Frame3f.cos_theta(si.wi))
            w_r = mi.reflect(si.wi)
            wo = dr.select(is_glossy, dr.normalize(w_d + w_r), wo)
        h = dr.select(mi.has_flag(lobe, mi.BSDFFlags.Delta), 4.0, dr.select(is_glossy, 2.0, 1.0))
        power = power * mi.Color3f(weight)
        density = density * h
        active &= (dr.max(power) > 0) & (bs.pdf > 0)
        ray = si.spawn_ray(si.to_world(wo))
        si = intersect_visible(scene, ray, active, null_shapes)  # through null-BSDF shapes
        active &= si.is_valid()
        store = active & ~is_specular(si.bsdf(), active)  # A3
        n_s = mi.Normal3f(si.sh_frame.n)
        nrm = dr.select(dr.dot(n_s, ray.d) > 0, -n_s, n_s)
        part = ScreenPhotons(
            dr.select(store, si.p, 0.0),
            dr.select(store, nrm, 0.0),
            dr.select(store, power, 0.0),
            dr.select(store, density, 0.0),
            store,
        )
        dr.eval(part.pos, part.nrm, part.power, part.density, part.valid, si, active, power)
        parts.append(part)
    photons = _concat(parts)
    _check_power(photons)
    return photons


def _concat(parts: list[ScreenPhotons]) -> ScreenPhotons:
    """The bounce slots one after the other (slot = (k − 1)·W_L·H_L + texel)."""

    def cat(name):
        values = [getattr(p, name) for p in parts]
        if len(values) == 1:
            return values[0]
        if dr.size_v(values[0]) == 3:
            return type(values[0])(*(dr.concat([v[c] for v in values]) for c in range(3)))
        return dr.concat(values)

    photons = ScreenPhotons(*(cat(f.name) for f in dataclasses.fields(ScreenPhotons)))
    dr.eval(photons.pos, photons.nrm, photons.power, photons.density, photons.valid)
    return photons


def _check_power(photons: ScreenPhotons) -> None:
    if not dr.all(dr.isfinite(dr.sum(photons.power, axis=None))):
        raise SceneError(
            "photon tracing produced NaN or infinite power; a BSDF or texture of the scene "
            "evaluates to NaN or infinity"
        )
