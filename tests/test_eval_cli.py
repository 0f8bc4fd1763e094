"""`jaxdepth eval PRED GT --json OUT`: KITTI devkit metrics of prediction folders.

Oracle: jaxdepth.depth_metrics / mean_metrics on the same PNG contents, and a
brute-force NumPy RMSE / MAE where the prediction is dense (no background fill).
"""

from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

import jaxdepth
from jaxdepth import cli
from jaxdepth.io import read_depth_png, write_depth_png

# One worker for the module: its tests score frames of a few sizes, each a depth_metrics program of its own.
pytestmark = pytest.mark.xdist_group("eval_cli")

KEYS = ("rmse", "mae", "irmse", "imae")


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err, *fragments):
    assert code == 1 and "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxdepth: error: ")
    for fragment in fragments:
        assert fragment in lines[0]


def _depth(rng, shape, density):
    d = rng.uniform(2.0, 80.0, shape).astype(np.float32)
    return np.where(rng.random(shape) < density, d, 0.0).astype(np.float32)


@pytest.fixture
def folders(tmp_path):
    rng = np.random.default_rng(0)
    pred, gt = tmp_path / "pred", tmp_path / "gt"
    pred.mkdir()
    gt.mkdir()
    names = ["a.png", "b.png", "c.png"]
    for i, name in enumerate(names):
        write_depth_png(pred / name, _depth(rng, (24, 40), 1.0 if i < 2 else 0.3))  # c: sparse, needs the fill
        write_depth_png(gt / name, _depth(rng, (24, 40), 0.4))
    write_depth_png(gt / "only_gt.png", _depth(rng, (24, 40), 0.4))  # no prediction: reported, not scored
    return pred, gt, names


def test_eval_json_schema_and_numbers(capsys, folders, tmp_path):
    pred, gt, names = folders
    out_json = tmp_path / "eval.json"
    code, out, err = run(capsys, "eval", pred, gt, "--json", out_json)
    assert code == 0, err
    doc = json.loads(out_json.read_text())
    assert set(doc["mean"]) == set(KEYS) and set(doc["per_frame"]) == set(names)
    assert doc["missing_predictions"] == ["only_gt.png"]
    rows = []
    for name in names:
        p, g = read_depth_png(pred / name), read_depth_png(gt / name)
        m = jaxdepth.depth_metrics(p, g)
        assert set(doc["per_frame"][name]) == set(KEYS)
        for key in KEYS:
            np.testing.assert_allclose(doc["per_frame"][name][key], float(m[key]), rtol=1e-6)
        rows.append(m)
        if name != "c.png":  # dense prediction: plain NumPy RMSE / MAE over the ground-truth pixels
            mask = g > 0
            err_mm = (p[mask].astype(np.float64) - g[mask]) * 1000.0
            np.testing.assert_allclose(doc["per_frame"][name]["rmse"], np.sqrt(np.mean(err_mm ** 2)), rtol=1e-4)
            np.testing.assert_allclose(doc["per_frame"][name]["mae"], np.mean(np.abs(err_mm)), rtol=1e-4)
    mean = jaxdepth.mean_metrics(rows)
    for key in KEYS:
        np.testing.assert_allclose(doc["mean"][key], mean[key], rtol=1e-6)
    # Printed table: one line per frame, the mean, the missing-prediction warning, the prediction's settings.
    lines = out.splitlines()
    assert lines[0].split()[0] == "frame" and len(lines) == 1 + len(names) + 3
    assert lines[-3].startswith("mean (3 frames)")
    assert float(lines[-3].split()[3]) == pytest.approx(doc["mean"]["rmse"], abs=0.051)
    assert "1 ground-truth frames have no prediction" in lines[-2]
    assert lines[-1].startswith("prediction settings: unknown (no jaxdepth_run.json")


def test_eval_without_json_prints_only(capsys, folders, tmp_path):
    pred, gt, _ = folders
    code, out, err = run(capsys, "eval", pred, gt)
    assert code == 0 and "mean (3 frames)" in out
    assert not list(tmp_path.glob("*.json"))


