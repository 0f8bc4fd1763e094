"""Hidden-point evaluation: score completion where no dense ground truth exists.

A seeded share of the LiDAR points is hidden; the rest is completed; every
method is scored (KITTI devkit metrics) at the pixels that the hidden points
win in their own per-pixel z-buffer. Nothing that a method under test does
filters these targets: the score must not grade a method with itself (an
earlier version kept only targets that survived jaxdepth's own outlier
removal). The price: a hidden point that the camera cannot see (a parallax
outlier) is still a target, so removing its visible twins in the input is
scored as an error; read the scores with that in mind.

Methods on the same input: the SGM as configured, the SGM without outlier
removal, the nearest-LiDAR-pixel fill it starts from (its own distance metric,
no removal), the Euclidean nearest fill ("nearest_l2"; the same as "nearest"
when the SGM runs with ``distance_metric="l2"``) and IP_Basic (no removal).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src import presets
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.geometry import project_to_image
from jaxdepth._src.ip_basic import ip_basic
from jaxdepth._src.metrics import depth_metrics
from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.rig import RigCameras, _complete_rig_stages
from jaxdepth._src.types import LidarSpec


def hidden_point_mask(valid: np.ndarray, *, fraction: float = 0.1, seed: int = 0) -> np.ndarray:
    """(N,) bool: a seeded random ``fraction`` of the valid points (host-side, deterministic)."""
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"hidden_point_mask: field 'fraction' expected in (0, 1), got {fraction!r}")
    valid = np.asarray(valid, bool)
    draw = np.random.default_rng(seed).random(valid.shape[0])
    return valid & (draw < fraction)


METHODS = ("sgm", "sgm_no_removal", "nearest", "nearest_l2", "ip_basic")


def hidden_point_scores(points: jax.Array, valid: jax.Array, hidden: jax.Array, cameras: RigCameras, *,
                        config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64) -> dict:
    """Per-camera metrics of every method in :data:`METHODS` at the hidden points.

    Args:
      points: (N, 3) float32 LiDAR frame. valid: (N,) bool. hidden: (N,) bool
        subset of ``valid`` held out from the input.
      cameras: :class:`RigCameras`.
      config: the SGM's configuration ("sgm"); "sgm_no_removal" is the same
        with ``outlier_removal=False``.

    Returns:
      {method: {metric: (C,)} for each of :data:`METHODS`, "hidden_pixels": (C,) int32};
      metrics in mm and 1/km as :func:`depth_metrics`. Targets: the hidden
      points' own z-buffer (nearest hidden point per pixel), unfiltered.
    """
    return _hidden_point_scores(points, valid, hidden, cameras, config=config, lidar=lidar)


@functools.partial(jax.jit, static_argnames=("config", "lidar"))
def _hidden_point_scores(points, valid, hidden, cameras, *, config, lidar):
    valid = jnp.asarray(valid, bool)
    hidden = jnp.asarray(hidden, bool) & valid
    given = valid & ~hidden
    stages = _complete_rig_stages(points, given, cameras, config=config, lidar=lidar)
    plain = _complete_rig_stages(points, given, cameras, config=config.replace(outlier_removal=False), lidar=lidar)
    if config.distance_metric == "l2":
        euclid = plain.seed_depth
    else:
        euclid = _complete_rig_stages(points, given, cameras, lidar=lidar, config=config.replace(
            outlier_removal=False, distance_metric="l2")).seed_depth

    def gt_for(K, T, size):
        depth, _ = project_to_image(points, hidden, K, T, height=cameras.height, width=cameras.width,
                                    valid_size=size)
        return depth

    gt = jax.vmap(gt_for)(cameras.K, cameras.T_cam_lidar, cameras.image_size)
    score = jax.vmap(depth_metrics)
    predictions = {"sgm": stages.depth, "sgm_no_removal": plain.depth, "nearest": plain.seed_depth,
                   "nearest_l2": euclid, "ip_basic": jax.vmap(ip_basic)(plain.sparse_depth)}
    out = {name: score(predictions[name], gt) for name in METHODS}
    out["hidden_pixels"] = jnp.sum(gt > 0, axis=(1, 2)).astype(jnp.int32)
    return out
