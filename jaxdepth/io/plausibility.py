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

Far points (:func:`drop_far_points`): a return farther than :func:`max_range_m` from the
sensor (default :data:`MAX_RANGE_M` = 1000 m, ``JAXDEPTH_MAX_RANGE_M`` overrides) is no LiDAR
measurement: automotive LiDARs reach 100-300 m (HDL-64E 120 m, VLP-32C 200 m, long-range units
250-600 m). One such point (a driver's glitch, a corrupted record) is not worth refusing the sweep
for, but kept it would be completed like any other: it is dropped (set to NaN, like a missing
return) and a one-line warning names the file, the count, the farthest range and the limit
(``--force`` keeps them, as read, and says so).

Every check raises :class:`~jaxdepth.io.errors.InputError` naming the file, what was
measured and what it seems to be. Callers that know better pass ``force=True`` to the
readers (``--force`` on the command line), which logs the override as a warning.
"""

from __future__ import annotations

import logging
import os
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
#: Farthest plausible LiDAR return, metres (module docs); ``JAXDEPTH_MAX_RANGE_M`` overrides it.
MAX_RANGE_M = 1000.0
MAX_RANGE_ENV = "JAXDEPTH_MAX_RANGE_M"
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


def max_range_m() -> float:
    """The far-point limit in metres: ``JAXDEPTH_MAX_RANGE_M`` if set, else :data:`MAX_RANGE_M`.

    Raises:
      InputError: the variable is not a positive number.
    """
    text = os.environ.get(MAX_RANGE_ENV)
    if text is None or not text.strip():
        return MAX_RANGE_M
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and value > 0):
        raise InputError(f"environment variable {MAX_RANGE_ENV}: expected a positive number of metres, got {text!r}")
    return value


def far_point_mask(points: np.ndarray, *, limit_m: float | None = None) -> np.ndarray:
    """(N,) bool: finite points whose range about the origin exceeds ``limit_m`` (default :func:`max_range_m`).

    >>> far_point_mask(np.array([[10.0, 0, 0], [1e6, 0, 0], [np.nan, 0, 0]]), limit_m=1000.0).tolist()
    [False, True, False]
    """
    limit = max_range_m() if limit_m is None else float(limit_m)
    with np.errstate(all="ignore"):
        xyz = np.asarray(points, np.float64)[:, :3]
        rng = np.sqrt(np.sum(xyz * xyz, axis=1))  # float64: no overflow below 1e150
    # A finite point whose squared range overflows (float64 input near 1e308) is far too.
    return (rng > limit) & np.all(np.isfinite(xyz), axis=1)


def report_far_points(path: PathLike, points: np.ndarray, far: np.ndarray, *, limit_m: float | None = None,
                      kept: bool = False) -> str:
    """Logs (and returns) the one-line warning for the ``far`` (N,) points of ``points``: dropped, or
    ``kept`` (``--force``)."""
    limit = max_range_m() if limit_m is None else float(limit_m)
    with np.errstate(all="ignore"):
        farthest = float(np.max(np.linalg.norm(np.asarray(points, np.float64)[far, :3], axis=1)))
    count = int(np.count_nonzero(far))
    what = "--force: keeping" if kept else "dropped"
    text = (f"{path}: {what} {count} point{'s' if count != 1 else ''} farther than {limit:g} m from the sensor "
            f"(farthest {farthest:.3g} m): beyond any automotive LiDAR's range, not a measurement "
            f"({MAX_RANGE_ENV} sets the limit)")
    _LOG.warning("%s", text)
    return text


def drop_far_points(points: np.ndarray, *, path: PathLike, limit_m: float | None = None,
                    force: bool = False) -> np.ndarray:
    """``points`` with x, y, z of every point farther than the limit set to NaN (a missing return), warned once.

    Args:
      points: (N, C) real, x, y, z first, metres about the sensor (or the file's origin).
      path: the file, named in the warning.
      limit_m: the limit, default :func:`max_range_m`.
      force: keep them (``--force``: the input is used as read), still warned.

    Returns:
      ``points`` itself when no point is that far (or ``force``), else a float copy with those rows NaN.
    """
    far = far_point_mask(points, limit_m=limit_m)
    if not far.any():
        return points
    report_far_points(path, points, far, limit_m=limit_m, kept=force)
    if force:
        return points
    out = np.array(points, dtype=np.result_type(np.asarray(points).dtype, np.float32), copy=True)
    out[far, :3] = np.nan
    return out


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


#: Ground fit of :func:`sweep_ground`: horizontal distances of the candidate points (metres), the
#: height bin and band (metres), the fewest band points (absolute and share of the candidates).
GROUND_RING_M = (2.0, 40.0)
GROUND_BIN_M, GROUND_BAND_M = 0.1, 0.25
GROUND_MIN_POINTS, GROUND_MIN_SHARE = 200, 0.10
#: The band must spread at least this far (metres, standard deviation across its narrowest horizontal
#: direction): a ground is a surface around the vehicle, not one beam's line on a wall.
GROUND_MIN_SPREAD_M = 1.0
#: At most this many points (every k-th of the sweep) go into the ground fit.
GROUND_SAMPLE = 32768
#: Largest angle between a camera's up axis (-y) and the ground's normal, degrees: a camera on a
#: vehicle looks at the road, not at the sky or sideways (real rigs: <= 2.4 deg).
MAX_CAMERA_TILT_DEG = 45.0


def sweep_ground(points: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The ground plane of a sweep: ``(n (3,), d)`` with ``n . p + d = 0``, ``n`` pointing up; None if unclear.

    The points' frame has z along the LiDAR's spin axis, up (the range image's convention, which
    Steps 1-2 already rely on). The ground is the most populated 10 cm height bin at or below the
    origin among the points 2-40 m away horizontally (the road around the vehicle); a plane is
    fitted by least squares to the points within 25 cm of it. Too few points there, or points along a
    line (spread under :data:`GROUND_MIN_SPREAD_M` across it: a wall's beam): None. At
    most :data:`GROUND_SAMPLE` points (every k-th) are used.

    Args:
      points: (N, 3) real metres (NaN rows ignored).
    """
    xyz = np.asarray(points)[:, :3]
    xyz = xyz[::max(1, xyz.shape[0] // GROUND_SAMPLE)]  # every k-th point: all azimuths, bounded cost
    with np.errstate(all="ignore"):
        xyz = xyz.astype(np.float64)
        xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
        horizontal = np.hypot(xyz[:, 0], xyz[:, 1])
        near = xyz[(horizontal >= GROUND_RING_M[0]) & (horizontal <= GROUND_RING_M[1])]
    low = near[near[:, 2] <= GROUND_BAND_M]
    if low.shape[0] < GROUND_MIN_POINTS:
        return None
    bins = np.floor(low[:, 2] / GROUND_BIN_M).astype(np.int64)
    counts = np.bincount(bins - bins.min())
    height = (bins.min() + np.argmax(counts) + 0.5) * GROUND_BIN_M
    band = low[np.abs(low[:, 2] - height) <= GROUND_BAND_M]
    if band.shape[0] < max(GROUND_MIN_POINTS, GROUND_MIN_SHARE * near.shape[0]):
        return None
    if np.sqrt(max(np.linalg.eigvalsh(np.cov(band[:, :2].T))[0], 0.0)) < GROUND_MIN_SPREAD_M:
        return None  # the band is a line (one beam on a wall), not a surface around the vehicle
    A = np.column_stack([band[:, 0], band[:, 1], np.ones(band.shape[0])])
    (a, b, c), *_ = np.linalg.lstsq(A, band[:, 2], rcond=None)
    n = np.array([-a, -b, 1.0]) / np.sqrt(a * a + b * b + 1.0)
    return n, float(-c * n[2])


def _tilt_deg(T: np.ndarray, normal: np.ndarray) -> float:
    """Angle between the camera's up axis (-y, in the points' frame: -R[1]) and the ground's normal."""
    return float(np.degrees(np.arccos(np.clip(-T[1, :3] @ normal, -1.0, 1.0))))


#: Projection checks (:func:`projection_problem`): points nearer than this in front of a camera are
#: not used (metres); fewer in-image points than this are not judged.
PROJECT_MIN_DEPTH_M, PROJECT_MIN_POINTS = 1.0, 100
#: At most about this many points (every k-th of the sweep) are projected: >= 800 land in each real
#: camera's image, enough for the 1-99 % band.
PROJECT_SAMPLE = 8192
#: Smallest share of the points within K's own view (the image a centred principal point implies,
#: 2 cx x 2 cy) that must land in the image (real rigs: >= 0.86; K x 1.5 on KITTI: 0.33-0.42).
MIN_VIEW_SHARE = 0.5
#: Rows (columns) of the in-image points, 1-99 %: the band spans at least this share of the height
#: (width) and reaches past the outer edge share (real rigs: spans >= 0.46, rows 0.38-0.79 always
#: inside the band, columns 0.12-0.90).
MIN_BAND_SPAN, EDGE_SHARE = 0.3, 0.4


def _swapped_size(K: np.ndarray, width: int, height: int) -> bool:
    """The principal point is off-centre in the width x height image and centred in height x width."""
    from jaxdepth.io.checks import CENTRE_TOL
    cx, cy = float(K[0, 2]), float(K[1, 2])

    def centred(w: float, h: float) -> bool:
        return abs(cx / w - 0.5) <= CENTRE_TOL and abs(cy / h - 0.5) <= CENTRE_TOL

    return width != height and not centred(width, height) and centred(height, width)


def _project(points: np.ndarray, K: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(M, 2) pixel coordinates (u, v) of the finite points at least PROJECT_MIN_DEPTH_M in front."""
    with np.errstate(all="ignore"):
        xyz = np.asarray(points, np.float64)[:, :3]
        xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
        cam = xyz @ T[:3, :3].T + T[:3, 3]
    cam = cam[cam[:, 2] >= PROJECT_MIN_DEPTH_M]
    pixel = cam @ K.T  # K's last row is (0, 0, 1): the third column is the depth
    return pixel[:, :2] / pixel[:, 2:3]


def _band_problem(coords: np.ndarray, size: int, axis: str) -> str | None:
    """Why the points' ``axis`` coordinates (rows or columns) in an image ``size`` long look wrong."""
    lo, hi = (float(x) / size for x in np.percentile(coords, [1, 99]))
    where = f"fill only {axis} {lo * size:.0f}-{hi * size:.0f} of {size}"
    if hi - lo < MIN_BAND_SPAN:
        return f"the sweep's points {where} (a thin band)"
    edge = ("top", "bottom") if axis == "rows" else ("left", "right")
    if hi < EDGE_SHARE:
        return f"the sweep's points {where} (only at the {edge[0]} edge)"
    if lo > 1.0 - EDGE_SHARE:
        return f"the sweep's points {where} (only at the {edge[1]} edge)"
    return None


def projection_problem(points: np.ndarray, K: np.ndarray, T_cam_lidar: np.ndarray, width: int,
                       height: int) -> tuple[str, str] | None:
    """``(field, what is wrong)`` when the sweep projects into the image as no camera on a vehicle sees it.

    Projected density: of the points within K's own view (the ``2 cx x 2 cy`` image a centred principal
    point implies), at least :data:`MIN_VIEW_SHARE` land in the image (else K is made for a larger
    image). Field of view: a LiDAR scans every azimuth and the ground to a few metres, so the
    in-image points span the image's width and its rows from near the horizon down; a thin band
    (under :data:`MIN_BAND_SPAN` of the rows or columns) or a band only at one edge (inside the
    outer :data:`EDGE_SHARE`) means the image's rows do not match the LiDAR's vertical field of view.
    Fewer than :data:`PROJECT_MIN_POINTS` points in the view or the image: not judged. About
    :data:`PROJECT_SAMPLE` points (every k-th) are projected.

    Args:
      points: (N, 3) the sweep in the frame ``T_cam_lidar`` (4, 4) maps from; K: (3, 3); width,
        height: pixels.
    """
    K = np.asarray(K, np.float64)
    points = np.asarray(points)[::max(1, np.shape(points)[0] // PROJECT_SAMPLE)]  # every k-th: bounded cost
    uv = _project(points, K, np.asarray(T_cam_lidar, np.float64))
    u, v = uv[:, 0], uv[:, 1]
    view = (u >= 0) & (u < 2 * K[0, 2]) & (v >= 0) & (v < 2 * K[1, 2])
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    n_view, n_in = int(np.count_nonzero(view)), int(np.count_nonzero(inside))
    if n_view >= PROJECT_MIN_POINTS and n_in / n_view < MIN_VIEW_SHARE:
        return "K", (f"only {100 * n_in / n_view:.0f} % of the sweep's points in K's view land in the "
                     f"{width}x{height} image: K seems made for a larger image (principal point "
                     f"({K[0, 2]:.0f}, {K[1, 2]:.0f}): K scaled, or the image size of another camera?)")
    if n_in < PROJECT_MIN_POINTS:
        return None
    for coords, size, axis in ((v[inside], height, "rows"), (u[inside], width, "columns")):
        problem = _band_problem(coords, size, axis)
        if problem:
            return "K", (f"{problem}: the image does not fit the LiDAR's field of view (K's focal length or "
                         "the image size of another camera, or T_cam_lidar of another sensor?)")
    return None


def camera_geometry_problem(K: np.ndarray, T_cam_lidar: np.ndarray, width: int, height: int, *,
                            ground: tuple[np.ndarray, float] | None,
                            points: np.ndarray | None = None) -> tuple[str, str] | None:
    """``(field, what is wrong)`` when a camera's calibration cannot fit the sweep; None: plausible.

    In this order: K scaled for another image size (principal point), width and height swapped,
    the ground not below the camera (``ground``), then :func:`projection_problem` (``points``).

    Args:
      K: (3, 3); T_cam_lidar: (4, 4) points' frame -> camera; width, height: pixels.
      ground: :func:`sweep_ground` of the sweep in the points' frame, or None: a sweep without a clear
        ground (not a street) is judged by neither the ground nor the projection.
      points: (N, 3) the sweep in the points' frame, or None (projection not judged).
    """
    from jaxdepth.io.checks import principal_point_scale
    K = np.asarray(K, np.float64)
    T = np.asarray(T_cam_lidar, np.float64)
    s = principal_point_scale(K, width, height)
    if s is not None:
        return "K", (f"K seems scaled by {s:g} for this image size: principal point ({K[0, 2]:.0f}, {K[1, 2]:.0f}) in "
                     f"a {width}x{height} image, K x {1 / s:g} puts it near the centre (scale K with the image)")
    if _swapped_size(K, width, height):
        return "width, height", (f"the image size {width}x{height} seems swapped: the principal point "
                                 f"({K[0, 2]:.0f}, {K[1, 2]:.0f}) is near the centre of a {height}x{width} image")
    if ground is None:  # no street around the vehicle: neither the ground nor the projection is judged
        return None
    problem = _ground_problem(T, ground)
    if problem is None and points is not None:
        problem = projection_problem(points, K, T, width, height)
    return problem


def _ground_problem(T: np.ndarray, ground: tuple[np.ndarray, float]) -> tuple[str, str] | None:
    """The ground check of :func:`camera_geometry_problem` (``T`` (4, 4) float64)."""
    normal, d = ground
    tilt = _tilt_deg(T, normal)
    centre = -T[:3, :3].T @ T[:3, 3]
    above = float(normal @ centre + d)
    if tilt <= MAX_CAMERA_TILT_DEG and above > 0:
        return None
    where = (f"the sweep's ground is {tilt:.0f} deg from below the camera (a camera on a vehicle: under "
             f"{MAX_CAMERA_TILT_DEG:g}), the camera {above:+.2f} m above it")
    inverse = np.linalg.inv(T)
    inv_above = float(normal @ (-inverse[:3, :3].T @ inverse[:3, 3]) + d)
    if _tilt_deg(inverse, normal) <= MAX_CAMERA_TILT_DEG and inv_above > 0:
        return "T_cam_lidar", (f"T_cam_lidar looks inverted: {where}; with its inverse "
                               f"{_tilt_deg(inverse, normal):.0f} deg (it seems to map the camera into the LiDAR "
                               "frame: write its inverse)")
    return "T_cam_lidar", (f"T_cam_lidar does not fit the sweep: {where} (another sensor's frame, or its axes "
                           "swapped?)")


def check_rig_geometry(points: np.ndarray, cameras, *, path: PathLike, force: bool = False) -> None:
    """Refuses a calibration that cannot fit the sweep: a K scaled for another image size, width and height
    swapped, a camera the sweep's ground is not below (an inverted or foreign T_cam_lidar), an image that
    holds less than half of K's view or gets the sweep's points only in a thin band or at one edge
    (:func:`projection_problem`). See docs/bad_input_checks.md.

    Args:
      points: (N, 3) the sweep in the frame every ``T_cam_lidar`` maps from (z up).
      cameras: objects with ``K``, ``T_cam_lidar``, ``width``, ``height`` and optionally ``name``
        (rig cameras, :class:`jaxdepth.Camera`).
      path: the file that holds the calibration, named in the message.
      force: log the problem as a warning instead of raising.

    Raises:
      InputError: ``<path>: camera '<name>' field '<K | width, height | T_cam_lidar>': <what is wrong>;
        --force uses it anyway``
        (the first camera; the others with the same problem are counted).
    """
    ground = sweep_ground(points)
    found = [(getattr(c, "name", f"#{i}"), camera_geometry_problem(np.asarray(c.K), np.asarray(c.T_cam_lidar),
                                                                   int(c.width), int(c.height), ground=ground,
                                                                   points=points))
             for i, c in enumerate(cameras)]
    found = [(name, p) for name, p in found if p is not None]
    if not found:
        return
    name, (field, problem) = found[0]
    others = f" (also {', '.join(n for n, _ in found[1:])})" if len(found) > 1 else ""
    text = f"camera '{name}'{others} field '{field}': {problem}"
    if force:
        _forced(path, text)
        return
    raise file_error(path, f"{text}; --force uses it anyway")


def depth_scale_problem(depth_m: np.ndarray) -> str | None:
    """Why a depth image read as metres x 256 is in another scale (None: plausible).

    Args:
      depth_m: (H, W) real metres as read (value / 256), 0 = empty.
    """
    a = np.asarray(depth_m)
    # Only the pixels with depth become float64 (KITTI: 4 % of the image), not the whole image.
    d = a.ravel()[np.flatnonzero(np.isfinite(a) & (a > 0))].astype(np.float64)
    if d.size < _MIN_PIXELS:
        return None
    raw = np.rint(d * 256.0)
    # raw % 256 == 0 without float64 remainders (~20 ns each): raw / 256 is exact, and whole.
    quotient = raw * (1.0 / 256.0)
    if np.isfinite(raw).all() and np.all(np.floor(quotient) == quotient) and np.unique(raw).size >= 20:
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


__all__ = ["check_sweep", "check_rig_geometry", "camera_geometry_problem", "projection_problem", "sweep_ground", "drop_far_points", "far_point_mask", "report_far_points", "max_range_m", "MAX_RANGE_M", "sweep_problem", "suggest_layouts", "decode_layout", "layout_problem", "LAYOUTS",
           "check_depth_scale", "depth_scale_problem", "read_checked_depth_png", "InputError"]