def test_eval_errors_are_one_line(capsys, folders, tmp_path):
    pred, gt, _ = folders
    one_line_error(*run(capsys, "eval", tmp_path / "nope", gt)[::2], "nope", "folder not found")
    one_line_error(*run(capsys, "eval", pred, tmp_path / "nope")[::2], "nope", "folder not found")
    other = tmp_path / "other"
    other.mkdir()
    write_depth_png(other / "zzz.png", np.ones((24, 40), np.float32))
    one_line_error(*run(capsys, "eval", pred, other)[::2], "no prediction PNG has a ground-truth PNG")
    empty = tmp_path / "empty"
    empty.mkdir()
    one_line_error(*run(capsys, "eval", empty, gt)[::2], "no prediction PNG")
    mismatch = tmp_path / "mismatch"
    mismatch.mkdir()
    write_depth_png(mismatch / "a.png", np.ones((10, 10), np.float32))
    one_line_error(*run(capsys, "eval", mismatch, gt)[::2], "a.png", "shape")


def test_eval_scores_a_complete_rig_folder_against_per_camera_ground_truth(capsys, tmp_path):
    # complete-rig writes <camera>.png per sweep; ground truth named the same way matches by file name.
    rng = np.random.default_rng(1)
    pred, gt = tmp_path / "rig_out", tmp_path / "rig_gt"
    pred.mkdir()
    gt.mkdir()
    cameras = ["CAM_FRONT", "CAM_BACK", "image_02"]
    for cam in cameras:
        write_depth_png(pred / f"{cam}.png", _depth(rng, (18, 32), 1.0))
        write_depth_png(gt / f"{cam}.png", _depth(rng, (18, 32), 0.5))
    out_json = tmp_path / "rig.json"
    code, out, err = run(capsys, "eval", pred, gt, "--json", out_json)
    assert code == 0, err
    doc = json.loads(out_json.read_text())
    assert set(doc["per_frame"]) == {f"{c}.png" for c in cameras} and doc["missing_predictions"] == []
    for cam in cameras:
        m = jaxdepth.depth_metrics(read_depth_png(pred / f"{cam}.png"), read_depth_png(gt / f"{cam}.png"))
        np.testing.assert_allclose(doc["per_frame"][f"{cam}.png"]["mae"], float(m["mae"]), rtol=1e-6)
    assert "warning" not in out


def test_eval_reads_kitti_layout_subfolders(capsys, tmp_path):
    # PRED/velodyne_raw/ or GT/groundtruth_depth/ layouts are found when the folder itself has no PNG.
    rng = np.random.default_rng(2)
    pred, gt = tmp_path / "p", tmp_path / "g" / "groundtruth_depth"
    pred.mkdir()
    gt.mkdir(parents=True)
    write_depth_png(pred / "f.png", _depth(rng, (12, 20), 1.0))
    write_depth_png(gt / "f.png", _depth(rng, (12, 20), 0.5))
    code, out, err = run(capsys, "eval", pred, tmp_path / "g")
    assert code == 0, err
    assert "mean (1 frames)" in out


# ---------------------------------------------------------------- pairing by frame identity
# Oracle for the numbers: the KITTI devkit formulas in float64 NumPy on the PNGs as cv2 reads
# them (uint16 / 256 m), predictions dense so that no background fill is involved.

import csv  # noqa: E402

import cv2  # noqa: E402

from jaxdepth.research import evaluation  # noqa: E402

DRIVE = "2011_09_26_drive_0002_sync"
DRIVE_B = "2011_09_29_drive_0071_sync"


def _write_u16(path, rng, shape=(12, 20), density=1.0):
    path.parent.mkdir(parents=True, exist_ok=True)
    raw = rng.integers(256 * 2, 256 * 80, size=shape).astype(np.uint16)
    raw[rng.random(shape) >= density] = 0
    assert cv2.imwrite(str(path), raw)
    return path


def _devkit_numpy(pred_path, gt_path):
    p = cv2.imread(str(pred_path), cv2.IMREAD_UNCHANGED).astype(np.float64) / 256.0
    g = cv2.imread(str(gt_path), cv2.IMREAD_UNCHANGED).astype(np.float64) / 256.0
    assert (p > 0).all()  # dense: the devkit's fill changes nothing
    mask = g > 0
    err_mm = (p[mask] - g[mask]) * 1000.0
    ierr = 1000.0 / p[mask] - 1000.0 / g[mask]  # 1/km
    return {"rmse": np.sqrt(np.mean(err_mm ** 2)), "mae": np.mean(np.abs(err_mm)),
            "irmse": np.sqrt(np.mean(ierr ** 2)), "imae": np.mean(np.abs(ierr))}


