"""The sweeps of one ``complete-rig`` call: one file, a folder, a glob or a list file.

``complete-rig SWEEP RIG.json OUT/`` reads SWEEP as (first rule that applies):

* ``@FILE`` or a path ending in ``.txt``: a list file, one sweep path per line; blank lines and
  lines starting with ``#`` are skipped; relative paths are relative to the list file's folder;
* an existing folder: its point files (``.bin``, ``.pcd.bin``, ``.npy``, ``.npz``), sorted by name
  (not its subfolders, not JSON files: list sweeps JSONs in a list file or a glob);
* a path that does not exist and holds a glob character (``*``, ``?``, ``[``): the matching files,
  sorted (quote it so that the shell leaves it alone);
* anything else: one sweep (a point file or a sweeps JSON), written as today to ``OUT/<camera>.png``.

Several sweeps write ``OUT/<sweep stem>/<camera>.png``, the stem being the file name without its
point-file suffix (``000001.bin``, ``000001.pcd.bin``, ``000001.npz`` and ``000001.json`` all give
``000001``). Two sweeps with one stem (``a/000001.bin`` and ``b/000001.bin``) are refused, naming
both, before anything is computed: complete them into separate output folders.
"""

from __future__ import annotations

import glob
import os
import pathlib

from jaxdepth.io.errors import InputError, PathLike

#: Suffixes of the point files a folder contributes (``.pcd.bin`` ends in ``.bin``).
POINT_SUFFIXES = (".bin", ".npy", ".npz")
#: Suffixes stripped from a sweep's file name to give its output folder, longest first.
STEM_SUFFIXES = (".pcd.bin", ".bin", ".npy", ".npz", ".json")
_GLOB_CHARS = "*?["


def is_list_file(arg: str) -> bool:
    """True when ``arg`` names a list file: ``@FILE`` or a path ending in ``.txt``."""
    return arg.startswith("@") or arg.lower().endswith(".txt")


def sweep_stem(path: PathLike) -> str:
    """The output folder name of a sweep: its file name without the point-file suffix."""
    name = pathlib.Path(path).name
    for suffix in STEM_SUFFIXES:
        if name.lower().endswith(suffix) and len(name) > len(suffix):
            return name[: -len(suffix)]
    return name


def _read_list(arg: str) -> list[pathlib.Path]:
    path = pathlib.Path(arg[1:] if arg.startswith("@") else arg)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read the list of sweeps ({getattr(err, 'strerror', None) or err})") from None
    base = path.parent
    lines = [line.strip() for line in text.splitlines()]
    paths = [base / line for line in lines if line and not line.startswith("#")]
    if not paths:
        raise InputError(f"{path}: the list of sweeps names no file (expected one sweep path per line)")
    return paths


def _folder_sweeps(folder: pathlib.Path) -> list[pathlib.Path]:
    try:
        files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in POINT_SUFFIXES)
    except OSError as err:
        raise InputError(f"{folder}: cannot list the folder of sweeps ({err.strerror or err})") from None
    if not files:
        raise InputError(f"{folder}: no sweep in this folder (expected point files: "
                         f"{', '.join('*' + s for s in POINT_SUFFIXES)})")
    return files


def list_sweeps(arg: PathLike) -> list[pathlib.Path] | None:
    """The sweeps that ``arg`` names (rules in the module docstring), or None for one sweep (today's layout).

    Raises:
      InputError: an unreadable or empty list file, an empty folder, a glob that matches nothing,
        or two sweeps with the same stem (:func:`check_unique_stems`).
    """
    arg = os.fspath(arg)
    if is_list_file(arg):
        sweeps = _read_list(arg)
    elif os.path.isdir(arg):
        sweeps = _folder_sweeps(pathlib.Path(arg))
    elif not os.path.exists(arg) and any(c in arg for c in _GLOB_CHARS):
        sweeps = [pathlib.Path(p) for p in sorted(glob.glob(arg)) if os.path.isfile(p)]
        if not sweeps:
            raise InputError(f"{arg}: no sweep file matches this pattern")
    else:
        return None
    check_unique_stems(sweeps)
    return sweeps


def check_unique_stems(sweeps) -> None:
    """Raises :class:`InputError` naming the first two sweeps that would write one output folder."""
    seen = {}
    for path in sweeps:
        stem = sweep_stem(path)
        if stem in seen:
            raise InputError(f"{path}: its output folder '{stem}' is also that of {seen[stem]} (sweeps must have "
                             "distinct file names without suffix; complete them into separate output folders)")
        seen[stem] = path


__all__ = ["list_sweeps", "sweep_stem", "check_unique_stems", "is_list_file", "POINT_SUFFIXES", "STEM_SUFFIXES"]
