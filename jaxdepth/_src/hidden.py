"""Hidden-point evaluation: score completion where no dense ground truth exists.

A seeded share of the LiDAR points is hidden; the rest is completed; the
prediction is scored (KITTI devkit metrics) at the pixels that a hidden point wins
in the z-buffer of the whole sweep and that outlier removal keeps on the whole
sweep: a hidden point the camera cannot see (a parallax outlier) is not a valid
target, and scoring it would penalise the very removal that makes the depth
right. A nearest-neighbour fill of the same input is scored the same way as the
baseline.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src import presets
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.geometry import project_to_image, transform_points
from jaxdepth._src.outliers import outlier_keep_mask
from jaxdepth._src.metrics import depth_metrics
from jaxdepth._src.pipeline import DEFAULT_CONFIG
from jaxdepth._src.rig import RigCameras, _complete_rig_stages
from jaxdepth._src.types import LidarSpec


def hidden_point_mask(valid: np.ndarray, *, fraction: float = 0.1, seed: int = 0) -> np.ndarray:
    """(N,) bool: a seeded random ``fraction`` of the valid points (host-side, deterministic)."""
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"hidden_point_mask: 'fraction' expected in (0, 1), got {fraction!r}")
    valid = np.asarray(valid, bool)
    draw = np.random.default_rng(seed).random(valid.shape[0])
    return valid & (draw < fraction)


def hidden_point_scores(points: jax.Array, valid: jax.Array, hidden: jax.Array, cameras: RigCameras, *,
                        config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64) -> dict:
    """Per-camera metrics of SGM and of a nearest-neighbour fill at the hidden points.

    Args:
      points: (N, 3) float32 LiDAR frame. valid: (N,) bool. hidden: (N,) bool
        subset of ``valid`` held out from the input.
      cameras: :class:`RigCameras`.

    Returns:
      {"sgm": {metric: (C,)}, "nearest": {metric: (C,)}, "hidden_pixels": (C,) int32};
      metrics in mm and 1/km as :func:`depth_metrics`.
    """
    return _hidden_point_scores(points, valid, hidden, cameras, config=config, lidar=lidar)


@functools.partial(jax.jit, static_argnames=("config", "lidar"))
def _hidden_point_scores(points, valid, hidden, cameras, *, config, lidar):
    valid = jnp.asarray(valid, bool)
    hidden = jnp.asarray(hidden, bool) & valid
    stages = _complete_rig_stages(points, valid & ~hidden, cameras, config=config, lidar=lidar)

    def gt_for(K, T, size):
        depth, index = project_to_image(points, valid, K, T, height=cameras.height, width=cameras.width,
                                        valid_size=size)
        hit = index >= 0
        winner = jnp.where(hit, index, 0)
        points_cam = jnp.where(hit[None], transform_points(T, points[winner.reshape(-1)]).T.reshape(
            3, cameras.height, cameras.width), 0.0)
        keep = outlier_keep_mask(depth, K, T, beams=lidar.beams, epsilon_m=config.epsilon_m,
                                 max_half_width_px=config.outlier_max_half_width_px,
                                 max_half_height_px=config.outlier_max_half_height_px, points_cam=points_cam)
        return jnp.where(hit & hidden[winner] & keep, depth, 0.0)

    gt = jax.vmap(gt_for)(cameras.K, cameras.T_cam_lidar, cameras.image_size)
    score = jax.vmap(depth_metrics)
    return {"sgm": score(stages.depth, gt), "nearest": score(stages.seed_depth, gt),
            "hidden_pixels": jnp.sum(gt > 0, axis=(1, 2)).astype(jnp.int32)}