def _sel(drive, kind, frame, cam):
    return f"{drive}_{kind}_{frame:010d}_image_0{cam}.png"


def _tree(drive, kind, frame, cam):
    return f"{drive}/proj_depth/{kind}/image_0{cam}/{frame:010d}.png"


@pytest.mark.parametrize("relpath, identity, kind", [
    (_sel(DRIVE, "velodyne_raw", 5, 2), f"{DRIVE}/image_02/0000000005", "velodyne_raw"),
    (_sel(DRIVE, "groundtruth_depth", 5, 2), f"{DRIVE}/image_02/0000000005", "groundtruth_depth"),
    ("velodyne_raw/" + _sel(DRIVE, "velodyne_raw", 5, 3), f"{DRIVE}/image_03/0000000005", "velodyne_raw"),
    ("image/" + _sel(DRIVE, "image", 5, 2), f"{DRIVE}/image_02/0000000005", "image"),
    (_tree(DRIVE, "groundtruth", 5, 2), f"{DRIVE}/image_02/0000000005", "groundtruth"),
    ("val/" + _tree(DRIVE, "sgm", 5, 3), f"{DRIVE}/image_03/0000000005", "sgm"),
    ("groundtruth_depth/f.png", "f.png", "groundtruth_depth"),
    ("sel/velodyne_raw/f.png", "sel/f.png", "velodyne_raw"),
    ("CAM_FRONT.png", "CAM_FRONT.png", None),
    ("sweep_7/CAM_FRONT.png", "sweep_7/CAM_FRONT.png", None),
    ("a/proj_depth/x/image_02/sub/f.png", "a/proj_depth/x/image_02/sub/f.png", None),  # not the tree layout
    ("d/drive_0002_velodyne_raw_5_image_02.png", "d/drive_0002_5_image_02.png", "velodyne_raw"),  # not a KITTI drive
    ("d/drive_0002_groundtruth_depth_5_image_02.png", "d/drive_0002_5_image_02.png", "groundtruth_depth"),
    ("velodyne_raw_image_03.png", "image_03.png", "velodyne_raw"),
    ("groundtruth_image_03.png", "image_03.png", "groundtruth"),
    ("groundtruth_depth/f_groundtruth.png", "f.png", "groundtruth"),
    ("groundtruth.png", "groundtruth.png", None),  # the whole stem is no frame name
    ("my_velodyne_rawish_1.png", "my_velodyne_rawish_1.png", None),  # only whole words
])
def test_frame_identity_layouts(relpath, identity, kind):
    assert evaluation.frame_identity(relpath) == (identity, kind)
    assert evaluation.frame_identity(pathlib.PurePosixPath(relpath)) == (identity, kind)


def test_frame_identity_same_frame_across_layouts_and_distinct_otherwise():
    keys = {}
    for drive in (DRIVE, DRIVE_B):
        for frame in (0, 5, 123):
            for cam in (2, 3):
                names = [_sel(drive, "velodyne_raw", frame, cam), _sel(drive, "groundtruth_depth", frame, cam),
                         _tree(drive, "groundtruth", frame, cam), _tree(drive, "velodyne_raw", frame, cam),
                         "out/" + _tree(drive, "sgm", frame, cam)]
                ids = {evaluation.frame_identity(n)[0] for n in names}
                assert len(ids) == 1, names
                keys[(drive, frame, cam)] = ids.pop()
    assert len(set(keys.values())) == len(keys)  # every (drive, frame, camera) its own identity


def _read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _check_csv_against_numpy(rows, expected_pairs):
    """rows: the CSV; expected_pairs: {identity: (pred path, gt path)} built by the test."""
    assert [r["frame"] for r in rows] == sorted(expected_pairs)
    for r in rows:
        pred_path, gt_path = expected_pairs[r["frame"]]
        assert pathlib.Path(r["prediction"]) == pred_path and pathlib.Path(r["ground_truth"]) == gt_path
        want = _devkit_numpy(pred_path, gt_path)
        for key, column in zip(KEYS, ("rmse_mm", "mae_mm", "irmse_per_km", "imae_per_km")):
            np.testing.assert_allclose(float(r[column]), want[key], rtol=2e-5, err_msg=f"{r['frame']} {key}")


