"""Research subcommands (jaxdepth.research.cli): ablation, sparsity, hidden-eval.

Each runs through jaxdepth.cli.main (exit codes, one-line errors) with the
commands registered on the lead's parser; the printed tables and the JSON are
checked against the library functions called directly.
"""

from __future__ import annotations

import argparse
import glob
import json

import jax.numpy as jnp
import numpy as np
import pytest

import jaxdepth
from jaxdepth import cli
from jaxdepth.research import cli as research_cli, sparsity
from jaxdepth.research.ablation import frame_ablation, mean_ablation
from jaxdepth.io import (crop_to_benchmark, read_depth_png, read_kitti_raw_calib, read_points,
                         rig_from_nuscenes_calibration, write_depth_png, write_rig_json)


@pytest.fixture(autouse=True)
def _registered(monkeypatch):
    """cli.main with the research commands (until cli.build_parser calls register itself)."""
    original = cli.build_parser

    def build():
        parser = original()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        if "ablation" not in sub.choices:
            research_cli.register(sub)
        return parser

    monkeypatch.setattr(cli, "build_parser", build)


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err, *fragments):
    assert code == 1
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxdepth: error: ")
    for fragment in fragments:
        assert fragment in lines[0]


def test_register_adds_the_subcommands():
    parser = argparse.ArgumentParser()
    research_cli.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["ablation", "src"])
    assert args.func is research_cli.cmd_ablation and args.gt is None and args.distance == jaxdepth.SGMConfig().distance_metric
    args = parser.parse_args(["sparsity", "s.bin", "calib", "gt.png"])
    assert args.func is research_cli.cmd_sparsity and args.beams == [64, 32, 16] and args.camera == 2
    args = parser.parse_args(["hidden-eval", "p.bin", "rig.json", "--scale", "0.5"])
    assert args.func is research_cli.cmd_hidden_eval and args.fraction == 0.2 and args.scale == 0.5
    assert args.seeds == [0, 1, 2, 3, 4]
    with pytest.raises(SystemExit):
        parser.parse_args(["sparsity", "s.bin", "calib", "gt.png", "--camera", "7"])


# ---------------------------------------------------------------- ablation


@pytest.fixture(scope="module")
def kitti_folder(tmp_path_factory, kitti_frame):
    """Both KITTI frames in the benchmark layout, plus one frame whose ground truth has the wrong shape."""
    root = tmp_path_factory.mktemp("kitti_layout")
    calib = read_kitti_raw_calib(kitti_frame / "calib_cam_to_cam.txt", kitti_frame / "calib_velo_to_cam.txt")
    for sub in ("velodyne_raw", "intrinsics", "groundtruth_depth"):
        (root / sub).mkdir()
    frames = {}
    for cam in (2, 3):
        K = calib["cameras"][cam]["K"]
        sparse, Kc = crop_to_benchmark(read_depth_png(kitti_frame / f"velodyne_raw_image_0{cam}.png"), K)
        gt, _ = crop_to_benchmark(read_depth_png(kitti_frame / f"groundtruth_image_0{cam}.png"), K)
        name = f"drive_0001_velodyne_raw_0000000005_image_0{cam}"
        write_depth_png(root / "velodyne_raw" / f"{name}.png", sparse)
        write_depth_png(root / "groundtruth_depth" / f"{name.replace('velodyne_raw', 'groundtruth_depth')}.png", gt)
        (root / "intrinsics" / f"{name.replace('velodyne_raw', 'image')}.txt").write_text(
            " ".join(f"{v:.6f}" for v in Kc.ravel()))
        frames[name] = (read_depth_png(root / "velodyne_raw" / f"{name}.png"),
                        read_depth_png(root / "groundtruth_depth" / f"{name.replace('velodyne_raw', 'groundtruth_depth')}.png"),
                        Kc)
    bad = "zz_bad_frame"
    write_depth_png(root / "velodyne_raw" / f"{bad}.png", np.ones((10, 12), np.float32))
    write_depth_png(root / "groundtruth_depth" / f"{bad}.png", np.ones((11, 12), np.float32))
    (root / "intrinsics" / f"{bad}.txt").write_text("100 0 6 0 100 5 0 0 1")
    return root, frames


