"""No silent wrong depth: each input that used to complete into wrong depth with exit 0 is refused
with a one-line message (or, with --force, used and logged). See docs/bad_input_checks.md."""

from __future__ import annotations

import json
import re
import shutil

import cv2
import numpy as np
import pytest

from jaxdepth import cli
from jaxdepth.io import read_depth_png, write_depth_png
from tests.conftest import require_shared

DATE, DRIVE = "2011_09_26", "2011_09_26_drive_0001_sync"


def _run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("jaxdepth: error:") or line.startswith("FAILED")]
    assert lines and "Traceback" not in err, err
    return lines[0]


def _kitti_records():
    return np.fromfile(require_shared("kitti", "drive_0001_frame05", "lidar_data.bin"), "<f4").reshape(-1, 4)


def _nusc_sweep():
    return next(require_shared("nuscenes", "sample").glob("*.pcd.bin"))


def _raw_tree(root, sweep_bytes: bytes):
    frame = require_shared("kitti", "drive_0001_frame05")
    data = root / DATE / DRIVE / "velodyne_points" / "data"
    data.mkdir(parents=True)
    (data / "0000000005.bin").write_bytes(sweep_bytes)
    shutil.copyfile(frame / "calib_cam_to_cam.txt", root / DATE / "calib_cam_to_cam.txt")
    shutil.copyfile(frame / "calib_velo_to_cam.txt", root / DATE / "calib_velo_to_cam.txt")
    return root


# ------------------------------------------------------------------ sweeps with the wrong layout


@pytest.mark.parametrize("layout, fits", [("3 columns", "3 float32 per point"),
                                          ("nuScenes .pcd.bin renamed", "5 float32 per point (nuScenes")])
def test_kitti_raw_job_refuses_a_bin_with_another_column_count(tmp_path, capsys, layout, fits):
    data = (_kitti_records()[:, :3].tobytes() if layout == "3 columns" else _nusc_sweep().read_bytes())
    root = _raw_tree(tmp_path / "raw", data)
    code, _, err = _run(capsys, "complete", root, tmp_path / "out", "--camera", "2")
    line = _one_line_error(err)
    assert code == 1 and "0000000005.bin: not a plausible LiDAR sweep when read as 4 float32 per point" in line
    assert fits in line and "--force" in line
    # `complete` has no --point-columns (a KITTI raw sweep is 4 columns): the hint names the layout instead
    assert "--point-columns" not in line and "this dataset's sweeps are 4 float32 per point" in line
    assert not list((tmp_path / "out").rglob("*.png"))


@pytest.fixture(scope="module")
def kitti_rig(tmp_path_factory):
    from jaxdepth.io.rig import rig_from_kitti_raw, write_rig_json
    frame = require_shared("kitti", "drive_0001_frame05")
    path = tmp_path_factory.mktemp("rig") / "kitti_rig.json"
    write_rig_json(path, rig_from_kitti_raw(frame / "calib_cam_to_cam.txt", frame / "calib_velo_to_cam.txt",
                                            cameras=(2,)))
    return path


@pytest.mark.parametrize("variant", ["3 columns", "float64", "pcd.bin as 4 columns"])
def test_complete_rig_refuses_a_sweep_in_the_wrong_layout_and_names_the_layouts_it_fits(
        tmp_path, capsys, kitti_rig, variant):
    records = _kitti_records()
    extra = []
    if variant == "3 columns":
        sweep, fits = tmp_path / "sweep.bin", "3 float32 per point"
        sweep.write_bytes(records[:, :3].tobytes())
        extra = ["--point-columns", "4"]
    elif variant == "float64":
        sweep, fits = tmp_path / "sweep.bin", "4 float64 per point"
        sweep.write_bytes(records.astype("<f8").tobytes())
    else:
        sweep, fits = tmp_path / "sweep.pcd.bin", "5 float32 per point (nuScenes"
        shutil.copyfile(_nusc_sweep(), sweep)
        extra = ["--point-columns", "4"]
    code, _, err = _run(capsys, "complete-rig", sweep, kitti_rig, tmp_path / "out", *extra)
    line = _one_line_error(err)
    assert code == 1 and "not a plausible LiDAR sweep" in line and fits in line, line
    assert "not one spinning LiDAR" not in err
    assert not list((tmp_path / "out").glob("*.png"))


