"""`jaxdepth demo`: complete the built-in synthetic street scene and score it against exact depth."""

from __future__ import annotations

import dataclasses
import pathlib
import time

import jax
import numpy as np

from jaxdepth._src.colorize import colorize_depth
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.metrics import depth_metrics
from jaxdepth._src.pipeline import complete_points_stages
from jaxdepth._src.synthetic import make_street_scene, parallax_outlier_mask
from jaxdepth.io.atomic import atomic_write_png
from jaxdepth.io.depth_png import write_depth_png


@dataclasses.dataclass
class DemoResult:
    out_dir: pathlib.Path
    metrics: dict
    nearest_metrics: dict
    points: int
    sparse_pixels: int
    parallax_outliers: int
    removed: int
    removed_true_outliers: int
    seconds: float

    def report_lines(self):
        m, n = self.metrics, self.nearest_metrics
        return [
            f"synthetic street scene: {self.points} LiDAR points, {self.sparse_pixels} sparse pixels, "
            f"{self.parallax_outliers} parallax outliers",
            f"outlier removal: removed {self.removed} pixels, {self.removed_true_outliers} of them true outliers",
            f"{'':8s}{'RMSE mm':>10s}{'MAE mm':>10s}{'iRMSE 1/km':>12s}{'iMAE 1/km':>11s}",
            f"{'sgm':8s}{m['rmse']:10.1f}{m['mae']:10.1f}{m['irmse']:12.2f}{m['imae']:11.2f}",
            f"{'nearest':8s}{n['rmse']:10.1f}{n['mae']:10.1f}{n['irmse']:12.2f}{n['imae']:11.2f}",
            f"wrote {self.out_dir}/depth.png (uint16, metres*256), depth_preview.png, sparse_preview.png "
            f"({self.seconds:.1f} s including compilation)",
        ]


def run_demo(out_dir: pathlib.Path, *, seed: int = 0, method: str = "sgm",
             config: SGMConfig = SGMConfig()) -> DemoResult:
    """Renders the scene, completes camera 0 from the raw sweep and writes the outputs."""
    start = time.perf_counter()
    frame = make_street_scene(seed)
    camera = frame.cameras[0]
    gt = np.asarray(frame.dense_depth[0], np.float32)
    stages = complete_points_stages(frame.points, frame.valid, camera, config=config, lidar=frame.lidar)
    sparse = np.asarray(stages.sparse_depth)
    keep = np.asarray(stages.inlier_mask)
    if method == "sgm":
        depth = np.asarray(stages.depth)
    else:
        from jaxdepth._src.methods import complete_with
        depth = np.asarray(complete_with(sparse, camera.K, camera.T_cam_lidar, method=method, config=config,
                                         lidar=frame.lidar))
    nearest = np.asarray(stages.seed_depth)
    metrics = {k: float(v) for k, v in depth_metrics(depth, gt).items()}
    nearest_metrics = {k: float(v) for k, v in depth_metrics(nearest, gt).items()}
    outlier_mask = np.asarray(parallax_outlier_mask(frame.points, frame.valid, camera, gt))
    removed = (sparse > 0) & ~keep
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_depth_png(out_dir / "depth.png", depth)
    vmax = float(np.percentile(gt[gt > 0], 99)) if np.any(gt > 0) else None
    atomic_write_png(out_dir / "depth_preview.png", colorize_depth(depth, vmin=0.0, vmax=vmax)[..., ::-1])
    atomic_write_png(out_dir / "sparse_preview.png", colorize_depth(sparse, vmin=0.0, vmax=vmax)[..., ::-1])
    return DemoResult(out_dir=out_dir, metrics=metrics, nearest_metrics=nearest_metrics,
                      points=int(np.sum(frame.valid)), sparse_pixels=int(np.sum(sparse > 0)),
                      parallax_outliers=int(outlier_mask.sum()), removed=int(removed.sum()),
                      removed_true_outliers=int((removed & outlier_mask).sum()),
                      seconds=time.perf_counter() - start)
