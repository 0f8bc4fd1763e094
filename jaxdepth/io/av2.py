"""Argoverse 2 sensor logs -> :class:`~jaxdepth.io.sources.SourceCloud` + :class:`~jaxdepth.io.rig.Rig` (host side).

Reads one log folder of the Argoverse 2 *sensor* dataset with ``pyarrow`` alone
(``pip install 'jaxdepth[av2]'``; the official ``av2`` package pulls PyTorch and the
non-headless OpenCV). Layout and columns, as published by the dataset::

    <log>/sensors/lidar/<timestamp_ns>.feather        x, y, z (float16 or float32, metres, ego frame),
                                                      intensity (uint8), laser_number (uint8), offset_ns (int32)
    <log>/calibration/egovehicle_SE3_sensor.feather   sensor_name, qw, qx, qy, qz, tx_m, ty_m, tz_m
    <log>/calibration/intrinsics.feather              sensor_name, fx_px, fy_px, cx_px, cy_px, k1, k2, k3,
                                                      height_px, width_px
    <log>/city_SE3_egovehicle.feather                 timestamp_ns, qw, qx, qy, qz, tx_m, ty_m, tz_m
    <log>/sensors/cameras/<camera>/<timestamp_ns>.jpg (optional; only the names, the images' timestamps,
                                                      are read)

Conventions:

* ``A_SE3_B`` rows are poses of frame B in frame A (they map B coordinates to A),
  quaternion scalar first ``(qw, qx, qy, qz)``.
* Points are in the ego-vehicle frame at the sweep's timestamp (x forward, y left, z up,
  origin under the rear axle, about 0.4 m above the road). The sweep is a merged cloud of
  two Velodyne VLP-32C: ``laser_number`` 0-31 is ``up_lidar``, 32-63 ``down_lidar``
  (mounted upside down, 11 cm lower). Each LiDAR is one source with its calibrated pose
  ``egovehicle_SE3_<lidar>``; ``ring = laser_number mod 32`` is the laser within its LiDAR.
  By default no spec is stated (``lidars`` None): each source gets one range-image row per laser,
  ranked by the laser's elevation about its own LiDAR, and its field of view from those elevations
  (:func:`jaxdepth.batch.sources_job.source_spec`). A stated uniform spec instead puts the
  VLP-32C's unevenly spaced lasers on 18 of 32 rows (several lasers per row near the horizon).
* Camera time (the devkit's motion-compensated projection): a camera image taken at ``t_cam``
  sees the sweep's ego-frame points (ego pose at the sweep's ``t_lidar``) through
  ``T_cam_ego = inv(egovehicle_SE3_cam) @ inv(city_SE3_ego(t_cam)) @ city_SE3_ego(t_lidar)``
  (:func:`camera_from_ego`). The image paired with a sweep (:func:`paired_image`) is the camera's
  image nearest in time to the sweep, provided the sweep is also the sweep nearest to that image
  (so no image is paired with two sweeps); ties go to the later image and the earlier sweep.
* Cameras: ``T_cam_lidar = inv(egovehicle_SE3_<camera>)`` maps ego-frame points into the
  camera frame, which is OpenCV's (x right, y down, z forward). ``K`` is the pinhole part of
  the intrinsics; the radial distortion ``k1..k3`` is not applied (the depth images are on
  the distorted image's pixel grid only to first order: at the corners of the ring cameras
  this is tens of pixels, so undistort images before pairing them with the depth).
* Several sweeps (``sweeps = N``: up to N neighbours on each side of the reference sweep):
  sweep ``j``'s points and LiDAR poses are moved into the reference sweep's ego frame with
  the city poses, ``T_ref_sweep = inv(city_SE3_ego(t_ref)) @ city_SE3_ego(t_j)``. The ego pose
  at a sweep's timestamp is the table's row at that timestamp, else interpolated between the
  two rows around it (linear in translation, spherical-linear in rotation); a timestamp outside
  the table is an error.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np

from jaxdepth.io.errors import InputError, PathLike, field_error, file_error

#: The seven ring cameras (the stereo pair is not completed by default).
RING_CAMERAS = ("ring_front_center", "ring_front_left", "ring_front_right", "ring_rear_left",
                "ring_rear_right", "ring_side_left", "ring_side_right")
#: (LiDAR sensor name, first laser_number): each LiDAR has LASERS_PER_LIDAR lasers.
LIDARS = (("up_lidar", 0), ("down_lidar", 32))
LASERS_PER_LIDAR = 32

_POSE_COLUMNS = ("qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
_INTRINSIC_COLUMNS = {"fx_px": "f", "fy_px": "f", "cx_px": "f", "cy_px": "f", "height_px": "i", "width_px": "i"}


def _pyarrow_feather():
    try:
        import pyarrow.feather as feather
    except ImportError:  # pragma: no cover - depends on the environment
        raise InputError("reading Argoverse 2 logs needs pyarrow: pip install 'jaxdepth[av2]'") from None
    return feather


def read_feather_columns(path: PathLike, columns: dict, *, expected: str) -> dict:
    """The named columns of a Feather file as NumPy arrays.

    Args:
      path: the ``.feather`` file.
      columns: column name -> dtype kind it must have: ``"f"`` float, ``"i"`` integer
        (signed or unsigned), ``"U"`` string.
      expected: what the file is, for the "not found" message.

    Raises:
      InputError: the file is missing or not Feather, a column is missing, has nulls or has
        the wrong type; the message names the file and the column.
    """
    feather = _pyarrow_feather()
    path = pathlib.Path(path)
    if not path.is_file():
        raise file_error(path, f"file not found, expected {expected}")
    try:
        table = feather.read_table(path)
    except Exception as err:  # pyarrow raises ArrowInvalid / OSError for non-Feather bytes
        raise file_error(path, f"cannot read as Arrow/Feather ({expected}): {err}") from None
    out = {}
    kinds = {"f": "floats", "i": "integers", "U": "strings"}
    for name, kind in columns.items():
        if name not in table.column_names:
            raise field_error(path, name, f"a column of {kinds[kind]}", f"no such column (columns: "
                                                                       f"{', '.join(table.column_names)})")
        col = table.column(name)
        if col.null_count:
            raise field_error(path, name, f"a column of {kinds[kind]} without nulls", f"{col.null_count} nulls")
        if kind == "U":
            values = np.asarray(col.to_pylist(), dtype=object)
            ok = all(isinstance(v, str) for v in values)
        else:
            values = col.to_numpy()
            ok = values.dtype.kind == kind or (kind == "i" and values.dtype.kind == "u")
        if not ok:
            raise field_error(path, name, f"a column of {kinds[kind]}", f"type {col.type}")
        out[name] = values
    return out


def _quaternion_pose(row: dict, i: int, where: str) -> np.ndarray:
    from jaxdepth._src.poses import pose_matrix
    try:
        return pose_matrix([row[k][i] for k in ("tx_m", "ty_m", "tz_m")],
                           [row[k][i] for k in ("qw", "qx", "qy", "qz")], where=where)
    except ValueError as err:
        raise InputError(str(err)) from None


@dataclasses.dataclass(frozen=True)
class Av2Log:
    """The calibration, city poses and sweep list of one log.

    Attributes:
      folder: the log folder.
      sweeps: sorted int64 timestamps (ns) of the LiDAR sweeps (``sensors/lidar/<ts>.feather``).
      sensor_poses: sensor name -> (4, 4) float64 ``egovehicle_SE3_sensor``.
      intrinsics: camera name -> (K (3, 3) float64, width, height).
      city_times: (M,) sorted int64 timestamps of the city poses, ns.
      city_poses: (M, 4, 4) float64 ``city_SE3_egovehicle``.
      camera_times: camera name -> (K,) sorted int64 timestamps (ns) of its images
        (``sensors/cameras/<camera>/<ts>.jpg``), for the cameras that have a folder there.
    """

    folder: pathlib.Path
    sweeps: tuple
    sensor_poses: dict
    intrinsics: dict
    city_times: np.ndarray
    city_poses: np.ndarray
    camera_times: dict = dataclasses.field(default_factory=dict)

    def sweep_path(self, timestamp_ns: int) -> pathlib.Path:
        return self.folder / "sensors" / "lidar" / f"{int(timestamp_ns)}.feather"

    @property
    def calibration_path(self) -> pathlib.Path:
        return self.folder / "calibration" / "egovehicle_SE3_sensor.feather"

    @property
    def intrinsics_path(self) -> pathlib.Path:
        return self.folder / "calibration" / "intrinsics.feather"

    @property
    def city_path(self) -> pathlib.Path:
        return self.folder / "city_SE3_egovehicle.feather"

    def sensor_pose(self, name: str) -> np.ndarray:
        """(4, 4) ``egovehicle_SE3_<name>``; InputError naming the calibration file when absent."""
        if name not in self.sensor_poses:
            raise field_error(self.calibration_path, "sensor_name", f"a row for {name!r}",
                              f"sensors {sorted(self.sensor_poses)}")
        return self.sensor_poses[name]


def is_av2_log(folder: PathLike) -> bool:
    """True when ``folder`` looks like an Argoverse 2 sensor log (LiDAR sweeps and calibration)."""
    folder = pathlib.Path(folder)
    return (folder / "sensors" / "lidar").is_dir() and (folder / "calibration").is_dir()


def read_log(folder: PathLike) -> Av2Log:
    """Reads a log's calibration, intrinsics, city poses and sweep list (not the sweeps).

    Raises:
      InputError: the folder has no LiDAR sweeps, a table is missing, a column is missing or of
        the wrong type, a pose is not a unit quaternion; the message names the file and field.
    """
    folder = pathlib.Path(folder)
    lidar_dir = folder / "sensors" / "lidar"
    if not lidar_dir.is_dir():
        raise file_error(folder, "not an Argoverse 2 sensor log (expected sensors/lidar/<timestamp_ns>.feather)")
    stamps = []
    for p in lidar_dir.glob("*.feather"):
        if not p.stem.isdigit():
            raise file_error(p, "expected a LiDAR sweep named <timestamp_ns>.feather")
        stamps.append(int(p.stem))
    if not stamps:
        raise file_error(lidar_dir, "no LiDAR sweeps (<timestamp_ns>.feather) found")
    pose_cols = {k: "f" for k in _POSE_COLUMNS}
    log_paths = dict(calibration=folder / "calibration" / "egovehicle_SE3_sensor.feather",
                     intrinsics=folder / "calibration" / "intrinsics.feather",
                     city=folder / "city_SE3_egovehicle.feather")
    cal = read_feather_columns(log_paths["calibration"], {"sensor_name": "U", **pose_cols},
                               expected="the sensor calibration (egovehicle_SE3_sensor)")
    sensor_poses = {}
    for i, name in enumerate(cal["sensor_name"]):
        sensor_poses[str(name)] = _pose_or_error(cal, i, log_paths["calibration"], str(name))
    intr = read_feather_columns(log_paths["intrinsics"], {"sensor_name": "U", **_INTRINSIC_COLUMNS},
                                expected="the camera intrinsics")
    intrinsics = {}
    for i, name in enumerate(intr["sensor_name"]):
        K = np.array([[intr["fx_px"][i], 0.0, intr["cx_px"][i]], [0.0, intr["fy_px"][i], intr["cy_px"][i]],
                      [0.0, 0.0, 1.0]])
        w, h = int(intr["width_px"][i]), int(intr["height_px"][i])
        if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0 and w > 0 and h > 0):
            raise field_error(log_paths["intrinsics"], f"{name}.fx_px/fy_px/width_px/height_px",
                              "positive focal lengths and image size", f"K={K.tolist()}, size {w}x{h}")
        intrinsics[str(name)] = (K, w, h)
    city = read_feather_columns(log_paths["city"], {"timestamp_ns": "i", **pose_cols},
                                expected="the ego poses (city_SE3_egovehicle)")
    times = city["timestamp_ns"].astype(np.int64)
    order = np.argsort(times, kind="stable")
    if times.size == 0:
        raise field_error(log_paths["city"], "timestamp_ns", "at least one ego pose", "no rows")
    if np.any(np.diff(times[order]) == 0):
        dup = int(times[order][np.flatnonzero(np.diff(times[order]) == 0)[0]])
        raise field_error(log_paths["city"], "timestamp_ns", "distinct timestamps", f"{dup} twice")
    poses = np.stack([_pose_or_error(city, int(i), log_paths["city"], f"timestamp_ns {times[i]}") for i in order])
    return Av2Log(folder=folder, sweeps=tuple(sorted(stamps)), sensor_poses=sensor_poses, intrinsics=intrinsics,
                  city_times=times[order], city_poses=poses, camera_times=_camera_times(folder))


def _camera_times(folder: pathlib.Path) -> dict:
    """camera name -> sorted int64 image timestamps of ``<log>/sensors/cameras/<camera>/<ts>.jpg``."""
    root = folder / "sensors" / "cameras"
    out = {}
    if not root.is_dir():
        return out
    for cam_dir in sorted(p for p in root.iterdir() if p.is_dir()):
        stamps = []
        for p in cam_dir.glob("*.jpg"):
            if not p.stem.isdigit():
                raise file_error(p, "expected a camera image named <timestamp_ns>.jpg")
            stamps.append(int(p.stem))
        if stamps:
            out[cam_dir.name] = np.array(sorted(stamps), np.int64)
    return out


def _pose_or_error(table: dict, i: int, path: pathlib.Path, row: str) -> np.ndarray:
    try:
        return _quaternion_pose(table, i, row)
    except InputError as err:
        raise file_error(path, str(err)) from None


def interpolate_pose(times: np.ndarray, poses: np.ndarray, t: int, *, path: PathLike = "poses") -> np.ndarray:
    """(4, 4) pose at time ``t`` from sorted ``times`` (M,) and ``poses`` (M, 4, 4).

    A row at ``t`` is returned as is; between two rows, translation is linear and rotation
    spherical-linear in time. InputError (naming ``path``) when ``t`` is outside the table.

    >>> T0, T1 = np.eye(4), np.eye(4)
    >>> T1[:3, 3] = (2.0, 0.0, 0.0)
    >>> interpolate_pose(np.array([0, 10]), np.stack([T0, T1]), 5)[:3, 3].tolist()
    [1.0, 0.0, 0.0]
    """
    times = np.asarray(times, np.int64)
    t = int(t)
    k = int(np.searchsorted(times, t))
    if k < times.size and times[k] == t:
        return np.array(poses[k], np.float64)
    if k == 0 or k == times.size:
        raise field_error(path, "timestamp_ns", f"ego poses around {t} (a sweep's timestamp)",
                          f"poses from {int(times[0])} to {int(times[-1])}")
    t0, t1 = int(times[k - 1]), int(times[k])
    a = (t - t0) / (t1 - t0)
    P0, P1 = poses[k - 1], poses[k]
    from jaxdepth._src.poses import slerp_rotation
    out = np.eye(4)
    out[:3, :3] = slerp_rotation(P0[:3, :3], P1[:3, :3], a)
    out[:3, 3] = (1 - a) * P0[:3, 3] + a * P1[:3, 3]
    return out


def ego_pose(log: Av2Log, timestamp_ns: int) -> np.ndarray:
    """(4, 4) float64 ``city_SE3_egovehicle`` at ``timestamp_ns`` (:func:`interpolate_pose`)."""
    return interpolate_pose(log.city_times, log.city_poses, timestamp_ns, path=log.city_path)


def read_sweep(path: PathLike, *, force: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``(points (N, 3) float32 metres ego frame, laser_number (N,) int32)`` of one sweep file.

    The points and intensities pass :func:`jaxdepth.io.plausibility.check_sweep` (ranges, share of
    steep points, intensity) unless ``force`` (then a failure is logged). Its ring test is not run:
    about the ego frame's origin, 1.5 m below the LiDARs, a laser's points spread over ~5 degrees.
    Points beyond any LiDAR's range are dropped with a warning
    (:func:`jaxdepth.io.plausibility.far_point_mask`).

    Raises:
      InputError: a missing column, a wrong type, non-finite coordinates, a laser number
        outside [0, 64) or an implausible sweep; the message names the file and the column.
    """
    from jaxdepth.io.plausibility import check_sweep, far_point_mask, report_far_points

    path = pathlib.Path(path)
    cols = read_feather_columns(path, {"x": "f", "y": "f", "z": "f", "intensity": "i", "laser_number": "i"},
                                expected="an Argoverse 2 LiDAR sweep")
    points = np.stack([cols[k].astype(np.float32) for k in "xyz"], axis=1)
    laser = cols["laser_number"].astype(np.int64)
    n_lasers = LASERS_PER_LIDAR * len(LIDARS)
    if laser.size and (laser.min() < 0 or laser.max() >= n_lasers):
        bad = int(laser[(laser < 0) | (laser >= n_lasers)][0])
        raise field_error(path, "laser_number", f"laser numbers in [0, {n_lasers})", bad)
    finite = np.all(np.isfinite(points), axis=1)
    if not finite.all():
        raise field_error(path, "x/y/z", "finite coordinates", f"{int((~finite).sum())} non-finite rows")
    check_sweep(points, path=path, intensity=cols["intensity"].astype(np.float32), force=force)
    far = far_point_mask(points)
    if far.any():  # beyond any LiDAR's range: dropped, warned (docs/bad_input_checks.md)
        report_far_points(path, points, far, kept=force)
        if not force:
            points, laser = points[~far], laser[~far]
    return points, laser.astype(np.int32)


