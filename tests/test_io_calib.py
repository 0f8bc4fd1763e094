"""KITTI calibration readers and the intrinsics file, against the official data."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import ndimage

from conftest import require_shared
from jaxdepth._src.geometry import project_to_image
from jaxdepth._src.presets import KITTI_K_CAM2, KITTI_T_CAM2_LIDAR
from jaxdepth.io import (InputError, pad_points, read_depth_png, read_intrinsics_txt, read_kitti_object_calib,
                         read_kitti_raw_calib, read_points)

_HYP = settings(deadline=None, max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def raw_calib(kitti_frame):
    return read_kitti_raw_calib(kitti_frame / "calib_cam_to_cam.txt", kitti_frame / "calib_velo_to_cam.txt")


def _kv(path) -> dict[str, np.ndarray]:
    """Independent tiny parser for the oracle (float64, no validation)."""
    out = {}
    for line in path.read_text().splitlines():
        key, _, value = line.partition(":")
        try:
            out[key.strip()] = np.array([float(x) for x in value.split()])
        except ValueError:
            pass
    return out


def test_camera2_matches_preset(raw_calib):
    cam = raw_calib["cameras"][2]
    assert cam["K"].dtype == np.float32 and cam["T_cam_lidar"].dtype == np.float32
    np.testing.assert_allclose(cam["T_cam_lidar"], KITTI_T_CAM2_LIDAR, atol=1e-5)
    np.testing.assert_allclose(cam["K"], KITTI_K_CAM2, atol=1e-5)
    assert (cam["height"], cam["width"]) == (375, 1242)


@pytest.mark.parametrize("i", [0, 1, 2, 3])
def test_K_T_reproduce_official_projection_matrix(kitti_frame, raw_calib, i):
    """K @ T[:3] must equal KITTI's P_rect_0i @ R_rect_00 @ [R|T] (the devkit's projection)."""
    c2c = _kv(kitti_frame / "calib_cam_to_cam.txt")
    v2c = _kv(kitti_frame / "calib_velo_to_cam.txt")
    R_rect = np.eye(4)
    R_rect[:3, :3] = c2c["R_rect_00"].reshape(3, 3)
    Tr = np.eye(4)
    Tr[:3, :3] = v2c["R"].reshape(3, 3)
    Tr[:3, 3] = v2c["T"]
    official = c2c[f"P_rect_0{i}"].reshape(3, 4) @ R_rect @ Tr
    cam = raw_calib["cameras"][i]
    ours = cam["K"].astype(np.float64) @ cam["T_cam_lidar"][:3].astype(np.float64)
    np.testing.assert_allclose(ours, official, rtol=1e-6, atol=1e-4)
    R = cam["T_cam_lidar"][:3, :3].astype(np.float64)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-5)
    np.testing.assert_array_equal(cam["T_cam_lidar"][3], [0, 0, 0, 1])


def test_cv2_projectpoints_agrees(kitti_frame, raw_calib):
    """OpenCV's pinhole model with (K, rvec, tvec) from our T gives the devkit's pixels."""
    points, _ = read_points(kitti_frame / "lidar_data.bin")
    cam = raw_calib["cameras"][2]
    T = cam["T_cam_lidar"].astype(np.float64)
    p_cam = points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    front = points[p_cam[:, 2] > 1.0].astype(np.float64)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    uv_cv, _ = cv2.projectPoints(front, rvec, T[:3, 3], cam["K"].astype(np.float64), None)
    c2c = _kv(kitti_frame / "calib_cam_to_cam.txt")
    v2c = _kv(kitti_frame / "calib_velo_to_cam.txt")
    hom = np.c_[front, np.ones(len(front))] @ np.r_[np.c_[v2c["R"].reshape(3, 3), v2c["T"]], [[0, 0, 0, 1]]].T
    hom = hom @ np.r_[np.c_[c2c["R_rect_00"].reshape(3, 3), np.zeros(3)], [[0, 0, 0, 1]]].T
    x = hom @ c2c["P_rect_02"].reshape(3, 4).T
    np.testing.assert_allclose(uv_cv[:, 0], x[:, :2] / x[:, 2:], atol=2e-2)


def test_baselines(raw_calib):
    # Colour pair: |t_2 - t_3| with t_i = K^-1 P_rect_0i[:, 3]; grey pair: P_rect_01[0, 3] / fx = -0.537 m.
    assert raw_calib["baseline_gray_m"] == pytest.approx(387.5744 / 721.5377, abs=1e-6)
    assert raw_calib["baseline_m"] == pytest.approx(0.5327, abs=1e-3)


@pytest.mark.parametrize("cam", [2, 3])
def test_projection_reproduces_official_velodyne_raw(kitti_frame, raw_calib, cam):
    """The data README's measured facts: counts within 1 %, pixels within 2 px, depths within 0.1 m."""
    points, _ = read_points(kitti_frame / "lidar_data.bin")
    padded, valid = pad_points(points)
    c = raw_calib["cameras"][cam]
    depth, _ = project_to_image(padded, valid, c["K"], c["T_cam_lidar"], height=c["height"], width=c["width"])
    depth = np.asarray(depth)
    official = read_depth_png(kitti_frame / f"velodyne_raw_image_0{cam}.png")
    n_ours, n_official = int((depth > 0).sum()), int((official > 0).sum())
    assert abs(n_ours - n_official) <= 0.01 * n_official
    stats = _match_stats(depth, official)
    assert stats["within_2px"] >= 0.88  # README: 92 % (camera 3: 90 %)
    assert stats["coincident_within_0.1m"] >= 0.90  # README: 93 %
    assert stats["depth_within_0.1m_in_5x5"] >= 0.83  # measured 86 %


