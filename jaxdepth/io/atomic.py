"""Atomic file writes: a finished file or nothing.

Every writer of :mod:`jaxdepth.io` goes through :func:`atomic_write_bytes`:

1. the bytes go to a new temporary file in the *target folder* (same file
   system, so the final rename is atomic), named ``.<name>.<random>.tmp``;
2. the temporary file is flushed and ``fsync``-ed;
3. it is moved into place with :func:`os.replace` (or hard-linked, when
   overwriting is not allowed, so an existing file is never clobbered even by a
   concurrent writer), and the folder is ``fsync``-ed (best effort).

On any exception, including :class:`KeyboardInterrupt`, the temporary file is
removed and the target is left as it was. Operating-system failures become
:class:`~jaxdepth.io.errors.OutputError` with the path and the reason (for
example ``No space left on device``); ``KeyboardInterrupt`` and other
non-``OSError`` exceptions are re-raised unchanged after the clean-up.
"""

from __future__ import annotations

import errno
import os
import pathlib
import secrets

import numpy as np

from jaxdepth.io.errors import OutputError, PathLike

# New files get the usual permissions (0666 minus the process umask), like open().
_FILE_MODE = 0o666
_TEMP_ATTEMPTS = 16


def _reason(exc: OSError) -> str:
    if exc.errno == errno.ENOSPC:
        return "no space left on device (ENOSPC)"
    if exc.errno == errno.EDQUOT:
        return "disk quota exceeded (EDQUOT)"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return "permission denied"
    if exc.errno == errno.EROFS:
        return "read-only file system"
    return exc.strerror or repr(exc)


def _open_temp(folder: pathlib.Path, name: str) -> tuple[int, pathlib.Path]:
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0) | getattr(os, "O_CLOEXEC", 0)
    for _ in range(_TEMP_ATTEMPTS):
        tmp = folder / f".{name}.{secrets.token_hex(6)}.tmp"
        try:
            return os.open(tmp, flags, _FILE_MODE), tmp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "could not create a unique temporary file", str(folder))


def _write_all(fd: int, data: memoryview) -> None:
    view = data
    while len(view):
        written = os.write(fd, view)
        if written <= 0:  # pragma: no cover - os.write raises instead on POSIX
            raise OSError(errno.EIO, "write returned 0 bytes")
        view = view[written:]