@pytest.mark.slow  # both real KITTI frames at 352 x 1216, every ablation variant compiled
def test_ablation_table_and_json_match_the_library(capsys, kitti_folder, tmp_path):
    root, frames = kitti_folder
    out_json = tmp_path / "ablation.json"
    code, out, err = run(capsys, "ablation", root, "--json", out_json)
    assert code == 1  # one bad frame: reported, skipped, exit 1
    assert "FAILED zz_bad_frame:" in err and "differ in shape" in err and "Traceback" not in err
    assert "2 frames evaluated, 1 failed" in err
    doc = json.loads(out_json.read_text())
    assert set(doc["per_frame"]) == set(frames) and set(doc["failed"]) == {"zz_bad_frame"}
    per_frame = {}
    for name, (sparse, gt, K) in frames.items():
        # The CLI reads K from a text file with 6 decimals; the same numbers here.
        K_txt = np.array([float(f"{v:.6f}") for v in K.ravel()], np.float32).reshape(3, 3)
        per_frame[name] = frame_ablation(sparse, gt, K_txt)
    want = mean_ablation(per_frame)
    assert doc["mean"]["frames"] == 2
    for step, row in want["steps"].items():
        for key, value in row.items():
            np.testing.assert_allclose(doc["mean"]["steps"][step][key], value, rtol=1e-5)
    for key in ("with_outlier_removal", "without_outlier_removal"):
        for metric, value in want[key].items():
            np.testing.assert_allclose(doc["mean"][key][metric], value, rtol=1e-5)
    np.testing.assert_allclose(doc["mean"]["keep_ratio"], want["keep_ratio"], rtol=1e-6)
    # Printed table: the format_ablation lines of that mean.
    assert out.splitlines()[0].startswith("Table 1/6: each step (mean of 2 frames")
    final = next(line for line in out.splitlines() if line.startswith("+ smooth"))
    assert float(final.split()[2]) == pytest.approx(want["steps"]["+ smooth"]["rmse"], abs=0.051)
    # Real data sanity (the paper: input RMSE 1595 mm -> 663 mm after removal; ours on these frames
    # is measured in benchmarks/accuracy_kitti.py): removal lowers the input error, SGM beats NN fill.
    steps = want["steps"]
    assert steps["+ outlier removal"]["rmse"] < 0.9 * steps["original input"]["rmse"]
    assert want["with_outlier_removal"]["rmse"] < want["nearest_fill_without_outlier_removal"]["rmse"]


def test_ablation_with_explicit_gt_dir_and_errors(capsys, kitti_folder, tmp_path):
    root, _ = kitti_folder
    code, out, err = run(capsys, "ablation", tmp_path / "missing")
    assert_one_line_error(code, err, "missing", "not found")
    code, out, err = run(capsys, "ablation", root, tmp_path / "no_gt")
    assert_one_line_error(code, err, "no_gt", "ground-truth folder not found")
    empty_gt = tmp_path / "empty_gt"
    empty_gt.mkdir()
    code, out, err = run(capsys, "ablation", root, empty_gt)
    assert code == 1 and "no frame could be evaluated (3 failed)" in err and "Traceback" not in err


# ---------------------------------------------------------------- sparsity


@pytest.mark.slow  # real KITTI sweep, SGM and nearest at 352 x 1216
def test_sparsity_command_matches_the_library(capsys, kitti_frame, tmp_path):
    out_json = tmp_path / "sparsity.json"
    code, out, err = run(capsys, "sparsity", kitti_frame / "lidar_data.bin", kitti_frame,
                         kitti_frame / "groundtruth_image_02.png", "--beams", "16", "--json", out_json)
    assert code == 0, err
    assert "beams found from elevation: 64" in out
    doc = json.loads(out_json.read_text())
    assert doc["beams_found"] == 64 and len(doc["points_per_beam"]) == 64 and doc["camera"] == 2
    row = doc["rows"]["16"]
    assert row["keep_every"] == 4 and row["beams"] == 16
    # Direct library computation (same compiled function: cached).
    points, _ = read_points(kitti_frame / "lidar_data.bin")
    calib = read_kitti_raw_calib(kitti_frame / "calib_cam_to_cam.txt", kitti_frame / "calib_velo_to_cam.txt")
    cam = calib["cameras"][2]
    gt, Kc = crop_to_benchmark(read_depth_png(kitti_frame / "groundtruth_image_02.png"), cam["K"])
    camera = jaxdepth.Camera(K=jnp.asarray(Kc), T_cam_lidar=jnp.asarray(cam["T_cam_lidar"]), height=352, width=1216)
    want = sparsity.sparsity_study(points, None, camera, gt, lidar=jaxdepth.KITTI_HDL64, beams=(16,))["rows"]["16"]
    assert row["points"] == want["points"] and row["input_pixels"] == want["input_pixels"]
    for method in ("sgm", "nearest"):
        for key in ("rmse", "mae", "irmse", "imae"):
            np.testing.assert_allclose(row[method][key], want[method][key], rtol=1e-6)
    # A quarter of the beams: about a quarter of the points and of the projected pixels.
    assert 0.2 < row["points"] / points.shape[0] < 0.3
    line = next(row for row in out.splitlines() if row.split() and row.split()[0] == "16")
    assert float(line.split()[4]) == pytest.approx(row["sgm"]["rmse"], abs=0.051)


