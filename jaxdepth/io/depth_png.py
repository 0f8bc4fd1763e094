"""KITTI depth PNGs: uint16 greyscale, metres = value / 256, 0 = no measurement.

This is the format of KITTI depth completion (``velodyne_raw``,
``groundtruth_depth`` and the submitted predictions; Uhrig et al., 3DV 2017).
The largest representable depth is 65535 / 256 = 255.996 m and the resolution
is 1/256 m (3.9 mm); a write followed by a read returns every depth to within
1/512 m.
"""

from __future__ import annotations

import logging
import pathlib
import struct
import zlib

import numpy as np

from jaxdepth.io.atomic import atomic_write_bytes
from jaxdepth.io.errors import OutputError, PathLike, file_error, read_input_bytes

_LOG = logging.getLogger("jaxdepth")

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_COLOUR_TYPES = {0: "greyscale", 2: "RGB colour", 3: "palette colour", 4: "greyscale + alpha", 6: "RGBA colour"}
_SCALE = 256.0
_MAX_PIXELS = 1 << 28  # refuse absurd headers before allocating
_UP_FILTER = 2  # PNG row filter type "Up": each byte minus the byte above it

#: zlib level of the depth PNGs jaxdepth writes (0 = stored, 9 = smallest; any level decodes to
#: the same values, and KITTI's devkit reads them all). Level 1 encodes much faster than OpenCV's
#: level 3 for a few per cent more bytes; level 0 is fastest and ~2.5x the bytes. See docs/cli.md; other
#: filters, zlib strategies and libraries measured on the jobs' outputs: docs/speed.md, branch pngfast.
DEFAULT_PNG_COMPRESSION = 1

# The one choice of the IDAT's zlib encoder (the optional extra ``fast-png``, docs/speed.md): ISA-L's
# zlib stream for levels 1-3 (about 0.3x the CPU of zlib level 1, about the same bytes) when the package
# ``isal`` imports; Python's zlib otherwise and for levels 0 and 4-9 (ISA-L's level 0 is not "stored").
try:
    import isal
    from isal import isal_zlib as _isal_zlib
except ImportError:  # pragma: no cover - depends on the installation
    _isal_zlib = None
    _ISAL_VERSION = None
else:
    _ISAL_VERSION = getattr(isal, "__version__", "?")
_ISAL_LEVELS = (1, 2, 3)


def png_encoder() -> str:
    """Which library compresses the depth PNGs at the default level: ``"isal 1.9.1"`` (the optional
    extra ``fast-png``) or ``"zlib 1.3.1"`` (Python's zlib; its runtime version)."""
    if _isal_zlib is not None:
        return f"isal {_ISAL_VERSION}"
    return f"zlib {zlib.ZLIB_RUNTIME_VERSION}"


def _compress(data: np.ndarray, level: int) -> bytes:
    if _isal_zlib is not None and level in _ISAL_LEVELS:
        return _isal_zlib.compress(data, level)
    return zlib.compress(data, level)


def _read_bytes(path: pathlib.Path) -> bytes:
    return read_input_bytes(path, expected="a PNG file")


def _png_header(path: pathlib.Path, data: bytes) -> tuple[int, int, int, int]:
    """(width, height, bit_depth, colour_type) from the IHDR chunk, validated."""
    if len(data) == 0:
        raise file_error(path, "file is empty, expected a 16-bit greyscale PNG")
    if not data.startswith(_PNG_SIGNATURE):
        raise file_error(path, "not a PNG file (the 8-byte PNG signature is missing), "
                         "expected a 16-bit greyscale PNG")
    if len(data) < 33:
        raise file_error(path, f"truncated PNG: {len(data)} bytes, too short for the IHDR header")
    length, ctype = struct.unpack(">I4s", data[8:16])
    if ctype != b"IHDR" or length != 13:
        raise file_error(path, "corrupt PNG: the first chunk is not a 13-byte IHDR header")
    if zlib.crc32(data[12:29]) != struct.unpack(">I", data[29:33])[0]:
        raise file_error(path, "corrupt PNG: IHDR checksum mismatch")
    width, height, bit_depth, colour_type = struct.unpack(">IIBB", data[16:26])
    if width == 0 or height == 0 or width * height > _MAX_PIXELS:
        raise file_error(path, f"corrupt PNG: image size {width}x{height} is not plausible")
    if colour_type != 0 or bit_depth != 16:
        kind = _COLOUR_TYPES.get(colour_type, f"colour type {colour_type}")
        raise file_error(path, f"expected a 16-bit greyscale PNG (KITTI depth: metres * 256), "
                         f"got a {bit_depth}-bit {kind} PNG")
    return width, height, bit_depth, colour_type