def test_force_uses_a_refused_sweep_and_logs_it(tmp_path, capsys, kitti_rig, caplog):
    from jaxdepth.io.points import read_points
    sweep = tmp_path / "sweep.bin"
    sweep.write_bytes(_kitti_records()[:, :3].tobytes())
    points, _ = read_points(sweep, columns=4, force=True)
    assert points.shape == (121948 * 3 // 4, 3)
    assert any("--force: using it although" in r.message for r in caplog.records)


# ------------------------------------------------------------------ depth PNG scale


def _kitti_u16(name):
    return cv2.imread(str(require_shared("kitti", "drive_0001_frame05", name)), cv2.IMREAD_UNCHANGED)


def _millimetres(u16):
    return np.clip(np.rint(u16.astype(np.float64) / 256 * 1000), 0, 65535).astype(np.uint16)


def test_depth_pngs_in_millimetres_are_refused_as_lidar_input_and_as_ground_truth(tmp_path, capsys):
    folder = tmp_path / "mm"
    folder.mkdir()
    cv2.imwrite(str(folder / "frame.png"), _millimetres(_kitti_u16("velodyne_raw_image_02.png")))
    K = tmp_path / "K.txt"
    K.write_text("721.5377 0 609.5593\n0 721.5377 172.854\n0 0 1\n")
    code, _, err = _run(capsys, "complete", folder, tmp_path / "out", "--intrinsics", K, "-q")
    line = _one_line_error(err)
    assert code == 1 and "frame.png: LiDAR input is not in metres x 256" in line and "millimetres" in line
    assert not (tmp_path / "out" / "frame.png").exists()
    # as ground truth of eval
    pred, gt = tmp_path / "pred", tmp_path / "gt"
    pred.mkdir()
    gt.mkdir()
    truth = _kitti_u16("groundtruth_image_02.png")
    write_depth_png(pred / "f.png", np.full(truth.shape, 10.0, np.float32))
    cv2.imwrite(str(gt / "f.png"), _millimetres(truth))
    code, out, err = _run(capsys, "eval", pred, gt)
    assert code == 1 and "ground truth is not in metres x 256" in _one_line_error(err) and not out


def test_integer_metres_are_refused_and_real_metres_pass():
    from jaxdepth.io.plausibility import depth_scale_problem
    metres = _kitti_u16("velodyne_raw_image_02.png").astype(np.float64) / 256
    assert depth_scale_problem(metres) is None
    assert depth_scale_problem(_kitti_u16("groundtruth_image_02.png") / 256.0) is None
    assert "multiple of 256" in depth_scale_problem(np.rint(metres))
    assert "decimetres" in depth_scale_problem(np.rint(metres * 10) / 256)


def test_whole_metre_check_follows_the_png_units_exactly():
    """Whole metres are flagged iff every value rounds to a multiple of 256 PNG units (analytic cases)."""
    from jaxdepth.io.plausibility import depth_scale_problem
    whole = np.tile(np.arange(1.0, 61.0), (10, 1))          # 1..60 m, 60 distinct values
    flagged = lambda d: "multiple of 256" in (depth_scale_problem(d) or "")  # noqa: E731
    assert flagged(whole) and flagged(whole.astype(np.float32))
    assert flagged(whole + 1 / 1024)                        # a quarter unit: rounds back to the multiple
    one_unit = whole.copy()
    one_unit[3, 7] += 1 / 256                               # one PNG unit off a whole metre
    assert not flagged(one_unit) and not flagged(one_unit.astype(np.float32))
    with_gaps = whole.copy()
    with_gaps[0, :4] = [np.nan, np.inf, -5.0, 0.0]          # not depths: ignored
    assert flagged(with_gaps)
    with np.errstate(over="ignore"):
        assert not flagged(np.full((10, 60), 1e306))        # 256 x the value overflows: never whole


# ------------------------------------------------------------------ run records


def _sparse_folder(root, n=2, shape=(64, 128)):
    """``n`` random sparse depths and one K. 64 x 128, the size of ``tests/helpers.small_frames``: two
    frames in one batch compile what test_extras_cli / test_cli compile for that size (the session's
    compilation cache reads it back)."""
    rng = np.random.default_rng(3)
    root.mkdir()
    for i in range(n):
        d = np.where(rng.random(shape) < 0.08, rng.uniform(4.0, 40.0, shape), 0.0).astype(np.float32)
        write_depth_png(root / f"f{i}.png", d)
    K = root.parent / "K.txt"
    K.write_text("60 0 64\n0 60 32\n0 0 1\n")
    return root, K


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_rerun_with_other_settings_is_refused_same_settings_resume_overwrite_recomputes(tmp_path, capsys):
    src, K = _sparse_folder(tmp_path / "src")
    out = tmp_path / "out"
    # The records and refusals are the same for every method: "nearest" (the runner tests' batch
    # program) and its l2 fill without removal compile in a fraction of SGM's time.
    nearest = ("--method", "nearest")
    other = (*nearest, "--distance", "l2", "--no-outlier-removal")
    assert _run(capsys, "complete", src, out, "--intrinsics", K, *nearest)[0] == 0
    record = json.loads((out / "jaxdepth_run.json").read_text())
    assert record["settings"]["distance_metric"] == "l1" and record["settings"]["method"] == "nearest"
    assert record["inputs"] == [str(src.resolve())] and "complete" in record["command"]
    before = {p.name: p.read_bytes() for p in out.glob("*.png")}

    code, _, err = _run(capsys, "complete", src, out, "--intrinsics", K, *other)
    line = _one_line_error(err)
    assert code == 1 and "distance_metric: l1 -> l2" in line and "outlier_removal: true -> false" in line
    assert "--overwrite" in line
    assert {p.name: p.read_bytes() for p in out.glob("*.png")} == before

    code, _, err = _run(capsys, "complete", src, out, "--intrinsics", K, *nearest)
    assert code == 0 and "0 completed, 2 skipped" in err

    fresh = tmp_path / "fresh"
    assert _run(capsys, "complete", src, fresh, "--intrinsics", K, *other)[0] == 0
    code, _, err = _run(capsys, "complete", src, out, "--intrinsics", K, *other, "--overwrite")
    assert code == 0 and "2 completed" in err
    assert {p.name: p.read_bytes() for p in out.glob("*.png")} == {p.name: p.read_bytes() for p in fresh.glob("*.png")}
    assert json.loads((out / "jaxdepth_run.json").read_text())["settings"]["distance_metric"] == "l2"


def test_folder_with_outputs_but_no_record_is_refused(tmp_path, capsys):
    src, K = _sparse_folder(tmp_path / "src", n=1)
    out = tmp_path / "old"
    out.mkdir()
    shutil.copyfile(src / "f0.png", out / "f0.png")
    code, _, err = _run(capsys, "complete", src, out, "--intrinsics", K)
    assert code == 1 and "no jaxdepth_run.json" in _one_line_error(err)


@pytest.mark.xdist_group("eval_full_frame")  # the 375 x 1242 depth_metrics program: one worker
def test_eval_prints_the_predictions_recorded_settings(tmp_path, capsys):
    from jaxdepth.batch import run_record
    from jaxdepth._src.config import SGMConfig
    pred, gt = tmp_path / "pred", tmp_path / "gt"
    pred.mkdir()
    gt.mkdir()
    truth = _kitti_u16("groundtruth_image_02.png")
    cv2.imwrite(str(gt / "f.png"), truth)
    write_depth_png(pred / "f.png", np.where(truth > 0, truth / 256.0, 12.0).astype(np.float32))
    settings = run_record.settings_of(SGMConfig(distance_metric="l2"), method="sgm")
    run_record.claim_folder(pred, run_record.make_record(settings, inputs=[tmp_path], command=["x", "complete"]),
                            overwrite=True)
    code, out, _ = _run(capsys, "eval", pred, gt, "--json", tmp_path / "t.json")
    assert code == 0 and "prediction settings" in out and "distance_metric l2" in out
    assert json.loads((tmp_path / "t.json").read_text())["prediction_run"]["settings"]["distance_metric"] == "l2"


# ------------------------------------------------------------------ eval sides


@pytest.fixture
def eval_sides(tmp_path):
    """velodyne_raw (~4 %), groundtruth (~19 %) and a dense 'completion' of the shared KITTI frame."""
    folders = {k: tmp_path / k for k in ("lidar", "gt", "completion")}
    for f in folders.values():
        f.mkdir()
    truth = _kitti_u16("groundtruth_image_02.png")
    cv2.imwrite(str(folders["lidar"] / "f.png"), _kitti_u16("velodyne_raw_image_02.png"))
    cv2.imwrite(str(folders["gt"] / "f.png"), truth)
    dense = np.where(truth > 0, truth / 256.0, 15.0).astype(np.float32)
    write_depth_png(folders["completion"] / "f.png", dense)
    return folders


@pytest.mark.xdist_group("eval_full_frame")  # the 375 x 1242 depth_metrics program: one worker
def test_eval_with_swapped_folders_is_refused_and_suggests_the_swap(capsys, eval_sides):
    code, out, err = _run(capsys, "eval", eval_sides["gt"], eval_sides["completion"])
    line = _one_line_error(err)
    assert code == 1 and not out and "swapped" in line and "semi-dense, like KITTI ground truth" in line
    assert "dense, like a completion" in line


def test_eval_with_lidar_input_as_prediction_is_refused(capsys, eval_sides):
    code, _, err = _run(capsys, "eval", eval_sides["lidar"], eval_sides["gt"])
    line = _one_line_error(err)
    assert code == 1 and "LiDAR input" in line and "sparse" in line


def test_eval_right_way_round_scores_and_force_overrides(capsys, eval_sides, caplog):
    code, out, _ = _run(capsys, "eval", eval_sides["completion"], eval_sides["gt"])
    assert code == 0 and re.search(r"mean \(1 frames\)\s+0\.0", out)
    code, out, err = _run(capsys, "eval", eval_sides["gt"], eval_sides["completion"], "--force")
    assert code == 0 and any("--force: scoring although" in r.message for r in caplog.records)


# ------------------------------------------------------------------ validity from the sensor


def test_validity_limit_from_the_sensor_kitti_keeps_16_px():
    from jaxdepth._src import presets, validity as vd
    K = np.diag([721.5377, 721.5377, 1.0]).astype(np.float32)
    spacing = float(vd.scan_line_spacing_px(K, presets.KITTI_HDL64))
    assert spacing == pytest.approx(721.5377 * np.radians(2.0 + 24.9) / 63, rel=1e-5)
    assert float(vd.sensor_max_seed_distance_px(K, presets.KITTI_HDL64)) == pytest.approx(3 * spacing, rel=1e-6)
    assert abs(3 * spacing - 16.0) < 0.2


@pytest.mark.slow  # the real nuScenes sweep: SGM with extras at 450 x 800
def test_nuscenes_validity_marks_only_pixels_beyond_the_scan_line_spacing_and_count_honours_zero_invalid(
        tmp_path, capsys):
    """CAM_FRONT of the nuScenes sample through complete-rig: every pixel marked invalid is farther than one
    scan-line spacing from a seed (the fixed 16 px limit marked 26 % of the field of view invalid, in
    stripes, at full size), and the printed count is the written PNG's non-zero pixels. The camera at
    half size (800 x 450, K scaled) to keep the test fast."""
    import dataclasses

    from jaxdepth._src import validity as vd
    from jaxdepth.batch.extras import decode_seed_distance
    from jaxdepth.io.rig import read_rig_json, rig_from_nuscenes_calibration, write_rig_json
    sample = require_shared("nuscenes", "sample")
    full = rig_from_nuscenes_calibration(sample / "calibration.json")
    front = full.camera("CAM_FRONT")
    half = dataclasses.replace(front, width=front.width // 2, height=front.height // 2,
                               K=np.diag([0.5, 0.5, 1.0]).astype(np.float32) @ front.K)
    rig = type(full)(lidar=full.lidar, cameras=(half,))
    write_rig_json(tmp_path / "rig.json", rig)
    rig = read_rig_json(tmp_path / "rig.json")
    out = tmp_path / "out"
    code, stdout, _ = _run(capsys, "complete-rig", _nusc_sweep(), tmp_path / "rig.json", out, "--validity",
                           "--seed-distance", "--zero-invalid")
    assert code == 0
    count = int(re.search(r"CAM_FRONT: 800x450, (\d+) completed pixels", stdout).group(1))
    depth = read_depth_png(out / "CAM_FRONT.png")
    assert count == int(np.count_nonzero(depth)) < 800 * 450
    valid = cv2.imread(str(out / "CAM_FRONT_validity.png"), cv2.IMREAD_UNCHANGED) > 0
    distance = decode_seed_distance(cv2.imread(str(out / "CAM_FRONT_seed_distance.png"), cv2.IMREAD_UNCHANGED))
    camera = rig.cameras[0]
    inside = np.asarray(vd.fov_mask(camera.K, camera.T_cam_lidar, height=450, width=800, lidar=rig.lidar))
    spacing = float(vd.scan_line_spacing_px(camera.K, rig.lidar))
    assert 12.5 < spacing < 17.5  # HDL-32E, fy ~1266 / 2
    invalid = inside & ~valid
    assert np.all(distance[~valid] > spacing)  # anywhere: only pixels farther than one spacing from a seed
    assert invalid.sum() / inside.sum() < 0.10
    assert np.any(valid & ~inside)  # rows just beyond the outermost scan lines, within one spacing
    assert np.array_equal(depth > 0, valid & (depth > 0)) and not np.any(depth[~valid])


# ------------------------------------------------------------------ small items


def test_demo_into_a_folder_that_cannot_be_written_fails_before_any_work(tmp_path, capsys, monkeypatch):
    from jaxdepth import demo
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setattr(demo, "make_street_scene", lambda seed: pytest.fail("computed before checking --out"))
    code, _, err = _run(capsys, "demo", "--out", blocker / "sub")
    assert code == 1 and "cannot create output folder" in _one_line_error(err)


def test_single_png_output_folder_is_created_or_refused_before_computing(tmp_path, capsys, monkeypatch):
    src, K = _sparse_folder(tmp_path / "src", n=1)
    from jaxdepth.batch import runner
    blocker = tmp_path / "file"
    blocker.write_text("x")
    real = runner.run_jobs
    monkeypatch.setattr(runner, "run_jobs", lambda *a, **k: pytest.fail("computed before checking the output"))
    code, _, err = _run(capsys, "complete", src / "f0.png", blocker / "out.png", "--intrinsics", K)
    assert code == 1 and "cannot create output folder" in _one_line_error(err)
    monkeypatch.setattr(runner, "run_jobs", real)
    # One 64 x 128 PNG, the nearest fill without outlier removal: test_cli's single-image run compiles
    # the same program.
    target = tmp_path / "new" / "deeper" / "out.png"
    code, _, err = _run(capsys, "complete", src / "f0.png", target, "--intrinsics", K, "--method", "nearest",
                        "--no-outlier-removal")
    assert code == 0 and read_depth_png(target).shape == (64, 128)


def test_nuscenes_dataroot_without_version_gets_the_hint(tmp_path, capsys):
    root = tmp_path / "nuscenes"
    (root / "v1.0-mini").mkdir(parents=True)
    (root / "samples").mkdir()
    code, _, err = _run(capsys, "complete", root, tmp_path / "out")
    line = _one_line_error(err)
    assert code == 1 and "looks like a nuScenes dataroot" in line and "--nusc-version" in line


def test_eval_describes_ignored_files_by_what_they_are(tmp_path, capsys, eval_sides):
    pred = eval_sides["completion"]
    for kind in ("preview", "validity"):
        shutil.copyfile(pred / "f.png", pred / f"f_{kind}.png")
    code, out, _ = _run(capsys, "eval", pred, eval_sides["gt"])
    assert code == 0
    note = next(line for line in out.splitlines() if line.startswith("note:"))
    assert "colour previews (_preview.png)" in note and "validity masks (_validity.png)" in note
    assert "camera images" not in note


def test_ray_records_carry_force(tmp_path):
    from jaxdepth.batch import scale
    from jaxdepth.batch.runner import FrameJob
    jobs = [FrameJob(name=f"f{i}", sparse_path=tmp_path / f"f{i}.png", out_path=tmp_path / "o.png", force=bool(i))
            for i in range(2)]
    records = [scale._record(job) for job in jobs]
    batch = {key: np.array([r[key] for r in records], dtype=object) for key in records[0]}
    assert [job.force for job in scale._jobs_from_batch(batch)] == [False, True]


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_kitti_tree_keeps_one_record_per_method_so_two_methods_share_an_output_root(tmp_path, capsys):
    frame = require_shared("kitti", "drive_0001_frame05")
    src = tmp_path / "kitti_depth" / "train"
    folder = src / DRIVE / "proj_depth" / "velodyne_raw" / "image_02"
    folder.mkdir(parents=True)
    # The real frame at its own 375 x 1242: the nearest fill of one such frame is the program
    # test_kitti_datasets' depth-completion tree run compiles (what is checked here is the records).
    shutil.copyfile(frame / "velodyne_raw_image_02.png", folder / "0000000005.png")
    calib = tmp_path / "calib" / DATE
    calib.mkdir(parents=True)
    for name in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        shutil.copyfile(frame / name, calib / name)
    dst = tmp_path / "out"
    base = ["complete", src, dst, "--calib-dir", tmp_path / "calib", "-q"]
    assert _run(capsys, *base, "--method", "nearest")[0] == 0
    assert _run(capsys, *base, "--method", "ip-basic")[0] == 0  # another proj_depth/<name>: its own record
    for method in ("nearest", "ip-basic"):
        record = json.loads((dst / DRIVE / "proj_depth" / method / "jaxdepth_run.json").read_text())
        assert record["settings"]["method"] == method
    code, _, err = _run(capsys, *base, "--method", "nearest", "--epsilon", "2")
    assert code == 1 and "epsilon_m: 1.0 -> 2.0" in _one_line_error(err)
