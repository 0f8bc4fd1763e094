"""The paper's ablations (Tables 1, 5 and 6) on frames with ground truth.

Table 1: error of the raw sparse input against ground truth (pixels valid in
both), before and after outlier removal, with the keep ratio. Table 6: RMSE,
MAE and density after each step (input, + outlier removal, + distance
transform, + residual, + smoothing). Table 5: the completed depth with and
without outlier removal. Sparse rows use the paired (no fill) errors; dense rows
the KITTI devkit metrics. Dataset figures are means over frames.
"""

from __future__ import annotations

import numpy as np

from jaxdepth._src.config import SGMConfig
from jaxdepth._src.metrics import depth_metrics, keep_ratio, pair_errors
from jaxdepth._src.pipeline import complete_stages
from jaxdepth._src import presets
from jaxdepth._src.types import LidarSpec

STEPS = ("original input", "+ outlier removal", "+ distance transform", "+ residual", "+ column bracket",
         "+ smooth")
KEYS = ("rmse", "mae", "irmse", "imae")


def _row(metrics, density):
    row = {k: float(metrics[k]) for k in KEYS}
    row["density"] = float(density)
    return row


def frame_ablation(sparse: np.ndarray, gt: np.ndarray, K: np.ndarray, T_cam_lidar: np.ndarray | None = None, *,
                   config: SGMConfig = SGMConfig(), lidar: LidarSpec = presets.KITTI_HDL64) -> dict:
    """Every ablation figure of one frame.

    Returns:
      {"steps": {step: {rmse, mae, irmse, imae, density}}, "keep_ratio": float,
       "with_outlier_removal": {...}, "without_outlier_removal": {...}} (mm, 1/km, %).
    """
    with_or = complete_stages(sparse, K, T_cam_lidar, config=config.replace(outlier_removal=True), lidar=lidar)
    without = complete_stages(sparse, K, T_cam_lidar, config=config.replace(outlier_removal=False), lidar=lidar)
    kept = np.where(np.asarray(with_or.inlier_mask), sparse, 0.0)
    size = sparse.size
    # The paper's Step 4a alone (z' + Delta z, clipped like the pipeline), before the column bracket.
    seed = np.asarray(with_or.seed_depth)
    paper_raw = np.where(seed > 0, np.clip(seed + np.asarray(with_or.residual), config.min_depth_m,
                                           config.max_depth_m), 0.0).astype(np.float32)
    steps = {
        STEPS[0]: _row(pair_errors(sparse, gt), 100.0 * np.count_nonzero(sparse > 0) / size),
        STEPS[1]: _row(pair_errors(kept, gt), 100.0 * np.count_nonzero(kept > 0) / size),
        STEPS[2]: _row(depth_metrics(with_or.seed_depth, gt), 100.0 * np.count_nonzero(np.asarray(with_or.seed_depth) > 0) / size),
        STEPS[3]: _row(depth_metrics(paper_raw, gt), 100.0 * np.count_nonzero(paper_raw > 0) / size),
        STEPS[4]: _row(depth_metrics(with_or.depth_raw, gt), 100.0 * np.count_nonzero(np.asarray(with_or.depth_raw) > 0) / size),
        STEPS[5]: _row(depth_metrics(with_or.depth, gt), 100.0 * np.count_nonzero(np.asarray(with_or.depth) > 0) / size),
    }
    return {
        "steps": steps,
        "keep_ratio": float(keep_ratio(kept, sparse)),
        "with_outlier_removal": _row(depth_metrics(with_or.depth, gt), 100.0),
        "without_outlier_removal": _row(depth_metrics(without.depth, gt), 100.0),
        "nearest_fill_without_outlier_removal": _row(depth_metrics(without.seed_depth, gt), 100.0),
    }


def mean_ablation(per_frame: dict) -> dict:
    """Mean of :func:`frame_ablation` results over frames (the devkit's dataset score)."""
    frames = list(per_frame.values())
    out = {"steps": {}, "frames": len(frames)}
    for step in STEPS:
        rows = [f["steps"][step] for f in frames]
        out["steps"][step] = {k: float(np.mean([r[k] for r in rows])) for k in KEYS + ("density",)}
    for key in ("with_outlier_removal", "without_outlier_removal", "nearest_fill_without_outlier_removal"):
        out[key] = {k: float(np.mean([f[key][k] for f in frames])) for k in KEYS}
    out["keep_ratio"] = float(np.mean([f["keep_ratio"] for f in frames]))
    return out


def format_ablation(mean: dict) -> list:
    lines = [f"Table 1/6: each step (mean of {mean['frames']} frames; sparse rows: pixels valid in input and gt)",
             f"{'step':24s}{'RMSE mm':>10s}{'MAE mm':>10s}{'iRMSE':>9s}{'iMAE':>8s}{'density %':>11s}"]
    for step in STEPS:
        r = mean["steps"][step]
        lines.append(f"{step:24s}{r['rmse']:10.1f}{r['mae']:10.1f}{r['irmse']:9.2f}{r['imae']:8.2f}{r['density']:11.2f}")
    lines.append(f"keep ratio after outlier removal: {100 * mean['keep_ratio']:.1f} %")
    lines.append("Table 5: completion with and without outlier removal")
    for key, label in (("without_outlier_removal", "SGM w/o outlier removal"),
                       ("with_outlier_removal", "SGM w/ outlier removal"),
                       ("nearest_fill_without_outlier_removal", "nearest fill (no removal)")):
        r = mean[key]
        lines.append(f"{label:28s}{r['rmse']:10.1f}{r['mae']:10.1f}{r['irmse']:9.2f}{r['imae']:8.2f}")
    return lines