def _fsync_folder(folder: pathlib.Path) -> None:
    """Makes the rename durable; not every platform can open a folder, so best effort."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _place(tmp: pathlib.Path, path: pathlib.Path, overwrite: bool) -> None:
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)  # fails with EEXIST, atomically, if the target exists
    except FileExistsError:
        raise OutputError(f"{path}: already exists (pass overwrite=True / --overwrite to replace it)") from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK, errno.ENOSYS):
            raise
        # File systems without hard links: check, then rename (not race-free).
        if os.path.lexists(path):
            raise OutputError(f"{path}: already exists (pass overwrite=True / --overwrite to replace it)") from None
        os.replace(tmp, path)
        return
    try:
        os.unlink(tmp)  # the target now holds the data; the extra name is only clutter
    except OSError:
        pass


def atomic_write_bytes(path: PathLike, data: bytes, *, overwrite: bool = True) -> pathlib.Path:
    """Writes ``data`` to ``path`` atomically (temp file in the same folder + fsync + rename).

    Args:
      path: target file. Its folder must exist (it is not created).
      data: the complete file contents (``bytes``, ``bytearray`` or ``memoryview``).
      overwrite: replace an existing file (default). With ``False`` an existing
        target raises :class:`OutputError` and is left untouched.

    Returns:
      The target path as a :class:`pathlib.Path`.

    Raises:
      OutputError: the folder is missing or not writable, the target is a folder,
        the target exists and ``overwrite`` is False, or writing failed (disk
        full, quota, I/O error). No partial file and no temporary file remain.
    """
    path = pathlib.Path(path)
    folder = path.parent
    if not folder.is_dir():
        raise OutputError(f"{path}: output folder '{folder}' does not exist")
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, expected a file path")
    if not overwrite and os.path.lexists(path):
        raise OutputError(f"{path}: already exists (pass overwrite=True / --overwrite to replace it)")
    payload = memoryview(data).cast("B")

    tmp: pathlib.Path | None = None
    fd: int | None = None
    try:
        fd, tmp = _open_temp(folder, path.name)
        _write_all(fd, payload)
        os.fsync(fd)
        os.close(fd)
        fd = None
        _place(tmp, path, overwrite)
        tmp = None
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {_reason(exc)}") from exc
    finally:
        # Runs for every exception type (KeyboardInterrupt included) and on success.
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
    _fsync_folder(folder)
    return path


def make_output_folders(paths) -> int:
    """Creates the parent folder of every output path (writers write into existing folders only).

    Returns:
      The number of distinct folders.

    Raises:
      OutputError: a folder cannot be created (named).
    """
    folders = sorted({pathlib.Path(p).parent for p in paths})
    for folder in folders:
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise OutputError(f"{folder}: cannot create output folder ({err.strerror or err})") from None
    return len(folders)


def ensure_output_dir(path: PathLike) -> pathlib.Path:
    """Creates the output folder ``path`` if needed and checks that files can be written into it,
    before any computation (a run must not fail at its first write).

    Returns:
      The folder.

    Raises:
      OutputError: it cannot be created, is not a folder, or is not writable (a probe file
        cannot be created in it; root passes permission bits, so the probe is real).
    """
    folder = pathlib.Path(path)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{folder}: cannot create output folder ({err.strerror or err})") from None
    if not folder.is_dir():
        raise OutputError(f"{folder}: output path exists and is not a folder")
    try:
        fd, tmp = _open_temp(folder, ".jaxdepth_write_probe")
    except OSError as err:
        raise OutputError(f"{folder}: output folder is not writable ({_reason(err)})") from None
    os.close(fd)
    try:
        os.unlink(tmp)
    except OSError:
        pass
    return folder


def encode_png(array: np.ndarray) -> bytes:
    """Encodes an image as PNG bytes with OpenCV (fixed settings: deterministic bytes).

    Args:
      array: (H, W) uint8/uint16 greyscale, or (H, W, 3|4) uint8/uint16 BGR(A).

    Raises:
      ValueError: unsupported dtype or shape.
    """
    import cv2  # local: keep `import jaxdepth.io` light

    array = np.asarray(array)
    if array.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"encode_png: field 'array' expected dtype uint8 or uint16, got {array.dtype}")
    if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] in (1, 3, 4))):
        raise ValueError(f"encode_png: field 'array' expected shape (H, W) or (H, W, 1|3|4), got {array.shape}")
    if array.shape[0] < 1 or array.shape[1] < 1:
        raise ValueError(f"encode_png: field 'array' expected a non-empty image, got shape {array.shape}")
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(array),
                           [cv2.IMWRITE_PNG_COMPRESSION, 3, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_DEFAULT])
    if not ok:  # pragma: no cover - OpenCV reports failure for exotic builds only
        raise ValueError(f"encode_png: OpenCV could not encode an array of shape {array.shape} and dtype {array.dtype}")
    return buf.tobytes()


def atomic_write_png(path: PathLike, array: np.ndarray, *, overwrite: bool = True) -> pathlib.Path:
    """Encodes ``array`` as PNG (OpenCV) and writes it with :func:`atomic_write_bytes`.

    Args:
      path: target ``.png`` file.
      array: (H, W) uint8/uint16 greyscale or (H, W, 3|4) BGR(A), as ``cv2.imwrite``.
      overwrite: see :func:`atomic_write_bytes`.

    Raises:
      ValueError: unsupported dtype or shape (checked before anything is written).
      OutputError: the path does not end in ``.png`` or the write failed.
    """
    path = pathlib.Path(path)
    if path.suffix.lower() != ".png":
        raise OutputError(f"{path}: expected a file name ending in .png, got suffix '{path.suffix}'")
    return atomic_write_bytes(path, encode_png(array), overwrite=overwrite)
