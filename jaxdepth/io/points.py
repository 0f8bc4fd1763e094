"""LiDAR sweeps: reading point files and padding them to static-size buckets.

File formats (metres, LiDAR frame):

- ``.bin``: little-endian float32 records of ``columns`` values, the first three
  are x, y, z (KITTI velodyne: 4 = x, y, z, reflectance; nuScenes ``.pcd.bin``:
  5 = x, y, z, intensity, ring index);
- ``.npy``: one (N, columns) real array;
- ``.npz``: the array under key ``"points"``, or the only array in the archive.

Non-finite coordinates (NaN, inf) are *not* an error when reading: some drivers
write them for missing returns. :func:`pad_points` marks them invalid, so they
never reach a projection. Values no LiDAR produces are: :func:`read_points` runs the
checks of :mod:`jaxdepth.io.plausibility` on every sweep it reads (a wrong column count
or dtype decodes without error into garbage points) unless ``force=True``, and drops
points farther than any LiDAR measures (:func:`jaxdepth.io.plausibility.drop_far_points`:
their x, y, z become NaN, one warning names the file and the count).
"""

from __future__ import annotations

import math
import pathlib
import tokenize
import zipfile
import zlib
from typing import BinaryIO

import numpy as np

from jaxdepth.io.errors import InputError, PathLike, check_input_file, file_error, read_input_bytes

#: Smallest padded size: sweeps are padded to max(MIN_BUCKET, next power of two).
MIN_BUCKET = 1024


def _check_columns(columns: int) -> int:
    if isinstance(columns, bool) or not isinstance(columns, (int, np.integer)) or columns < 3:
        raise ValueError(f"read_points: field 'columns' expected an integer >= 3, got {columns!r}")
    return int(columns)


