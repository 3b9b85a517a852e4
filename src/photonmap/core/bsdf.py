"""BSDF and visibility helpers shared by the pipelines.

- :func:`is_specular` — a BSDF with only delta lobes (mirror, glass): eye and gather rays follow
  it, photon maps store nothing on it (Steinhurst 2007 §7.3.2); with
  ``rough_glass``, also a BSDF that transmits through glossy lobes and has no diffuse one
  (:func:`is_rough_glass`).
- :func:`diffuse_albedo` — the reflectance of a BSDF's diffuse lobes, for Lambertian lookups.
- :func:`is_null` — a ``null`` BSDF: an index-matched boundary (a fog box, a medium's container)
  that light crosses unchanged. Every method treats such a shape as invisible: photons, eye rays
  and shadow rays pass straight through it (the shape only bounds a medium).
- :func:`intersect_visible` and :func:`occluded` — closest hit and shadow test that skip ``null``
  surfaces (:func:`pass_through`, :func:`beyond`). They cost one extra ray per crossed null surface,
  and nothing when the scene has none (:func:`has_null_shapes`).
"""

from __future__ import annotations

import re

import drjit as dr
import mitsuba as mi
import numpy as np

# lobe bits of BSDFFlags (the side bits FrontSide/BackSide are not lobes)
_LOBES = int(mi.BSDFFlags.All)
MAX_NULL_CROSSINGS = 16  # iteration cap of the loops below (nested fog boxes: 2 per box)


def is_specular(bsdf: mi.BSDFPtr, active, rough_glass: bool = False) -> mi.Bool:
    """True where the BSDF has only delta (perfectly specular) lobes (``null`` included), and
    with ``rough_glass`` where it is rough glass (:func:`is_rough_glass`)."""
    specular = active & ~mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
    return specular | is_rough_glass(bsdf, active) if rough_glass else specular


def is_rough_glass(bsdf: mi.BSDFPtr, active) -> mi.Bool:
    """True where the BSDF transmits through glossy lobes and has no diffuse lobe
    (``roughdielectric``; a ``principled`` or a blend with a diffuse lobe is not). A method may
    follow such a surface as it follows glass — its BSDF sampled whatever lobe it picks, no
    visible point and no photon record on it — where a photon density estimate of a
    near-specular transmission lobe would blur what lies behind it (Jensen 2001 §9.2: glossy
    surfaces of low roughness are ray traced)."""
    flags = bsdf.flags()
    return (
        active
        & mi.has_flag(flags, mi.BSDFFlags.GlossyTransmission)
        & ~mi.has_flag(flags, mi.BSDFFlags.Diffuse)
    )


def is_null(bsdf: mi.BSDFPtr, active) -> mi.Bool:
    """True where the BSDF is Mitsuba's ``null`` BSDF (its only lobe is the Null lobe)."""
    lobes = mi.UInt32(bsdf.flags()) & _LOBES
    return active & (bsdf != None) & (lobes == int(mi.BSDFFlags.Null))  # noqa: E711


DIFFUSE = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.DiffuseReflection)


def diffuse_albedo(bsdf: mi.BSDFPtr, si: mi.SurfaceInteraction3f, active) -> mi.Spectrum:
    """The reflectance ρ of the BSDF's diffuse lobes as seen from ``si.wi``: ``π f_d(ω_i, n)``
    through Mitsuba's ``eval`` restricted to them — a ``mask``'s opacity, a ``blendbsdf``'s
    weight, a ``plastic``'s coating and a ``twosided`` back face included, glossy and delta lobes
    left out (``eval_diffuse_reflectance`` is not implemented by every BSDF: a mask's ignores
    its opacity, a blend's evaluates its glossy lobe)."""
    normal = mi.Vector3f(0.0, 0.0, dr.sign(mi.Frame3f.cos_theta(si.wi)))
    return dr.pi * bsdf.eval(DIFFUSE, si, normal, active)


