"""Photon tracing from the light G-buffer (Yao 2011 §3.1–3.2, Ch. 4). Where the thesis leaves a rule
open, the choice made is said below.

Every light G-buffer texel (i, j) starts one path at its first hit x₁ with the incident power Φ_ij.
The path scatters B times — the first time at x₁ here, then in the transport core's photon loop
(:func:`photonmap.core.photon_trace.trace_light_paths`, without Russian roulette) — and draws its
random numbers from the **fixed random map** (Yao's PRM): one 32-bit seed per texel made once from
``seed``, the path's n-th number u = hash(seed_ij, n) ∈ [0, 1) by TEA (:class:`FixedRandom`), so
bounces are uncorrelated and frames are temporally stable. Hit k + 1 (k = 1 … B) goes to the fixed
slot ``(k − 1)·W_L·H_L + texel`` (the map holds W_L·H_L·B records, the product that gives Tables
1–2's 10k per bounce); hit 1 is never stored, direct light covers it (the thesis's "more than twice"
read as "from the second hit on").

Scattering rules (Yao §3.1–3.2; cosine-weighted diffuse bounces and the exact Fresnel term where the
thesis gives neither), through Mitsuba's BSDFs in importance mode:

| surface | direction | power | path density h |
|---|---|---|---|
| diffuse | cosine-weighted hemisphere | Φ·ρ_d | 1 |
| mirror | ω_i − 2(ω_i·n)n | Φ·ρ_s | 4 |
| glossy | ``"yao_average"``: normalize(ω_d + ω_r) (Yao's); ``"bsdf"``: Mitsuba's lobe sample | Φ·ρ_g | 2 |
| glass | reflect with probability F, else refract; TIR reflects | Φ | 4 |

Glass uses the exact unpolarized dielectric Fresnel F with η from the BSDF (1.5 in the built-in
scenes).

Mitsuba's ``diffuse``, ``conductor`` and ``dielectric`` samplers are exactly these rules (the
dielectric chooses reflection iff u < F). No Russian roulette (none in the thesis). Photons are
stored only on surfaces with a diffuse or glossy lobe; a mirror or glass hit uses up its bounce and
leaves its slot invalid (a Lambertian splat would light glass). ρ_path = Π h_k scales the splat
radius (Yao stores a path density without defining it; h after ISPM's a-priori density, McGuire &
Luebke 2009). Photons pass through ``null``-BSDF shapes: crossing one is no bounce.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.emission import LightPaths
from ..core.errors import ParameterError, SceneError
from ..core.photon_trace import PhotonRules, trace_light_paths
from ..core.scene_info import SceneTraits
from ..core.settings import PathSettings
from .light_gbuffer import LightGBuffer

GLOSSY_MODES = ("yao_average", "bsdf")


@dataclass
class ScreenPhotons:
    """The photon map (module docstring): ``W_L·H_L·B`` fixed slots (texel, bounce), flat arrays.

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


class FixedRandom:
    """The fixed random map as a per-path generator: the ``n``-th number a path draws is
    u = hash(seed_ij, n) ∈ [0, 1) — the same every frame (a Dr.Jit struct, so it can be loop
    state and be compacted with its path)."""

    DRJIT_STRUCT = {"seed": mi.UInt32, "counter": mi.UInt32}

    def __init__(self, seed: mi.UInt32 | None = None, counter: mi.UInt32 | None = None):
        self.seed = mi.UInt32(seed) if seed is not None else mi.UInt32()
        self.counter = counter if counter is not None else dr.zeros(mi.UInt32, dr.width(self.seed))

    def next_float32(self) -> mi.Float:
        u = mi.sample_tea_float32(self.seed, self.counter, 4)
        self.counter += 1
        return u