def _reference_index(log: Av2Log, timestamp_ns: int | None) -> int:
    if timestamp_ns is None:
        return 0
    try:
        return log.sweeps.index(int(timestamp_ns))
    except ValueError:
        raise file_error(log.sweep_path(timestamp_ns), "no such LiDAR sweep in the log") from None


def read_cloud(log: Av2Log, timestamp_ns: int | None = None, *, sweeps: int = 0, force: bool = False,
               spec=None):
    """The sources of one reference sweep (and its neighbours) as a :class:`~jaxdepth.io.sources.SourceCloud`.

    Args:
      log: from :func:`read_log`.
      timestamp_ns: the reference sweep (default: the log's first).
      sweeps: neighbours on each side of the reference sweep to add (default 0; fewer at
        the ends of the log).
      force: use sweeps that fail the plausibility checks (logged) instead of refusing them.
      spec: a :class:`~jaxdepth.LidarSpec` stated for every LiDAR (rows from elevation), or None
        (default): no spec stated, so each source's rows come from its laser numbers (one row
        per laser, ranked by elevation about its own LiDAR; see the module docstring).

    Returns:
      SourceCloud in the reference sweep's ego frame: one source per (LiDAR, sweep), ordered
      sweep by sweep (reference first, then -1, +1, -2, +2, ...) and ``up_lidar`` before
      ``down_lidar``; ``sweep`` is the signed offset from the reference sweep; ``lidars``
      ``spec`` for every source; ``ring = laser_number mod 32``; names ``"<lidar>@<offset>"``.
    """
    from jaxdepth.io.sources import SourceCloud

    if isinstance(sweeps, bool) or not isinstance(sweeps, (int, np.integer)) or sweeps < 0:
        raise ValueError(f"read_cloud: field 'sweeps' expected an integer >= 0, got {sweeps!r}")
    ref = _reference_index(log, timestamp_ns)
    offsets = [0]
    for k in range(1, int(sweeps) + 1):
        offsets += [o for o in (-k, k) if 0 <= ref + o < len(log.sweeps)]
    from jaxdepth._src.poses import invert_pose

    ref_from_city = invert_pose(ego_pose(log, log.sweeps[ref])) if len(offsets) > 1 else None
    lidar_poses = [log.sensor_pose(name) for name, _ in LIDARS]
    points, source, ring, T_ref_source, sweep_ids, names = [], [], [], [], [], []
    for offset in offsets:
        t = log.sweeps[ref + offset]
        T_ref_sweep = np.eye(4) if offset == 0 else ref_from_city @ ego_pose(log, t)
        xyz, laser = read_sweep(log.sweep_path(t), force=force)
        moved = xyz if offset == 0 else (xyz.astype(np.float64) @ T_ref_sweep[:3, :3].T
                                        + T_ref_sweep[:3, 3]).astype(np.float32)
        lidar_of = laser // LASERS_PER_LIDAR
        for j, (name, _) in enumerate(LIDARS):
            keep = lidar_of == j
            points.append(moved[keep])
            source.append(np.full(int(keep.sum()), len(names), np.int32))
            ring.append((laser[keep] % LASERS_PER_LIDAR).astype(np.int32))
            T_ref_source.append(T_ref_sweep @ lidar_poses[j])
            sweep_ids.append(offset)
            names.append(f"{name}@{offset}")
    return SourceCloud(points=np.concatenate(points), source=np.concatenate(source),
                       T_ref_source=np.stack(T_ref_source), lidars=(spec,) * len(names),
                       sweep=np.asarray(sweep_ids, np.int32), names=tuple(names), ring=np.concatenate(ring),
                       path=str(log.sweep_path(log.sweeps[ref])))


