"""Plausibility checks of LiDAR sweeps and depth PNGs, run before any computation.

A file can be well-formed and still be the wrong thing: float32 bytes read with the
wrong number of values per point, float64 read as float32, or a depth PNG in
millimetres read as metres x 256 all decode without error and complete into wrong
depth. These checks look at the *values* and refuse what no sensor produces.

Sweeps (:func:`check_sweep`), on the finite points, ranges about the file's origin (a
cloud of fewer than :data:`MIN_POINTS` finite points is too small to judge and passes
once one point is finite):

* some point is finite;
* at least :data:`MIN_IN_RANGE_SHARE` of the ranges lie in [0.5, 300] m
  (measured: 0.85-1.00 on the shared KITTI and nuScenes sweeps, <= 0.18 when their
  bytes are read as float64);
* at most :data:`MAX_STEEP_SHARE` of the points are steeper than 50 degrees from the
  horizontal plane (measured: <= 0.009 on the right layout; >= 0.25 under every
  wrong float32 column count, because the z column then holds x and y values);
* the intensity column (4th) is finite and within [-1, 65535] for 99 % of the points;
* a ring column (5th, nuScenes) holds integers 0-1023, and each ring is one beam: the
  median over rings of the 10-90 % elevation spread is at most
  :data:`MAX_RING_SPREAD_DEG` (measured 0.44 deg on the nuScenes sweep, 30 deg when
  the ring column is shuffled).

The azimuth structure is not checked: camera-cropped sweeps cover only part of the
circle. A refused ``.bin`` is decoded under the other layouts (3-6 float32 values per
point, float64) and the message lists those that pass (:func:`suggest_layouts`).

Depth PNGs (:func:`check_depth_scale`), on the non-zero pixels, metres = value / 256:

* not every value a multiple of 256 (integer metres, or depth scaled wrong) when there
  are at least 20 distinct values (a synthetic plane at a whole number of metres is fine);
* median <= 200 m (beyond every automotive LiDAR);
* not (5th percentile > 15 m and median > 40 m): millimetres read as metres x 256
  (measured on KITTI's velodyne_raw: 5th percentile 6.3 m and median 14.3 m in metres,
  24.6 m and 55.9 m when the PNG holds millimetres);
* median >= 1 m (decimetres or a normalised image give medians of 0.5 m).

Every check raises :class:`~jaxdepth.io.errors.InputError` naming the file, what was
measured and what it seems to be. Callers that know better pass ``force=True`` to the
readers (``--force`` on the command line), which logs the override as a warning.
"""

from __future__ import annotations

import logging
import pathlib

import numpy as np

from jaxdepth.io.errors import InputError, PathLike, file_error

_LOG = logging.getLogger("jaxdepth")

#: Range window of plausible returns, metres.
RANGE_MIN_M, RANGE_MAX_M = 0.5, 300.0
#: Smallest share of finite points whose range lies in the window.
MIN_IN_RANGE_SHARE = 0.5
#: Elevation beyond which a return counts as steep, degrees, and the largest plausible steep share.
STEEP_DEG = 50.0
MAX_STEEP_SHARE = 0.10
#: Intensity bounds (KITTI reflectance 0-1, nuScenes 0-255, 16-bit sensors up to 65535).
INTENSITY_MIN, INTENSITY_MAX = -1.0, 65535.0
#: Largest median 10-90 % elevation spread of one ring, degrees.
MAX_RING_SPREAD_DEG = 5.0
#: Depth PNG scale checks (metres).
DEPTH_MAX_MEDIAN_M = 200.0
DEPTH_MIN_MEDIAN_M = 1.0
MM_P5_M, MM_MEDIAN_M = 15.0, 40.0
_MIN_PIXELS = 50  # fewer non-zero pixels: too few to judge the scale
#: Fewer finite points are not judged by the statistical checks (a LiDAR sweep has thousands).
MIN_POINTS = 100


