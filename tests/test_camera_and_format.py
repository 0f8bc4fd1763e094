"""Issue 13, part 3: the right camera and the right point format, always."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from jaxdepth import cli
from jaxdepth._src import presets
from jaxdepth.io import InputError, read_depth_png, read_kitti_raw_calib, write_depth_png
from jaxdepth.io.calib import read_extrinsic_txt
from jaxdepth.io.kitti_layout import KittiExtrinsics, crop_to_benchmark, kitti_camera_from_name, kitti_date_from_name
from jaxdepth.io.points import infer_point_columns

NAME = "2011_09_26_drive_0001_sync_velodyne_raw_0000000005_image_0{}"


# ---------------------------------------------------------------- names and calibration
def test_camera_and_date_from_kitti_names():
    assert kitti_camera_from_name(NAME.format(2)) == 2 and kitti_camera_from_name(NAME.format(3)) == 3
    assert kitti_camera_from_name("0000000005") is None and kitti_camera_from_name("x_image_03_crop") is None
    assert kitti_date_from_name(NAME.format(2)) == "2011_09_26" and kitti_date_from_name("0000000005") is None


def test_built_in_extrinsics_match_the_shared_calibration(kitti_frame):
    calib = read_kitti_raw_calib(kitti_frame / "calib_cam_to_cam.txt", kitti_frame / "calib_velo_to_cam.txt")
    for cam, T in ((2, presets.KITTI_T_CAM2_LIDAR), (3, presets.KITTI_T_CAM3_LIDAR)):
        np.testing.assert_allclose(T, calib["cameras"][cam]["T_cam_lidar"], atol=1e-6)
    # Cameras 2 and 3 sit 0.54 m apart along x.
    assert abs(presets.KITTI_T_CAM2_LIDAR[0, 3] - presets.KITTI_T_CAM3_LIDAR[0, 3] - 0.537) < 0.01


def test_per_date_calibration_folder(tmp_path, kitti_frame):
    for date in ("2011_09_26", "2011_09_28"):
        (tmp_path / date).mkdir()
        for f in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
            shutil.copy(kitti_frame / f, tmp_path / date / f)
    # A different date gets a different (here: edited) calibration.
    velo = (tmp_path / "2011_09_28" / "calib_velo_to_cam.txt").read_text().splitlines()
    velo = [("T: 0.1 -0.2 -0.3" if line.startswith("T:") else line) for line in velo]
    (tmp_path / "2011_09_28" / "calib_velo_to_cam.txt").write_text("\n".join(velo) + "\n")
    extrinsics = KittiExtrinsics(tmp_path)
    T26 = extrinsics(tmp_path / f"{NAME.format(3)}.png")
    T28 = extrinsics(tmp_path / f"{NAME.format(3).replace('09_26', '09_28')}.png")
    np.testing.assert_allclose(T26, presets.KITTI_T_CAM3_LIDAR, atol=1e-6)
    assert np.abs(T28 - T26).max() > 0.05
    with pytest.raises(InputError, match="2011_10_03"):
        extrinsics(tmp_path / f"{NAME.format(2).replace('09_26', '10_03')}.png")
    with pytest.raises(InputError, match="recording date"):
        extrinsics(tmp_path / "0000000005.png")
    assert KittiExtrinsics(tmp_path, camera=2).camera_of(NAME.format(3)) == 2


@pytest.mark.parametrize("text, message", [
    ("1 0 0 0\n0 1 0 0\n0 0 1", r"12 \(3x4\) or 16 \(4x4\) numbers"),
    ("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 2", r"last row \(0, 0, 0, 1\)"),
    ("2 0 0 0 0 1 0 0 0 0 1 0", "a rotation"),
    ("1 0 0 0 0 1 0 0 0 0 1 nan", "finite"),
])
def test_extrinsic_file_errors(tmp_path, text, message):
    path = tmp_path / "T.txt"
    path.write_text(text + "\n")  # complete files end with a line end (a 3x4 without one is refused as cut short)
    with pytest.raises(InputError, match=message) as err:
        read_extrinsic_txt(path)
    assert "T.txt" in str(err.value)


def test_extrinsic_file_reads_3x4_and_4x4(tmp_path):
    T = presets.KITTI_T_CAM3_LIDAR
    (tmp_path / "a.txt").write_text(" ".join(f"{x:.9g}" for x in T[:3].ravel()) + "\n")
    (tmp_path / "b.txt").write_text("\n".join(", ".join(f"{x:.9g}" for x in row) for row in T))
    for name in ("a.txt", "b.txt"):
        np.testing.assert_allclose(read_extrinsic_txt(tmp_path / name), T, atol=1e-7)


# ---------------------------------------------------------------- point format
@pytest.mark.parametrize("n_floats, name, expected", [
    (4 * 7, "a.bin", 4),          # 112 bytes: 4 columns only
    (5 * 7, "a.bin", 5),          # 140 bytes: 5 columns only
    (20 * 3, "a.pcd.bin", 5),     # fits both, but *.pcd.bin is nuScenes' 5-column format
])
def test_point_columns_follow_the_file(tmp_path, n_floats, name, expected):
    path = tmp_path / name
    np.zeros(n_floats, np.float32).tofile(path)
    assert infer_point_columns(path) == expected
    assert infer_point_columns(path, 4) == 4


def test_ambiguous_bin_is_refused(tmp_path, capsys):
    path = tmp_path / "sweep.bin"
    np.zeros(20 * 50, np.float32).tofile(path)          # 4000 bytes: 250 x 4 or 200 x 5
    with pytest.raises(InputError, match="fits both 4 and 5"):
        infer_point_columns(path)
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps({"lidar": {"beams": 32}, "cameras": [
        {"name": "c", "width": 16, "height": 12, "K": [[10, 0, 8], [0, 10, 6], [0, 0, 1]],
         "T_cam_lidar": np.eye(4).tolist()}]}))
    code = cli.main(["complete-rig", str(path), str(rig), str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 1 and "--point-columns" in err and "Traceback" not in err


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_complete_rig_warns_when_a_camera_sees_nothing(tmp_path, capsys, caplog):
    """The stereo rig of the shared small street (``scenes.stereo_street``: the same compiled completion as
    tests/test_rig.py) with CAM_B turned to look straight up, above the LiDAR's field of view (+2 degrees):
    it sees none of the sweep's points, is warned about and written all zero; CAM_A is not. A camera looking
    straight up does not fit a ground-bound sweep, so the plausibility checks refuse it unless ``--force``
    (tests/test_far_points_and_calibration.py checks that refusal)."""
    from scenes import SMALL_LIDAR, stereo_street
    frame, cams = stereo_street()
    points = np.asarray(frame.points)[np.asarray(frame.valid)]
    sweep = tmp_path / "sweep.npy"
    np.save(sweep, np.c_[points, np.zeros(len(points))].astype(np.float32))
    up = [[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]   # camera z = LiDAR +z, at the LiDAR
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps({
        "lidar": {"beams": SMALL_LIDAR.beams, "fov_up_deg": SMALL_LIDAR.fov_up_deg,
                  "fov_down_deg": SMALL_LIDAR.fov_down_deg, "columns": SMALL_LIDAR.columns, "origin_m": [0, 0, 0]},
        "cameras": [{"name": name, "width": cam.width, "height": cam.height, "K": np.asarray(cam.K, float).tolist(),
                     "T_cam_lidar": T} for name, cam, T in
                    (("CAM_A", cams[0], np.asarray(cams[0].T_cam_lidar, float).tolist()), ("CAM_B", cams[1], up))]}))
    code = cli.main(["complete-rig", str(sweep), str(rig), str(tmp_path / "out"), "--no-estimate", "--force"])
    err = capsys.readouterr().err
    assert code == 0 and "CAM_B: no LiDAR point projects into this camera" in err and "CAM_A: no LiDAR" not in err
    # said once: the command prints the job's report, the job does not log it as well
    assert err.count("CAM_B: no LiDAR point") == 1
    assert not [r for r in caplog.records if "no LiDAR point" in r.getMessage()]
    assert not read_depth_png(tmp_path / "out" / "CAM_B.png").any()
    assert read_depth_png(tmp_path / "out" / "CAM_A.png").all()


# ---------------------------------------------------------------- the shared frame through the CLI
@pytest.mark.slow  # the real KITTI pair: SGM batches at 352 x 1216
def test_cli_uses_each_cameras_own_extrinsic(tmp_path, kitti_frame):
    """Done when of issue 13: the CLI on the shared KITTI frame in depth-completion layout (the
    benchmark crop) equals the API called with each camera's own extrinsic. Both cameras go
    through one compiled batch (``--batch-size 2``): each frame carries its own extrinsic.

    Oracle: :func:`jaxdepth.batch.runner.complete_batch` with the extrinsics given explicitly, at
    the CLI's batch shape (one compiled program for the CLI and the oracle; ``tests/test_runner.py``
    checks the runner's batches against per-frame ``complete_with``). The uncropped frame
    takes the same path at another shape (another compile, nothing else)."""
    from jaxdepth.batch.runner import complete_batch
    from jaxdepth.io import encode_depth_uint16
    calib = read_kitti_raw_calib(kitti_frame / "calib_cam_to_cam.txt", kitti_frame / "calib_velo_to_cam.txt")
    src = tmp_path / "src"
    (src / "velodyne_raw").mkdir(parents=True)
    (src / "intrinsics").mkdir()
    names, depths, Ks, Ts = [], [], [], []
    for cam in (2, 3):
        sparse, K = crop_to_benchmark(read_depth_png(kitti_frame / f"velodyne_raw_image_0{cam}.png"),
                                      calib["cameras"][cam]["K"])
        name = NAME.format(cam)
        write_depth_png(src / "velodyne_raw" / f"{name}.png", sparse)
        text = " ".join(f"{x:.9g}" for x in np.asarray(K).ravel())
        (src / "intrinsics" / f"{name}.txt").write_text(text)
        names.append(name)
        depths.append(read_depth_png(src / "velodyne_raw" / f"{name}.png"))
        Ks.append(np.asarray(text.split(), np.float32).reshape(3, 3))
        Ts.append(calib["cameras"][cam]["T_cam_lidar"])
    depths, Ks = np.stack(depths), np.stack(Ks)
    options = dict(batch_size=2, strategy="map", devices=1)
    api = complete_batch(depths, Ks, np.stack(Ts).astype(np.float32), **options)
    wrong = complete_batch(depths, Ks, presets.KITTI_T_CAM2_LIDAR, **options)  # camera 2's for both
    dst = tmp_path / "dst"
    assert cli.main(["complete", str(src), str(dst), "--quiet", "--batch-size", "2", "--cpu-devices", "1"]) == 0
    for i, name in enumerate(names):
        got = cv2.imread(str(dst / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(got, encode_depth_uint16(api[i]), err_msg=name)
    np.testing.assert_array_equal(wrong[0], api[0])  # camera 2: its own extrinsic either way
    assert np.mean(np.abs(api[1] - wrong[1]) > 0.05) > 0.001  # camera 2's extrinsic would differ on camera 3