def test_sparsity_command_errors(capsys, kitti_frame, tmp_path):
    sweep, gt = kitti_frame / "lidar_data.bin", kitti_frame / "groundtruth_image_02.png"
    code, out, err = run(capsys, "sparsity", sweep, kitti_frame, gt, "--beams", "48")
    assert_one_line_error(code, err, "--beams", "divisor", "48")
    code, out, err = run(capsys, "sparsity", sweep, tmp_path, gt)
    assert_one_line_error(code, err, "calib_cam_to_cam.txt")
    small = tmp_path / "small.png"
    write_depth_png(small, np.ones((20, 30), np.float32))
    code, out, err = run(capsys, "sparsity", sweep, kitti_frame, small)
    assert_one_line_error(code, err, "ground truth shape (20, 30)")
    code, out, err = run(capsys, "sparsity", tmp_path / "none.bin", kitti_frame, gt)
    assert_one_line_error(code, err, "none.bin", "not found")


# ---------------------------------------------------------------- hidden-eval


@pytest.fixture(scope="module")
def nuscenes_rig(tmp_path_factory, nuscenes_sample):
    path = tmp_path_factory.mktemp("rig") / "nuscenes_rig.json"
    rig = rig_from_nuscenes_calibration(nuscenes_sample / "calibration.json")
    write_rig_json(path, rig)
    return path, rig