def sweep_problem(points: np.ndarray, *, intensity: np.ndarray | None = None,
                  ring: np.ndarray | None = None) -> str | None:
    """Why ``points`` cannot be one LiDAR sweep in metres (None: plausible).

    Args:
      points: (N, 3) real x, y, z about the sensor (or a nearby vehicle origin).
      intensity: (N,) real, the intensity / reflectance column, or None.
      ring: (N,) real, the beam index column, or None.

    Returns:
      A short sentence of what was measured, or None.
    """
    with np.errstate(all="ignore"):
        xyz = np.asarray(points, np.float64)
        finite = np.all(np.isfinite(xyz), axis=1)
        if not finite.any():
            return "no point has finite x, y, z"
        xyz = xyz[finite]
        if xyz.shape[0] < MIN_POINTS:
            return None
        horizontal = np.hypot(xyz[:, 0], xyz[:, 1])
        rng = np.hypot(horizontal, xyz[:, 2])
        in_range = float(np.mean((rng >= RANGE_MIN_M) & (rng <= RANGE_MAX_M)))
        if in_range < MIN_IN_RANGE_SHARE:
            return (f"only {100 * in_range:.0f} % of the ranges lie in {RANGE_MIN_M:g}-{RANGE_MAX_M:g} m "
                    f"(median {np.median(rng):.3g} m), expected most returns of a LiDAR there")
        elevation = np.degrees(np.arctan2(np.abs(xyz[:, 2]), horizontal))
        steep = float(np.mean(elevation > STEEP_DEG))
        if steep > MAX_STEEP_SHARE:
            return (f"{100 * steep:.0f} % of the points lie more than {STEEP_DEG:g} degrees above or below the "
                    f"horizontal (z holds values as large as x and y), expected at most "
                    f"{100 * MAX_STEEP_SHARE:.0f} % for a LiDAR")
        if intensity is not None:
            values = np.asarray(intensity, np.float64)
            bad = float(np.mean(~(np.isfinite(values) & (values >= INTENSITY_MIN) & (values <= INTENSITY_MAX))))
            if bad > 0.01:
                return (f"the intensity column (4th value) is outside {INTENSITY_MIN:g}..{INTENSITY_MAX:g} or not "
                        f"finite for {100 * bad:.0f} % of the points")
        if ring is not None:
            problem = _ring_problem(np.asarray(ring, np.float64)[finite], elevation_deg=np.degrees(
                np.arctan2(xyz[:, 2], horizontal)), rng=rng)
            if problem:
                return problem
    return None


def _ring_problem(ring: np.ndarray, *, elevation_deg: np.ndarray, rng: np.ndarray) -> str | None:
    ok = np.isfinite(ring) & (ring == np.round(ring)) & (ring >= 0) & (ring <= 1023)
    if not ok.all():
        return (f"the ring column (5th value) holds {int(np.count_nonzero(~ok))} values that are not integers "
                "0-1023, expected a beam index")
    far = rng > 2.0  # the beam's elevation about the origin, away from the sensor's own mount
    spreads = []
    for beam in np.unique(ring[far]):
        e = elevation_deg[far & (ring == beam)]
        if e.size >= 20:
            lo, hi = np.percentile(e, [10, 90])
            spreads.append(hi - lo)
    if spreads and float(np.median(spreads)) > MAX_RING_SPREAD_DEG:
        return (f"the points of one ring index spread over {float(np.median(spreads)):.1f} degrees of elevation "
                f"(median over rings), expected one beam each (at most {MAX_RING_SPREAD_DEG:g} degrees)")
    return None


#: Layouts tried by :func:`suggest_layouts`: (numpy dtype, values per point, description).
LAYOUTS = (("<f4", 3, "3 float32 per point (x, y, z)"),
           ("<f4", 4, "4 float32 per point (KITTI .bin: x, y, z, reflectance)"),
           ("<f4", 5, "5 float32 per point (nuScenes .pcd.bin: x, y, z, intensity, ring)"),
           ("<f4", 6, "6 float32 per point"),
           ("<f8", 3, "3 float64 per point"),
           ("<f8", 4, "4 float64 per point"),
           ("<f8", 5, "5 float64 per point"))


def decode_layout(raw: bytes, dtype: str, columns: int) -> np.ndarray | None:
    """(N, columns) array of ``raw`` in one layout; None when the size does not fit."""
    record = np.dtype(dtype).itemsize * columns
    if len(raw) == 0 or len(raw) % record:
        return None
    return np.frombuffer(raw, dtype).reshape(-1, columns)


def layout_problem(array: np.ndarray) -> str | None:
    """:func:`sweep_problem` of an (N, C) decoded record array (column 4 intensity, 5 ring)."""
    c = array.shape[1]
    return sweep_problem(array[:, :3], intensity=array[:, 3] if c >= 4 else None,
                         ring=array[:, 4] if c == 5 else None)


def suggest_layouts(raw: bytes, *, exclude: tuple | None = None) -> list[str]:
    """Descriptions of the :data:`LAYOUTS` under which ``raw`` decodes into a plausible sweep."""
    fits = []
    for dtype, columns, text in LAYOUTS:
        if exclude is not None and (dtype, columns) == exclude:
            continue
        array = decode_layout(raw, dtype, columns)
        if array is not None and layout_problem(array) is None:
            fits.append(text)
    return fits


def _forced(path: PathLike, problem: str) -> None:
    _LOG.warning("%s: --force: using it although %s", path, problem)


