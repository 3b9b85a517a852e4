"""Ctrl-C as a request, answered at a safe point.

A ``KeyboardInterrupt`` raised wherever Python happens to be is not safe here: raised inside the
Python body of a Dr.Jit symbolic loop it surfaces as a ``RuntimeError`` from ``dr.while_loop``
(DESIGN.md, Dr.Jit notes), and raised in the middle of a write it would leave half a file. So
while :func:`deferred` is active, SIGINT only sets a flag; long work calls :func:`check` between
kernel launches, stages and iterations, which raises :class:`Interrupted` (a
``KeyboardInterrupt``) there, and the caller keeps what was complete (the iterations of a
progressive render) or nothing.

A second Ctrl-C while the first is still pending: in the ``photonmap`` command (``force=True``)
the process stops at once — the temporary files of writes in progress (:data:`pending_files`)
are removed, so no output is ever partial, one line says so, exit status 130; in a Python session
the usual ``KeyboardInterrupt`` is raised where the program is. (Python runs a signal handler
when the main thread is back in Python code, once for a burst of signals: two Ctrl-C during one
long Dr.Jit kernel count as one.) A process that ignores SIGINT (a ``nohup`` or background job)
keeps ignoring it.

>>> with deferred():
...     for i in range(n):
...         step()            # a Ctrl-C here finishes the step ...
...         check()           # ... and stops here with Interrupted
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager

EXIT_STATUS = 130  # 128 + SIGINT, what a shell reports for a process ended by Ctrl-C
pending_files: set[str] = set()  # temporary files of writes in progress (core.image)
_requested = threading.Event()


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, raised at a safe point (between kernel launches, stages or iterations)."""


def requested() -> bool:
    """Whether Ctrl-C was pressed (and not yet answered)."""
    return _requested.is_set()


def check() -> None:
    """Raise :class:`Interrupted` if Ctrl-C was pressed."""
    if _requested.is_set():
        raise Interrupted()


def _force_exit() -> None:
    for path in list(pending_files):
        try:
            os.unlink(path)
        except OSError:
            pass
    try:
        os.write(2, b"interrupted again: stopped at once, nothing more written\n")
    finally:
        os._exit(EXIT_STATUS)


def _command_handler(signum, frame) -> None:
    if _requested.is_set():
        _force_exit()
    _requested.set()


def _session_handler(signum, frame) -> None:
    if _requested.is_set():
        _requested.clear()
        signal.default_int_handler(signum, frame)
    _requested.set()


_HANDLERS = (_command_handler, _session_handler)


@contextmanager
def deferred(force: bool = False):
    """While active (in the main thread), SIGINT sets the flag :func:`check` reads. ``force``: a
    second Ctrl-C ends the process at once (the command line); else it raises
    ``KeyboardInterrupt`` as usual (a Python session). Nested uses keep the outer handler; the
    outermost clears the flag when it ends. Elsewhere than the main thread it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    if previous in _HANDLERS or previous == signal.SIG_IGN:  # nested, or Ctrl-C ignored (nohup)
        yield
        return
    signal.signal(signal.SIGINT, _command_handler if force else _session_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        _requested.clear()


def _is_command() -> bool:
    """Whether this process is the ``photonmap`` command (console script or ``python -m``)."""
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    if name in ("photonmap", "photonmap.exe", "photonmap-script.py"):
        return True
    orig = list(getattr(sys, "orig_argv", []))
    if "-m" in orig[:-1]:
        return orig[orig.index("-m") + 1] in ("photonmap", "photonmap.cli")
    return False


def guard_command() -> None:
    """In the ``photonmap`` command, defer Ctrl-C from the start (the package import takes
    seconds): the command answers it at its first safe point. Nothing in a Python session."""
    if _is_command() and threading.current_thread() is threading.main_thread():
        if signal.getsignal(signal.SIGINT) != signal.SIG_IGN:  # a background job ignores it
            signal.signal(signal.SIGINT, _command_handler)


def answered() -> None:
    """In the ``photonmap`` command, once it has answered Ctrl-C and is exiting with status 130:
    a further Ctrl-C changes nothing, and is ignored — one landing while Python shuts down
    (which restores the default handler) would end the process by the signal instead."""
    if _is_command() and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextmanager
def held():
    """SIGINT held pending in this thread (delivered when the block ends).

    Mitsuba's ``Integrator.render`` installs its own SIGINT handler for the duration of a render,
    and that handler writes a log line — not async-signal-safe: a Ctrl-C that lands while the
    thread it interrupts is inside ``malloc`` deadlocks the process. Rendering with Mitsuba's
    integrators (``photonmap reference``) therefore holds SIGINT in the calling thread; the
    photonmap package starts Dr.Jit's worker threads under this block (threads inherit the
    signal mask of the thread that starts them), so that no thread takes the signal while
    Mitsuba's handler is installed, and Ctrl-C is answered by ours when the render returns.
    Outside the main thread, or where signal masks do not exist, it does nothing."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(
        signal, "pthread_sigmask"
    ):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