def test_eval_pairs_selection_names_against_a_selection_folder(capsys, tmp_path):
    # `jaxdepth complete val_selection_cropped OUT` keeps the velodyne_raw names; GT_ROOT is the
    # selection folder itself (velodyne_raw/, groundtruth_depth/, image/): its ground truth is used.
    rng = np.random.default_rng(3)
    pred, sel = tmp_path / "out", tmp_path / "val_selection_cropped"
    expected = {}
    for frame, cam in [(5, 2), (5, 3), (11, 2)]:
        p = _write_u16(pred / _sel(DRIVE, "velodyne_raw", frame, cam), rng)
        g = _write_u16(sel / "groundtruth_depth" / _sel(DRIVE, "groundtruth_depth", frame, cam), rng, density=0.4)
        _write_u16(sel / "velodyne_raw" / _sel(DRIVE, "velodyne_raw", frame, cam), rng, density=0.05)
        (sel / "image").mkdir(exist_ok=True)
        cv2.imwrite(str(sel / "image" / _sel(DRIVE, "image", frame, cam)), np.zeros((12, 20, 3), np.uint8))
        expected[f"{DRIVE}/image_0{cam}/{frame:010d}"] = (p, g)
    out_csv, out_json = tmp_path / "frames.csv", tmp_path / "eval.json"
    code, out, err = run(capsys, "eval", pred, sel, "--csv", out_csv, "--json", out_json)
    assert code == 0, err
    _check_csv_against_numpy(_read_csv(out_csv), expected)
    doc = json.loads(out_json.read_text())
    assert sorted(doc["per_frame"]) == sorted(expected)
    assert doc["missing_predictions"] == [] and doc["unmatched_predictions"] == []
    assert len(doc["ignored"]["ground_truth"]) == 6 and doc["ignored"]["prediction"] == []
    for identity, (p, g) in expected.items():
        assert pred / doc["pairs"][identity]["prediction"] == p and sel / doc["pairs"][identity]["ground_truth"] == g
    # Full frame names: image_02 and image_03 rows differ, the columns line up after the longest name.
    lines = out.splitlines()
    frame_rows = [line for line in lines if line.startswith(DRIVE)]
    assert sorted(line.split()[0] for line in frame_rows) == sorted(expected)
    assert lines[0].split()[0] == "frame" and len({len(line) for line in [lines[0]] + frame_rows}) == 1
    rmse_end = lines[0].index("RMSE mm") + len("RMSE mm")
    for line in frame_rows:  # the RMSE column ends under its header
        rmse = line.split()[1]
        assert line.index(" " + rmse + " ") + 1 + len(rmse) == rmse_end, line
    assert "6 ground truth files ignored" in out


def test_eval_scores_an_output_tree_against_the_annotated_tree(capsys, tmp_path):
    rng = np.random.default_rng(4)
    pred, gt = tmp_path / "out", tmp_path / "data_depth_annotated" / "val"
    expected = {}
    for drive in (DRIVE, DRIVE_B):
        for frame in (5, 6):
            for cam in (2, 3):
                p = _write_u16(pred / _tree(drive, "sgm", frame, cam), rng)
                g = _write_u16(gt / _tree(drive, "groundtruth", frame, cam), rng, density=0.3)
                expected[f"{drive}/image_0{cam}/{frame:010d}"] = (p, g)
    # A prediction without ground truth (annotations skip drive ends) and ground truth without a
    # prediction: both listed, neither scored; LiDAR input in the same (merged) tree is not ground truth.
    _write_u16(pred / _tree(DRIVE, "sgm", 0, 2), rng)
    _write_u16(gt / _tree(DRIVE_B, "groundtruth", 7, 3), rng, density=0.3)
    _write_u16(gt / _tree(DRIVE, "velodyne_raw", 5, 2), rng, density=0.05)
    out_csv = tmp_path / "tree.csv"
    code, out, err = run(capsys, "eval", pred, tmp_path / "data_depth_annotated", "--csv", out_csv)
    assert code == 0, err
    expected = {k: (p, tmp_path / "data_depth_annotated" / g.relative_to(tmp_path / "data_depth_annotated"))
                for k, (p, g) in expected.items()}
    _check_csv_against_numpy(_read_csv(out_csv), expected)
    assert f"mean ({len(expected)} frames)" in out
    assert (f"warning: 1 predictions have no ground truth (not scored): "
            f"{pred / _tree(DRIVE, 'sgm', 0, 2)}") in out
    assert (f"warning: 1 ground-truth frames have no prediction (not scored, not in the mean): "
            f"{gt / _tree(DRIVE_B, 'groundtruth', 7, 3)}") in out
    # The mean printed is the mean of the per-frame CSV rows (frames without prediction not in it).
    rows = _read_csv(out_csv)
    mean_line = next(line for line in out.splitlines() if line.startswith("mean ("))
    assert float(mean_line.split()[3]) == pytest.approx(np.mean([float(r["rmse_mm"]) for r in rows]), abs=0.051)