def check_sweep(points: np.ndarray, *, path: PathLike, columns: int | None = None,
                intensity: np.ndarray | None = None, ring: np.ndarray | None = None,
                raw: bytes | None = None, force: bool = False,
                columns_option: str | None = "--point-columns N") -> None:
    """Refuses a sweep no LiDAR produces (see module docs).

    Args:
      points: (N, 3) x, y, z metres as read.
      path: the file, named in the message.
      columns: values per point the file was read with (named in the message).
      intensity, ring: (N,) columns as read, or None.
      raw: the file's bytes; when given, a refusal lists the layouts they fit.
      force: log the problem as a warning instead of raising.
      columns_option: how the caller's user picks another layout, named after the layouts the bytes
        fit; None where the layout fixes the column count (KITTI raw / object jobs).

    Raises:
      InputError: ``<path>: not a plausible LiDAR sweep when read as ...: <measured>;
        the bytes fit ...``.
    """
    problem = sweep_problem(points, intensity=intensity, ring=ring)
    if problem is None:
        return
    if force:
        _forced(path, problem)
        return
    how = f" when read as {columns} float32 per point" if columns else ""
    hint = ""
    if raw is not None:
        fits = suggest_layouts(raw, exclude=("<f4", columns) if columns else None)
        how_else = (f" ({columns_option})" if columns_option else
                    f" (this dataset's sweeps are {columns} float32 per point: a file of another dataset?)")
        hint = ("; the bytes fit " + " or ".join(f"{f}?" for f in fits) + how_else) if fits else \
            "; no other layout (3-6 float32 or 3-5 float64 per point) fits either"
    raise file_error(path, f"not a plausible LiDAR sweep{how}: {problem}{hint}; --force uses it anyway")


def depth_scale_problem(depth_m: np.ndarray) -> str | None:
    """Why a depth image read as metres x 256 is in another scale (None: plausible).

    Args:
      depth_m: (H, W) real metres as read (value / 256), 0 = empty.
    """
    d = np.asarray(depth_m, np.float64)
    d = d[np.isfinite(d) & (d > 0)]
    if d.size < _MIN_PIXELS:
        return None
    raw = np.rint(d * 256.0)
    if np.all(raw % 256 == 0) and np.unique(raw).size >= 20:
        return ("every value is a multiple of 256 (whole metres): the depth seems scaled to integer metres, "
                "expected metres x 256")
    p5, median = (float(x) for x in np.percentile(d, [5, 50]))
    if median > DEPTH_MAX_MEDIAN_M:
        return f"median depth {median:.1f} m is beyond a LiDAR's range: the values seem to be in another unit"
    if p5 > MM_P5_M and median > MM_MEDIAN_M:
        return (f"5th percentile {p5:.1f} m and median {median:.1f} m as metres x 256, i.e. {p5 * 256 / 1000:.1f} m "
                f"and {median * 256 / 1000:.1f} m as millimetres: the PNG seems to hold millimetres, expected "
                "metres x 256 (KITTI)")
    if median < DEPTH_MIN_MEDIAN_M:
        return (f"median depth {median:.2f} m (as metres x 256) is too close for a LiDAR: the values seem to be "
                "in a coarser unit (decimetres?) or normalised")
    return None


def check_depth_scale(depth_m: np.ndarray, *, path: PathLike, role: str = "depth image",
                      force: bool = False) -> None:
    """Refuses a depth PNG whose values cannot be metres x 256 (see module docs).

    Args:
      depth_m: (H, W) metres as read by :func:`jaxdepth.io.depth_png.read_depth_png`.
      path: the file, named in the message. role: what it is ("LiDAR input", "ground truth").
      force: log the problem as a warning instead of raising.

    Raises:
      InputError: ``<path>: <role> is not in metres x 256: <measured>``.
    """
    problem = depth_scale_problem(depth_m)
    if problem is None:
        return
    if force:
        _forced(path, problem)
        return
    raise file_error(path, f"{role} is not in metres x 256: {problem}; --force uses it anyway")


def read_checked_depth_png(path: PathLike, *, role: str, force: bool = False) -> np.ndarray:
    """:func:`jaxdepth.io.depth_png.read_depth_png` followed by :func:`check_depth_scale`."""
    from jaxdepth.io.depth_png import read_depth_png
    depth = read_depth_png(path)
    check_depth_scale(depth, path=pathlib.Path(path), role=role, force=force)
    return depth


__all__ = ["check_sweep", "sweep_problem", "suggest_layouts", "decode_layout", "layout_problem", "LAYOUTS",
           "check_depth_scale", "depth_scale_problem", "read_checked_depth_png", "InputError"]
