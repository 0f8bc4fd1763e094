"""Ctrl-C in the ``jaxdepth`` program: a clean message and exit 130, never a crash.

Returning from ``main`` after a KeyboardInterrupt lets the interpreter shut down while XLA's
compile threads still run, and that shutdown crashed (SIGSEGV, exit 139; issue 39): 4 of 5
interrupts 2.5 s into the demo's cold compile. So the program prints the message, flushes its
streams and ends with ``os._exit(130)``. JAX also runs Python callbacks (its gc callback) in which
a KeyboardInterrupt is lost (Python would print it as an "Exception ignored" traceback; the hook
installed here keeps that traceback off the terminal): :func:`received` still tells that one came, so
the command ends with 130 when its job returns; a second Ctrl-C ends it at once.

A leaf module (no jaxdepth import); only the command line (``jaxdepth.cli.main``) installs it.
"""

from __future__ import annotations

import os
import signal
import sys

MESSAGE = "jaxdepth: interrupted; finished outputs are complete, re-run to resume"

_COUNT = [0]


def catch() -> None:
    """Installs the SIGINT handler: the first raises KeyboardInterrupt (the job stops at its next step,
    queued writes finish), a second prints :data:`MESSAGE` and ends the process at once (130)."""

    def on_sigint(signum, frame):
        _COUNT[0] += 1
        if _COUNT[0] > 1:
            print(MESSAGE, file=sys.stderr)
            exit_now(130)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)
    default_hook = sys.unraisablehook

    def on_unraisable(info):
        # our own KeyboardInterrupt raised inside a callback that cannot propagate it (JAX's gc
        # callback): already counted by on_sigint, so no traceback for the user
        if isinstance(info.exc_value, KeyboardInterrupt) and received():
            return
        default_hook(info)

    sys.unraisablehook = on_unraisable


def received() -> bool:
    """Whether a SIGINT came since :func:`catch` (also one that something swallowed)."""
    return _COUNT[0] > 0


def interrupted(*, end_process: bool) -> int:
    """Prints :data:`MESSAGE`; ends the process with 130 when ``end_process`` (the program), else returns 130."""
    print(MESSAGE, file=sys.stderr)
    if end_process:
        exit_now(130)
    return 130


def exit_now(code: int) -> None:
    """Flushes stdout and stderr and ends the process with ``code`` without the interpreter's shutdown."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


__all__ = ["MESSAGE", "catch", "received", "interrupted", "exit_now"]
