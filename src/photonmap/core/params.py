"""Pipeline parameter dataclasses: validated updates, and reading them from Mitsuba integrator
properties."""

from __future__ import annotations

import dataclasses

import mitsuba as mi

from .errors import ParameterError

# properties every Mitsuba integrator may receive; the pipelines ignore them
MITSUBA_BASE = {"samples_per_pass", "hide_emitters", "timeout", "max_depth", "rr_depth"}


def updated(params, changes: dict, what: str):
    """``params`` (a dataclass with ``validate()``) with ``changes`` applied and validated;
    unknown names raise a :class:`ParameterError` listing the valid ones."""
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
    defaults = params_type()
    fields = {f.name: type(getattr(defaults, f.name)) for f in dataclasses.fields(params_type)}
    fields.update(extra or {})
    names = set(props.keys())
    unknown = sorted(names - set(fields) - set(ignore))
    if unknown:
        raise ParameterError(
            f"{plugin}: unknown parameter(s) {', '.join(unknown)}; valid: "
            f"{', '.join(sorted(fields))}"
        )
    return {name: _convert(props[name], kind) for name, kind in fields.items() if name in names}
