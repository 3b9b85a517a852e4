"""What the transport core's eye-path loop (:mod:`~photonmap.core.eye_trace`) does along a path
and what it returns: :class:`EyeRules` (the path settings, how media and smooth surfaces are
treated), a method's per-vertex hook (:class:`EyeVertexRule`), the photon estimates read along
the paths (:class:`Caustics`), and the vertices where the paths ended (:class:`EyeVertices`).
The modes are explained in :mod:`~photonmap.core.eye_trace`'s docstring."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mitsuba as mi

from .media import Segments
from .scene_info import SceneTraits
from .settings import PathSettings

MEDIA_MODES = ("transmit", "march", "end", "continue")
SURFACE_MODES = ("stop", "continue")


@dataclass
class Caustics:
    """The light eye paths cannot find by themselves — light that reached a medium or a surface
    through mirrors and glass only — as photon estimates read along the paths: ``medium(mei,
    depth_left, active)`` the in-scattered radiance per unit length at a medium collision,
    ``surface(si, depth_left, active)`` the radiance a smooth surface vertex reflects towards
    the path (``surfaces="continue"``); photons of depth at most ``depth_left``. Either may be
    None."""

    medium: Callable | None = None
    surface: Callable | None = None


@dataclass
class EyeVertices:
    """Where each eye path ended (one lane a path)."""

    si: mi.SurfaceInteraction3f  # the smooth surface vertex, where ``found``
    mei: mi.MediumInteraction3f  # the medium vertex, where ``in_medium`` ("end" mode)
    beta: mi.Spectrum  # throughput from the start to the vertex
    radiance: mi.Spectrum  # light collected on the way (emission met, media in "continue")
    found: mi.Bool  # ended on a smooth surface
    in_medium: mi.Bool  # ended at a medium collision ("end" mode)
    depth: mi.UInt32  # segments from the camera to the vertex
    medium: mi.MediumPtr  # the medium the path arrived in
    bounces: mi.UInt32  # followed (delta) bounces on the way
    rays: mi.UInt32  # rays the path cast: one per segment, one per shadow ray
    segments: Segments | None = None  # the pieces in media ("march" mode)

    @property
    def bsdf(self) -> mi.BSDFPtr:
        return self.si.bsdf()


@dataclass(frozen=True)
class EyeRules:
    """What :func:`~photonmap.core.eye_trace.trace_eye_paths` does along every path (its module
    docstring): the path
    ``settings`` and the scene's ``traits``; ``emission``: add the emitters met; ``media_mode``
    (:data:`MEDIA_MODES`) and ``surfaces`` (:data:`SURFACE_MODES`); ``rough_glass``: follow
    rough glass (``surfaces="stop"``); ``segments``: pieces recorded per path in ``"march"``
    mode; ``vertex``: a method's :class:`EyeVertexRule` (module docstring; refused with media)."""

    settings: PathSettings
    traits: SceneTraits
    emission: bool = True
    media_mode: str = "continue"
    surfaces: str = "stop"
    rough_glass: bool = False
    segments: int = 4
    vertex: EyeVertexRule | None = None

    def __post_init__(self):
        if self.media_mode not in MEDIA_MODES:
            raise ValueError(f"media_mode must be one of {MEDIA_MODES}, got {self.media_mode!r}")
        if self.surfaces not in SURFACE_MODES:
            raise ValueError(f"surfaces must be one of {SURFACE_MODES}, got {self.surfaces!r}")
        if self.vertex is not None and self.traits.media:
            raise ValueError(f"{type(self.vertex).__name__} handles surface vertices only; the "
                             "scene has participating media")  # fmt: skip


class EyeVertexRule:
    """What a method does at the surface vertices of the core's eye paths (the per-vertex hook;
    its module docstring): its per-path state (:meth:`extra`, carried in ``walk.extra``), and the
    steps the loop calls at a surface — on arrival, the emission met (:meth:`arrive`, which adds
    it to ``walk.radiance``), at a smooth vertex within ``max_depth`` the radiance of the
    method's techniques (:meth:`at_vertex`), and after the BSDF sample the lanes that go on
    (:meth:`bounced`, which updates the state there)."""

    def extra(self):
        return None

    def arrive(self, walk, si, arrived, hit) -> None:
        raise NotImplementedError

    def at_vertex(self, walk, si, bsdf, gen, arrived, here) -> mi.Spectrum:
        raise NotImplementedError

    def bounced(self, walk, si, bsdf, sample, go_on) -> mi.Bool:
        raise NotImplementedError
