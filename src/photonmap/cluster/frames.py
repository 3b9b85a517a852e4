"""Frame specs of ``photonmap render-sequence``: a camera path, a light path or a list of
parameter sets, read from a JSON file and expanded to one complete state per frame.

Two forms, both JSON objects::

    {"frames": 24,                                   # a path: this many frames, and
     "camera": [{"origin": [0, 1, 4], "target": [0, 0.5, 0]},
                {"origin": [3, 1, 3], "target": [0, 0.5, 0]}],   # keyframes spread evenly
     "light":  {"position": [0.3, 0.9, 0.4]},        # one object: the same in every frame
     "set":    {"photons": 65536},                   # method or scene parameters
     "method": "volume", "width": 160, "height": 120}   # optional

    {"frames": [{"set": {"photons": 1000}},           # a list: one entry per frame
                {"set": {"photons": 10000}},
                {"set": {"photons": 100000}}],
     "set": {"seed": 7}}                              # optional: under every frame's own

A path interpolates its keyframes linearly (numbers and lists of numbers; integers are rounded;
text and true/false keep the earlier keyframe's value). Each frame is rendered on whichever worker
is free, so every frame must state the same keys as every other (its state is then complete and
independent of what that worker rendered before): a key present in one frame and missing in
another is refused. ``camera`` takes the keys of ``set_camera`` (origin, target, up, fov);
``light`` those of the method's ``set_light`` (volume: index, position, direction, intensity, ...;
screen: position, target, intensity, cutoff, index); ``set`` the keys of ``--set``.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field

from ..core.errors import ParameterError

PARTS = ("camera", "light", "set")
CAMERA_KEYS = ("origin", "target", "up", "fov")
TOP_KEYS = ("frames", "method", "width", "height", *PARTS)
MAX_FRAMES = 100_000


class FrameSpecError(ParameterError):
    """A frame spec (``--frames spec.json``) that cannot be read or is inconsistent."""


@dataclass(frozen=True)
class Frame:
    """One frame's complete state: its index in the sequence and the camera, light and parameter
    settings applied before it renders (empty: the scene's own)."""

    index: int
    camera: dict = field(default_factory=dict)
    light: dict = field(default_factory=dict)
    set: dict = field(default_factory=dict)


@dataclass(frozen=True)
class FrameSpec:
    """A parsed frame spec: the frames and the optional method and image size."""

    frames: tuple[Frame, ...]
    method: str | None = None
    width: int | None = None
    height: int | None = None


def load_frames(path: str) -> FrameSpec:
    """Read and check the JSON frame spec at ``path`` (module docstring)."""
    if not os.path.isfile(path):
        raise FrameSpecError(f"frame spec {path!r} does not exist (give a JSON file)")
    try:
        with open(path) as f:
            data = json.load(f)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FrameSpecError(f"frame spec {path!r} is not valid JSON: {exc}") from None
    return parse_frames(data, path)


def parse_frames(data, where: str = "frame spec") -> FrameSpec:
    """Expand a frame spec (the decoded JSON) to one :class:`Frame` per frame."""
    if not isinstance(data, dict):
        raise FrameSpecError(f"{where}: expected a JSON object with a 'frames' key")
    unknown = sorted(set(data) - set(TOP_KEYS))
    if unknown:
        raise FrameSpecError(f"{where}: unknown key(s) {unknown}; valid: {', '.join(TOP_KEYS)}")
    if "frames" not in data:
        raise FrameSpecError(f"{where}: no 'frames' (a frame count with keyframe paths, or a list)")
    method = data.get("method")
    if method is not None and not isinstance(method, str):
        raise FrameSpecError(f"{where}: 'method' must be a name, got {method!r}")
    size = {}
    for key in ("width", "height"):
        value = data.get(key)
        if value is not None and (not _is_int(value) or not 1 <= value <= 16384):
            raise FrameSpecError(f"{where}: {key!r} must be an integer in 1…16384, got {value!r}")
        size[key] = value
    frames = data["frames"]
    if _is_int(frames):
        states = _path(data, frames, where)
    elif isinstance(frames, list):
        states = _listed(data, frames, where)
    else:
        raise FrameSpecError(
            f"{where}: 'frames' must be a frame count (with keyframe paths) or a list of frames, "
            f"got {frames!r}"
        )
    _check_same_keys(states, where)
    out = tuple(Frame(i, **state) for i, state in enumerate(states))
    return FrameSpec(out, method, **size)


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _part(value, part: str, where: str) -> dict:
    if not isinstance(value, dict):
        raise FrameSpecError(f"{where}: {part!r} must be an object of key: value, got {value!r}")
    if part == "camera":
        unknown = sorted(set(value) - set(CAMERA_KEYS))
        if unknown:
            raise FrameSpecError(
                f"{where}: unknown camera key(s) {unknown}; valid: {', '.join(CAMERA_KEYS)}"
            )
    for key, v in value.items():
        _check_value(v, f"{where}: {part}.{key}")
    if part == "camera":
        _check_camera(value, where)
    return dict(value)


def _check_camera(camera: dict, where: str) -> None:
    """``origin``, ``target``, ``up``: 3 numbers each; ``fov``: degrees in (0, 180)."""
    for key in ("origin", "target", "up"):
        v = camera.get(key)
        if v is not None and not (isinstance(v, list) and len(v) == 3):
            raise FrameSpecError(f"{where}: camera.{key} must be 3 numbers [x, y, z], got {v!r}")
    fov = camera.get("fov")
    if fov is not None and (
        isinstance(fov, bool) or not isinstance(fov, int | float) or not 0 < fov < 180
    ):
        raise FrameSpecError(f"{where}: camera.fov must be degrees in (0, 180), got {fov!r}")


def _check_value(value, what: str) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise FrameSpecError(f"{what} must be finite, got {value}")
    if isinstance(value, list):
        for v in value:
            if not isinstance(v, int | float) or isinstance(v, bool):
                raise FrameSpecError(f"{what}: a list must hold numbers, got {value!r}")
            _check_value(v, what)
    elif value is not None and not isinstance(value, int | float | str | bool):
        raise FrameSpecError(f"{what}: expected a number, text, true/false or a list of numbers")


def _path(data: dict, count: int, where: str) -> list[dict]:
    if not 1 <= count <= MAX_FRAMES:
        raise FrameSpecError(f"{where}: 'frames' must lie in 1…{MAX_FRAMES}, got {count}")
    keyframes = {}
    for part in PARTS:
        value = data.get(part, {})
        keys = value if isinstance(value, list) else [value]
        if not keys:
            raise FrameSpecError(f"{where}: {part!r} is an empty list of keyframes")
        keys = [_part(k, part, f"{where}: {part} keyframe {i}") for i, k in enumerate(keys)]
        _check_same_keys([{part: k} for k in keys], f"{where}: {part} keyframes")
        keyframes[part] = keys
    return [
        {part: _interpolate(keys, i / max(count - 1, 1)) for part, keys in keyframes.items()}
        for i in range(count)
    ]


def _interpolate(keys: list[dict], t: float) -> dict:
    """The state at ``t`` ∈ [0, 1] of keyframes spread evenly over [0, 1]."""
    x = t * (len(keys) - 1)
    i = min(int(x), len(keys) - 2) if len(keys) > 1 else 0
    a, b = keys[i], keys[min(i + 1, len(keys) - 1)]
    w = x - i
    return {k: _mix(a[k], b[k], w, k) for k in a}


def _mix(a, b, w: float, key: str):
    if isinstance(a, bool) or isinstance(a, str) or a is None:
        return a if w < 1 else b
    if isinstance(a, list):
        if not isinstance(b, list) or len(a) != len(b):
            raise FrameSpecError(f"keyframes of {key!r} must be lists of one length: {a} vs {b}")
        return [_mix(x, y, w, key) for x, y in zip(a, b, strict=True)]
    if not isinstance(b, int | float) or isinstance(b, bool):
        raise FrameSpecError(f"keyframes of {key!r} mix a number and {b!r}")
    value = a + (b - a) * w
    return round(value) if _is_int(a) and _is_int(b) else float(value)


def _listed(data: dict, frames: list, where: str) -> list[dict]:
    if not 1 <= len(frames) <= MAX_FRAMES:
        raise FrameSpecError(f"{where}: 'frames' must list 1…{MAX_FRAMES} frames")
    base = {part: _part(data.get(part, {}), part, f"{where}: {part}") for part in PARTS}
    states = []
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise FrameSpecError(f"{where}: frame {i} must be an object, got {frame!r}")
        unknown = sorted(set(frame) - set(PARTS))
        if unknown:
            raise FrameSpecError(
                f"{where}: frame {i} has unknown key(s) {unknown}; valid: {', '.join(PARTS)}"
            )
        states.append(
            {p: {**base[p], **_part(frame.get(p, {}), p, f"{where}: frame {i}")} for p in PARTS}
        )
    return states


def _check_same_keys(states: list[dict], where: str) -> None:
    """Every frame states the same keys (module docstring: frames render on any worker)."""
    first = states[0]
    for i, state in enumerate(states[1:], 1):
        for part, value in state.items():
            if set(value) != set(first[part]):
                missing = sorted(set(first[part]) ^ set(value))
                raise FrameSpecError(
                    f"{where}: frame {i} and frame 0 differ in which {part} keys they give "
                    f"({', '.join(missing)}); give every frame the same keys, since frames "
                    "render on any worker in any order"
                )
    if "light" in first and "index" in first["light"]:
        indices = {s["light"]["index"] for s in states}
        if len(indices) > 1:
            raise FrameSpecError(f"{where}: light index changes between frames ({indices})")


def frame_path(pattern: str, index: int) -> str:
    """The output path of frame ``index`` for a printf pattern such as ``out/%04d.png``."""
    return pattern % index


def check_pattern(pattern: str) -> None:
    """An output pattern holds exactly one integer field (``%d``, ``%04d``) and no other ``%``
    (a literal one is written ``%%``)."""
    fields = re.findall(r"%(?:%|0?\d*d|.?)", pattern)
    if [f for f in fields if f != "%%" and not f.endswith("d")] or sum(
        f.endswith("d") for f in fields
    ) != 1:
        raise FrameSpecError(
            f"output {pattern!r} needs one frame-number field such as %04d (out/%04d.png)"
        )