_GROUP_NAME = re.compile(r'ShapeGroup\[\s*name = "([^"]*)"')


def instanced_shapes(scene: mi.Scene) -> list[tuple[mi.Shape, list[mi.Shape]]]:
    """``(instance, shapes)`` per ``instance`` of ``scene``: the shapes of its ``shapegroup``
    (placed in the group's space). Mitsuba lists an instance among ``scene.shapes()`` as one shape
    whose ``bsdf()`` is a default diffuse one; its group's shapes, with their own BSDFs, are
    reachable only through the scene's parameter tree (``mi.traverse``) — what a ray meets."""
    instances = [s for s in scene.shapes() if s.class_name() == "Instance"]
    if not instances:
        return []
    members: dict[str, list[mi.Shape]] = {}
    for node, (parent, _) in mi.traverse(scene).hierarchy.items():
        if isinstance(node, mi.Shape) and isinstance(parent, mi.Shape):
            members.setdefault(parent.id(), []).append(node)
    out = []
    for instance in instances:
        name = _GROUP_NAME.search(str(instance))
        out.append((instance, members.get(name.group(1), []) if name else []))
    return out


def surface_shapes(scene: mi.Scene) -> list[mi.Shape]:
    """Every shape a ray can meet: ``scene.shapes()`` with each instance replaced by the shapes
    of its group (:func:`instanced_shapes`) — the list to read BSDFs from."""
    groups = {instance.ptr: shapes for instance, shapes in instanced_shapes(scene)}
    return [t for s in scene.shapes() for t in groups.get(s.ptr, [s])]


def shape_box(shape: mi.Shape) -> mi.ScalarBoundingBox3f:
    """``shape.bbox()``, or, where that box is invalid (the mesh Mitsuba merges from shapes of
    equal BSDFs has none), the box of the mesh's vertices."""
    box = shape.bbox()
    if box.valid() or not shape.is_mesh() or not shape.vertex_count():
        return box
    points = np.array(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3)
    return mi.ScalarBoundingBox3f(points.min(axis=0), points.max(axis=0))


def has_null_shapes(scene: mi.Scene) -> bool:
    """Whether any shape of ``scene`` has a ``null`` BSDF and no emitter (an invisible boundary)."""
    return any(
        s.bsdf() is not None
        and s.bsdf().flags() & _LOBES == int(mi.BSDFFlags.Null)
        and not s.is_emitter()
        for s in surface_shapes(scene)
    )


def has_null_lobes(scene: mi.Scene) -> bool:
    """Whether any shape's BSDF lets light pass straight through in part or whole (a ``Null``
    lobe: ``null``, ``mask``, ``thindielectric``): shadow rays then need its
    ``eval_null_transmission`` (:func:`photonmap.core.media.transmittance`)."""
    return any(
        s.bsdf() is not None and s.bsdf().flags() & int(mi.BSDFFlags.Null)
        for s in surface_shapes(scene)
    )


MIRROR_OR_REFRACTION = int(mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.DeltaTransmission)


def has_delta_lobes(scene: mi.Scene) -> bool:
    """Whether any shape's BSDF has a delta lobe that turns light (mirror reflection or
    refraction; Mitsuba's ``Delta`` flag also holds ``Null``): caustics are possible."""
    return any(
        s.bsdf() is not None and s.bsdf().flags() & MIRROR_OR_REFRACTION
        for s in surface_shapes(scene)
    )


def has_glossy_shapes(scene: mi.Scene) -> bool:
    """Whether any shape of ``scene`` has a BSDF with a glossy lobe (rough conductors and
    dielectrics, plastics): radiance leaving such a surface depends on the direction."""
    return any(
        s.bsdf() is not None and s.bsdf().flags() & int(mi.BSDFFlags.Glossy)
        for s in surface_shapes(scene)
    )


