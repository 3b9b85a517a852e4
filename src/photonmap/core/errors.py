"""Errors raised by photonmap.

Every error a user can cause is a :class:`PhotonmapError` whose message says what was wrong and
how to fix it. Subclasses let callers tell the kinds apart.
"""


class PhotonmapError(Exception):
    """Base class of every error photonmap raises on purpose. ``exit_code`` is the command's exit
    status for it: 2 for input the user can fix, 1 for a failure outside the input (I/O)."""

    exit_code = 2


class SceneError(PhotonmapError):
    """The scene cannot be rendered by the chosen pipeline (missing light, open mesh, ...)."""


class ParameterError(PhotonmapError, ValueError):
    """A parameter is out of range, of the wrong type, or unknown."""


class OutputError(ParameterError):
    """An output path that cannot be written (missing directory, permission, not a regular
    file): the user picks another path."""


class WriteError(PhotonmapError):
    """Writing an output failed for a reason outside the path the user gave (disk full, I/O
    error, file too large): the previous file at that path, if any, is left as it was."""

    exit_code = 1


class BackendError(PhotonmapError):
    """The Dr.Jit / Mitsuba backend cannot run here (no suitable libLLVM, no CUDA, ...)."""


class PhotonmapWarning(UserWarning):
    """Something in the scene that the chosen method does not model (a medium in the surface or
    screen method, ...): the image is rendered without it, and this says so."""


class DeprecatedParameter(PhotonmapWarning, FutureWarning):
    """A parameter given by its old name (or unit), which keeps working for one release: the
    warning names the current one."""