def test_wrong_camera_fails_the_same_check(kitti_frame, raw_calib):
    """Negative control: camera 3's extrinsic with camera 2's image must not pass the 2-px check."""
    points, _ = read_points(kitti_frame / "lidar_data.bin")
    padded, valid = pad_points(points)
    c = raw_calib["cameras"][3]
    depth, _ = project_to_image(padded, valid, c["K"], c["T_cam_lidar"], height=375, width=1242)
    stats = _match_stats(np.asarray(depth), read_depth_png(kitti_frame / "velodyne_raw_image_02.png"))
    assert stats["depth_within_0.1m_in_5x5"] < 0.6


def _match_stats(depth: np.ndarray, official: np.ndarray) -> dict[str, float]:
    mask = official > 0
    dist = ndimage.distance_transform_edt(depth == 0)
    same = mask & (depth > 0)
    best = np.full(official.shape, np.inf)
    padded = np.pad(np.where(depth > 0, depth, np.inf), 2, constant_values=np.inf)
    h, w = depth.shape
    for dy in range(5):
        for dx in range(5):
            best = np.minimum(best, np.abs(padded[dy:dy + h, dx:dx + w] - official))
    return {
        "within_2px": float((dist[mask] <= 2).mean()),
        "coincident_within_0.1m": float((np.abs(depth[same] - official[same]) < 0.1).mean()),
        "depth_within_0.1m_in_5x5": float((best[mask] < 0.1).mean()),
    }


@pytest.mark.parametrize("frame", ["000001", "000002"])
def test_object_calib_agrees_with_raw_same_date(raw_calib, frame):
    obj = read_kitti_object_calib(require_shared("kitti", "object", "calib", f"{frame}.txt"))
    for i in range(4):
        np.testing.assert_allclose(obj["cameras"][i]["K"], raw_calib["cameras"][i]["K"], atol=1e-5)
        np.testing.assert_allclose(obj["cameras"][i]["T_cam_lidar"], raw_calib["cameras"][i]["T_cam_lidar"],
                                   atol=1e-5)
        assert obj["cameras"][i]["width"] is None and obj["cameras"][i]["height"] is None
    assert obj["baseline_m"] == pytest.approx(raw_calib["baseline_m"], abs=1e-6)