@pytest.mark.xdist_group("jobs_nuscenes")  # one worker: the hidden-point program is test_rig's too
@pytest.mark.slow  # real nuScenes sweep, six 225 x 400 cameras, five methods
def test_hidden_eval_matches_hidden_point_scores(capsys, nuscenes_sample, nuscenes_rig, tmp_path):
    rig_path, rig = nuscenes_rig
    sweep = glob.glob(str(nuscenes_sample / "*LIDAR_TOP*.pcd.bin"))[0]
    out_json = tmp_path / "hidden.json"
    code, out, err = run(capsys, "hidden-eval", sweep, rig_path, "--scale", "0.25", "--seeds", "3",
                         "--json", out_json)
    assert code == 0, err
    doc = json.loads(out_json.read_text())
    names = [c.name for c in rig.cameras]
    assert sorted(doc["cameras"]) == sorted(names) and len(names) == 6
    # Direct library computation: the same padding, range cut, hidden draw and scaled cameras.
    points, _ = read_points(sweep, columns=5)
    padded, valid = jaxdepth.io.pad_points(points)
    valid &= np.linalg.norm(padded, axis=1) >= 1.0
    hidden = jaxdepth.hidden_point_mask(valid, fraction=0.2, seed=3)
    cams = jaxdepth.stack_cameras([research_cli.scaled_camera(c.as_camera(), 0.25) for c in rig.cameras])
    assert (cams.height, cams.width) == (225, 400)
    scores = jaxdepth.hidden_point_scores(padded, valid, hidden, cams, lidar=rig.lidar)
    assert doc["hidden_points"] == int(hidden.sum()) and doc["points"] == int(valid.sum())
    for i, name in enumerate(names):
        assert doc["cameras"][name]["hidden_pixels"] == int(scores["hidden_pixels"][i]) > 0
        for method in ("sgm", "sgm_no_removal", "nearest", "nearest_l2", "ip_basic"):
            for key in ("rmse", "mae"):
                np.testing.assert_allclose(doc["cameras"][name][method][key], float(scores[method][key][i]),
                                           rtol=1e-6)
        line = next(row for row in out.splitlines() if row.startswith(name + " "))
        assert int(line.split()[1]) == doc["cameras"][name]["hidden_pixels"]
    # The mean row is the mean over camera images (the devkit's data-set score).
    np.testing.assert_allclose(doc["mean"]["sgm"]["rmse"], np.mean(np.asarray(scores["sgm"]["rmse"])), rtol=1e-5)
    assert doc["targets"].startswith("held-out points' own per-pixel z-buffer")
    # The separately reported score without the covered targets.
    assert "uncovered" in out
    covered = np.asarray(scores["covered_pixels"])
    assert np.all(covered <= np.asarray(scores["hidden_pixels"]))
    np.testing.assert_allclose(doc["covered_share"], covered.sum() / np.asarray(scores["hidden_pixels"]).sum())
    np.testing.assert_allclose(doc["mean_uncovered"]["nearest"]["mae"],
                               np.mean(np.asarray(scores["uncovered"]["nearest"]["mae"])), rtol=1e-5)


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_hidden_point_targets_are_the_hidden_z_buffer():
    """Targets come from the hidden points alone, whatever the SGM removes: a
    hidden far point that a given near point hides from the camera stays a
    target, and the SGM's outlier removal cannot drop it."""
    import jax.numpy as jnp
    from helpers import square_before_plane
    # the point count of tests/test_hidden_cover.py: the same compiled hidden_point_scores
    cams, K, T, points = square_before_plane(seed=0, far_points=1500, near_points=300, near_half_m=1.0)
    valid = np.ones(len(points), bool)
    hidden = np.zeros(len(points), bool)
    hidden[:40] = True
    scores = jaxdepth.hidden_point_scores(points, valid, hidden, cams, lidar=jaxdepth.LidarSpec(beams=16))
    from jaxdepth._src.geometry import project_to_image
    gt, _ = project_to_image(jnp.asarray(points), jnp.asarray(hidden), jnp.asarray(K), jnp.asarray(T),
                             height=48, width=64)
    assert int(scores["hidden_pixels"][0]) == int((np.asarray(gt) > 0).sum()) > 30


def test_scaled_camera_keeps_projections_consistent():
    # Scaling K by s maps a pixel centre x to s (x + 0.5) - 0.5.
    cam = jaxdepth.Camera(K=jnp.asarray([[800.0, 0, 640], [0, 800.0, 360], [0, 0, 1]]),
                          T_cam_lidar=jnp.eye(4), height=720, width=1280)
    half = research_cli.scaled_camera(cam, 0.5)
    assert (half.height, half.width) == (360, 640)
    p = np.array([1.0, -2.0, 10.0])
    x = np.asarray(cam.K) @ p
    y = np.asarray(half.K) @ p
    np.testing.assert_allclose(y[:2] / y[2], 0.5 * (x[:2] / x[2] + 0.5) - 0.5, rtol=1e-6)
    assert research_cli.scaled_camera(cam, 1.0) is cam


def test_hidden_eval_errors(capsys, nuscenes_sample, nuscenes_rig, tmp_path):
    rig_path, _ = nuscenes_rig
    sweep = glob.glob(str(nuscenes_sample / "*LIDAR_TOP*.pcd.bin"))[0]
    code, out, err = run(capsys, "hidden-eval", sweep, rig_path, "--fraction", "1.5")
    assert_one_line_error(code, err, "--fraction")
    code, out, err = run(capsys, "hidden-eval", sweep, tmp_path / "none.json")
    assert_one_line_error(code, err, "none.json", "not found")
    code, out, err = run(capsys, "hidden-eval", sweep, rig_path, "--point-columns", "7")
    assert_one_line_error(code, err, "columns")
    bad = tmp_path / "bad_rig.json"
    bad.write_text('{"lidar": {"beams": 32}, "cameras": []}')
    code, out, err = run(capsys, "hidden-eval", sweep, bad)
    assert code == 1 and "Traceback" not in err and len(err.strip().splitlines()) == 1
