"""The viewer's state document and the checks of an update against it.

The state is plain JSON: what ``GET /api/state`` returns and what ``POST /api/update`` takes, an
update carrying only what changes::

    {"camera": {"origin": [x, y, z], "target": [x, y, z], "fov": 40, "width": 640, "height": 480},
     "lights": [{"kind": "point", "position": [x, y, z], "color": [r, g, b], "intensity": s}],
     "materials": {"glass": {"ior": 1.5, "sigma_s": [r, g, b], "sigma_a": [r, g, b]}},
     "params": {"photons": 262144, "emission": "uniform"},
     "volume": {"frame": 0}}

Lights are addressed by their index: ``"lights"`` in an update is a list (``null`` or ``{}``
leaves a light as it is) or an object ``{"1": {...}}``. A light's RGB power is ``color ×
intensity``. Keys shown read-only (``scene``, ``method``, a light's ``kind``) may be sent back
unchanged. The ``check_*`` functions here (and :meth:`.adapters.Adapter.check`, which adds each
method's own checks) raise a :class:`~photonmap.core.errors.ParameterError` naming the first bad
value; nothing is applied then. Coalescing has two halves: each checked update
yields the next target state (the newest value of each key wins;
:meth:`.adapters.Adapter.check`), and the render thread applies only the difference from what
the pipeline holds (:func:`changes`).
"""

from __future__ import annotations

import math

import numpy as np

from ..core.errors import ParameterError
from ..core.params import check_vector3

SECTIONS = ("camera", "lights", "materials", "params", "volume")
READ_ONLY = ("scene", "method", "methods", "stages", "frames", "brush_fields")
MAX_SIDE = 4096  # the viewer's largest image side (the CLI's check_side allows 16384)
SHOWN = 60  # characters of a refused value quoted in an error (never the whole request)


def shown(value) -> str:
    """``repr(value)``, cut to :data:`SHOWN` characters."""
    text = repr(value) if not isinstance(value, list | dict) or len(value) <= 16 else (
        f"<{type(value).__name__} of {len(value)}>"
    )
    return text if len(text) <= SHOWN else text[: SHOWN - 1] + "…"


def vector(name: str, value, nonnegative: bool = False) -> list[float]:
    """Three finite numbers (``nonnegative``: each >= 0) as a list of floats."""
    a = check_vector3(name, value, shown)
    if nonnegative and np.any(a < 0):
        raise ParameterError(f"{name} must be >= 0 in every channel, got {shown(value)}")
    return a.tolist()


def rgb(name: str, value) -> list[float]:
    """A colour or coefficient: one number (grey) or three, each finite and >= 0."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        value = [value] * 3
    return vector(name, value, nonnegative=True)


def number(name: str, value, lo=None, hi=None, lo_open=False, integer=False) -> float | int:
    """A finite number (``integer``: an integer) within [lo, hi] (``lo_open``: lo excluded)."""
    kinds = int if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds):
        raise ParameterError(f"{name} must be {'an integer' if integer else 'a number'}, got "
                             f"{shown(value)}")
    if not math.isfinite(value):
        raise ParameterError(f"{name} must be finite, got {shown(value)}")
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise ParameterError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {shown(value)}")
    if hi is not None and value > hi:
        raise ParameterError(f"{name} must be <= {hi}, got {shown(value)}")
    return value if integer else float(value)


def as_object(name: str, value) -> dict:
    """``value``, which must be a JSON object."""
    if not isinstance(value, dict):
        raise ParameterError(f"{name} must be an object, got {shown(value)}")
    return value


def check_keys(name: str, given: dict, allowed) -> None:
    """No keys in ``given`` but ``allowed`` (the message lists them)."""
    unknown = sorted(set(given) - set(allowed))
    if unknown:
        raise ParameterError(
            f"unknown key(s) {', '.join(unknown)} in {name}; valid: {', '.join(sorted(allowed))}"
        )


def light_changes(update, count: int) -> dict[int, dict]:
    """``update["lights"]`` as {index: changes}: a list by position (``null``/``{}`` skip) or an
    object whose keys are indices."""
    if isinstance(update, list):
        if len(update) > count:
            raise ParameterError(f"lights: {len(update)} given, the scene has {count}")
        items = {i: v for i, v in enumerate(update) if v}
    elif isinstance(update, dict):
        items = {}
        for key, v in update.items():
            try:
                index = int(key)
            except ValueError:
                index = -1
            if not 0 <= index < count:
                raise ParameterError(
                    f"no light {shown(key)}; the scene has {count} (indices 0..{count - 1})"
                )
            items[index] = v
    else:
        raise ParameterError(f"lights must be a list or an object of indices, got {shown(update)}")
    return {i: as_object(f"lights[{i}]", v) for i, v in items.items()}


def check_camera(camera: dict, update: dict) -> dict:
    """The camera after ``update``: origin and target finite and apart, fov in (0, 180)
    degrees, width and height integers in 1…:data:`MAX_SIDE`."""
    check_keys("camera", as_object("camera", update), camera)
    new = dict(camera)
    for key, value in update.items():
        if key in ("origin", "target"):
            new[key] = vector(f"camera.{key}", value)
        elif key == "fov":
            new[key] = number("camera.fov", value, 0, 180, lo_open=True)
            if new[key] >= 180:
                raise ParameterError(f"camera.fov must be < 180 degrees, got {shown(value)}")
        else:
            new[key] = number(f"camera.{key}", value, 1, MAX_SIDE, integer=True)
    if np.allclose(new["origin"], new["target"]):
        raise ParameterError("camera.origin and camera.target must differ")
    return new


def check_light(index: int, light: dict, update: dict) -> dict:
    """Light ``index`` after ``update``: a position (if the light has one) finite, colour and
    intensity >= 0; its kind cannot change."""
    check_keys(f"lights[{index}]", update, light)
    new = dict(light)
    for key, value in update.items():
        where = f"lights[{index}].{key}"
        if key == "kind":
            if value != light["kind"]:
                raise ParameterError(f"{where} is read-only ({light['kind']!r})")
        elif key == "position":
            new[key] = vector(where, value)
        elif key == "color":
            new[key] = rgb(where, value)
        elif key == "intensity":
            new[key] = number(where, value, 0)
    return new


def check_material(name: str, material: dict, update: dict) -> dict:
    """Material ``name`` after ``update``: n finite and > 0, σ_s and σ_a >= 0 (a number or
    RGB)."""
    check_keys(f"materials.{name}", as_object(f"materials.{name}", update), material)
    new = dict(material)
    for key, value in update.items():
        where = f"materials.{name}.{key}"
        new[key] = number(where, value, 0, lo_open=True) if key == "ior" else rgb(where, value)
    return new


def changes(old: dict, new: dict) -> dict:
    """The update that turns ``old`` into ``new`` (only the keys whose values differ)."""
    out: dict = {}
    for section in SECTIONS:
        if section not in new:
            continue
        if section == "lights":
            diff = {
                i: {k: v for k, v in b.items() if a.get(k) != v}
                for i, (a, b) in enumerate(zip(old["lights"], new["lights"], strict=True))
            }
            diff = {i: d for i, d in diff.items() if d}
        elif section == "materials":
            diff = {
                name: {k: v for k, v in b.items() if old["materials"][name].get(k) != v}
                for name, b in new["materials"].items()
            }
            diff = {name: d for name, d in diff.items() if d}
        else:
            diff = {k: v for k, v in new[section].items() if old[section].get(k) != v}
        if diff:
            out[section] = diff
    return out
