"""Errors raised by photonmap.

Every error a user can cause is a :class:`PhotonmapError` whose message says what was wrong and
how to fix it. Subclasses let callers tell the kinds apart.
"""


class PhotonmapError(Exception):
    """Base class of every error photonmap raises on purpose."""


class SceneError(PhotonmapError):
    """The scene cannot be rendered by the chosen pipeline (missing light, open mesh, ...)."""


class ParameterError(PhotonmapError, ValueError):
    """A parameter is out of range, of the wrong type, or unknown."""


class BackendError(PhotonmapError):
    """The Dr.Jit / Mitsuba backend cannot run here (no suitable libLLVM, no CUDA, ...)."""


class PhotonmapWarning(UserWarning):
    """Something in the scene that the chosen method does not model (a medium in the surface or
    screen method, ...): the image is rendered without it, and this says so."""
