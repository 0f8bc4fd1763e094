"""User-facing data errors of the I/O edge.

Every reader and writer in :mod:`jaxdepth.io` reports bad input or an output it
cannot produce with one of these exceptions. The message is a single line that
names the file, the field and what was expected, e.g.::

    calib_velo_to_cam.txt: field 'T' expected 3 floats, got 2

The command line prints ``str(error)`` and exits with status 1; anything else
(a bug) keeps its traceback.
"""

from __future__ import annotations

import os
from typing import Union

PathLike = Union[str, "os.PathLike[str]"]


class JaxdepthError(Exception):
    """Base class of the user-facing data errors (CLI: one-line message, exit code 1)."""


class InputError(JaxdepthError, ValueError):
    """An input file is missing, unreadable or has a bad field.

    Also a :class:`ValueError`, so callers that validate with ``except ValueError``
    keep working.
    """


class OutputError(JaxdepthError):
    """An output file cannot be written (folder missing or read-only, disk full,
    target exists and overwriting was not allowed)."""


def field_error(path: PathLike, field: str, expected: str, got: object) -> InputError:
    """Builds ``InputError("<path>: field '<field>' expected <expected>, got <got>")``."""
    return InputError(f"{os.fspath(path)}: field '{field}' expected {expected}, got {got}")


def file_error(path: PathLike, message: str) -> InputError:
    """Builds ``InputError("<path>: <message>")``."""
    return InputError(f"{os.fspath(path)}: {message}")


def check_input_file(path: PathLike, *, expected: str) -> None:
    """Raises :class:`InputError` naming ``path`` when it is missing or a folder
    (``expected`` says what it should be, e.g. "a PNG file")."""
    if not os.path.exists(path):
        raise file_error(path, "file not found")
    if os.path.isdir(path):
        raise file_error(path, f"is a folder, expected {expected}")


def read_input_bytes(path: PathLike, *, expected: str) -> bytes:
    """The bytes of an input file; :class:`InputError` naming it when it is missing,
    a folder or unreadable (every reader's common first step)."""
    check_input_file(path, expected=expected)
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError as exc:
        raise file_error(path, f"cannot read: {exc.strerror or exc}") from exc
