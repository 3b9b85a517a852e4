"""The ``diff_dielectric`` BSDF: Mitsuba's smooth ``dielectric`` with a differentiable index.

Mitsuba 3's ``dielectric`` keeps its relative index ``eta`` as a plain float (``mi.traverse``
shows it as non-differentiable), and ``roughdielectric`` samples its directions detached, so
neither gives the derivative of a caustic with respect to the index of refraction. This plugin is
the same smooth interface — Fresnel reflection and Snell refraction (Mitsuba's ``dielectric.cpp``;
pbrt-v4 §9.5), the lobe chosen with probability ``F`` — with ``eta = int_ior / ext_ior`` a
differentiable parameter: the refracted direction follows ``eta``, and the chosen lobe's weight is
``F / detach(F)`` (or ``(1 − F) / detach(1 − F)``), whose derivative is that of the choice's
probability. Radiance transport scales refraction by ``1/η²`` as Mitsuba does.

.. code-block:: xml

    <bsdf type="diff_dielectric">
        <float name="int_ior" value="1.5"/>
        <float name="ext_ior" value="1.0"/>
    </bsdf>

``params = mi.traverse(scene)`` then holds ``<shape>.bsdf.eta`` (a differentiable ``Float``).
Every method renders it as it renders ``dielectric``.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from .errors import ParameterError

BK7, AIR = 1.5046, 1.000277  # Mitsuba's default int_ior and ext_ior


class DiffDielectric(mi.BSDF):
    """A smooth dielectric interface with a differentiable relative index (module docstring)."""

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        values = {}
        for name, default in (("int_ior", BK7), ("ext_ior", AIR)):
            value = props.get(name, default)
            if not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
                raise ParameterError(
                    f"diff_dielectric: {name} must be a positive number, got {value!r} (named "
                    "materials are not supported; give the index as a float)"
                )
            values[name] = float(value)
        self.eta = mi.Float(values["int_ior"] / values["ext_ior"])
        reflection = mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        transmission = (
            mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            | mi.BSDFFlags.NonSymmetric
        )  # fmt: skip
        self.m_components = [reflection, transmission]
        self.m_flags = reflection | transmission

    def sample(self, ctx, si, sample1, sample2, active=True):
        cos_theta_i = mi.Frame3f.cos_theta(si.wi)
        r_i, cos_theta_t, eta_it, eta_ti = mi.fresnel(cos_theta_i, self.eta)
        t_i = 1.0 - r_i
        has_r = ctx.is_enabled(mi.BSDFFlags.DeltaReflection, 0)
        has_t = ctx.is_enabled(mi.BSDFFlags.DeltaTransmission, 1)
        bs = dr.zeros(mi.BSDFSample3f, dr.width(cos_theta_i))
        if has_r and has_t:
            reflect = sample1 <= dr.detach(r_i)
            bs.pdf = dr.detach(dr.select(reflect, r_i, t_i))
            weight = dr.select(reflect, r_i, t_i) / dr.maximum(bs.pdf, 1e-30)
        elif has_r or has_t:
            reflect = dr.full(mi.Bool, has_r, dr.width(cos_theta_i))
            bs.pdf = mi.Float(1.0)
            weight = r_i if has_r else t_i
        else:
            return bs, dr.zeros(mi.Spectrum, dr.width(cos_theta_i))
        bs.wo = dr.select(
            reflect, mi.reflect(si.wi), mi.refract(si.wi, cos_theta_t, eta_ti)
        )
        bs.eta = dr.select(reflect, 1.0, eta_it)
        bs.sampled_component = dr.select(reflect, mi.UInt32(0), mi.UInt32(1))
        bs.sampled_type = dr.select(
            reflect, mi.UInt32(int(mi.BSDFFlags.DeltaReflection)),
            mi.UInt32(int(mi.BSDFFlags.DeltaTransmission)),
        )  # fmt: skip
        if ctx.mode == mi.TransportMode.Radiance:
            weight = weight * dr.select(reflect, 1.0, dr.square(eta_ti))
        ok = active & (bs.pdf > 0)
        return bs, dr.select(ok, mi.Spectrum(weight), 0.0)

    def eval(self, ctx, si, wo, active=True):
        return dr.zeros(mi.Spectrum, dr.width(wo))

    def pdf(self, ctx, si, wo, active=True):
        return dr.zeros(mi.Float, dr.width(wo))

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def traverse(self, callback):
        callback.put("eta", self.eta, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        if not dr.all(self.eta > 0, axis=None):
            raise ParameterError("diff_dielectric: eta must stay positive")

    def to_string(self):
        return f"DiffDielectric[eta = {self.eta}]"


def register() -> None:
    mi.register_bsdf("diff_dielectric", lambda props: DiffDielectric(props))