def _split(path: pathlib.Path, array: np.ndarray, columns: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    if array.dtype.kind not in "fiu":
        raise file_error(path, f"{what} expected a real-valued array, got dtype {array.dtype}")
    if array.ndim != 2 or array.shape[1] != columns:
        raise file_error(path, f"{what} expected shape (N, {columns}) for columns={columns}, got {array.shape}")
    if array.shape[0] == 0:
        raise file_error(path, f"{what} contains no points, expected at least one")
    with np.errstate(over="ignore", invalid="ignore"):  # float64 beyond float32 range -> inf, kept as data
        data = array.astype(np.float32)
    return np.ascontiguousarray(data[:, :3]), np.ascontiguousarray(data[:, 3:])


def _read_bin(path: pathlib.Path, columns: int, force: bool, columns_option) -> tuple[np.ndarray, np.ndarray]:
    record = 4 * columns
    raw = read_input_bytes(path, expected="a point file")
    if len(raw) == 0:
        raise file_error(path, f"file is empty, expected float32 records of {columns} values")
    if len(raw) % record:
        raise file_error(path, f"size {len(raw)} bytes is not a whole number of {columns}-value float32 records "
                         f"({record} bytes each; {len(raw) // record} records + {len(raw) % record} bytes); "
                         "check 'columns' (KITTI 4, nuScenes 5)")
    array = np.frombuffer(raw, dtype="<f4").reshape(-1, columns)
    points, extra = _split(path, array, columns, "file")
    _check(path, points, extra, columns, raw=raw, force=force, columns_option=columns_option)
    return points, extra


def _check(path, points, extra, columns, *, raw=None, force=False, columns_option="--point-columns N"):
    """The plausibility checks of :mod:`jaxdepth.io.plausibility` on a sweep as read."""
    from jaxdepth.io.plausibility import check_sweep
    check_sweep(points, path=path, columns=columns, intensity=extra[:, 0] if extra.shape[1] >= 1 else None,
                ring=extra[:, 1] if columns == 5 else None, raw=raw, force=force, columns_option=columns_option)


# Everything a corrupt .npy / .npz can raise while being parsed.
_PARSE_ERRORS = (ValueError, OSError, EOFError, TypeError, KeyError, SyntaxError, OverflowError,
                 tokenize.TokenError, zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, zlib.error)


def _parse_npy(path: pathlib.Path, stream: BinaryIO, available: int, what: str) -> np.ndarray:
    """Parses one .npy stream with ``available`` bytes, checking the header against the size.

    ``np.load`` would trust the header's shape (and allocate it) before noticing
    that the data are missing; this reads only what the file holds.
    """
    start = stream.tell() if stream.seekable() else 0
    version = np.lib.format.read_magic(stream)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(stream)
    elif version in ((2, 0), (3, 0)):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(stream)
    else:
        raise ValueError(f"unsupported .npy format version {version}")
    header_len = (stream.tell() - start) if stream.seekable() else None
    if dtype.hasobject or dtype.kind not in "fiu":
        raise file_error(path, f"{what} expected a real-valued array, got dtype {dtype}")
    count = math.prod(int(d) for d in shape)
    nbytes = count * dtype.itemsize
    if header_len is not None and nbytes > available - header_len:
        raise file_error(path, f"{what} is truncated: header says shape {shape} ({nbytes} bytes), "
                         f"the file holds {max(available - header_len, 0)} bytes of data")
    data = stream.read(nbytes)
    if len(data) != nbytes:
        raise file_error(path, f"{what} is truncated: expected {nbytes} bytes of data, got {len(data)}")
    return np.frombuffer(data, dtype).reshape(shape, order="F" if fortran else "C")


def _read_npy(path: pathlib.Path, columns: int) -> tuple[np.ndarray, np.ndarray]:
    try:
        with open(path, "rb") as stream:
            array = _parse_npy(path, stream, path.stat().st_size, "array")
    except InputError:
        raise
    except _PARSE_ERRORS as exc:
        raise file_error(path, f"not a readable .npy array ({type(exc).__name__}: {str(exc)[:80]})") from None
    return _split(path, array, columns, "array")


def _read_npz(path: pathlib.Path, columns: int) -> tuple[np.ndarray, np.ndarray]:
    key = "?"
    try:
        with zipfile.ZipFile(path) as archive:
            names = [n for n in archive.namelist() if n.endswith(".npy")]
            keys = [n[:-4] for n in names]
            if "points" in keys:
                key = "points"
            elif len(keys) == 1:
                key = keys[0]
            else:
                raise file_error(path, f"expected an array named 'points' or a single array, got keys {keys[:10]}")
            info = archive.getinfo(key + ".npy")
            with archive.open(info) as stream:
                array = _parse_npy(path, stream, info.file_size, f"array '{key}'")
    except InputError:
        raise
    except _PARSE_ERRORS as exc:
        raise file_error(path, f"not a readable .npz archive ({type(exc).__name__}: {str(exc)[:80]})") from None
    return _split(path, array, columns, f"array '{key}'")


def infer_point_columns(path: PathLike, given: int | None = None) -> int:
    """Float32 values per point of a sweep file, from the file when not ``given``.

    ``*.pcd.bin`` (nuScenes: x, y, z, intensity, ring) has 5. A plain ``.bin``
    has 4 (KITTI: x, y, z, reflectance) or 5: the one its byte size fits; a size
    that fits both is refused (reading it the wrong way gives garbage points
    and no error). ``.npy`` / ``.npz`` carry their own shape (4 assumed, checked
    by :func:`read_points`).

    Raises:
      InputError: the size of a plain ``.bin`` fits both 4 and 5 columns.
    """
    if given is not None:
        return int(given)
    path = pathlib.Path(path)
    name = path.name.lower()
    if name.endswith(".pcd.bin"):
        return 5
    if path.suffix.lower() != ".bin" or not path.is_file():
        return 4
    size = path.stat().st_size
    fits = [c for c in (4, 5) if size and size % (4 * c) == 0]
    if len(fits) == 2:
        raise file_error(path, f"size {size} bytes fits both 4 and 5 float32 values per point; "
                         "pass --point-columns (KITTI: 4, nuScenes .pcd.bin: 5)")
    return fits[0] if fits else 4


def read_points(path: PathLike, *, columns: int | None = None, force: bool = False,
                columns_option: str | None = "--point-columns N",
                drop_far: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Reads a LiDAR sweep.

    Args:
      path: ``.bin`` (float32 records), ``.npy`` or ``.npz`` file (see module docs).
      columns: values per point, >= 3 (KITTI 4, nuScenes 5); default 5 for ``*.pcd.bin``
        (nuScenes: x, y, z, intensity, ring), else 4. For ``.npy`` / ``.npz`` the array must
        have exactly this many columns.
      force: read a sweep that fails the plausibility checks
        (:func:`jaxdepth.io.plausibility.check_sweep`), logging a warning.
      columns_option: named in a refusal as the way to read another layout (the command's
        option); None where the layout fixes the column count.
      drop_far: set x, y, z of points farther than any LiDAR measures to NaN, with one
        warning (:func:`jaxdepth.io.plausibility.drop_far_points`; ``force`` keeps them, warned);
        False when the first three columns are not x, y, z (the caller drops them after reordering).

    Returns:
      (points, extra): points (N, 3) float32 x, y, z in metres (non-finite
      values are returned as they are, far points as NaN); extra (N, columns - 3) float32, the
      remaining columns (reflectance, ring index, ...).

    Raises:
      InputError: missing file, unknown suffix, empty file, a ``.bin`` size that
        is not a whole number of records, wrong array shape or dtype, corrupt
        ``.npy`` / ``.npz``; values no LiDAR produces (a wrong column count or
        dtype: the message lists the layouts the bytes fit), unless ``force``.
      ValueError: ``columns`` is not an integer >= 3.
    """
    path = pathlib.Path(path)
    columns = _check_columns((5 if path.name.lower().endswith(".pcd.bin") else 4) if columns is None else columns)
    check_input_file(path, expected="a point file")
    suffix = path.suffix.lower()
    if suffix == ".bin":
        points, extra = _read_bin(path, columns, force, columns_option)
    elif suffix in (".npy", ".npz"):
        points, extra = (_read_npy if suffix == ".npy" else _read_npz)(path, columns)
        _check(path, points, extra, columns, force=force)
    else:
        raise file_error(path, f"unsupported suffix '{path.suffix}', expected .bin, .npy or .npz")
    if drop_far:
        from jaxdepth.io.plausibility import drop_far_points
        points = drop_far_points(points, path=path, force=force)
    return points, extra


def bucket_size(n: int) -> int:
    """Padded size for ``n`` points: ``max(MIN_BUCKET, 2 ** ceil(log2(n)))``.

    >>> bucket_size(1), bucket_size(1024), bucket_size(1025), bucket_size(121948)
    (1024, 1024, 2048, 131072)
    """
    n = int(n)
    if n < 0:
        raise ValueError(f"bucket_size: field 'n' expected a non-negative integer, got {n}")
    return max(MIN_BUCKET, 1 << max(n - 1, 0).bit_length())


def pad_points(points: np.ndarray, *, bucket: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pads a sweep to a static size so sweeps of different lengths share one compiled function.

    Args:
      points: (N, 3) real array, metres. Not modified.
      bucket: padded size B >= N; default :func:`bucket_size` (N) (a power of
        two, at least 1024).

    Returns:
      (padded, valid): padded (B, 3) float32, the input points in their order
      followed by zeros; valid (B,) bool, True for input points whose three
      coordinates are finite. Non-finite points are set to 0 and marked invalid,
      so a padded sweep never contains NaN or inf.

    Raises:
      ValueError: ``points`` is not (N, 3), or ``bucket`` < N or < 1.
    """
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"pad_points: field 'points' expected shape (N, 3), got {points.shape}")
    if points.dtype.kind not in "fiu":
        raise ValueError(f"pad_points: field 'points' expected real numbers, got dtype {points.dtype}")
    n = points.shape[0]
    size = bucket_size(n) if bucket is None else bucket
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < max(n, 1):
        raise ValueError(f"pad_points: field 'bucket' expected an integer >= max(N, 1) = {max(n, 1)}, got {bucket!r}")
    size = int(size)
    with np.errstate(over="ignore", invalid="ignore"):
        pts = points.astype(np.float32)
    finite = np.all(np.isfinite(pts), axis=1)
    padded = np.zeros((size, 3), np.float32)
    padded[:n] = np.where(finite[:, None], pts, np.float32(0.0))
    valid = np.zeros((size,), bool)
    valid[:n] = finite
    return padded, valid


def ring_column(extra: np.ndarray, columns: int) -> np.ndarray | None:
    """The beam (ring) index of a 5-column sweep (nuScenes: x, y, z, intensity, ring) when the
    5th column holds small non-negative integers; None otherwise."""
    if columns != 5 or extra.shape[1] < 2:
        return None
    ring = extra[:, 1]
    finite = np.isfinite(ring)
    if not finite.any() or np.any(ring[finite] != np.round(ring[finite])) or np.any(ring[finite] < 0) \
            or np.any(ring[finite] > 1023):
        return None
    return ring


__all__ = ["read_points", "infer_point_columns", "pad_points", "bucket_size", "MIN_BUCKET", "ring_column"]
