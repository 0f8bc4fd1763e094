"""Scoring folders of predictions against ground truth with KITTI devkit metrics.

Predictions and ground truth are KITTI depth PNGs matched by file name (a
``complete-rig`` output folder, ``<camera>.png``, is scored against a folder of
per-camera ground truth the same way). Per-frame metrics follow the devkit
(empty predictions filled by ``interpolate_background``), and the dataset score
is the mean over frames.
"""

from __future__ import annotations

import pathlib

import numpy as np

from jaxdepth._src.metrics import depth_metrics, mean_metrics
from jaxdepth.io.depth_png import read_depth_png
from jaxdepth.io.errors import InputError

METRIC_KEYS = ("rmse", "mae", "irmse", "imae")


def evaluate_pairs(pairs) -> dict:
    """``pairs``: iterable of (name, pred (H, W), gt (H, W)) metres. Returns {'mean', 'per_frame'}."""
    per_frame = {}
    for name, pred, gt in pairs:
        if pred.shape != gt.shape:
            raise InputError(f"{name}: prediction shape {pred.shape} expected to equal ground truth {gt.shape}")
        m = depth_metrics(np.asarray(pred, np.float32), np.asarray(gt, np.float32))
        per_frame[name] = {k: float(m[k]) for k in METRIC_KEYS}
    if not per_frame:
        raise InputError("no frames to evaluate")
    mean = mean_metrics(list(per_frame.values()))
    return {"mean": {k: float(mean[k]) for k in METRIC_KEYS}, "per_frame": per_frame}


def _png_files(folder: pathlib.Path) -> dict:
    if not folder.is_dir():
        raise InputError(f"{folder}: folder not found")
    files = {p.name: p for p in sorted(folder.glob("*.png"))}
    if not files and (folder / "velodyne_raw").is_dir():
        files = {p.name: p for p in sorted((folder / "velodyne_raw").glob("*.png"))}
    if not files and (folder / "groundtruth_depth").is_dir():
        files = {p.name: p for p in sorted((folder / "groundtruth_depth").glob("*.png"))}
    return files


def evaluate_folders(pred_dir: pathlib.Path, gt_dir: pathlib.Path) -> dict:
    """Metrics of every prediction PNG that has a ground-truth PNG of the same name."""
    preds, gts = _png_files(pred_dir), _png_files(gt_dir)
    names = sorted(set(preds) & set(gts))
    if not names:
        raise InputError(f"{pred_dir}: no prediction PNG has a ground-truth PNG of the same name in {gt_dir}")
    missing = sorted(set(gts) - set(preds))
    table = evaluate_pairs((n, read_depth_png(preds[n]), read_depth_png(gts[n])) for n in names)
    table["missing_predictions"] = missing
    return table


def format_table(table: dict) -> list:
    lines = [f"{'frame':40s}{'RMSE mm':>10s}{'MAE mm':>10s}{'iRMSE 1/km':>12s}{'iMAE 1/km':>11s}"]
    for name, m in table["per_frame"].items():
        lines.append(f"{name[:40]:40s}{m['rmse']:10.1f}{m['mae']:10.1f}{m['irmse']:12.2f}{m['imae']:11.2f}")
    m = table["mean"]
    lines.append(f"{'mean (' + str(len(table['per_frame'])) + ' frames)':40s}"
                 f"{m['rmse']:10.1f}{m['mae']:10.1f}{m['irmse']:12.2f}{m['imae']:11.2f}")
    if table.get("missing_predictions"):
        lines.append(f"warning: {len(table['missing_predictions'])} ground-truth frames have no prediction")
    return lines
