"""The ``photonmap`` command: render a scene with a method, render Mitsuba's own reference of the
same scene, compare two images, list the built-in scenes; on Ray workers, progressive passes
(``render --workers/--ray``) and frame sequences (``render-sequence``, :mod:`photonmap.cluster`).

Every argument is checked before any work starts (output paths, image size and its memory, the
``--set`` keys and values); each bad input is one line ``error: ...`` and exit status 2 (1 for a
failure outside the input, such as a full disk). Outputs are written atomically
(:func:`photonmap.core.image.write_bytes`). Ctrl-C is answered at the next safe point
(:mod:`photonmap.core.interrupt`): the image reached is written (a progressive render's) or
nothing, one line ``interrupted: ...`` says which, exit status 130. The CLI goes through the
package API only (:data:`photonmap.METHODS`).
"""

from . import render, tools  # noqa: F401  (the commands register themselves on the app)
from .base import app, main

__all__ = ["app", "main"]
