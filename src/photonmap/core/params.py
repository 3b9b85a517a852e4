"""The one validation path of pipeline parameters (CLI ``--set``, Python keywords, plugin
properties): every ``*Params`` dataclass's ``validate()`` starts with :func:`check_fields` (types,
seeds) and states its ranges with :func:`check_range` and :func:`check_choice`; :func:`updated`
applies and validates changes; :func:`read_properties` reads Mitsuba plugin properties;
:func:`parse_value` reads the CLI's ``KEY=VALUE`` strings as the field's type."""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable

import mitsuba as mi
import numpy as np

from .errors import DeprecatedParameter, ParameterError

# properties every Mitsuba integrator may receive; the pipelines ignore them
MITSUBA_BASE = {"samples_per_pass", "hide_emitters", "timeout", "max_depth", "rr_depth"}


@dataclasses.dataclass(frozen=True)
class Renamed:
    """An old parameter name that keeps working for one release (a ``*Params`` class lists them
    in its ``RENAMED`` dict, old name → :class:`Renamed`): ``kind`` is the old value's type,
    ``convert`` (if given) turns it into the value of the parameter ``new``."""

    new: str
    kind: type
    convert: Callable | None = None


def renamed(params_type) -> dict[str, Renamed]:
    """The old names ``params_type`` still accepts."""
    return getattr(params_type, "RENAMED", {})


def parameter_names(params_type) -> set[str]:
    """Every name ``params_type`` accepts: its fields and their old names."""
    return {f.name for f in dataclasses.fields(params_type)} | set(renamed(params_type))


def current_names(params_type, changes: dict, what: str) -> dict:
    """``changes`` with old names (:class:`Renamed`) replaced by the current ones and their
    values converted, each with a :class:`~.errors.DeprecatedParameter` warning."""
    old = renamed(params_type)
    out = {}
    for key, value in changes.items():
        if key not in old:
            out[key] = value
            continue
        r = old[key]
        if r.new in changes:
            raise ParameterError(
                f"{key} is the old name of {r.new}; give {r.new} only (got both)"
            )
        check_type(key, value, r.kind)
        warnings.warn(
            f"the {what} parameter {key!r} is now {r.new!r}; {key!r} will be removed in the next "
            "release",
            DeprecatedParameter,
            stacklevel=3,
        )
        out[r.new] = r.convert(value) if r.convert else value
    return out


def updated(params, changes: dict, what: str):
    """``params`` (a dataclass with ``validate()``) with ``changes`` applied and validated;
    old names are translated (:func:`current_names`); unknown names raise a
    :class:`ParameterError` listing the valid ones."""
    changes = current_names(type(params), changes, what)
    valid = {f.name for f in dataclasses.fields(params)}
    unknown = sorted(set(changes) - valid)
    if unknown:
        raise ParameterError(
            f"unknown {what} parameter(s) {', '.join(unknown)}; valid: {', '.join(sorted(valid))}"
        )
    new = dataclasses.replace(params, **changes)
    new.validate()
    return new


def _convert(value, kind: type):
    """A plugin property as the type of its parameter field."""
    if kind is float and isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if kind is int and isinstance(value, float) and value.is_integer():
        return int(value)
    if kind is bool and isinstance(value, str) and value.lower() in ("true", "false"):
        return value.lower() == "true"
    return value  # the dataclass's validate() names anything of the wrong type


def read_properties(
    props: mi.Properties, params_type, plugin: str, extra: dict | None = None, ignore=MITSUBA_BASE
) -> dict:
    """The properties that are fields of ``params_type`` (or of ``extra``: name → type), converted;
    unknown names raise a :class:`ParameterError` listing the valid ones."""
    old = {name: r.kind for name, r in renamed(params_type).items()}
    fields = {**field_types(params_type), **old, **(extra or {})}
    names = set(props.keys())
    unknown = sorted(names - set(fields) - set(ignore))
    if unknown:
        raise ParameterError(
            f"{plugin}: unknown parameter(s) {', '.join(unknown)}; valid: "
            f"{', '.join(sorted(fields))}"
        )
    return {name: _convert(props[name], kind) for name, kind in fields.items() if name in names}


TRUE, FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def check_type(name: str, value, kind: type) -> None:
    """``value`` must suit a field whose default has type ``kind`` (ints are accepted as floats;
    bools are never taken for numbers; floats must be finite)."""
    if kind is bool:
        ok = isinstance(value, bool | np.bool_)
    elif kind is int:
        ok = isinstance(value, int | np.integer) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
            value, bool
        )
        if ok and not math.isfinite(value):
            raise ParameterError(f"{name} must be a finite number, got {value!r}")
    else:
        ok = isinstance(value, kind)
    if not ok:
        article = (
            "an integer" if kind is int else f"a {'number' if kind is float else kind.__name__}"
        )
        raise ParameterError(f"{name} must be {article}, got {value!r} ({type(value).__name__})")


def field_types(params_type) -> dict[str, type]:
    """Each field's type: its default's, or ``metadata["type"]`` for a field whose default is
    None (None then means "from the scene")."""
    return {
        f.name: f.metadata.get("type", type(f.default)) for f in dataclasses.fields(params_type)
    }