def trace_photons(
    scene: mi.Scene,
    lgb: LightGBuffer,
    prm: mi.UInt32,
    bounces: int,
    glossy: str = "yao_average",
) -> ScreenPhotons:
    """The photon map of ``bounces`` recorded bounces per light G-buffer texel (module
    docstring)."""
    if not isinstance(bounces, int) or bounces < 1:
        raise ParameterError(f"bounces must be an integer >= 1, got {bounces!r}")
    if glossy not in GLOSSY_MODES:
        raise ParameterError(f"glossy must be one of {', '.join(GLOSSY_MODES)}, got {glossy!r}")
    n = lgb.width * lgb.height
    if dr.width(prm) != n:
        raise ParameterError(f"the random map has {dr.width(prm)} seeds for {n} texels")
    gen = FixedRandom(prm)
    # the first bounce, at x₁
    si, active = lgb.si, mi.Bool(lgb.valid)
    bs, weight = si.bsdf().sample(
        mi.BSDFContext(mi.TransportMode.Importance), si, gen.next_float32(),
        mi.Point2f(gen.next_float32(), gen.next_float32()), active,
    )  # fmt: skip
    wo = _redirect(si, bs, gen) if glossy == "yao_average" else bs.wo
    power = dr.select(active & (bs.pdf > 0), mi.Color3f(lgb.flux) * mi.Color3f(weight), 0.0)
    first_density = _density(bs.sampled_type)
    light = LightPaths(
        si.spawn_ray(si.to_world(wo)), power, dr.zeros(mi.MediumPtr, n), dr.zeros(mi.Bool, n),
        dr.zeros(mi.Bool, n), np.zeros(3), 0,
    )  # fmt: skip
    redirect = _redirect if glossy == "yao_average" else None
    rules = PhotonRules(PathSettings(max_depth=bounces + 2), SceneTraits.of(scene),
                        roulette=False, redirect=redirect)  # fmt: skip
    records, _ = trace_light_paths(scene, light, gen, rules, first_depth=1)
    photons = _slots(records, n * bounces, n, first_density)
    _check_power(photons)
    return photons


def _density(lobe: mi.UInt32) -> mi.Float:
    """h of a bounce (§2.4 table): 4 for a delta lobe, 2 for a glossy one, 1 for a diffuse one."""
    is_glossy = mi.has_flag(lobe, mi.BSDFFlags.Glossy)
    return dr.select(mi.has_flag(lobe, mi.BSDFFlags.Delta), 4.0, dr.select(is_glossy, 2.0, 1.0))


def _redirect(si: mi.SurfaceInteraction3f, bs: mi.BSDFSample3f, gen) -> mi.Vector3f:
    """Yao's glossy direction (not a BSDF sample): normalize(ω_d + ω_r), ω_d cosine-distributed, ω_r
    the mirror direction, where a glossy lobe was sampled (two more numbers from ``gen``)."""
    w_d = mi.warp.square_to_cosine_hemisphere(mi.Point2f(gen.next_float32(), gen.next_float32()))
    w_d = dr.mulsign(w_d, mi.Frame3f.cos_theta(si.wi))
    is_glossy = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Glossy)
    return dr.select(is_glossy, dr.normalize(w_d + mi.reflect(si.wi)), bs.wo)


def _slots(records, slots: int, n: int, first_density: mi.Float) -> ScreenPhotons:
    """The records in their fixed slots ``(k − 1)·n + texel`` (hit k + 1 has depth k + 1), with the
    path density ρ_path = h₁ · 4^(delta bounces) · 2^(glossy bounces) and the normal turned
    towards the side the photon arrived from."""
    photons = ScreenPhotons(
        dr.zeros(mi.Point3f, slots), dr.zeros(mi.Normal3f, slots), dr.zeros(mi.Color3f, slots),
        dr.zeros(mi.Float, slots), dr.zeros(mi.Bool, slots),
    )  # fmt: skip
    if records.count:  # (Dr.Jit refuses arithmetic between an empty array and a literal)
        slot = (records.depth - 2) * n + records.path
        density = dr.gather(mi.Float, first_density, records.path)
        density *= dr.power(4.0, mi.Float(records.delta)) * dr.power(2.0, mi.Float(records.glossy))
        n_s = mi.Normal3f(records.normal)
        nrm = dr.select(dr.dot(n_s, records.direction) > 0, -n_s, n_s)
        dr.scatter(photons.pos, records.position, slot)
        dr.scatter(photons.nrm, nrm, slot)
        dr.scatter(photons.power, records.power, slot)
        dr.scatter(photons.density, density, slot)
        dr.scatter(photons.valid, True, slot)
    dr.eval(photons.pos, photons.nrm, photons.power, photons.density, photons.valid)
    return photons


def _check_power(photons: ScreenPhotons) -> None:
    if not dr.all(dr.isfinite(dr.sum(photons.power, axis=None))):
        raise SceneError(
            "photon tracing produced NaN or infinite power; a BSDF or texture of the scene "
            "evaluates to NaN or infinity"
        )
