"""KITTI raw drives: OXTS poses and neighbouring sweeps -> :class:`~jaxdepth.io.sources.SourceCloud` (host side).

A KITTI raw drive records, per frame, a Velodyne HDL-64E sweep
(``velodyne_points/data/<frame>.bin``) and an OXTS GPS/IMU packet
(``oxts/data/<frame>.txt``: 30 numbers, the first six ``lat lon alt roll pitch yaw``, degrees,
metres and radians); the date folder holds ``calib_imu_to_velo.txt`` (``R`` 9 floats,
``T`` 3 floats: ``p_velo = R p_imu + T``).

Pose of the IMU in a world frame (the KITTI raw devkit's ``convertOxtsToPose``, as pykitti
does it; written from the devkit readme and the KITTI paper, Geiger et al. IJRR 2013):

* Mercator scale from the *first* frame's latitude: ``s = cos(lat_0 pi / 180)``;
* translation, Earth radius ``r = 6378137`` m::

      t_x = s r lon pi / 180
      t_y = s r ln(tan((90 + lat) pi / 360))
      t_z = alt

  relative to the first frame's translation (pykitti's origin);
* rotation ``R = Rz(yaw) Ry(pitch) Rx(roll)``; the IMU frame is x forward, y left, z up,
  ``yaw = 0`` is east, positive counter-clockwise; ``roll`` positive = left side up,
  ``pitch`` positive = front down (a right-handed rotation about y).

Sweep ``j`` moved into the reference sweep ``i``'s LiDAR frame::

    T_ref_j = T_velo_imu @ inv(T_w_imu[i]) @ T_w_imu[j] @ inv(T_velo_imu)

Each sweep is one source (``T_ref_source = T_ref_j``, the KITTI HDL-64E preset); the
points are as recorded (KITTI's Velodyne sweeps are not motion-compensated within the sweep,
and neither is this reader).
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

from jaxdepth._src.poses import apply_pose, rigid, rotation_rpy
from jaxdepth.io.errors import PathLike, field_error, file_error

#: Earth radius of the devkit's Mercator projection, metres.
EARTH_RADIUS_M = 6378137.0
#: Values of one OXTS packet line (lat, lon, alt, roll, pitch, yaw, velocities, accelerations, ...).
OXTS_VALUES = 30
OXTS_FIELDS = ("lat", "lon", "alt", "roll", "pitch", "yaw")


def read_oxts(path: PathLike) -> np.ndarray:
    """(6,) float64 ``lat lon alt roll pitch yaw`` of one ``oxts/data/<frame>.txt`` packet.

    Raises:
      InputError: missing file, not 30 numbers on the line, a non-finite value, or a latitude
        outside (-90, 90); the message names the file and the field.
    """
    from jaxdepth.io.calib import _read_text

    path = pathlib.Path(path)
    tokens = _read_text(path).split()
    if len(tokens) != OXTS_VALUES:
        raise field_error(path, "packet", f"{OXTS_VALUES} numbers (lat lon alt roll pitch yaw ...)",
                          f"{len(tokens)} values")
    values = np.zeros(6)
    for k, (name, token) in enumerate(zip(OXTS_FIELDS, tokens)):
        try:
            values[k] = float(token)
        except ValueError:
            raise field_error(path, name, "a number", repr(token[:20])) from None
        if not math.isfinite(values[k]):
            raise field_error(path, name, "a finite number", token)
    if not -90.0 < values[0] < 90.0:
        raise field_error(path, "lat", "a latitude in (-90, 90) degrees", values[0])
    return values


def mercator_scale(lat_deg: float) -> float:
    """The devkit's Mercator scale ``cos(lat pi / 180)`` (of the drive's first frame)."""
    return math.cos(math.radians(lat_deg))


def mercator_xy(lat_deg, lon_deg, scale: float) -> np.ndarray:
    """(..., 2) metres: the devkit's scaled Mercator ``(s r lon pi/180, s r ln tan((90 + lat) pi/360))``.

    >>> round(float(mercator_xy(0.0, 1.0, 1.0)[0]), 3)  # 1 degree along the equator
    111319.491
    """
    lat = np.asarray(lat_deg, np.float64)
    lon = np.asarray(lon_deg, np.float64)
    x = scale * EARTH_RADIUS_M * np.radians(lon)
    y = scale * EARTH_RADIUS_M * np.log(np.tan(np.radians(90.0 + lat) / 2.0))
    return np.stack([x, y], axis=-1)


def oxts_poses(packets, *, scale_lat_deg: float | None = None) -> np.ndarray:
    """(F, 4, 4) float64 ``T_w_imu`` of F packets ``(lat, lon, alt, roll, pitch, yaw)`` (module docstring).

    The Mercator scale is that of ``scale_lat_deg`` (default: the first packet's latitude, the
    devkit's choice for a whole drive); translations are relative to the first packet's.
    """
    packets = np.asarray(packets, np.float64).reshape(-1, 6)
    scale = mercator_scale(packets[0, 0] if scale_lat_deg is None else scale_lat_deg)
    xy = mercator_xy(packets[:, 0], packets[:, 1], scale)
    t = np.concatenate([xy, packets[:, 2:3]], axis=1)
    t = t - t[0]
    poses = np.tile(np.eye(4), (len(packets), 1, 1))
    for k, (roll, pitch, yaw) in enumerate(packets[:, 3:6]):
        poses[k, :3, :3] = rotation_rpy(roll, pitch, yaw)
    poses[:, :3, 3] = t
    return poses


def read_imu_to_velo(path: PathLike) -> np.ndarray:
    """(4, 4) float64 ``T_velo_imu`` of ``calib_imu_to_velo.txt`` (``R``, ``T``: IMU -> Velodyne).

    Raises:
      InputError: missing file or field, wrong count of floats, ``R`` not a rotation.
    """
    from jaxdepth.io.calib import _check_rotation, _floats, _parse_kv

    path = pathlib.Path(path)
    fields = _parse_kv(path)
    R = _floats(path, fields, "R", 9).reshape(3, 3)
    _check_rotation(path, "R", R)
    return rigid(R, _floats(path, fields, "T", 3))


def relative_velo_poses(T_w_imu: np.ndarray, T_velo_imu: np.ndarray, ref: int) -> np.ndarray:
    """(F, 4, 4) ``T_ref_j``: sweep j's Velodyne frame -> the reference sweep's (module docstring)."""
    inv = np.linalg.inv
    T_imu_velo = inv(T_velo_imu)
    return np.stack([T_velo_imu @ inv(T_w_imu[ref]) @ T @ T_imu_velo for T in T_w_imu])


def drive_frames(drive: PathLike) -> list:
    """Sorted frame names (file stems) of a drive's ``velodyne_points/data/*.bin``."""
    data = pathlib.Path(drive) / "velodyne_points" / "data"
    return sorted(p.stem for p in data.glob("*.bin"))


def oxts_path(drive: PathLike, frame: str) -> pathlib.Path:
    return pathlib.Path(drive) / "oxts" / "data" / f"{frame}.txt"


def read_drive_cloud(drive: PathLike, frame: str, *, sweeps: int, imu_to_velo: PathLike | None = None,
                     force: bool = False):
    """The reference sweep ``frame`` of a KITTI raw drive and up to ``sweeps`` neighbours on each side.

    Args:
      drive: ``<date>/<date>_drive_XXXX_sync`` folder.
      frame: the reference frame's name (``"0000000005"``).
      sweeps: neighbours on each side (0: the sweep alone; fewer at the ends of the drive).
      imu_to_velo: ``calib_imu_to_velo.txt`` (default: the drive's date folder's).
      force: use sweeps that fail the plausibility checks of :func:`~jaxdepth.io.points.read_points`
        (logged) instead of refusing them.

    Returns:
      SourceCloud in the reference sweep's Velodyne frame: one source per sweep, reference first,
      then -1, +1, -2, +2, ...; ``sweep`` the signed frame offset; names ``"velodyne@<offset>"``.
      The OXTS packets of the sweeps used are read, and the drive's first packet for the
      Mercator scale.

    Raises:
      InputError: a missing sweep, OXTS packet or calibration file, or a bad field in one.
    """
    from jaxdepth._src.presets import KITTI_HDL64
    from jaxdepth.io.kitti_datasets import KITTI_POINT_COLUMNS
    from jaxdepth.io.points import read_points
    from jaxdepth.io.sources import SourceCloud

    if isinstance(sweeps, bool) or not isinstance(sweeps, (int, np.integer)) or sweeps < 0:
        raise ValueError(f"read_drive_cloud: field 'sweeps' expected an integer >= 0, got {sweeps!r}")
    drive = pathlib.Path(drive)
    frames = drive_frames(drive)
    if frame not in frames:
        raise file_error(drive / "velodyne_points" / "data" / f"{frame}.bin", "sweep not found")
    i = frames.index(frame)
    offsets = [0]
    for k in range(1, int(sweeps) + 1):
        offsets += [o for o in (-k, k) if 0 <= i + o < len(frames)]
    data = drive / "velodyne_points" / "data"
    if len(offsets) == 1:
        T = np.eye(4)[None]
    else:
        calib = drive.parent / "calib_imu_to_velo.txt" if imu_to_velo is None else pathlib.Path(imu_to_velo)
        if not calib.is_file():
            raise file_error(calib, "KITTI raw IMU -> Velodyne calibration not found (needed for --sweeps)")
        T_velo_imu = read_imu_to_velo(calib)
        used = sorted(i + o for o in offsets)
        for k in used:
            if not oxts_path(drive, frames[k]).is_file():
                raise file_error(oxts_path(drive, frames[k]), "OXTS packet not found (needed for --sweeps)")
        packets = np.stack([read_oxts(oxts_path(drive, frames[k])) for k in used])
        first_lat = packets[0, 0] if used[0] == 0 else read_oxts(oxts_path(drive, frames[0]))[0]
        rel = relative_velo_poses(oxts_poses(packets, scale_lat_deg=first_lat), T_velo_imu, used.index(i))
        T = np.stack([rel[used.index(i + o)] for o in offsets])
        T[0] = np.eye(4)
    points, source = [], []
    for s, o in enumerate(offsets):
        xyz, _ = read_points(data / f"{frames[i + o]}.bin", columns=KITTI_POINT_COLUMNS, force=force,
                             columns_option=None)
        xyz = np.asarray(xyz, np.float32)[:, :3]
        if o:
            xyz = apply_pose(T[s], xyz)
        points.append(xyz)
        source.append(np.full(len(xyz), s, np.int32))
    return SourceCloud(points=np.concatenate(points), source=np.concatenate(source), T_ref_source=T,
                       lidars=(KITTI_HDL64,) * len(offsets), sweep=np.asarray(offsets, np.int32),
                       names=tuple(f"velodyne@{o}" for o in offsets), path=str(data / f"{frame}.bin"))


__all__ = ["read_oxts", "oxts_poses", "mercator_scale", "mercator_xy", "rotation_rpy", "read_imu_to_velo",
           "relative_velo_poses", "read_drive_cloud", "drive_frames", "oxts_path", "EARTH_RADIUS_M"]
