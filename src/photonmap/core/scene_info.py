"""What a Mitsuba scene holds, as far as choosing and checking a method goes: its participating
media (the fog) and the shapes that bound them.

The CLI picks the method from this (fog → ``volume``, else ``surface``), the volume method refuses
a scene without fog, and the screen method, which does not model media, warns once that it
renders without them (issue 10: never a silently wrong image). The surface method renders media
with a volume photon map (:mod:`photonmap.core.media`).
"""

from __future__ import annotations

import warnings

import mitsuba as mi

from .errors import PhotonmapWarning


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


def pick_method(scene: mi.Scene) -> str:
    """The method a scene is rendered with when the user names none: ``volume`` for a scene
    with fog (a participating medium), else ``surface``."""
    return "volume" if has_media(scene) else "surface"


def warn_unmodelled_media(scene: mi.Scene, method: str) -> list[str]:
    """Warn once (a :class:`PhotonmapWarning`) that ``method`` renders ``scene`` without its
    media, naming each; returns the lines warned about."""
    found = media(scene)
    if found:
        warnings.warn(
            f"the {method} method does not model participating media and renders this scene "
            f"as if in vacuum, ignoring: {'; '.join(found)}. Use --method volume for fog.",
            PhotonmapWarning,
            stacklevel=3,
        )
    return found


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