def test_object_calib_other_date_differs(raw_calib):
    obj = read_kitti_object_calib(require_shared("kitti", "object", "calib", "000000.txt"))
    assert obj["cameras"][2]["K"][0, 0] == pytest.approx(707.0493, abs=1e-3)
    assert np.max(np.abs(obj["cameras"][2]["T_cam_lidar"] - raw_calib["cameras"][2]["T_cam_lidar"])) > 1e-3


def test_raw_scene2_same_calibration(raw_calib):
    folder = require_shared("kitti", "raw_2011_09_26_scene2")
    other = read_kitti_raw_calib(folder / "calib_cam_to_cam.txt", folder / "calib_velo_to_cam.txt")
    for i in range(4):
        np.testing.assert_array_equal(other["cameras"][i]["T_cam_lidar"], raw_calib["cameras"][i]["T_cam_lidar"])


# ---------------------------------------------------------------- error messages


@pytest.fixture()
def calib_copy(kitti_frame, tmp_path):
    c2c = tmp_path / "calib_cam_to_cam.txt"
    v2c = tmp_path / "calib_velo_to_cam.txt"
    c2c.write_text((kitti_frame / "calib_cam_to_cam.txt").read_text())
    v2c.write_text((kitti_frame / "calib_velo_to_cam.txt").read_text())
    return c2c, v2c


def _edit(path, key, value):
    lines = path.read_text().splitlines()
    lines = [f"{key}: {value}" if line.startswith(f"{key}:") else line for line in lines]
    if value is None:
        lines = [line for line in lines if not line.startswith(f"{key}:")]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("which, key, value, pattern", [
    ("v2c", "T", "-4.069766e-03 -7.631618e-02", r"calib_velo_to_cam\.txt: field 'T' expected 3 floats, got 2$"),
    ("v2c", "T", "1 2 x", r"calib_velo_to_cam\.txt: field 'T' expected 3 floats, got non-number 'x'"),
    ("v2c", "T", "1 nan 3", r"calib_velo_to_cam\.txt: field 'T' expected 3 finite floats, got nan"),
    ("v2c", "R", None, r"calib_velo_to_cam\.txt: missing field 'R' \(expected 9 floats\)"),
    ("v2c", "R", "1 0 0 0 1 0 0 0 2", r"calib_velo_to_cam\.txt: field 'R' expected a rotation .*det R = 2"),
    ("v2c", "R", "1 0 0 0 1 0 0 0 -1", r"calib_velo_to_cam\.txt: field 'R' expected a rotation .*det R = -1"),
    ("c2c", "R_rect_00", "1 0 0 0 1 0 0 0", r"calib_cam_to_cam\.txt: field 'R_rect_00' expected 9 floats, got 8"),
    ("c2c", "P_rect_02", "0 0 600 0 0 700 170 0 0 0 1 0",
     r"calib_cam_to_cam\.txt: field 'P_rect_02' expected positive focal lengths fx, fy, got fx=0, fy=700"),
    ("c2c", "P_rect_03", "700 0 600 0 0 700 170 0 0 0 2 0",
     r"calib_cam_to_cam\.txt: field 'P_rect_03' expected a pinhole matrix"),
    ("c2c", "S_rect_01", "1242.5 375", r"calib_cam_to_cam\.txt: field 'S_rect_01' expected a positive integer"),
    ("c2c", "S_rect_00", None, r"calib_cam_to_cam\.txt: missing field 'S_rect_00'"),
])
def test_raw_calib_error_messages(calib_copy, which, key, value, pattern):
    c2c, v2c = calib_copy
    _edit(v2c if which == "v2c" else c2c, key, value)
    with pytest.raises(InputError, match=pattern):
        read_kitti_raw_calib(c2c, v2c)


def test_raw_calib_structure_errors(calib_copy, tmp_path):
    c2c, v2c = calib_copy
    with pytest.raises(InputError, match=r"missing\.txt: file not found"):
        read_kitti_raw_calib(tmp_path / "missing.txt", v2c)
    v2c.write_text(v2c.read_text() + "just some words\n")
    with pytest.raises(InputError, match=r"calib_velo_to_cam\.txt: line 6: expected 'key: values'"):
        read_kitti_raw_calib(c2c, v2c)
    v2c.write_text("R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\nT: 0 0 0\n")
    with pytest.raises(InputError, match=r"calib_velo_to_cam\.txt: line 3: field 'T' appears twice"):
        read_kitti_raw_calib(c2c, v2c)
    v2c.write_bytes(b"R: \xff\xfe\n")
    with pytest.raises(InputError, match=r"calib_velo_to_cam\.txt: expected a UTF-8 text file"):
        read_kitti_raw_calib(c2c, v2c)


