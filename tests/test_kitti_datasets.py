"""`jaxdepth complete` on KITTI dataset roots: raw (two dates), depth-completion train/val trees, object.

The trees are built in tmp_path from the shared KITTI files (never in the repo). The
oracle of every output is the library API called with that camera's own K and
extrinsic from the layout's own calibration files, read independently here.
"""

from __future__ import annotations

import re
import shutil

import cv2
import numpy as np
import pytest

import jaxdepth
from jaxdepth import cli
from jaxdepth.batch import runner
from jaxdepth.io import (encode_depth_uint16, pad_points, read_depth_png, read_kitti_raw_calib, read_points,
                         rig_from_kitti_object, rig_from_kitti_raw)
from jaxdepth.io import kitti_datasets
from jaxdepth.io.atomic import make_output_folders
from jaxdepth.io.calib import read_kitti_object_calib

from conftest import require_shared

DATE_A, DATE_B = "2011_09_26", "2011_09_28"
DRIVE_A, DRIVE_B = f"{DATE_A}_drive_0001_sync", f"{DATE_B}_drive_0002_sync"


def _shift_principal_points(text: str, dx: float) -> str:
    """calib_cam_to_cam.txt with every P_rect_0X's cx moved by dx pixels (another valid calibration)."""
    def shift(match):
        values = [float(v) for v in match.group(2).split()]
        values[2] += dx
        return match.group(1) + " ".join(f"{v:.6e}" for v in values)
    return re.sub(r"^(P_rect_0\d: )(.*)$", shift, text, flags=re.M)


@pytest.fixture(scope="module")
def raw_tree(tmp_path_factory):
    """Two dates: 2011_09_26 (drive_0001 frame 5) and '2011_09_28' (scene 2's sweep, calibration cx + 7 px)."""
    frame = require_shared("kitti", "drive_0001_frame05")
    scene = require_shared("kitti", "raw_2011_09_26_scene2")
    root = tmp_path_factory.mktemp("kitti_raw")
    for date, drive, source, sweep, dx in ((DATE_A, DRIVE_A, frame, "0000000005", 0.0),
                                           (DATE_B, DRIVE_B, scene, "0000000000", 7.0)):
        data = root / date / drive / "velodyne_points" / "data"
        data.mkdir(parents=True)
        shutil.copyfile(source / "lidar_data.bin", data / f"{sweep}.bin")
        for cam in (2, 3):
            images = root / date / drive / f"image_0{cam}" / "data"
            images.mkdir(parents=True)
            shutil.copyfile(source / f"image_0{cam}.png", images / f"{sweep}.png")
        text = (source / "calib_cam_to_cam.txt").read_text()
        (root / date / "calib_cam_to_cam.txt").write_text(_shift_principal_points(text, dx))
        shutil.copyfile(source / "calib_velo_to_cam.txt", root / date / "calib_velo_to_cam.txt")
    return root


def _expected_sweep_png(sweep, camera) -> np.ndarray:
    """The library's own answer, as the uint16 PNG values: the depth of complete_points_stages with this
    camera (the program test_extras_cli's KITTI sweep oracle and notebook 01 compile for this bucket and
    crop; ``complete_points`` is that same depth in a jit of its own)."""
    points, _ = read_points(sweep, columns=4)
    padded, valid = pad_points(points)
    depth = np.asarray(jaxdepth.complete_points_stages(padded, valid, camera.as_camera()).depth)
    return encode_depth_uint16(depth)


def _png_u16(path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)


