"""The geometry of each digital twin's rig: units, mounts, cameras, frames (host side, NumPy).

Frames: ``ego`` has the ground at ``z = 0`` under the vehicle (x forward, y left); ``P`` is the
frame the user's point files are in (:attr:`RigDef.T_ego_points`): the LiDAR frame (KITTI,
nuScenes, rosette), Argoverse 2's ego frame (0.33 m above the road, see
:data:`AV2_EGO_HEIGHT_M`), the raster rig's roof frame. Units are posed in ``P``
(:attr:`RigDef.units`); cameras map ``P`` points (``T_cam_points``).

Sources: KITTI and nuScenes from :mod:`jaxdepth.research.twin_tables` (measured laser tables,
nuScenes' calibration) and :mod:`jaxdepth._src.presets` (KITTI cameras 2 and 3); Argoverse 2 from
its calibration (LiDAR mounts, ring cameras) and per-laser elevations. The raster and rosette rigs
are built for their sensor class (no shared data of them exists), see :func:`raster_rig`,
:func:`rosette_rig`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxdepth._src.poses import rigid
from jaxdepth._src.presets import AV2_VLP32C, KITTI_HDL64, KITTI_K_CAM2, KITTI_T_CAM_LIDAR, NUSCENES_HDL32
from jaxdepth._src.types import LidarSpec
from jaxdepth.research import twin_tables as tables
from jaxdepth.research.twin_sensors import SensorEffects, Unit, raster_unit, rosette_unit, spinning_unit

#: KITTI's LiDAR height above the road (the KITTI setup), metres.
KITTI_LIDAR_HEIGHT_M = 1.73
#: Argoverse 2's ego-frame origin above the road (the real sweep's ground sits at z = -0.33), metres.
AV2_EGO_HEIGHT_M = 0.33
#: The raster rig's roof frame above the road, metres.
RASTER_ROOF_HEIGHT_M = 1.95


@dataclasses.dataclass(frozen=True, eq=False)
class RigDef:
    """One twin's rig.

    Attributes:
      name, sensor_class: as :class:`jaxdepth.research.twins.Twin`.
      T_ego_points: (4, 4) pose of the points frame ``P`` in the ego frame.
      units: tuple of ``(make_unit(sweep) -> Unit, T_points_unit (4, 4))``: each sweep's scan
        pattern (a spinning LiDAR's columns start at a new azimuth, a rosette continues its path).
      cameras: tuple of ``(name, K (3, 3), width, height, T_cam_points (4, 4))``.
      lidar: the rig JSON's ``lidar`` LidarSpec; stated: what a user states per source (a
        LidarSpec per unit, or None).
      per_unit_sources: True when each unit is its own source (a ``lidar`` column, Argoverse 2).
      ring_column: True when the point files carry the laser index.
      step_m, yaw_deg, dt_s: ego motion per sweep (forward, turning left), seconds per sweep.
      effects: the sensor effects' rates (:class:`SensorEffects`).
    """

    name: str
    sensor_class: str
    T_ego_points: np.ndarray
    units: tuple
    cameras: tuple
    lidar: LidarSpec
    stated: tuple
    per_unit_sources: bool
    ring_column: bool
    step_m: float
    yaw_deg: float
    dt_s: float
    effects: SensorEffects


def _pose(R=None, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) pose of a rotation (None: identity) and a translation (:func:`jaxdepth._src.poses.rigid`)."""
    return rigid(np.eye(3) if R is None else R, t)