def test_object_calib_error_messages(tmp_path):
    src = require_shared("kitti", "object", "calib", "000001.txt").read_text()
    path = tmp_path / "000001.txt"
    path.write_text(re.sub(r"^Tr_velo_to_cam:.*$", "Tr_velo_to_cam: 1 0 0 0 0 1 0 0 0 0 1", src, flags=re.M))
    with pytest.raises(InputError, match=r"000001\.txt: field 'Tr_velo_to_cam' expected 12 floats, got 11"):
        read_kitti_object_calib(path)
    path.write_text(re.sub(r"^P2:.*\n", "", src, flags=re.M))
    with pytest.raises(InputError, match=r"000001\.txt: missing field 'P2'"):
        read_kitti_object_calib(path)


# ---------------------------------------------------------------- intrinsics txt


def test_intrinsics_txt(tmp_path):
    path = tmp_path / "0000000000.txt"
    path.write_text("721.5377 0.0 596.5593 0.0 721.5377 149.854 0.0 0.0 1.0\n")
    K = read_intrinsics_txt(path)
    assert K.dtype == np.float32
    np.testing.assert_array_equal(K, np.array([[721.5377, 0, 596.5593], [0, 721.5377, 149.854], [0, 0, 1]],
                                              np.float32))
    path.write_text("721.5377 0 596.5593\n0 721.5377 149.854\n0 0 1\n")
    np.testing.assert_array_equal(read_intrinsics_txt(path), K)


@pytest.mark.parametrize("text, pattern", [
    ("1 0 0 0 1 0 0 0", r"k\.txt: field 'K' expected 9 floats, got 8"),
    ("1 0 0 0 1 0 0 0 1 5", r"k\.txt: field 'K' expected 9 floats, got 10"),
    ("1 0 0 0 inf 0 0 0 1", r"k\.txt: field 'K' expected 9 finite floats, got inf"),
    ("-700 0 600 0 700 170 0 0 1", r"k\.txt: field 'K' expected positive focal lengths fx, fy, got fx=-700"),
    ("700 0 600 0 0 170 0 0 1", r"k\.txt: field 'K' expected positive focal lengths fx, fy, got fx=700, fy=0"),
    ("700 0 600 0 700 170 0 1 1", r"k\.txt: field 'K' expected a pinhole matrix"),
    ("", r"k\.txt: field 'K' expected 9 floats, got 0"),
])
def test_intrinsics_txt_errors(tmp_path, text, pattern):
    path = tmp_path / "k.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=pattern):
        read_intrinsics_txt(path)


# ---------------------------------------------------------------- fuzzing


@_HYP
@given(data=st.binary(max_size=300))
def test_fuzz_intrinsics_random_bytes(tmp_path, data):
    path = tmp_path / "k.txt"
    path.write_bytes(data)
    try:
        K = read_intrinsics_txt(path)
    except InputError:
        return
    assert K.shape == (3, 3) and K[0, 0] > 0 and np.all(np.isfinite(K))


@_HYP
@given(cut=st.integers(0, 3000), junk=st.text(max_size=20))
def test_fuzz_calib_truncation(calib_copy, cut, junk):
    c2c, v2c = calib_copy
    text = c2c.read_text()
    c2c.write_text(text[:cut] + junk)
    try:
        read_kitti_raw_calib(c2c, v2c)
    except InputError:
        pass
    finally:
        c2c.write_text(text)


@_HYP
@given(data=st.binary(max_size=600))
def test_fuzz_object_calib_random_bytes(tmp_path, data):
    path = tmp_path / "o.txt"
    path.write_bytes(data)
    with pytest.raises(InputError):
        read_kitti_object_calib(path)