@pytest.mark.xdist_group("jobs_kitti_sweeps")  # one worker compiles the KITTI sweep batch and its oracle once
@pytest.mark.slow  # real KITTI sweeps completed at full camera size
@pytest.mark.production_flags  # job PNG == API bit for bit at the production codegen (level 0: one pixel 1/256 m off)
def test_raw_two_dates_per_camera_calibration_resume_and_bad_sweep(raw_tree, tmp_path, capsys):
    bad = raw_tree / DATE_B / DRIVE_B / "velodyne_points" / "data" / "0000000001.bin"
    bad.write_bytes((raw_tree / DATE_B / DRIVE_B / "velodyne_points" / "data" / "0000000000.bin").read_bytes()[:1003])
    try:
        dst = tmp_path / "out"
        code = cli.main(["complete", str(raw_tree), str(dst), "--crop", "--batch-size", "2"])
        err = capsys.readouterr().err
        assert code == 1
        assert "found KITTI raw: 6 frames = 3 sweeps x cameras 2, 3" in err and f"{DATE_A}, {DATE_B}" in err
        assert err.count("FAILED") == 2 and "0000000001.bin" in err and "Traceback" not in err
        assert "4 completed, 0 skipped (already done), 2 failed" in err
        outs = sorted(p.relative_to(dst).as_posix() for p in dst.rglob("*") if p.is_file())
        records = [o for o in outs if o.endswith("/jaxdepth_run.json")]  # one run record per proj_depth/<name>
        assert records == [f"{drive}/proj_depth/sgm/jaxdepth_run.json" for drive in (DRIVE_A, DRIVE_B)]
        outs = [o for o in outs if o not in records]
        assert outs == [f"{drive}/proj_depth/sgm/image_0{cam}/{frame}.png"
                        for drive, frame in ((DRIVE_A, "0000000005"), (DRIVE_B, "0000000000")) for cam in (2, 3)]
        for date, drive, frame in ((DATE_A, DRIVE_A, "0000000005"), (DATE_B, DRIVE_B, "0000000000")):
            rig = rig_from_kitti_raw(raw_tree / date / "calib_cam_to_cam.txt",
                                     raw_tree / date / "calib_velo_to_cam.txt", crop=True)
            for camera in rig.cameras:
                got = _png_u16(dst / drive / "proj_depth" / "sgm" / camera.name / f"{frame}.png")
                assert got.shape == (352, 1216)
                expected = _expected_sweep_png(raw_tree / date / drive / "velodyne_points" / "data" / f"{frame}.bin",
                                               camera)
                np.testing.assert_array_equal(got, expected)
        # each date's own calibration: the shifted cx of the second date moves its depth image
        calib_a = read_kitti_raw_calib(raw_tree / DATE_A / "calib_cam_to_cam.txt",
                                       raw_tree / DATE_A / "calib_velo_to_cam.txt")
        calib_b = read_kitti_raw_calib(raw_tree / DATE_B / "calib_cam_to_cam.txt",
                                       raw_tree / DATE_B / "calib_velo_to_cam.txt")
        assert calib_b["cameras"][2]["K"][0, 2] == pytest.approx(calib_a["cameras"][2]["K"][0, 2] + 7.0)
        # re-run: finished frames are skipped, untouched; the bad sweep fails again
        stamps = {p: p.stat().st_mtime_ns for p in dst.rglob("*.png")}
        code = cli.main(["complete", str(raw_tree), str(dst), "--crop", "--batch-size", "2"])
        err = capsys.readouterr().err
        assert code == 1 and "0 completed, 4 skipped (already done), 2 failed" in err
        assert stamps == {p: p.stat().st_mtime_ns for p in dst.rglob("*.png")}
        assert not [p for p in dst.rglob("*") if p.is_file() and p.suffix != ".png"
                    and p.name != "jaxdepth_run.json"]  # no temp files left
    finally:
        bad.unlink()


def test_raw_drive_folder_date_folder_and_camera_option_give_the_same_jobs(raw_tree, tmp_path):
    whole = kitti_datasets.kitti_raw_jobs(raw_tree, tmp_path, crop=True)
    date = kitti_datasets.kitti_raw_jobs(raw_tree / DATE_B, tmp_path, crop=True)
    drive = kitti_datasets.kitti_raw_jobs(raw_tree / DATE_B / DRIVE_B, tmp_path, crop=True)
    assert [j.out_path for j in drive.jobs] == [j.out_path for j in date.jobs] == \
        [j.out_path for j in whole.jobs if DRIVE_B in j.name]
    by_name = {j.name: j for j in whole.jobs}
    for job in drive.jobs:  # calibration from the drive's parent (its date folder)
        np.testing.assert_array_equal(job.K, by_name[job.name].K)
        np.testing.assert_array_equal(job.T_cam_lidar, by_name[job.name].T_cam_lidar)
    only3 = kitti_datasets.kitti_raw_jobs(raw_tree, tmp_path / "o", camera=3, name="mine")
    assert [j.out_path.relative_to(tmp_path / "o").as_posix() for j in only3.jobs] == [
        f"{DRIVE_A}/proj_depth/mine/image_03/0000000005.png", f"{DRIVE_B}/proj_depth/mine/image_03/0000000000.png"]
    assert {j.image_size for j in only3.jobs} == {(375, 1242)}  # full frame without --crop (S_rect_03)
    assert kitti_datasets.detect_kitti_layout(raw_tree / DATE_A / DRIVE_A) == "kitti-raw"