def paired_image(log: Av2Log, camera: str, sweep_ns: int) -> int | None:
    """The timestamp (ns) of ``camera``'s image paired with the sweep ``sweep_ns``, or None.

    The camera's image nearest in time to the sweep (a tie: the later image), provided this sweep
    is also the log's sweep nearest to that image (a tie: the earlier sweep); None when the camera
    has no images (:attr:`Av2Log.camera_times`) or its nearest image belongs to another sweep.

    >>> log = Av2Log(pathlib.Path("."), (0, 100), {}, {}, np.zeros(0), np.zeros((0, 4, 4)),
    ...              {"cam": np.array([40, 90, 160])})
    >>> paired_image(log, "cam", 0), paired_image(log, "cam", 100)
    (40, 90)
    """
    times = log.camera_times.get(camera)
    if times is None or times.size == 0:
        return None
    image = int(times[_nearest_index(times, int(sweep_ns), later=True)])
    sweeps = np.asarray(log.sweeps, np.int64)
    return image if int(sweeps[_nearest_index(sweeps, image, later=False)]) == int(sweep_ns) else None


def _nearest_index(sorted_times: np.ndarray, t: int, *, later: bool) -> int:
    """Index of the value of ``sorted_times`` nearest to ``t``; a tie goes to the later one if ``later``."""
    k = int(np.searchsorted(sorted_times, t))
    if k == 0:
        return 0
    if k == sorted_times.size:
        return k - 1
    before, after = t - int(sorted_times[k - 1]), int(sorted_times[k]) - t
    return k if (after < before or (after == before and later)) else k - 1


