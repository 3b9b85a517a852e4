"""The scene file's own rendering settings: the path-length limits of its ``<integrator>``.

A Mitsuba file says how long its light paths may be, and Mitsuba's image of the file depends on
it: ``max_depth`` is the longest path in segments (1: only emitters seen directly; 2: direct
light; -1: unbounded, ended by Russian roulette), ``rr_depth`` the depth from which Russian
roulette ends paths, ``hide_emitters`` hides the emitters (and the environment) seen directly.
Every method takes these as its defaults, so that the same file gives the same image
(``--set`` overrides them). Wrappers that hold another integrator (``aov``, ``moment``) pass on
the settings of the integrator they hold; Mitsuba's ``direct`` integrator is ``max_depth`` 2.
Without an ``<integrator>`` Mitsuba's own defaults hold: -1, 5, False.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi

from .errors import ParameterError
from .params import check_choice, check_range

UNBOUNDED = -1
MITSUBA_RR_DEPTH = 5  # Mitsuba's default rr_depth
RR_MAX = 0.95  # Mitsuba's cap on Russian roulette's survival probability


@dataclass(frozen=True)
class PathSettings:
    """Path-length settings with Mitsuba's meaning (module docstring)."""

    max_depth: int = UNBOUNDED
    rr_depth: int = MITSUBA_RR_DEPTH
    hide_emitters: bool = False

    def __post_init__(self):
        if self.max_depth != UNBOUNDED and not self.max_depth >= 1:
            raise ParameterError(
                f"max_depth must be -1 (unbounded) or >= 1 path segments, got {self.max_depth}"
            )
        if not self.rr_depth >= 1:
            raise ParameterError(f"rr_depth must be >= 1, got {self.rr_depth}")

    @classmethod
    def of(cls, scene: mi.Scene, source=None) -> PathSettings:
        """The settings of ``scene``'s ``<integrator>`` (Mitsuba's defaults without one);
        ``source``: the XML file it was loaded from, if any, where a wrapper's inner
        ``hide_emitters`` is read (a wrapper object does not show it)."""
        settings = integrator_settings(scene.integrator())
        if source is not None and is_wrapper(scene.integrator()) and not settings.hide_emitters:
            settings = replace(settings, hide_emitters=_inner_hide_emitters(source))
        return settings

    def allows(self, segments) -> bool:
        """Whether a path of ``segments`` segments is within ``max_depth`` (Python ints or Dr.Jit
        arrays)."""
        if self.max_depth == UNBOUNDED:
            return True if isinstance(segments, int) else segments >= 0
        return segments <= self.max_depth


def survival(beta, beta0=1.0, eta=1.0) -> mi.Float:
    """Russian roulette's survival probability from ``rr_depth`` on, the one rule of every light
    and eye path here (Mitsuba's ``path``, ``volpath`` and ``ptracer``):
    ``q = min(max_c (β_c / β₀,c) · η², 0.95)``, ``β`` the path's throughput (a colour per lane),
    ``β₀`` its start (1 for eye paths) and ``η`` the product of the relative indices it crossed
    (radiance through a dielectric scales by ``1/η²``: η² undoes it; 1 for photons, whose
    importance transport conserves power). Survivors divide their throughput by ``q``."""
    return dr.minimum(dr.max(beta / dr.maximum(beta0, 1e-30)) * dr.square(eta), RR_MAX)


_DEPTH = re.compile(r"\bmax_depth\s*=\s*(-?\d+)")
_RR = re.compile(r"\brr_depth\s*=\s*(-?\d+)")
_HIDE = re.compile(r"\bhide_emitters\s*=\s*(\w+)")


def integrator_settings(integrator) -> PathSettings:
    """:class:`PathSettings` of a Mitsuba integrator object (None: Mitsuba's defaults).

    Mitsuba's C++ integrators expose ``max_depth`` and ``rr_depth`` only in their description
    (``PathIntegrator[max_depth = 8, rr_depth = 5]``), which also lists the integrators a wrapper
    holds; Python integrators (``prb``, ...) have them as attributes."""
    if integrator is None:
        return PathSettings()
    text = str(integrator)
    hide = getattr(integrator, "hide_emitters", None)  # adjoint integrators (ptracer) have none
    if hide is None:
        found = _HIDE.search(text)
        hide = bool(found) and found.group(1).lower() in ("true", "1")
    hide = bool(hide() if callable(hide) else hide)
    depth = getattr(integrator, "max_depth", None)
    rr = getattr(integrator, "rr_depth", None)
    if depth is None:
        found = _DEPTH.search(text)
        if found:
            depth = int(found.group(1))
        elif integrator.class_name() == "DirectIntegrator" or text.startswith("DirectIntegrator"):
            depth = 2
    if rr is None:
        found = _RR.search(text)
        rr = int(found.group(1)) if found else MITSUBA_RR_DEPTH
    depth = UNBOUNDED if depth is None or not 0 < int(depth) < 2**31 else int(depth)
    return PathSettings(depth, max(int(rr), 1), hide)


WRAPPERS = ("AOVIntegrator", "MomentIntegrator")


def is_wrapper(integrator) -> bool:
    """Whether ``integrator`` holds another integrator whose image it passes on."""
    return integrator is not None and integrator.class_name() in WRAPPERS


_COMMENT = re.compile(r"<!--.*?-->", re.S)
_DECLARATION = re.compile(r"^\s*<\?xml[^>]*\?>")


def _inner_hide_emitters(source) -> bool:
    """``hide_emitters`` of the innermost ``<integrator>`` of the XML file ``source`` (a literal
    ``true``; False when unreadable). Comments are dropped before parsing: Mitsuba's parser reads
    a comment holding ``--`` (a command line, say), which strict XML forbids."""
    try:
        path = os.fspath(source)
        if not isinstance(path, str) or not os.path.isfile(path):
            return False
        with open(path, encoding="utf-8", errors="replace") as f:
            text = _COMMENT.sub("", f.read())
        node = ET.fromstring(_DECLARATION.sub("", text, count=1)).find("integrator")
    except (OSError, TypeError, ValueError, ET.ParseError):
        return False
    while node is not None and node.find("integrator") is not None:
        node = node.find("integrator")
    if node is None:
        return False
    for flag in node.findall("boolean"):
        if flag.get("name") == "hide_emitters":
            return flag.get("value", "").strip().lower() == "true"
    return False


HIDE_CHOICES = ("scene", "true", "false")


def overridden(
    settings: PathSettings, max_depth: int = 0, rr_depth: int = 0, hide_emitters: str = "scene"
) -> PathSettings:
    """``settings`` with a method's parameters applied: ``max_depth`` 0 keeps the file's (−1:
    unbounded), ``rr_depth`` 0 keeps the file's, ``hide_emitters`` ``"scene"`` keeps the
    file's."""
    return PathSettings(
        settings.max_depth if max_depth == 0 else (UNBOUNDED if max_depth < 0 else max_depth),
        settings.rr_depth if rr_depth == 0 else rr_depth,
        settings.hide_emitters if hide_emitters == "scene" else hide_emitters == "true",
    )


def check_path_params(params) -> None:
    """The ranges of a ``*Params``'s ``max_depth``, ``rr_depth`` and ``hide_emitters``."""
    check_range("max_depth", params.max_depth, -1, None,
                "path segments at most as Mitsuba counts them; 0 = the scene's, -1 = unbounded")
    check_range("rr_depth", params.rr_depth, 0, None,
                "depth where Russian roulette starts; 0 = the scene's")
    check_choice("hide_emitters", params.hide_emitters, HIDE_CHOICES,
                 "hide emitters seen directly: the scene's setting, or true/false")