def read_depth_png(path: PathLike) -> np.ndarray:
    """Reads a KITTI depth PNG.

    Args:
      path: a 16-bit greyscale PNG whose values are metres * 256 (0 = empty).

    Returns:
      (H, W) float32 depth in metres, 0.0 where there is no measurement.

    Raises:
      InputError: the file is missing, empty, not a PNG, truncated or corrupt,
        or not 16-bit greyscale (8-bit and colour PNGs are refused rather than
        rescaled: they are not depth maps).

    The file is decoded by OpenCV (``cv2.imdecode(..., IMREAD_UNCHANGED)``); the
    header is checked first so the error says what kind of PNG it found.
    """
    import cv2

    path = pathlib.Path(path)
    data = _read_bytes(path)
    width, height, _, _ = _png_header(path, data)
    try:
        raw = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise file_error(path, f"corrupt or truncated PNG: OpenCV could not decode it ({exc.err})") from None
    if raw is None:
        raise file_error(path, "corrupt or truncated PNG: OpenCV could not decode it")
    if raw.dtype != np.uint16 or raw.shape != (height, width):
        raise file_error(path, f"expected a ({height}, {width}) uint16 image as its header says, "
                         f"got {raw.shape} {raw.dtype}")
    # One pass, no float32 temporary: value * 2**-8 is exact in float32 (as value / 256 is).
    return np.multiply(raw, np.float32(1.0 / _SCALE), dtype=np.float32)


def encode_depth_uint16(depth_m: np.ndarray) -> np.ndarray:
    """Float metres -> KITTI uint16: ``clip(round(depth_m * 256), 0, 65535)``.

    Args:
      depth_m: (H, W) real array, metres; 0 (or below 1/512 m) means empty.

    Returns:
      (H, W) uint16. Negative depths and ``-inf`` become 0 (empty); depths above
      255.996 m and ``+inf`` become 65535. Clipping is logged as a warning on the
      ``"jaxdepth"`` logger.

    Raises:
      ValueError: not a non-empty 2-D real array, or it contains NaN (missing
        depth must be 0, never NaN).
    """
    depth = np.asarray(depth_m)
    if depth.ndim != 2 or depth.shape[0] < 1 or depth.shape[1] < 1:
        raise ValueError(f"write_depth_png: field 'depth_m' expected a non-empty (H, W) array, got shape {depth.shape}")
    if depth.dtype.kind not in "fiub":
        raise ValueError(f"write_depth_png: field 'depth_m' expected real numbers, got dtype {depth.dtype}")
    if depth.dtype == np.float32:  # x * 256 is exact in float32: the same result as float64, fewer bytes
        scaled = np.multiply(depth, np.float32(_SCALE))
    else:
        scaled = np.multiply(depth.astype(np.float64), _SCALE)
    np.rint(scaled, out=scaled)
    # The common case in two reductions: every value in range (NaN fails both tests), so the clip below
    # would change nothing; otherwise the full checks.
    if scaled.min() >= 0 and scaled.max() <= 65535:
        return scaled.astype(np.uint16)
    nan = np.isnan(scaled)
    if nan.any():
        raise ValueError(f"write_depth_png: field 'depth_m' expected no NaN (use 0 for missing depth), "
                         f"got {int(nan.sum())} NaN pixels")
    low = scaled < 0
    high = scaled > 65535
    if low.any() or high.any():
        _LOG.warning("write_depth_png: clipped %d negative depths to 0 (empty) and %d depths above %.3f m",
                     int(low.sum()), int(high.sum()), 65535 / _SCALE)
    return np.clip(scaled, 0, 65535).astype(np.uint16)