@pytest.mark.parametrize("extra,pattern", [
    (["--method", "nearest"], "sgm only"),
    (["--calib-dir", "."], "--calib-dir is for depth-completion trees"),
    (["--intrinsics", "K.txt"], "--intrinsics does not apply"),
])
def test_raw_options_that_do_not_apply_are_refused_before_any_work(raw_tree, tmp_path, capsys, extra, pattern):
    code = cli.main(["complete", str(raw_tree), str(tmp_path / "out"), *extra])
    err = capsys.readouterr().err
    assert code == 1 and pattern in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_crop_on_a_selection_folder_is_refused(tmp_path, capsys):
    frame = require_shared("kitti", "drive_0001_frame05")
    assert cli.main(["complete", str(frame), str(tmp_path / "out"), "--crop"]) == 1
    assert "--crop needs a KITTI raw or object folder" in capsys.readouterr().err


def test_raw_drive_without_date_calibration_is_a_clear_error(raw_tree, tmp_path):
    lone = tmp_path / "x" / DRIVE_A
    shutil.copytree(raw_tree / DATE_A / DRIVE_A, lone)
    with pytest.raises(jaxdepth.io.InputError, match="calib_cam_to_cam.txt.*not found"):
        kitti_datasets.kitti_raw_jobs(lone, tmp_path / "out")


