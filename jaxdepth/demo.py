"""`jaxdepth demo`: complete the built-in synthetic street scene and score it against exact depth."""

from __future__ import annotations

import dataclasses
import pathlib
import time

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
    scored_pixels: int
    seconds: float
    compile_seconds: float = 0.0

    def report_lines(self):
        m, n = self.metrics, self.nearest_metrics
        return [
            f"synthetic street scene: {self.points} LiDAR points, {self.sparse_pixels} sparse pixels, "
            f"{self.parallax_outliers} parallax outliers",
            f"scored against the exact depth on {self.scored_pixels} pixels (surfaces inside the LiDAR's vertical "
            "field of view)",
            f"outlier removal: removed {self.removed} pixels, {self.removed_true_outliers} of them true outliers",
            f"{'':8s}{'RMSE mm':>10s}{'MAE mm':>10s}{'iRMSE 1/km':>12s}{'iMAE 1/km':>11s}",
            f"{'sgm':8s}{m['rmse']:10.1f}{m['mae']:10.1f}{m['irmse']:12.2f}{m['imae']:11.2f}",
            f"{'nearest':8s}{n['rmse']:10.1f}{n['mae']:10.1f}{n['irmse']:12.2f}{n['imae']:11.2f}",
            f"wrote {self.out_dir}/depth.png (uint16, metres*256), depth_preview.png, sparse_preview.png "
            f"({self.seconds:.1f} s, " + (f"{self.compile_seconds:.1f} s of it compiling)" if self.compile_seconds >= 0.05
                                          else "no compile: the program came from the compile cache)"),
        ]


def lidar_visible_ground_truth(dense: np.ndarray, camera, lidar) -> np.ndarray:
    """The exact depth where the surface lies inside the LiDAR's vertical field of view, 0 elsewhere.

    Like KITTI's ground truth (accumulated LiDAR), the score only covers what the
    sensor can measure: tall walls above the top beam are not scored.
    """
    from jaxdepth._src.geometry import invert_rigid, transform_points, unproject_depth
    pts = np.asarray(unproject_depth(dense, camera.K)).reshape(-1, 3)
    lidar_pts = np.asarray(transform_points(invert_rigid(camera.T_cam_lidar), pts))
    elevation = np.degrees(np.arctan2(lidar_pts[:, 2], np.hypot(lidar_pts[:, 0], lidar_pts[:, 1])))
    inside = (elevation <= lidar.fov_up_deg + 0.2) & (elevation >= lidar.fov_down_deg - 0.2)
    return np.where(inside.reshape(dense.shape) & (dense > 0), dense, 0.0).astype(np.float32)


#: XLA compile seconds of this process so far (JAX's backend-compile events; a program read from the
#: persistent compile cache is not compiled, so it adds nothing).
_COMPILE_SECONDS = [0.0]


def _listen_to_compiles() -> None:
    import jax.monitoring

    if getattr(_listen_to_compiles, "done", False):
        return

    def listener(event, duration, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            _COMPILE_SECONDS[0] += duration

    jax.monitoring.register_event_duration_secs_listener(listener)
    _listen_to_compiles.done = True


def run_demo(out_dir: pathlib.Path, *, seed: int = 0, method: str = "sgm",
             config: SGMConfig = SGMConfig()) -> DemoResult:
    """Renders the scene, completes camera 0 from the raw sweep and writes the outputs.

    The output folder is created and checked first (:class:`~jaxdepth.io.errors.OutputError`
    before any computation when it cannot be written)."""
    from jaxdepth.io.atomic import ensure_output_dir
    ensure_output_dir(out_dir)
    _listen_to_compiles()
    compiled_before = _COMPILE_SECONDS[0]
    start = time.perf_counter()
    frame = make_street_scene(seed)
    camera = frame.cameras[0]
    gt = lidar_visible_ground_truth(np.asarray(frame.dense_depth[0], np.float32), camera, frame.lidar)
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
    outlier_mask = np.asarray(parallax_outlier_mask(frame.points, frame.valid, camera, frame.dense_depth[0]))
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
                      scored_pixels=int(np.count_nonzero(gt)),
                      seconds=time.perf_counter() - start, compile_seconds=_COMPILE_SECONDS[0] - compiled_before)
