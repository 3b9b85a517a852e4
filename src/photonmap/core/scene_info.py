"""What a Mitsuba scene holds, as far as choosing and checking a method goes: its participating
media (the fog) and the shapes that bound them.

The volume method refuses a scene without fog, and a method that does not model part of a scene
says so (never a silently wrong image). :class:`SceneTraits` tells the transport loops what a
scene needs.
"""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi

from .bsdf import has_null_lobes, has_null_shapes
from .errors import SceneError


def _name(obj) -> str:
    ident = obj.id() if hasattr(obj, "id") else ""
    return f"'{ident}'" if ident else obj.class_name()


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


@dataclass(frozen=True)
class SceneTraits:
    """What the transport loops need to know about a scene once, to leave out the work it does
    not need (the same code path either way): ``media`` — it holds participating media;
    ``null_shapes`` — shapes with a ``null`` BSDF that rays cross unchanged; ``null_lobes`` —
    BSDFs that let shadow rays through in part (``null``, ``mask``, ``thindielectric``)."""

    media: bool
    null_shapes: bool
    null_lobes: bool

    @classmethod
    def of(cls, scene: mi.Scene) -> SceneTraits:
        return cls(has_media(scene), has_null_shapes(scene), has_null_lobes(scene))


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
