"""``jaxdepth.io.load_kitti_frame`` against OpenCV, NumPy and the calibration text itself."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from jaxdepth.io import InputError, load_kitti_frame


def _calib_row(path, key):
    for line in path.read_text().splitlines():
        if line.startswith(key + ":"):
            return np.array(line.split(":", 1)[1].split(), np.float64)
    raise KeyError(key)


@pytest.mark.parametrize("camera", [2, 3])
def test_cropped_frame_matches_opencv_and_calibration(kitti_frame, camera):
    frame = load_kitti_frame(kitti_frame, camera=camera)
    top, left = 375 - 352, (1242 - 1216) // 2  # KITTI's crop: bottom rows, centre columns
    for field, name in (("sparse", "velodyne_raw"), ("truth", "groundtruth")):
        raw = cv2.imread(str(kitti_frame / f"{name}_image_0{camera}.png"), cv2.IMREAD_ANYDEPTH)
        np.testing.assert_array_equal(getattr(frame, field), raw[top:top + 352, left:left + 1216] / 256.0)
        assert getattr(frame, field).dtype == np.float32
    bgr = cv2.imread(str(kitti_frame / f"image_0{camera}.png"), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(frame.image, bgr[top:top + 352, left:left + 1216, ::-1])
    P = _calib_row(kitti_frame / "calib_cam_to_cam.txt", f"P_rect_0{camera}").reshape(3, 4)
    expected_K = P[:, :3].copy()
    expected_K[0, 2] -= left
    expected_K[1, 2] -= top
    np.testing.assert_allclose(frame.K, expected_K, rtol=1e-6)
    scan = np.fromfile(kitti_frame / "lidar_data.bin", np.float32).reshape(-1, 4)
    np.testing.assert_array_equal(frame.scan, scan)
    R = frame.T_cam_lidar[:3, :3].astype(np.float64)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-5)
    assert frame.camera == camera


def test_full_frame_and_no_image(kitti_frame):
    frame = load_kitti_frame(kitti_frame, crop=False, image=False)
    assert frame.image is None and frame.sparse.shape == (375, 1242)
    P = _calib_row(kitti_frame / "calib_cam_to_cam.txt", "P_rect_02").reshape(3, 4)
    np.testing.assert_allclose(frame.K, P[:, :3], rtol=1e-6)
    cropped = load_kitti_frame(kitti_frame, image=False)
    np.testing.assert_array_equal(cropped.T_cam_lidar, frame.T_cam_lidar)


def test_bad_camera_and_missing_file(kitti_frame, tmp_path):
    with pytest.raises(ValueError, match="camera"):
        load_kitti_frame(kitti_frame, camera=1)
    for name in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt", "velodyne_raw_image_02.png", "lidar_data.bin"):
        shutil.copy(kitti_frame / name, tmp_path / name)
    with pytest.raises(InputError, match="groundtruth_image_02.png"):
        load_kitti_frame(tmp_path)
