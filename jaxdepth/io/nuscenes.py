"""nuScenes dataroot -> one multi-camera completion input per sample (host side, NumPy).

Reads the metadata tables of one nuScenes version (``<dataroot>/<version>/*.json``,
schema as documented by the nuScenes devkit and https://www.nuscenes.org/nuscenes#data-format):

* ``sensor``: ``token``, ``channel`` (``LIDAR_TOP``, ``CAM_FRONT``, ...), ``modality``
  (``lidar``, ``camera``, ``radar``);
* ``calibrated_sensor``: ``token``, ``sensor_token``, ``translation`` (3, metres),
  ``rotation`` (unit quaternion ``w, x, y, z``), ``camera_intrinsic`` (3x3, cameras
  only): the pose of the sensor in the ego (vehicle) frame, i.e. the transform
  sensor -> ego;
* ``ego_pose``: ``token``, ``translation``, ``rotation``, ``timestamp``: the pose of
  the ego frame in the global frame at that time, i.e. ego -> global;
* ``sample``: ``token``, ``timestamp`` (microseconds);
* ``sample_data``: ``token``, ``sample_token``, ``ego_pose_token``,
  ``calibrated_sensor_token``, ``timestamp``, ``is_key_frame``, ``filename``
  (relative to the dataroot), ``width``, ``height``, ``prev`` (the previous sweep
  of the same sensor, ``""`` at the start of a scene).

The other tables (``scene``, ``log``, ``instance``, ``sample_annotation``, ``map``,
...) are not read. A sample's data are its key frames (``is_key_frame``), one per
channel, as the devkit's ``sample["data"]``.

Why not the devkit itself: ``nuscenes-devkit`` 1.2.0 requires ``numpy < 2`` and JAX
0.5+ requires ``numpy >= 2``; pip then falls back to devkit 1.1.9, which installs
the whole ``jupyter`` stack and the GUI build of OpenCV (``opencv-python``) over
the headless one. The few tables needed here are read directly, with the
devkit's semantics (written from its documentation):

* **Camera geometry.** K is ``camera_intrinsic``; the LiDAR -> camera transform
  follows the devkit's ``map_pointcloud_to_image`` chain, LiDAR -> ego at the
  LiDAR's timestamp -> global -> ego at the camera's timestamp -> camera::

      T_cam_lidar = inv(C_cam) @ inv(E(t_cam)) @ E(t_lidar) @ C_lidar

  (``C`` calibrated_sensor, ``E`` ego_pose as 4x4 matrices). This compensates the
  vehicle's motion between the LiDAR sweep and the camera exposure (nuScenes
  cameras fire up to ~45 ms from the LiDAR's key frame; at 10 m/s that is 0.45 m).
  With ``ego_motion=False`` both poses are the LiDAR's: ``inv(C_cam) @ C_lidar``.
* **Several sweeps** (``sweeps > 1``): the devkit's
  ``LidarPointCloud.from_file_multisweep(nsweeps=sweeps, min_distance=1.0)``: the
  key frame and up to ``sweeps - 1`` earlier sweeps (following ``prev``), each
  with the points inside the 1 m box ``|x| < 1 and |y| < 1`` of its own sensor
  frame removed (returns from the vehicle itself), moved into the key frame's
  LiDAR frame through the global frame with each sweep's own ego pose, and
  stacked key frame first. ``sweeps = 1`` is the key-frame file as recorded
  (the devkit's ``LidarPointCloud.from_file``, nothing removed).

Points: ``.pcd.bin`` float32 records of 5 values (x, y, z, intensity, ring index),
metres, in the LiDAR's own frame.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import re
from typing import Any

import numpy as np

from jaxdepth._src.poses import apply_pose, invert_pose, pose_matrix, quaternion_matrix
from jaxdepth.io.errors import InputError, PathLike, field_error, file_error, read_input_bytes

#: Tables read from ``<dataroot>/<version>/``.
TABLES = ("sensor", "calibrated_sensor", "ego_pose", "sample", "sample_data")
#: The LiDAR whose sweeps are completed.
LIDAR_CHANNEL = "LIDAR_TOP"
#: float32 values per record of a nuScenes ``.pcd.bin`` sweep.
POINT_COLUMNS = 5
#: The devkit's ``from_file_multisweep`` default: points with |x| < 1 and |y| < 1 m are dropped.
MULTISWEEP_MIN_DISTANCE_M = 1.0


@dataclasses.dataclass(frozen=True)
class NuScenesTables:
    """The tables of one version, indexed by token (records as read from the JSON).

    Attributes:
      dataroot: the dataroot (sweep and image ``filename`` s are relative to it).
      version: e.g. ``"v1.0-mini"``.
      tables: table name -> {token: record}.
      key_frames: sample token -> {channel: key-frame sample_data token}.
    """

    dataroot: pathlib.Path
    version: str
    tables: dict
    key_frames: dict

    def table_path(self, name: str) -> pathlib.Path:
        return self.dataroot / self.version / f"{name}.json"

    def record(self, table: str, token: Any, *, referrer: str) -> dict:
        """The record ``token`` of ``table``; InputError naming the referring field otherwise."""
        try:
            return self.tables[table][token]
        except (KeyError, TypeError):
            raise field_error(self.table_path(table), "token", f"a record referenced by {referrer}",
                              f"no record {token!r}") from None

    def channel(self, sample_data: dict) -> tuple[str, str]:
        """(channel, modality) of a sample_data record, through calibrated_sensor and sensor."""
        where = f"sample_data {sample_data['token']!r}"
        cs = self.record("calibrated_sensor", sample_data.get("calibrated_sensor_token"),
                         referrer=f"{where} calibrated_sensor_token")
        sensor = self.record("sensor", cs.get("sensor_token"), referrer=f"calibrated_sensor {cs['token']!r}")
        return str(sensor.get("channel")), str(sensor.get("modality"))

    def samples(self) -> list:
        """Sample tokens ordered by (timestamp, token)."""
        return [r["token"] for r in sorted(self.tables["sample"].values(),
                                           key=lambda r: (_timestamp_key(r), str(r["token"])))]


def _timestamp_key(record: dict) -> float:
    value = record.get("timestamp")
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.inf


def _load_table(path: pathlib.Path) -> dict:
    raw = read_input_bytes(path, expected="a nuScenes JSON table")
    try:
        doc = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise file_error(path, f"expected UTF-8 JSON, got undecodable bytes at offset {exc.start}") from None
    except json.JSONDecodeError as exc:
        raise file_error(path, f"invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    if not isinstance(doc, list):
        raise file_error(path, f"expected a JSON list of records, got {type(doc).__name__}")
    out = {}
    for i, record in enumerate(doc):
        if not isinstance(record, dict) or not isinstance(record.get("token"), str):
            raise field_error(path, f"[{i}].token", "a record with a string token", repr(record)[:60])
        out[record["token"]] = record
    return out


def load_tables(dataroot: PathLike, version: str) -> NuScenesTables:
    """Reads and indexes the tables of ``<dataroot>/<version>/`` (see the module docstring).

    Raises:
      InputError: the version folder or a table is missing or is not a JSON list of
        records with string tokens; the message names the file (and lists the
        versions found when the folder is missing).
    """
    dataroot = pathlib.Path(dataroot)
    folder = dataroot / version
    if not folder.is_dir():
        found = sorted(p.name for p in dataroot.glob("v1.0-*") if p.is_dir()) if dataroot.is_dir() else []
        hint = f" (found: {', '.join(found)})" if found else " (no v1.0-* folder there)"
        raise file_error(folder, f"nuScenes version folder not found{hint}")
    tables = {name: _load_table(folder / f"{name}.json") for name in TABLES}
    probe = NuScenesTables(dataroot=dataroot, version=version, tables=tables, key_frames={})
    key_frames: dict = {token: {} for token in tables["sample"]}
    for token, sd in tables["sample_data"].items():
        if not sd.get("is_key_frame"):
            continue
        sample = sd.get("sample_token")
        if sample not in key_frames:
            continue  # reported when the sample is completed (it would have no data)
        try:
            channel, _ = probe.channel(sd)
        except InputError:
            continue  # a broken reference costs only its sample: reported by sample_inputs
        key_frames[sample][channel] = token
    return NuScenesTables(dataroot=dataroot, version=version, tables=tables, key_frames=key_frames)


def _pose(tables: NuScenesTables, table: str, token: Any, referrer: str) -> np.ndarray:
    record = tables.record(table, token, referrer=referrer)
    try:
        return pose_matrix(record.get("translation"), record.get("rotation"), where=str(token))
    except ValueError as err:
        raise file_error(tables.table_path(table), str(err)) from None


def sensor_pose(tables: NuScenesTables, sample_data: dict) -> np.ndarray:
    """(4, 4) sensor -> ego of a sample_data record (its calibrated_sensor)."""
    return _pose(tables, "calibrated_sensor", sample_data.get("calibrated_sensor_token"),
                 f"sample_data {sample_data['token']!r} calibrated_sensor_token")


def ego_pose(tables: NuScenesTables, sample_data: dict) -> np.ndarray:
    """(4, 4) ego -> global of a sample_data record at its timestamp (its ego_pose)."""
    return _pose(tables, "ego_pose", sample_data.get("ego_pose_token"),
                 f"sample_data {sample_data['token']!r} ego_pose_token")


def camera_from_lidar(tables: NuScenesTables, cam_sd: dict, lidar_sd: dict, *, ego_motion: bool = True) -> np.ndarray:
    """(4, 4) float64 ``T_cam_lidar`` of a camera and a LiDAR sample_data (module docstring's chain).

    ``ego_motion=False`` uses the LiDAR's ego pose for the camera too (calibration only).
    """
    lidar_to_ego = sensor_pose(tables, lidar_sd)
    cam_to_ego = sensor_pose(tables, cam_sd)
    if not ego_motion:
        return invert_pose(cam_to_ego) @ lidar_to_ego
    return invert_pose(cam_to_ego) @ invert_pose(ego_pose(tables, cam_sd)) @ ego_pose(tables, lidar_sd) @ lidar_to_ego


def camera_intrinsics(tables: NuScenesTables, cam_sd: dict) -> np.ndarray:
    """(3, 3) float64 K of a camera sample_data (its calibrated_sensor's ``camera_intrinsic``)."""
    token = cam_sd.get("calibrated_sensor_token")
    cs = tables.record("calibrated_sensor", token, referrer=f"sample_data {cam_sd['token']!r}")
    try:
        K = np.asarray(cs.get("camera_intrinsic"), np.float64)
    except (TypeError, ValueError):
        K = np.zeros(0)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise field_error(tables.table_path("calibrated_sensor"), f"{token}.camera_intrinsic",
                          "a 3x3 matrix of finite numbers", repr(cs.get("camera_intrinsic"))[:60])
    return K


def read_sweep(tables: NuScenesTables, sample_data: dict, *, force: bool = False) -> np.ndarray:
    """(N, 5) float32 records of a LiDAR sample_data's ``.pcd.bin`` (x, y, z, intensity, ring).

    The records pass :func:`jaxdepth.io.plausibility.check_sweep` (ring column included)
    unless ``force`` (then a failure is logged); points beyond any LiDAR's range get NaN x, y, z
    (:func:`jaxdepth.io.plausibility.drop_far_points`, warned)."""
    filename = sample_data.get("filename")
    if not isinstance(filename, str) or not filename:
        raise field_error(tables.table_path("sample_data"), f"{sample_data['token']}.filename",
                          "a file name relative to the dataroot", repr(filename))
    path = tables.dataroot / filename
    raw = read_input_bytes(path, expected="a nuScenes .pcd.bin sweep")
    record = 4 * POINT_COLUMNS
    if len(raw) % record:
        raise file_error(path, f"size {len(raw)} bytes expected a multiple of {record} "
                               f"({POINT_COLUMNS} float32 values per point)")
    records = np.frombuffer(raw, np.float32).reshape(-1, POINT_COLUMNS).copy()
    from jaxdepth.io.plausibility import check_sweep, drop_far_points
    check_sweep(records[:, :3], path=path, columns=POINT_COLUMNS, intensity=records[:, 3], ring=records[:, 4],
                raw=raw, force=force)
    return drop_far_points(records, path=path, force=force)


def camera_image_path(tables: NuScenesTables, sample_data: dict) -> pathlib.Path:
    """The image file of a camera sample_data record: ``<dataroot>/<filename>`` (a JPEG in nuScenes;
    not opened here)."""
    filename = sample_data.get("filename")
    if not isinstance(filename, str) or not filename:
        raise field_error(tables.table_path("sample_data"), f"{sample_data['token']}.filename",
                          "a file name relative to the dataroot", repr(filename))
    return tables.dataroot / filename


def remove_close(points: np.ndarray, radius_m: float) -> np.ndarray:
    """Rows of ``points`` outside the box ``|x| < radius_m and |y| < radius_m`` (devkit ``remove_close``)."""
    close = (np.abs(points[:, 0]) < radius_m) & (np.abs(points[:, 1]) < radius_m)
    return points[~close]


def _sweep_parts(tables: NuScenesTables, key_sd: dict, *, sweeps: int, min_distance_m: float,
                 force: bool = False) -> list:
    """``[(points (n, 5) float32 in the key frame's LiDAR frame, T_key_sweep (4, 4))]``: the key frame and
    up to ``sweeps - 1`` earlier sweeps along ``prev``, each with :func:`remove_close` in its own frame."""
    key_from_global = invert_pose(sensor_pose(tables, key_sd)) @ invert_pose(ego_pose(tables, key_sd))
    parts = []
    sd = key_sd
    for _ in range(sweeps):
        points = remove_close(read_sweep(tables, sd, force=force), min_distance_m)
        T = key_from_global @ ego_pose(tables, sd) @ sensor_pose(tables, sd)
        moved = points.copy()
        moved[:, :3] = apply_pose(T, points[:, :3])
        parts.append((moved, T))
        prev = sd.get("prev")
        if not prev:
            break
        sd = tables.record("sample_data", prev, referrer=f"sample_data {sd['token']!r} prev")
    return parts


def _check_sweeps(sweeps, where: str) -> None:
    if isinstance(sweeps, bool) or not isinstance(sweeps, (int, np.integer)) or sweeps < 1:
        raise ValueError(f"{where}: field 'sweeps' expected an integer >= 1, got {sweeps!r}")


def accumulate_sweeps(tables: NuScenesTables, key_sd: dict, *, sweeps: int,
                      min_distance_m: float = MULTISWEEP_MIN_DISTANCE_M, force: bool = False) -> np.ndarray:
    """(N, 5) float32: ``sweeps`` LiDAR sweeps ending at ``key_sd``, in ``key_sd``'s LiDAR frame.

    ``sweeps == 1``: the key frame's file as recorded. Otherwise the devkit's
    ``from_file_multisweep`` (module docstring): key frame first, then earlier
    sweeps along ``prev`` (fewer at the start of a scene), each with
    :func:`remove_close` (``min_distance_m``) in its own frame and moved by
    ``inv(C_key) @ inv(E_key) @ E_sweep @ C_sweep``. Columns 3 and 4 (intensity,
    ring) are carried along unchanged. ``force``: sweeps that fail the plausibility checks are
    used anyway (logged), as in :func:`read_sweep`.
    """
    _check_sweeps(sweeps, "accumulate_sweeps")
    if sweeps == 1:
        return read_sweep(tables, key_sd, force=force)
    parts = _sweep_parts(tables, key_sd, sweeps=sweeps, min_distance_m=min_distance_m, force=force)
    return np.concatenate([points for points, _ in parts], axis=0)


def sweep_cloud(tables: NuScenesTables, key_sd: dict, *, sweeps: int,
                min_distance_m: float = MULTISWEEP_MIN_DISTANCE_M, force: bool = False):
    """The sweeps of :func:`accumulate_sweeps` as a :class:`~jaxdepth.io.sources.SourceCloud`: one source per
    sweep (same points, same order), its LiDAR pose ``T_ref_source = inv(C_key) @ inv(E_key) @ E_sweep @
    C_sweep`` in the key frame's LiDAR frame, ``sweep`` 0, -1, -2, ... (earlier sweeps), the HDL-32E
    preset, ``ring`` the files' 5th column; names ``"LIDAR_TOP@<offset>"``.

    ``sweeps == 1`` is the key frame as recorded (nothing removed), one source at the origin.
    """
    _check_sweeps(sweeps, "sweep_cloud")
    return _cloud(tables, key_sd, _parts(tables, key_sd, sweeps=sweeps, min_distance_m=min_distance_m,
                                         force=force))[0]


def _parts(tables: NuScenesTables, key_sd: dict, *, sweeps: int, min_distance_m: float, force: bool = False) -> list:
    if sweeps == 1:
        return [(read_sweep(tables, key_sd, force=force), np.eye(4))]
    parts = _sweep_parts(tables, key_sd, sweeps=sweeps, min_distance_m=min_distance_m, force=force)
    parts[0] = (parts[0][0], np.eye(4))  # the key frame's own pose, exactly
    return parts


def _cloud(tables: NuScenesTables, key_sd: dict, parts: list):
    """(SourceCloud, (N, 5) float32 stacked records) of :func:`_parts`."""
    from jaxdepth._src.presets import NUSCENES_HDL32
    from jaxdepth.io.sources import SourceCloud

    points = np.concatenate([p for p, _ in parts], axis=0)
    ring = np.rint(points[:, 4]).astype(np.int32) if np.all(np.isfinite(points[:, 4])) else None
    return SourceCloud(points=points[:, :3], source=np.concatenate([np.full(len(p), k, np.int32)
                                                                   for k, (p, _) in enumerate(parts)]),
                       T_ref_source=np.stack([T for _, T in parts]), lidars=(NUSCENES_HDL32,) * len(parts),
                       sweep=-np.arange(len(parts), dtype=np.int32),
                       names=tuple(f"{LIDAR_CHANNEL}@{-k}" for k in range(len(parts))),
                       ring=ring, path=str(tables.dataroot / str(key_sd.get("filename")))), points


@dataclasses.dataclass(frozen=True)
class SampleCamera:
    """One camera of a sample: its key-frame sample_data token, size, K and ``T_cam_lidar`` (float64)."""

    channel: str
    token: str
    width: int
    height: int
    K: np.ndarray
    T_cam_lidar: np.ndarray


@dataclasses.dataclass(frozen=True)
class SampleInputs:
    """What one sample's completion needs.

    Attributes:
      token: the sample token. lidar_token: its key-frame LiDAR sample_data token.
      points: (N, 5) float32 sweep(s) in the key-frame LiDAR frame (sensor at the origin).
      cameras: one :class:`SampleCamera` per camera channel, ordered by channel name.
      cloud: the same sweeps as a :class:`~jaxdepth.io.sources.SourceCloud` (:func:`sweep_cloud`),
        when asked for (``sample_inputs(..., sources=True)``), else None.
    """

    token: str
    lidar_token: str
    points: np.ndarray
    cameras: tuple
    cloud: object = None


def sample_cameras(tables: NuScenesTables, sample_token: str) -> tuple:
    """(lidar sample_data, [(channel, camera sample_data)] by channel name) of a sample's key frames."""
    frames = tables.key_frames.get(sample_token, {})
    where = f"sample {sample_token!r}"
    if LIDAR_CHANNEL not in frames:
        raise field_error(tables.table_path("sample_data"), "is_key_frame",
                          f"a key-frame {LIDAR_CHANNEL} sweep for {where}", f"channels {sorted(frames)}")
    lidar_sd = tables.tables["sample_data"][frames[LIDAR_CHANNEL]]
    cams = []
    for channel in sorted(frames):
        sd = tables.tables["sample_data"][frames[channel]]
        if tables.channel(sd)[1] == "camera":
            cams.append((channel, sd))
    if not cams:
        raise field_error(tables.table_path("sample_data"), "is_key_frame",
                          f"key-frame camera images for {where}", f"channels {sorted(frames)}")
    return lidar_sd, cams


def camera_size(tables: NuScenesTables, sd: dict) -> tuple[int, int]:
    """(width, height) of a camera sample_data record."""
    size = (sd.get("width"), sd.get("height"))
    if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size):
        raise field_error(tables.table_path("sample_data"), f"{sd['token']}.width/height",
                          "positive integers (the image size)", f"{size[0]!r}/{size[1]!r}")
    return size


def sample_inputs(tables: NuScenesTables, sample_token: str, *, sweeps: int = 1,
                  ego_motion: bool = True, sources: bool = False, force: bool = False) -> SampleInputs:
    """The points and cameras of one sample (see the module docstring for the geometry).

    ``sources``: also return the sweeps as a SourceCloud (``SampleInputs.cloud``), each sweep one
    source with its own LiDAR pose. ``force``: sweeps that fail the plausibility checks are used
    anyway (logged).

    Raises:
      InputError: a missing key frame, a broken token reference, a bad pose or
        intrinsic, a missing or malformed sweep file; the message names the file.
    """
    lidar_sd, cams = sample_cameras(tables, sample_token)
    cameras = []
    for channel, sd in cams:
        width, height = camera_size(tables, sd)
        cameras.append(SampleCamera(channel=channel, token=sd["token"], width=width, height=height,
                                    K=camera_intrinsics(tables, sd),
                                    T_cam_lidar=camera_from_lidar(tables, sd, lidar_sd, ego_motion=ego_motion)))
    if sources:
        _check_sweeps(sweeps, "sample_inputs")
        cloud, points = _cloud(tables, lidar_sd, _parts(tables, lidar_sd, sweeps=sweeps,
                                                        min_distance_m=MULTISWEEP_MIN_DISTANCE_M, force=force))
    else:
        cloud, points = None, accumulate_sweeps(tables, lidar_sd, sweeps=sweeps, force=force)
    return SampleInputs(token=sample_token, lidar_token=lidar_sd["token"], points=points, cameras=tuple(cameras),
                        cloud=cloud)


_SAFE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")


def output_path(dst: PathLike, version: str, channel: str, sample_data_token: str) -> pathlib.Path:
    """``<dst>/<version>/<channel>/<sample_data_token>.png``: where a camera's completed depth goes.

    Raises ValueError when the channel or the token is not a plain file name
    (letters, digits, ``_ . -``; nuScenes tokens are 32 hex digits).
    """
    for field, name in (("channel", channel), ("sample_data token", sample_data_token)):
        if not isinstance(name, str) or not _SAFE_NAME.fullmatch(name):
            raise ValueError(f"output_path: {field} expected a plain file name (letters, digits, _ . -), "
                             f"got {name!r}")
    return pathlib.Path(dst) / version / channel / f"{sample_data_token}.png"


__all__ = ["NuScenesTables", "SampleCamera", "SampleInputs", "load_tables", "sample_inputs", "sample_cameras",
           "camera_from_lidar", "camera_intrinsics", "camera_image_path", "accumulate_sweeps", "sweep_cloud",
           "read_sweep", "remove_close",
           "quaternion_matrix", "pose_matrix", "invert_pose", "output_path", "TABLES", "LIDAR_CHANNEL",
           "MULTISWEEP_MIN_DISTANCE_M"]