def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(tag)))


def encode_depth_png(depth_u16: np.ndarray, *, compression: int = DEFAULT_PNG_COMPRESSION) -> bytes:
    """Encodes a uint16 depth image as 16-bit greyscale PNG bytes.

    Args:
      depth_u16: (H, W) uint16 (KITTI: metres * 256), e.g. from :func:`encode_depth_uint16`.
      compression: zlib level 0-9 (0 stores the rows uncompressed, 9 is the smallest
        and slowest); every level decodes to the same values. Levels 1-3 use ISA-L's
        zlib stream when the optional extra ``fast-png`` (package ``isal``) is installed
        (:func:`png_encoder` says which), Python's zlib otherwise; 0 and 4-9 always zlib.

    Returns:
      The PNG file's bytes: IHDR, one IDAT, IEND. Every row uses the PNG filter "Up"
      (the difference to the row above, which suits depth maps), then one zlib
      stream at ``compression``: the same array and level always give the same bytes.
      NumPy filters and zlib (or ISA-L) compresses (releasing the GIL), so threads encode in
      parallel; OpenCV's encoder tries five filters per row and is slower.

    Raises:
      ValueError: not a non-empty 2-D uint16 array, or a level outside 0-9.
    """
    array = np.asarray(depth_u16)
    if array.dtype != np.uint16 or array.ndim != 2 or array.shape[0] < 1 or array.shape[1] < 1:
        raise ValueError(f"encode_depth_png: field 'depth_u16' expected a non-empty (H, W) uint16 array, "
                         f"got shape {array.shape} dtype {array.dtype}")
    if isinstance(compression, bool) or int(compression) != compression or not 0 <= compression <= 9:
        raise ValueError(f"encode_depth_png: field 'compression' expected an integer 0-9, got {compression!r}")
    h, w = array.shape
    big_endian = array.astype(">u2").view(np.uint8).reshape(h, 2 * w)
    rows = np.empty((h, 2 * w + 1), np.uint8)
    rows[:, 0] = _UP_FILTER
    rows[0, 1:] = big_endian[0]
    np.subtract(big_endian[1:], big_endian[:-1], out=rows[1:, 1:])  # uint8: modulo 256, as PNG wants
    header = struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0)  # 16-bit greyscale, no interlace
    return (_PNG_SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", _compress(rows, int(compression)))
            + _chunk(b"IEND", b""))


def write_depth_png(path: PathLike, depth_m: np.ndarray, *, overwrite: bool = True,
                    compression: int = DEFAULT_PNG_COMPRESSION) -> pathlib.Path:
    """Writes a depth map as a KITTI depth PNG, atomically.

    Args:
      path: target ``.png`` file; its folder must exist.
      depth_m: (H, W) float depth in metres, 0 = empty. Not modified.
      overwrite: replace an existing file (default); ``False`` raises
        :class:`~jaxdepth.io.errors.OutputError` if the file exists.
      compression: zlib level 0-9 of the PNG (see :func:`encode_depth_png`); the
        stored values do not depend on it, only the file size and the time.

    Returns:
      The path written.

    Values are stored as ``clip(round(depth_m * 256), 0, 65535)`` (see
    :func:`encode_depth_uint16`); the same input and level always give the same bytes.
    """
    path = pathlib.Path(path)
    if path.suffix.lower() != ".png":
        raise OutputError(f"{path}: expected a file name ending in .png, got suffix '{path.suffix}'")
    data = encode_depth_png(encode_depth_uint16(depth_m), compression=compression)
    return atomic_write_bytes(path, data, overwrite=overwrite)


__all__ = ["read_depth_png", "write_depth_png", "encode_depth_uint16", "encode_depth_png",
           "DEFAULT_PNG_COMPRESSION", "png_encoder"]
