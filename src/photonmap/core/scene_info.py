"""What a Mitsuba scene holds, as far as choosing and checking a method goes: its participating
media (the fog) and the shapes that bound them.

The volume method refuses a scene without fog, and a method that does not model part of a scene
says so (never a silently wrong image). :class:`SceneTraits` tells the transport loops what a
scene needs.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from .bsdf import has_null_lobes, has_null_shapes, has_rough_glass, surface_shapes
from .errors import PhotonmapWarning, SceneError


def _name(obj) -> str:
    ident = obj.id() if hasattr(obj, "id") else ""
    return f"'{ident}'" if ident else obj.class_name()


def shape_name(shape: mi.Shape) -> str:
    """``shape 'id'``; a shape without one (Mitsuba's merged meshes, a shape the file names
    not) by its kind."""
    return f"shape '{shape.id()}'" if shape.id().strip(" +") else f"a {shape.class_name()} shape"


def check_gathered_bsdfs(scene: mi.Scene, method: str) -> None:
    """Raise a :class:`SceneError` naming the shapes whose BSDF ``method``'s photon gather
    (SPPM's gather, VCM's merges) cannot weigh:
    the gather divides Mitsuba's ``eval`` by the cosine to the surface normal, which is right
    where ``eval`` carries that cosine; the ``hair`` BSDF's carries the cosine to the fibre
    instead, and on a hair-shaded sphere the photons' estimate came out 36–41 % too bright
    against ``path`` (64 and 256 iterations)."""
    hair = [
        shape_name(shape) for shape in surface_shapes(scene)
        if shape.bsdf() is not None and "Hair[" in str(shape.bsdf())  # nested too
    ]  # fmt: skip
    if hair:
        raise SceneError(
            f"the {method} method cannot gather photons on the hair BSDF of {', '.join(hair)}; "
            "render this scene with --method surface"
        )


def check_bsdfs_evaluate(scene: mi.Scene) -> None:
    """Raise a :class:`SceneError` naming the first shape whose BSDF Mitsuba cannot sample or
    evaluate — a part it leaves unimplemented, such as a ``bumpmap`` over a texture without
    derivatives (``checkerboard``: ``Texture::eval_1_grad(): not implemented``), which Mitsuba's
    own integrators refuse as well. Each distinct BSDF is traced once on one lane (no kernel
    runs): the error comes here, in one line, rather than from inside a method's loop."""
    seen = set()
    for shape in surface_shapes(scene):
        bsdf = shape.bsdf()
        if bsdf is None or bsdf.ptr in seen:
            continue
        seen.add(bsdf.ptr)
        si = dr.zeros(mi.SurfaceInteraction3f, 1)
        si.n = mi.Normal3f(0, 0, 1)
        si.sh_frame = mi.Frame3f(si.n)
        si.wi = mi.Vector3f(0, 0, 1)
        try:
            bsdf.sample(mi.BSDFContext(), si, 0.5, mi.Point2f(0.5))
            bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(0, 0, 1))
        except RuntimeError as exc:
            hint = (
                "; a bumpmap needs a texture Mitsuba can differentiate, such as a bitmap"
                if "eval_1_grad" in str(exc) else ""
            )  # fmt: skip
            raise SceneError(
                f"Mitsuba cannot evaluate the {bsdf.class_name()} BSDF of {shape_name(shape)} "
                f"({str(exc).strip()}){hint}"
            ) from None


def media(scene: mi.Scene) -> list[str]:
    """One line per participating medium of ``scene``: the medium and where it sits (a shape's
    interior or exterior, the sensor), e.g. ``"HomogeneousMedium 'fog' inside shape 'box'"``."""
    found = []
    for shape in scene.shapes():
        for where, medium in (
            ("inside", shape.interior_medium()),
            ("outside", shape.exterior_medium()),
        ):
            if medium is not None:
                found.append(f"{medium.class_name()} {_name(medium)} {where} shape {_name(shape)}")
    for sensor in scene.sensors():
        if sensor.get_medium() is not None:
            found.append(f"{sensor.get_medium().class_name()} {_name(sensor.get_medium())} "
                         "around the sensor")
    return found


def has_media(scene: mi.Scene) -> bool:
    """Whether ``scene`` holds any participating medium (fog)."""
    return bool(media(scene))



def parameter_values(obj) -> list[tuple[str, object]]:
    """The ``(key, value)`` pairs of ``mi.traverse(obj)`` that hold a value: a parameter left
    unset (the ``hair`` BSDF's ``sigma_a`` when it is coloured by pigments) has none, and
    Mitsuba raises a ``TypeError`` when it is read."""
    params = mi.traverse(obj)
    out = []
    for key in sorted(params.keys()):
        try:
            out.append((key, params[key]))
        except TypeError:
            continue
    return out

