"""What the screen method accepts of a Mitsuba scene, and the scene's scale (Yao 2011 §3).

The method shades a surface by its diffuse reflectance and ray-traces mirrors and glass
(:func:`check_shading`), needs finite indices of refraction (:func:`check_dielectrics`), and
measures lengths against the diagonal of what it sees (:func:`visible_diagonal`).
"""

from __future__ import annotations

import warnings

import mitsuba as mi
import numpy as np

from ..core.bsdf import MIRROR_OR_REFRACTION, is_null, shape_box, surface_shapes
from ..core.errors import PhotonmapWarning, SceneError
from ..core.scene_info import shape_name, warn_unmodelled


def visible_diagonal(scene: mi.Scene) -> float:
    """The bounding-box diagonal of the shapes the method sees, the scale of the automatic
    ``radius`` and the unit of ``light_size`` (module docstring): ``null``-BSDF shapes (a fog box
    around the scene) do not count, so that they change nothing in the image."""
    boxes = [shape_box(s) for s in scene.shapes() if not _null(s)]
    if not boxes:
        return 0.0
    lo = np.min([np.array(b.min, dtype=np.float64).ravel() for b in boxes], axis=0)
    hi = np.max([np.array(b.max, dtype=np.float64).ravel() for b in boxes], axis=0)
    return float(np.linalg.norm(hi - lo))


def _null(shape: mi.Shape) -> bool:
    bsdf = shape.bsdf()
    return bsdf is not None and not shape.is_emitter() and bool(is_null(bsdf, True)[0])


def check_shading(scene: mi.Scene) -> None:
    """The screen method shades a surface by its diffuse reflectance (Yao's G-buffer holds the
    albedo ρ, Eq 1) with its geometric shading normal, and ray-traces mirrors and glass. Raise a
    :class:`SceneError` naming the shapes it would render wrong: BSDFs with smooth lobes but no
    diffuse one (``roughconductor``, ``roughdielectric``: black) and partly transparent ones
    (``mask``: opaque); warn about the parts it leaves out (the glossy or specular lobes of a
    BSDF that also has a diffuse one, ``bumpmap`` and ``normalmap``)."""
    refused, left_out = [], []
    for number, shape in enumerate(surface_shapes(scene)):
        bsdf = shape.bsdf()
        if bsdf is None or shape.is_emitter() or bool(is_null(bsdf, True)[0]):
            continue
        flags = int(bsdf.flags())
        name = f"shape '{shape.id()}'" if shape.id() else f"shape number {number}"
        what = f"{name} ({bsdf.class_name()})"
        smooth, diffuse = flags & int(mi.BSDFFlags.Smooth), flags & int(mi.BSDFFlags.Diffuse)
        if flags & int(mi.BSDFFlags.Null) and smooth:
            refused.append(f"{what} is partly transparent")
        elif smooth and not diffuse:
            refused.append(f"{what} has no diffuse lobe")
        elif diffuse and flags & int(mi.BSDFFlags.Glossy | mi.BSDFFlags.Delta):
            left_out.append(f"the glossy or specular lobes of {what}")
        text = str(bsdf)
        for kind in ("BumpMap", "NormalMap"):
            if kind in text:
                left_out.append(f"the {kind.lower()} of {name} (shaded with its own normal)")
    if refused:
        raise SceneError(
            "the screen method shades surfaces by their diffuse reflectance and ray-traces "
            f"mirrors and glass; it would render wrong: {'; '.join(refused)}; render this scene "
            "with --method sppm (or surface)"
        )
    warn_unmodelled("screen", left_out, "--method sppm renders them")


def warn_sharp_caustics(scene: mi.Scene, light_radius: float, splat_radius: float) -> None:
    """Warn that the mirrors and glass (BSDFs with delta lobes and no diffuse one) of a scene lit
    by a light smaller than the splat radius ``r`` (a spot or point light, or an area light of
    virtual radius below ``r``) are rendered approximately: their caustics are splats of radius
    r/8 (Yao 2011 §3.4), and a mirror or glass pixel traces one ray through its centre (§3.5), so
    the light's small images in them come and go with the pixel grid: a gold ball under a small
    sphere light came out 8 % dark, and right under a light larger than the splat radius.
    ``--method sppm`` renders them converged."""
    if light_radius >= splat_radius:
        return
    names = [
        f"{shape_name(shape)} ({shape.bsdf().class_name()})"
        for shape in surface_shapes(scene)
        if shape.bsdf() is not None and not shape.is_emitter()
        and int(shape.bsdf().flags()) & MIRROR_OR_REFRACTION
        and not int(shape.bsdf().flags()) & int(mi.BSDFFlags.Diffuse)
    ]  # fmt: skip
    if names:
        warnings.warn(
            f"the screen method renders the caustics of {', '.join(names[:4])}"
            f"{' and others' * (len(names) > 4)} and the light's images in them only "
            f"approximately: the light (radius {light_radius:.3g}) is smaller than the splat "
            f"radius {splat_radius:.3g}; --method sppm renders them converged",
            PhotonmapWarning,
            stacklevel=3,
        )


def check_dielectrics(scene: mi.Scene) -> None:
    """Raise a :class:`SceneError` naming the shape if a BSDF's relative index of refraction
    ``eta`` (a dielectric's ``int_ior / ext_ior``, nested BSDFs included) is not a finite positive
    number: Snell's law and Fresnel would turn the glass pixels and caustic photons into NaN."""
    for number, shape in enumerate(surface_shapes(scene)):
        bsdf = shape.bsdf()
        if bsdf is None:
            continue
        params = mi.traverse(bsdf)
        for key in params.keys():
            if key.split(".")[-1] != "eta":
                continue
            eta = np.array(params[key], dtype=np.float64).ravel()
            if not (np.all(np.isfinite(eta)) and np.all(eta > 0)):
                name = f"'{shape.id()}'" if shape.id() else f"number {number}"
                raise SceneError(
                    f"shape {name} ({shape.class_name()}) has a {bsdf.class_name()} whose index "
                    f"of refraction eta = {eta.tolist()} is not a finite positive number; set "
                    "int_ior and ext_ior to finite values (e.g. 1.5 and 1.0 for glass in air)"
                )
