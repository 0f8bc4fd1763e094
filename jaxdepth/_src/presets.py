"""Sensor presets: the only place where KITTI / nuScenes constants live.

The algorithms in ``jaxdepth._src`` never hard-code a sensor; these presets are
defaults that callers (and the CLI) pass in.
"""

from __future__ import annotations

import numpy as np

from jaxdepth._src.types import LidarSpec

#: Velodyne HDL-64E as recorded in KITTI (about 1,900 points per beam per turn).
KITTI_HDL64 = LidarSpec(beams=64, fov_up_deg=2.0, fov_down_deg=-24.9, columns=2048)

#: Velodyne HDL-32E as recorded in nuScenes (about 1,080 points per beam per turn).
NUSCENES_HDL32 = LidarSpec(beams=32, fov_up_deg=10.67, fov_down_deg=-30.67, columns=1088)

#: Velodyne VLP-32C as recorded in Argoverse 2 (two of them: ``up_lidar``, ``down_lidar``): lasers from
#: -25 to +15 degrees (non-uniform spacing, densest near the horizon), 10 Hz, about 1,800 points per
#: laser per turn (0.2 degree azimuth steps).
AV2_VLP32C = LidarSpec(beams=32, fov_up_deg=15.0, fov_down_deg=-25.0, columns=1800)

# KITTI raw 2011_09_26 calibration: velodyne -> rectified camera 2 (left colour)
# T = [I | t_02] @ R_rect_00 @ Tr_velo_to_cam, with t_02 = P_rect_02[:, 3] / f.
_R_VELO_TO_CAM = np.array(
    [[7.533745e-03, -9.999714e-01, -6.166020e-04],
     [1.480249e-02, 7.280733e-04, -9.998902e-01],
     [9.998621e-01, 7.523790e-03, 1.480755e-02]], dtype=np.float64)
_T_VELO_TO_CAM = np.array([-4.069766e-03, -7.631618e-02, -2.717806e-01], dtype=np.float64)
_R_RECT_00 = np.array(
    [[9.999239e-01, 9.837760e-03, -7.445048e-03],
     [-9.869795e-03, 9.999421e-01, -4.278459e-03],
     [7.402527e-03, 4.351614e-03, 9.999631e-01]], dtype=np.float64)
_P_RECT_02 = np.array(
    [[7.215377e+02, 0.0, 6.095593e+02, 4.485728e+01],
     [0.0, 7.215377e+02, 1.728540e+02, 2.163791e-01],
     [0.0, 0.0, 1.0, 2.745884e-03]], dtype=np.float64)


_P_RECT_03 = np.array(
    [[7.215377e+02, 0.0, 6.095593e+02, -3.395242e+02],
     [0.0, 7.215377e+02, 1.728540e+02, 2.199936e+00],
     [0.0, 0.0, 1.0, 2.729905e-03]], dtype=np.float64)


def _kitti_cam_T(P_rect: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = _R_RECT_00 @ _R_VELO_TO_CAM
    T[:3, 3] = _R_RECT_00 @ _T_VELO_TO_CAM
    K = P_rect[:, :3]
    t_cam = np.linalg.solve(K, P_rect[:, 3])
    shift = np.eye(4)
    shift[:3, 3] = t_cam
    return (shift @ T).astype(np.float32)


def _kitti_cam2_T() -> np.ndarray:
    return _kitti_cam_T(_P_RECT_02)


#: (4, 4) LiDAR -> rectified left colour camera (KITTI camera 2), 2011_09_26.
#: The documented default extrinsic for completing a bare sparse depth image.
KITTI_T_CAM2_LIDAR: np.ndarray = _kitti_cam2_T()

#: (4, 4) LiDAR -> rectified right colour camera (KITTI camera 3), 2011_09_26.
KITTI_T_CAM3_LIDAR: np.ndarray = _kitti_cam_T(_P_RECT_03)

#: KITTI colour camera index -> its 2011_09_26 extrinsic.
KITTI_T_CAM_LIDAR = {2: KITTI_T_CAM2_LIDAR, 3: KITTI_T_CAM3_LIDAR}

#: (3, 3) KITTI camera 2 intrinsics at full size (1242 x 375), 2011_09_26.
KITTI_K_CAM2: np.ndarray = _P_RECT_02[:, :3].astype(np.float32)