@dataclass
class SceneTraits:
    """What the transport loops need to know about a scene once, to leave out the work it does
    not need (the same code path either way): ``media`` — it holds participating media;
    ``null_shapes`` — shapes with a ``null`` BSDF that rays cross unchanged; ``null_lobes`` —
    BSDFs that let shadow rays through in part (``null``, ``mask``, ``thindielectric``);
    ``rough_glass`` — rough glass, which eye paths of the surface method follow (not a
    frozen dataclass: Dr.Jit's symbolic loops write back every object they are passed)."""

    media: bool
    null_shapes: bool
    null_lobes: bool
    rough_glass: bool

    @classmethod
    def of(cls, scene: mi.Scene) -> SceneTraits:
        return cls(
            has_media(scene), has_null_shapes(scene), has_null_lobes(scene),
            has_rough_glass(scene),
        )  # fmt: skip


def pick_method(scene: mi.Scene) -> str:
    """The method a scene file is rendered with when the user names none: ``sppm``, the method
    that renders everything a Mitsuba file may hold — any BSDF, glass, caustics, media, lights
    inside reflectors — as Mitsuba's ``path``/``volpath`` does, and converges to it. The other
    methods are faster where their assumptions hold (``surface``: final gathers of diffuse
    interreflection; ``volume``: fog and refractive media as voxel grids; ``screen``: interactive
    image-space photons) and are chosen with ``--method``."""
    return "sppm"


def refuse_media(scene: mi.Scene, method: str) -> None:
    """Raise a :class:`SceneError` naming each medium of ``scene`` when ``method`` cannot render
    participating media (rendering the scene as if in vacuum would be a silently wrong image)."""
    found = media(scene)
    if found:
        raise SceneError(
            f"the {method} method renders surfaces in vacuum and cannot render participating "
            f"media ({'; '.join(found)}); render this scene with --method sppm (or surface)"
        )


CHECK_POINTS = 256  # points per medium-bearing shape that check its media (warn_disagreeing_media)
DISAGREE = 0.25  # the share of a shape's points in another medium that is warned about (a shape
# that merely touches another, a light on a floor, puts a few of its points outside)


def warn_disagreeing_media(scene: mi.Scene, method: str) -> list[str]:
    """Warn (a :class:`PhotonmapWarning`) about each shape whose declared interior or exterior
    medium is not the medium found on that side of it: from :data:`CHECK_POINTS` points on it, a
    ray leaves on that side, and the first medium transition it meets tells the medium there
    (``si.target_medium(−d)``; vacuum where it meets none). Mitsuba's ``volpath`` follows the
    declared media for light that leaves such a surface and the enclosing shapes' for light that
    arrives; photon methods, whose light travels the other way, cannot follow both, so their
    image differs from ``volpath``'s near it. Returns the lines warned about."""
    import drjit as dr

    from .media import first_transition_medium
    from .sampling import rng

    lines = []
    for shape in scene.shapes():
        for side, declared in ((-1.0, shape.interior_medium()), (1.0, shape.exterior_medium())):
            if declared is None:
                continue
            gen = rng(CHECK_POINTS, 0x6D656469, int(side > 0))
            ps = shape.sample_position(0.0, mi.Point2f(gen.next_float32(), gen.next_float32()))
            d = mi.warp.square_to_cosine_hemisphere(
                mi.Point2f(gen.next_float32(), gen.next_float32())
            )
            d = mi.Frame3f(ps.n * side).to_world(d)
            zero = dr.zeros(mi.Float, CHECK_POINTS)
            ray = mi.Interaction3f(zero, zero, dr.zeros(mi.Color0f), ps.p, ps.n).spawn_ray(d)
            found, met = first_transition_medium(scene, ray)
            found = dr.select(met, found, mi.MediumPtr(None))
            wrong = float(dr.mean(mi.Float(found != mi.MediumPtr(declared)), axis=None)[0])
            if wrong > DISAGREE:
                where = "interior" if side < 0 else "exterior"
                lines.append(
                    f"shape {_name(shape)} names {_name(declared)} its {where} medium, but on "
                    f"{wrong:.0%} of it the shapes around say otherwise"
                )
    if lines:
        warnings.warn(
            f"{'; '.join(lines)}. Mitsuba's volpath then puts the medium in the path of light "
            f"that leaves the shape but not of light that arrives, which the {method} method, "
            "whose photons travel the other way, cannot follow: expect its image to differ from "
            "volpath's near the shape. Make the shape lie inside its medium (e.g. cut a floor at "
            "its fog box) or leave that medium out.",
            PhotonmapWarning,
            stacklevel=3,
        )
    return lines


def warn_unmodelled(method: str, parts: list[str], instead: str) -> list[str]:
    """Warn once (a :class:`PhotonmapWarning`) that ``method`` does not render ``parts`` of the
    scene (one line each, naming the shapes or settings), and what renders them: ``instead``."""
    if parts:
        warnings.warn(
            f"the {method} method does not render: {'; '.join(parts)}. {instead}.",
            PhotonmapWarning,
            stacklevel=3,
        )
    return parts