def rough_glass_flags(flags: int) -> bool:
    """:func:`is_rough_glass` of one BSDF's flags (a Python int)."""
    return bool(flags & int(mi.BSDFFlags.GlossyTransmission)) and not flags & int(
        mi.BSDFFlags.Diffuse
    )


def has_rough_glass(scene: mi.Scene) -> bool:
    """Whether any shape of ``scene`` is rough glass (:func:`is_rough_glass`)."""
    return any(
        s.bsdf() is not None and rough_glass_flags(s.bsdf().flags())
        for s in surface_shapes(scene)
    )


def _crosses_null(scene: mi.Scene, null_shapes: bool | None) -> bool:
    """Whether rays may meet ``null`` surfaces: ``null_shapes``, or :func:`has_null_shapes`."""
    return has_null_shapes(scene) if null_shapes is None else null_shapes


def _passes(scene: mi.Scene, si: mi.SurfaceInteraction3f, ray: mi.Ray3f, active) -> mi.Bool:
    """Lanes whose hit is a ``null``-BSDF surface that emits nothing: the ray goes on."""
    hit = active & si.is_valid()
    return is_null(si.bsdf(ray), hit) & (si.emitter(scene) == None)  # noqa: E711


def intersect_visible(
    scene: mi.Scene, ray: mi.Ray3f, active=True, null_shapes: bool | None = None
) -> mi.SurfaceInteraction3f:
    """``scene.ray_intersect`` that passes through ``null``-BSDF surfaces: the first hit whose
    BSDF is not ``null`` (or that emits), or an invalid interaction. ``si.t`` is measured from
    ``ray.o``. ``null_shapes`` (default: :func:`has_null_shapes`) skips the loop when False."""
    active = mi.Bool(active)
    si = scene.ray_intersect(ray, active)
    if not _crosses_null(scene, null_shapes):
        return si
    return pass_through(
        scene, ray, si, active, lambda si, ray, going: _passes(scene, si, ray, going)
    )


def beyond(si: mi.SurfaceInteraction3f, ray: mi.Ray3f) -> mi.Ray3f:
    """The rest of ``ray`` after the surface ``si`` it passes straight through (a ``null``
    boundary): the same direction, the length left."""
    crossed = si.spawn_ray(ray.d)
    crossed.maxt = ray.maxt - si.t
    return crossed


@dr.syntax
def pass_through(scene, ray, si, active, passes, limit: int = MAX_NULL_CROSSINGS):
    """From ``si``, the hit of ``ray``: go on through every hit where ``passes(si, ray, active)``
    holds (at most ``limit`` of them) and return the first other one, or an invalid
    interaction; ``si.t`` is measured from ``ray.o``."""
    ray = mi.Ray3f(ray)
    travelled = dr.zeros(mi.Float, dr.width(si.t))
    going = passes(si, ray, active)
    crossings = dr.zeros(mi.UInt32, dr.width(si.t))
    while going & (crossings < limit):
        travelled = dr.select(going, travelled + si.t, travelled)
        ray = dr.select(going, beyond(si, ray), ray)
        si_next = scene.ray_intersect(ray, going)
        si = dr.select(going, si_next, si)
        going = passes(si, ray, going)
        crossings += 1
    si.t = dr.select(si.is_valid(), si.t + travelled, si.t)
    return si


def occluded(
    scene: mi.Scene, ray: mi.Ray3f, active=True, null_shapes: bool | None = None
) -> mi.Bool:
    """``scene.ray_test`` that ignores ``null``-BSDF surfaces: True where something that is not
    a ``null`` boundary lies on the ray within ``ray.maxt``. Rays that the any-hit test finds
    blocked are traced again through the null surfaces (:func:`intersect_visible`)."""
    active = mi.Bool(active)
    blocked = scene.ray_test(ray, active)
    if not _crosses_null(scene, null_shapes):
        return blocked
    si = intersect_visible(scene, ray, blocked, null_shapes=True)
    return blocked & si.is_valid()