def test_unknown_layout_lists_the_layouts_understood(tmp_path, capsys):
    (tmp_path / "src" / "something").mkdir(parents=True)
    code = cli.main(["complete", str(tmp_path / "src"), str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1
    for word in ("KITTI raw", "depth-completion train/val", "KITTI object", "selection folder", "nuScenes dataroot",
                 "Argoverse 2 sensor logs"):
        assert word in err


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_depth_completion_train_val_tree_with_per_date_calibration(tmp_path, capsys):
    frame = require_shared("kitti", "drive_0001_frame05")
    scene = require_shared("kitti", "raw_2011_09_26_scene2")
    src, calib = tmp_path / "kitti_depth", tmp_path / "calib"
    for split, date, drive, source, dx in (("train", DATE_A, DRIVE_A, frame, 0.0),
                                           ("val", DATE_B, DRIVE_B, scene, -5.0)):
        for cam in (2, 3):
            folder = src / split / drive / "proj_depth" / "velodyne_raw" / f"image_0{cam}"
            folder.mkdir(parents=True)
            shutil.copyfile(frame / f"velodyne_raw_image_0{cam}.png", folder / "0000000005.png")
        (calib / date).mkdir(parents=True)
        text = (source / "calib_cam_to_cam.txt").read_text()
        (calib / date / "calib_cam_to_cam.txt").write_text(_shift_principal_points(text, dx))
        shutil.copyfile(source / "calib_velo_to_cam.txt", calib / date / "calib_velo_to_cam.txt")
    dst = tmp_path / "out"
    code = cli.main(["complete", str(src / "train"), str(dst), "--method", "nearest"])
    assert code == 1 and "--calib-dir" in capsys.readouterr().err  # no intrinsics folder: a clear error
    args = ["complete", str(src / "train"), str(dst), "--calib-dir", str(calib), "--method", "nearest",
            "--camera", "3"]
    assert cli.main(args) == 0
    err = capsys.readouterr().err
    assert "found KITTI depth-completion tree: 1 frames, 1 drive(s), cameras 3" in err
    assert [p.relative_to(dst).as_posix() for p in dst.rglob("*.png")] == [
        f"{DRIVE_A}/proj_depth/nearest/image_03/0000000005.png"]
    # the whole tree (train and val) mirrors into dst; per date and camera its own K and extrinsic
    # (--batch-size 1: the first run's compiled batch again)
    assert cli.main(["complete", str(src), str(dst / "all"), "--calib-dir", str(calib), "--method", "nearest",
                     "--name", "nn", "-q", "--batch-size", "1"]) == 0
    # Oracle: the library's batch completion with each frame's K and extrinsic given explicitly, at the
    # CLI's batch shape (the same compiled program; tests/test_runner.py checks complete_batch against
    # per-frame calls).
    from jaxdepth.batch.runner import complete_batch
    paths, depths, Ks, Ts = [], [], [], []
    for split, date, drive in (("train", DATE_A, DRIVE_A), ("val", DATE_B, DRIVE_B)):
        cams = read_kitti_raw_calib(calib / date / "calib_cam_to_cam.txt",
                                    calib / date / "calib_velo_to_cam.txt")["cameras"]
        for cam in (2, 3):
            depths.append(read_depth_png(src / split / drive / "proj_depth" / "velodyne_raw" / f"image_0{cam}"
                                         / "0000000005.png"))
            Ks.append(cams[cam]["K"])
            Ts.append(cams[cam]["T_cam_lidar"])
            paths.append(dst / "all" / split / drive / "proj_depth" / "nn" / f"image_0{cam}" / "0000000005.png")
    expected = complete_batch(np.stack(depths), np.stack(Ks), np.stack(Ts).astype(np.float32), method="nearest",
                              batch_size=1)
    for path, want in zip(paths, expected):
        np.testing.assert_array_equal(_png_u16(path), encode_depth_uint16(want))
    # --calib-dir holding the two files directly: every date uses them
    flat = kitti_datasets.kitti_depth_tree_jobs(src, dst, calib_dir=calib / DATE_A)
    assert len(flat.jobs) == 4 and all(np.array_equal(j.K, flat.jobs[0].K) for j in flat.jobs[::2])


def test_selection_folder_keeps_its_layout(tmp_path):
    frame = require_shared("kitti", "drive_0001_frame05")
    assert kitti_datasets.detect_kitti_layout(frame) is None  # a flat folder of PNGs: the old path


@pytest.fixture(scope="module")
def object_split(tmp_path_factory):
    source = require_shared("kitti", "object")
    root = tmp_path_factory.mktemp("kitti_object") / "training"
    for sub in ("velodyne", "calib", "image_2"):
        shutil.copytree(source / sub, root / sub)
    return root


@pytest.mark.xdist_group("jobs_kitti_sweeps")  # one worker compiles the KITTI sweep batch and its oracle once
@pytest.mark.slow  # real KITTI object frames completed at full camera size
def test_object_split_per_frame_calibration_and_bad_calibration(object_split, tmp_path, capsys):
    calib = object_split / "calib" / "000001.txt"
    good = calib.read_text()
    calib.write_text(good.replace("R0_rect:", "R0_rect_missing:"))
    try:
        dst = tmp_path / "out"
        code = cli.main(["complete", str(object_split.parent), str(dst), "--crop", "--batch-size", "2"])
        err = capsys.readouterr().err
        assert code == 1 and "found KITTI object: 3 frames in training, camera 2" in err
        assert "FAILED training/000001:" in err and "R0_rect" in err
        assert "2 completed, 0 skipped (already done), 1 failed" in err
        assert sorted(p.relative_to(dst).as_posix() for p in dst.rglob("*.png")) == [
            "training/depth_2/000000.png", "training/depth_2/000002.png"]
        for frame in ("000000", "000002"):
            h, w = cv2.imread(str(object_split / "image_2" / f"{frame}.png")).shape[:2]
            rig = rig_from_kitti_object(object_split / "calib" / f"{frame}.txt", width=w, height=h, crop=True)
            got = _png_u16(dst / "training" / "depth_2" / f"{frame}.png")
            np.testing.assert_array_equal(got, _expected_sweep_png(object_split / "velodyne" / f"{frame}.bin",
                                                                   rig.cameras[0]))
    finally:
        calib.write_text(good)
    # fixed calibration, and one finished output deleted by hand: the re-run completes only the two
    # missing frames (two: the first run's compiled batch again) and leaves the finished one untouched
    kept = dst / "training" / "depth_2" / "000000.png"
    stamp = kept.stat().st_mtime_ns
    (dst / "training" / "depth_2" / "000002.png").unlink()
    code = cli.main(["complete", str(object_split), str(dst), "--crop", "--batch-size", "2"])
    assert code == 0 and "2 completed, 1 skipped (already done), 0 failed" in capsys.readouterr().err
    assert kept.stat().st_mtime_ns == stamp
    assert sorted(p.name for p in (dst / "training" / "depth_2").glob("*.png")) == [
        "000000.png", "000001.png", "000002.png"]


def test_rig_from_kitti_object_matches_the_calibration_projection(object_split):
    """K T == P2 R0_rect Tr_velo_to_cam (KITTI's own projection), and the crop shifts the principal point."""
    path = object_split / "calib" / "000000.txt"
    fields = {}
    for line in path.read_text().splitlines():
        if ":" in line:
            key, values = line.split(":", 1)
            fields[key] = np.array(values.split(), np.float64)
    R0 = np.eye(4)
    R0[:3, :3] = fields["R0_rect"].reshape(3, 3)
    Tr = np.eye(4)
    Tr[:3] = fields["Tr_velo_to_cam"].reshape(3, 4)
    P2 = fields["P2"].reshape(3, 4)
    rig = rig_from_kitti_object(path, width=1224, height=370)
    cam = rig.cameras[0]
    assert (cam.name, cam.width, cam.height) == ("image_02", 1224, 370)
    np.testing.assert_allclose(cam.K.astype(np.float64) @ cam.T_cam_lidar[:3].astype(np.float64), P2 @ R0 @ Tr,
                               rtol=1e-5, atol=1e-3)
    cropped = rig_from_kitti_object(path, width=1224, height=370, crop=True).cameras[0]
    assert (cropped.height, cropped.width) == (352, 1216)
    np.testing.assert_allclose(cropped.K[:2, 2], cam.K[:2, 2] - [4, 18], atol=1e-4)
    assert read_kitti_object_calib(path)["cameras"][2]["width"] is None
    with pytest.raises(jaxdepth.io.InputError, match="image"):
        rig_from_kitti_object(path, width=1000, height=300, crop=True)


@pytest.mark.xdist_group("jobs_kitti_sweeps")  # one worker compiles the KITTI sweep batch and its oracle once
@pytest.mark.slow  # real KITTI sweeps: SGM batches at 352 x 1216
def test_ray_actor_completes_sweep_jobs_like_the_local_runner(raw_tree, tmp_path):
    """The Ray engine's actor (called directly, no cluster) gives the local runner's bytes for sweep jobs."""
    from jaxdepth.batch import scale
    scan = kitti_datasets.kitti_raw_jobs(raw_tree / DATE_A, tmp_path / "ray", crop=True)
    records = [scale._record(runner.FrameJob.from_files(frame)) for frame in scan.jobs]
    assert [j.image_size for j in scale._jobs_from_batch({k: [r[k] for r in records] for k in records[0]})] == \
        [(352, 1216)] * 2
    batch = {key: np.array([r[key] for r in records], dtype=object) for key in records[0]}
    make_output_folders(job.out_path for job in scan.jobs)
    actor = scale._CompleteFrames(method="sgm", config=jaxdepth.SGMConfig(), lidar=jaxdepth.KITTI_HDL64,
                                  T_cam_lidar=np.eye(4), batch_size=2)
    rows = actor(batch)
    assert list(rows["status"]) == ["done", "done"], rows["message"]
    (tmp_path / "local").mkdir()
    local = runner.run_jobs([runner.FrameJob(**{**job.__dict__, "out_path": tmp_path / "local" / f"{i}.png"})
                             for i, job in enumerate(scan.jobs)], batch_size=2)
    assert local.ok
    for i, job in enumerate(scan.jobs):
        np.testing.assert_array_equal(_png_u16(job.out_path), _png_u16(tmp_path / "local" / f"{i}.png"))


def test_sweeps_of_different_lengths_group_by_power_of_two_bucket(raw_tree, tmp_path):
    """A short sweep lands in a smaller bucket (its own compiled batch); equal buckets share one."""
    (job,) = kitti_datasets.kitti_raw_jobs(raw_tree / DATE_A, tmp_path, camera=2, crop=True).jobs
    short = tmp_path / "short.bin"
    short.write_bytes(job.sparse_path.read_bytes()[:16 * 60000])
    keys = []
    for path in (job.sparse_path, short):
        data, K = runner._load(runner.FrameJob(**{**job.__dict__, "sparse_path": path}))
        keys.append(runner._group_key(job, data))
        assert data[0].shape[0] == data[1].shape[0] and data[1].sum() == path.stat().st_size // 16
    assert keys == [("sweep", 131072, 352, 1216), ("sweep", 65536, 352, 1216)]


# ---------------------------------------------------------------- camera images (image-guided seeds)


def _bgr_to_rgb(path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[:, :, ::-1]


def test_raw_jobs_find_the_drive_images_and_crop_them_like_the_depth(raw_tree, tmp_path):
    from jaxdepth.io import crop_to_benchmark
    for crop in (False, True):
        scan = kitti_datasets.kitti_raw_jobs(raw_tree, tmp_path, crop=crop)
        for job in scan.jobs:
            drive, cam, frame = job.name.split("/")
            assert job.image_path == raw_tree / drive[:10] / drive / cam / "data" / f"{frame}.png"
            assert job.image_crop_from == ((375, 1242) if crop else None)  # S_rect_0X of both dates
            image = runner._load_image(job, job.image_size)
            full = _bgr_to_rgb(job.image_path)
            expected = crop_to_benchmark(full, np.eye(3))[0] if crop else full
            assert image.shape == job.image_size + (3,)
            np.testing.assert_array_equal(image, expected)
    # another raw root holds the images: <root>/<date>/<drive>/... (or <root>/<drive>/...)
    other = tmp_path / "images"
    shutil.copytree(raw_tree / DATE_A / DRIVE_A / "image_02", other / DRIVE_A / "image_02")
    (job,) = kitti_datasets.kitti_raw_jobs(raw_tree / DATE_A, tmp_path, camera=2, image_dir=other).jobs
    assert job.image_path == other / DRIVE_A / "image_02" / "data" / "0000000005.png" and job.image_path.is_file()


def test_object_jobs_use_image_x_and_crop_from_its_own_size(object_split, tmp_path):
    for crop in (False, True):
        scan = kitti_datasets.kitti_object_jobs(object_split, tmp_path, crop=crop)
        for job in scan.jobs:
            frame = job.name.split("/")[1]
            assert job.image_path == object_split / "image_2" / f"{frame}.png"
            full = cv2.imread(str(job.image_path)).shape[:2]
            assert job.image_crop_from == (full if crop else None)
            assert job.image_size == ((352, 1216) if crop else full)
            assert runner._load_image(job, job.image_size).shape == job.image_size + (3,)
    assert {job.image_crop_from for job in kitti_datasets.kitti_object_jobs(object_split, tmp_path, crop=True).jobs} \
        == {(370, 1224), (375, 1242)}
    with pytest.raises(jaxdepth.io.InputError, match="--image-dir does not apply"):
        kitti_datasets.discover_kitti(object_split, tmp_path, image_dir=object_split)


def test_depth_tree_images_come_from_a_raw_root_or_a_clear_error(raw_tree, tmp_path, capsys):
    frame = require_shared("kitti", "drive_0001_frame05")
    src = tmp_path / "train"
    folder = src / DRIVE_A / "proj_depth" / "velodyne_raw" / "image_02"
    folder.mkdir(parents=True)
    shutil.copyfile(frame / "velodyne_raw_image_02.png", folder / "0000000005.png")
    calib = raw_tree / DATE_A
    (job,) = kitti_datasets.kitti_depth_tree_jobs(src, tmp_path / "o", calib_dir=calib, image_dir=raw_tree).jobs
    assert job.image_path == raw_tree / DATE_A / DRIVE_A / "image_02" / "data" / "0000000005.png"
    assert job.image_crop_from is None
    np.testing.assert_array_equal(runner._load_image(job, (375, 1242)), _bgr_to_rgb(job.image_path))
    assert kitti_datasets.kitti_depth_tree_jobs(src, tmp_path / "o", calib_dir=calib).jobs[0].image_path is None
    code = cli.main(["complete", str(src), str(tmp_path / "out"), "--calib-dir", str(calib),
                     "--guidance-weight", "1"])
    err = capsys.readouterr().err
    assert code == 1 and "holds no camera images" in err and "--image-dir" in err
    assert not (tmp_path / "out").exists()