def camera_from_ego(log: Av2Log, camera: str, *, sweep_ns: int | None = None,
                    camera_ns: int | None = None) -> np.ndarray:
    """(4, 4) float64 ``T_cam_ego``: points in the ego frame at ``sweep_ns`` -> ``camera`` at ``camera_ns``.

    ``inv(egovehicle_SE3_cam) @ inv(city_SE3_ego(camera_ns)) @ city_SE3_ego(sweep_ns)`` (the
    devkit's motion-compensated projection); the calibration alone, ``inv(egovehicle_SE3_cam)``,
    when either time is None or both are equal. InputError (naming the city poses) for a time
    outside the pose table.
    """
    from jaxdepth._src.poses import invert_pose

    T = invert_pose(log.sensor_pose(camera))
    if sweep_ns is None or camera_ns is None or int(sweep_ns) == int(camera_ns):
        return T
    return T @ invert_pose(ego_pose(log, camera_ns)) @ ego_pose(log, sweep_ns)


def read_rig(log: Av2Log, cameras=RING_CAMERAS, *, sweep_ns: int | None = None, camera_ns: dict | None = None):
    """The :class:`~jaxdepth.io.rig.Rig` of ``cameras`` (default: the 7 ring cameras) for ego-frame points.

    Each camera: its calibrated size, K from the pinhole part of the intrinsics,
    ``T_cam_lidar = inv(egovehicle_SE3_camera)`` (ego frame -> OpenCV camera frame), or, with
    ``sweep_ns`` and a camera's time in ``camera_ns`` (camera name -> ns), :func:`camera_from_ego`:
    the ego frame at the sweep's time into the camera at its image's time. The rig's LiDAR is
    the VLP-32C preset at ``up_lidar``'s origin (used by single-origin paths, as the fallback
    of sources whose spec cannot be estimated, and for the range-image columns and the validity
    mask; the :class:`SourceCloud` carries both LiDARs' poses).
    """
    from jaxdepth._src.presets import AV2_VLP32C
    from jaxdepth.io.rig import Rig, RigCamera

    camera_ns = camera_ns or {}
    rig_cameras = []
    for name in cameras:
        if name not in log.intrinsics:
            raise field_error(log.intrinsics_path, "sensor_name", f"a row for camera {name!r}",
                              f"sensors {sorted(log.intrinsics)}")
        K, w, h = log.intrinsics[name]
        T = camera_from_ego(log, name, sweep_ns=sweep_ns, camera_ns=camera_ns.get(name))
        try:
            rig_cameras.append(RigCamera(name, w, h, K.astype(np.float32), T.astype(np.float32)))
        except ValueError as err:
            raise file_error(log.calibration_path, f"camera {name!r}: {err}") from None
    up = log.sensor_pose(LIDARS[0][0])
    return Rig(lidar=AV2_VLP32C, cameras=tuple(rig_cameras), lidar_origin_m=tuple(up[:3, 3]))


__all__ = ["Av2Log", "read_log", "read_cloud", "read_rig", "read_sweep", "read_feather_columns", "ego_pose",
           "interpolate_pose", "is_av2_log", "paired_image", "camera_from_ego", "RING_CAMERAS", "LIDARS",
           "LASERS_PER_LIDAR"]