def _yaw(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _phase(sweep: int) -> float:
    """Column phase of a sweep's spinning scan (the golden ratio: never the same start twice)."""
    return (sweep * 0.6180339887) % 1.0


# Camera axes (x right, y down, z forward) for a camera looking along +x of its mount.
_R_CAM_FORWARD = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def _looking(yaw_deg: float, centre, K, width, height, name):
    """A camera looking horizontally at ``yaw_deg`` (left positive) from ``centre`` (points frame)."""
    R = _R_CAM_FORWARD @ _yaw(yaw_deg).T
    T = _pose(R, -R @ np.asarray(centre, np.float64))
    return (name, np.asarray(K, np.float64), int(width), int(height), T)


def kitti_rig(effects: SensorEffects) -> RigDef:
    units = ((lambda k: spinning_unit("hdl64", tables.KITTI_ELEVATIONS_DEG, cols=2048, phase=_phase(k),
                                      apex_m=tables.KITTI_APEX_M, max_range_m=120.0), np.eye(4)),)
    cams = tuple((f"image_0{i}", np.asarray(KITTI_K_CAM2, np.float64), 1242, 375,
                  np.asarray(KITTI_T_CAM_LIDAR[i], np.float64)) for i in (2, 3))
    return RigDef("kitti", "spinning", _pose(t=(0.0, 0.0, KITTI_LIDAR_HEIGHT_M)), units, cams, KITTI_HDL64,
                  (KITTI_HDL64,), False, False, 1.0, 0.3, 0.1, effects)


def nuscenes_rig(effects: SensorEffects) -> RigDef:
    units = ((lambda k: spinning_unit("hdl32", tables.NUSCENES_ELEVATIONS_DEG, cols=1088, phase=_phase(k),
                                      max_range_m=100.0), np.eye(4)),)
    cams = tuple((name, np.asarray(K, np.float64), 1600, 900, np.asarray(T, np.float64))
                 for name, (K, T) in tables.NUSCENES_CAMERAS.items())
    T_ego = np.asarray(tables.NUSCENES_LIDAR2EGO, np.float64).copy()
    return RigDef("nuscenes", "spinning", T_ego, units, cams, NUSCENES_HDL32, (NUSCENES_HDL32,), False, True,
                  0.5, 0.2, 0.05, effects)


def av2_rig(effects: SensorEffects) -> RigDef:
    units = []
    for name in ("up_lidar", "down_lidar"):
        el = tables.AV2_ELEVATIONS_DEG[name]
        units.append((lambda k, name=name, el=el: spinning_unit(name, el, cols=1800, phase=_phase(k + len(name)),
                                                                max_range_m=200.0),
                      np.asarray(tables.AV2_LIDARS[name], np.float64)))
    cams = []
    for name, (K, w, h, T_ego_cam) in tables.AV2_CAMERAS.items():
        T = np.linalg.inv(np.asarray(T_ego_cam, np.float64))
        cams.append((name, np.asarray(K, np.float64), w, h, T))
    return RigDef("av2", "spinning", _pose(t=(0.0, 0.0, AV2_EGO_HEIGHT_M)), tuple(units), tuple(cams), AV2_VLP32C,
                  (AV2_VLP32C, AV2_VLP32C), True, True, 1.0, 0.3, 0.1, effects)


#: Raster rig: unit yaw (deg) and mount in the roof frame; cameras 1936 x 1216.
RASTER_UNITS = ((45.0, (0.9, 0.75, 0.0)), (135.0, (-0.9, 0.75, 0.0)), (-135.0, (-0.9, -0.75, 0.0)),
                (-45.0, (0.9, -0.75, 0.0)))
RASTER_CAMERA_HW = (1216, 1936)
RASTER_LINES = 64


def raster_rig(effects: SensorEffects) -> RigDef:
    """Four raster units of 120 deg at the roof's corners (merged into one roof-frame cloud), six cameras."""
    units = tuple((lambda k, i=i: raster_unit(f"raster{i}", lines=RASTER_LINES, cols=600, phase=_phase(k + i)),
                   _pose(_yaw(yaw), pos)) for i, (yaw, pos) in enumerate(RASTER_UNITS))
    h, w = RASTER_CAMERA_HW
    K = np.array([[1000.0, 0.0, 0.5 * (w - 1)], [0.0, 1000.0, 0.5 * (h - 1)], [0.0, 0.0, 1.0]])
    cams = tuple(_looking(yaw, (0.8 * math.cos(math.radians(yaw)), 0.6 * math.sin(math.radians(yaw)), -0.12),
                          K, w, h, f"cam_{name}")
                 for name, yaw in (("front", 0.0), ("front_left", 60.0), ("rear_left", 120.0), ("rear", 180.0),
                                   ("rear_right", -120.0), ("front_right", -60.0)))
    spec = LidarSpec(beams=RASTER_LINES, fov_up_deg=10.0, fov_down_deg=-20.0, columns=2048)
    return RigDef("raster", "raster", _pose(t=(1.3, 0.0, RASTER_ROOF_HEIGHT_M)), units, cams, spec, (None,),
                  False, False, 1.26, 0.3, 0.1, effects)


ROSETTE_POINTS = 40000


def rosette_rig(effects: SensorEffects) -> RigDef:
    """One rosette scanner on the roof's front edge (1.6 m up), a forward camera 0.25 m below it."""
    units = ((lambda k: rosette_unit("rosette", points=ROSETTE_POINTS, start=k * ROSETTE_POINTS * 1.37),
              np.eye(4)),)
    K = np.array([[1100.0, 0.0, 959.5], [0.0, 1100.0, 539.5], [0.0, 0.0, 1.0]])
    cams = (_looking(0.0, (0.05, 0.1, -0.25), K, 1920, 1080, "cam_front"),)
    spec = LidarSpec(beams=64, fov_up_deg=35.0, fov_down_deg=-35.0, columns=2048)
    return RigDef("rosette", "rosette", _pose(t=(1.8, 0.0, 1.6)), units, cams, spec, (None,), False, False,
                  0.8, 0.3, 0.1, effects)


RIG_BUILDERS = {"kitti": kitti_rig, "nuscenes": nuscenes_rig, "av2": av2_rig, "raster": raster_rig,
                "rosette": rosette_rig}

__all__ = ["RigDef", "RIG_BUILDERS", "Unit"]