def test_eval_pairs_a_flat_selection_named_folder_with_the_tree(capsys, tmp_path):
    rng = np.random.default_rng(5)
    pred, gt = tmp_path / "out", tmp_path / "val"
    expected = {}
    for frame, cam in [(5, 2), (5, 3)]:
        p = _write_u16(pred / _sel(DRIVE, "velodyne_raw", frame, cam), rng)
        g = _write_u16(gt / _tree(DRIVE, "groundtruth", frame, cam), rng, density=0.5)
        expected[f"{DRIVE}/image_0{cam}/{frame:010d}"] = (p, g)
    out_csv = tmp_path / "x.csv"
    code, out, err = run(capsys, "eval", pred, gt, "--csv", out_csv)
    assert code == 0, err
    _check_csv_against_numpy(_read_csv(out_csv), expected)
    assert "warning" not in out


def test_eval_two_files_of_one_frame_is_an_error_naming_both(capsys, tmp_path):
    rng = np.random.default_rng(6)
    pred, gt = tmp_path / "pred", tmp_path / "gt"
    a = _write_u16(pred / "run1" / _sel(DRIVE, "velodyne_raw", 5, 2), rng)
    b = _write_u16(pred / _tree(DRIVE, "sgm", 5, 2), rng)
    _write_u16(gt / _sel(DRIVE, "groundtruth_depth", 5, 2), rng)
    code, _, err = run(capsys, "eval", pred, gt)
    one_line_error(code, err, str(pred), "run1/" + a.name, str(b.relative_to(pred)), f"{DRIVE}/image_02/0000000005",
                   "one prediction per frame")
    # The same on the ground-truth side.
    _write_u16(gt / _tree(DRIVE, "groundtruth", 5, 2), rng)
    b.unlink()
    code, _, err = run(capsys, "eval", pred, gt)
    one_line_error(code, err, str(gt), _sel(DRIVE, "groundtruth_depth", 5, 2), _tree(DRIVE, "groundtruth", 5, 2),
                   "one ground truth per frame")


def test_eval_no_pair_error_shows_both_sides_and_shape_error_names_both_files(capsys, tmp_path):
    rng = np.random.default_rng(7)
    pred, gt = tmp_path / "pred", tmp_path / "gt"
    _write_u16(pred / _sel(DRIVE, "velodyne_raw", 5, 2), rng)
    _write_u16(gt / _sel(DRIVE, "groundtruth_depth", 5, 3), rng)  # other camera: another frame
    code, _, err = run(capsys, "eval", pred, gt)
    one_line_error(code, err, "no prediction PNG has a ground-truth PNG of the same frame",
                   _sel(DRIVE, "velodyne_raw", 5, 2), _sel(DRIVE, "groundtruth_depth", 5, 3))
    g = _write_u16(gt / _sel(DRIVE, "groundtruth_depth", 5, 2), rng, shape=(10, 20))
    code, _, err = run(capsys, "eval", pred, gt)
    one_line_error(code, err, _sel(DRIVE, "velodyne_raw", 5, 2), str(g), "shape (12, 20)", "(10, 20)")


def test_eval_csv_is_deterministic_and_write_errors_are_one_line(capsys, folders, tmp_path):
    pred, gt, names = folders
    first, second = tmp_path / "1.csv", tmp_path / "2.csv"
    assert run(capsys, "eval", pred, gt, "--csv", first)[0] == 0
    assert run(capsys, "eval", pred, gt, "--csv", second)[0] == 0
    assert first.read_bytes() == second.read_bytes()
    rows = _read_csv(first)
    assert list(rows[0]) == list(evaluation.CSV_COLUMNS) and [r["frame"] for r in rows] == names
    assert not [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    code, _, err = run(capsys, "eval", pred, gt, "--csv", tmp_path / "no_such_dir" / "x.csv")
    one_line_error(code, err, "no_such_dir")