def check_fields(params) -> None:
    """Every field of the dataclass ``params`` has its type (:func:`field_types`,
    :func:`check_type`; None where the default is None); a ``seed`` field is an integer in
    [0, 2³²)."""
    for f in dataclasses.fields(params):
        value = getattr(params, f.name)
        if value is None and f.default is None:
            continue
        check_type(f.name, value, f.metadata.get("type", type(f.default)))
    if hasattr(params, "seed"):
        check_range("seed", params.seed, 0, 2**32 - 1, "the seed of every random choice")


def check_range(name: str, value, lo=None, hi=None, hint: str = "", lo_open=False, hi_open=False):
    """``lo <= value <= hi`` (``<`` where open; None = unbounded), else a :class:`ParameterError`
    naming the range and what the parameter means (``hint``)."""
    low_ok = lo is None or (value > lo if lo_open else value >= lo)
    high_ok = hi is None or (value < hi if hi_open else value <= hi)
    if low_ok and high_ok and not (isinstance(value, float) and math.isnan(value)):
        return
    if lo is not None and hi is not None:
        bounds = f"lie in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"
    elif lo is not None:
        bounds = f"be {'>' if lo_open else '>='} {lo}"
    else:
        bounds = f"be {'<' if hi_open else '<='} {hi}"
    raise ParameterError(f"{name} must {bounds}, got {value!r}" + (f": {hint}" if hint else ""))


def check_choice(name: str, value, allowed, hint: str = "") -> None:
    """``value`` is one of ``allowed``, else a :class:`ParameterError` listing them."""
    if value not in allowed:
        raise ParameterError(
            f"{name} must be one of {', '.join(map(str, allowed))}, got {value!r}"
            + (f" ({hint})" if hint else "")
        )


def parse_value(key: str, text: str, kind: type):
    """A CLI ``KEY=VALUE`` string as ``kind`` (bool: 1/true/yes/on, 0/false/no/off; int: also
    ``1e6``; float: also ``nan`` and ``inf``, which validation then refuses)."""
    try:
        if kind is bool:
            word = text.strip().lower()
            if word not in TRUE + FALSE:
                raise ValueError
            return word in TRUE
        if kind is int:
            number = float(text) if "e" in text.lower() else int(text)
            if isinstance(number, float) and not number.is_integer():
                raise ValueError
            return int(number)
        if kind is float:
            return float(text)
        return kind(text)
    except ValueError:
        raise ParameterError(f"--set {key}: cannot read {text!r} as {kind.__name__}") from None


def parse_field(params_type, key: str, text: str):
    """A CLI ``KEY=VALUE`` string as field ``key`` of ``params_type`` (a dataclass): through the
    field's own ``metadata["parse"]`` where it has one (e.g. a bounding box), else as its type
    (:func:`parse_value`)."""
    if key in renamed(params_type):
        return parse_value(key, text, renamed(params_type)[key].kind)
    field = next(f for f in dataclasses.fields(params_type) if f.name == key)
    if "parse" in field.metadata:
        return field.metadata["parse"](text)
    return parse_value(key, text, field_types(params_type)[key])


def check_vector3(name: str, value, shown=repr) -> np.ndarray:
    """``value`` as three finite numbers (float64), else a :class:`ParameterError` naming
    ``name`` and showing the value through ``shown``."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (3,) or isinstance(value, str | dict):
        raise ParameterError(f"{name} must be 3 numbers [x, y, z], got {shown(value)}")
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be finite, got {shown(value)}")
    return a


def check_view(origin, target, up, fov=None) -> None:
    """A camera placement ``look_at(origin, target, up)`` with horizontal ``fov`` (degrees):
    origin, target and up 3 finite numbers each, origin apart from target, up not along the
    view direction, fov in (0, 180); else a :class:`ParameterError` (a degenerate placement would
    give a NaN transform and a black image)."""
    vectors = {}
    for name, value in (("origin", origin), ("target", target), ("up", up)):
        vectors[name] = check_vector3(f"camera {name}", value)
    forward = vectors["target"] - vectors["origin"]
    length = float(np.linalg.norm(forward))
    if not length > 1e-9 * max(1.0, float(np.abs(vectors["origin"]).max())):
        raise ParameterError(
            f"camera origin and target must differ (both {vectors['origin'].tolist()}): the "
            "camera needs a direction to look in"
        )
    up_length = float(np.linalg.norm(vectors["up"]))
    if not up_length > 0 or np.linalg.norm(np.cross(forward / length, vectors["up"] / up_length)) < 1e-6:
        raise ParameterError(
            f"camera up {vectors['up'].tolist()} must be non-zero and not along the view "
            "direction (target - origin)"
        )
    check_fov(fov)


def check_fov(fov) -> None:
    """A horizontal field of view in degrees, in (0, 180); None: unchanged."""
    if fov is not None:
        check_type("camera fov", fov, float)
        check_range("camera fov", fov, 0, 180, "horizontal, in degrees", lo_open=True, hi_open=True)
