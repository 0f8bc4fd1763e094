"""`jaxdepth eval PRED GT --json OUT`: KITTI devkit metrics of prediction folders.

Oracle: jaxdepth.depth_metrics / mean_metrics on the same PNG contents, and a
brute-force NumPy RMSE / MAE where the prediction is dense (no background fill).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import jaxdepth
from jaxdepth import cli
from jaxdepth.io import read_depth_png, write_depth_png

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
    # Printed table: one line per frame, the mean, the missing-prediction warning.
    lines = out.splitlines()
    assert lines[0].split()[0] == "frame" and len(lines) == 1 + len(names) + 2
    assert lines[-2].startswith("mean (3 frames)")
    assert float(lines[-2].split()[3]) == pytest.approx(doc["mean"]["rmse"], abs=0.051)
    assert "1 ground-truth frames have no prediction" in lines[-1]


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
