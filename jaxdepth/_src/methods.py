"""Completion methods behind one signature, dispatched by a small static table.

Every method maps one sparse depth image (H, W) and its K (3, 3) to a dense
(H, W) depth, and takes the same optional outlier removal in front.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from jaxdepth._src import presets
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.distance import gather_at_seed, nearest_seed
from jaxdepth._src.ip_basic import ip_basic
from jaxdepth._src.outliers import keep_mask_for_config
from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.pipeline import complete_stages
from jaxdepth._src.types import LidarSpec
from jaxdepth._src.xla_tuning import entry_jit


def _keep_mask(sparse_depth, K, T_cam_lidar, config: SGMConfig, lidar: LidarSpec):
    return keep_mask_for_config(sparse_depth, K, T_cam_lidar, beams=lidar.beams, config=config)


def _sgm(sparse_depth, K, T_cam_lidar, *, config, lidar):
    return complete_stages(sparse_depth, K, T_cam_lidar, config=config, lidar=lidar).depth


def _nearest(sparse_depth, K, T_cam_lidar, *, config, lidar):
    keep = _keep_mask(sparse_depth, K, T_cam_lidar, config, lidar)
    seeds = nearest_seed(keep, metric=config.distance_metric)
    return gather_at_seed(jnp.where(keep, sparse_depth, 0.0), seeds.du, seeds.dv)


def _ip_basic(sparse_depth, K, T_cam_lidar, *, config, lidar):
    keep = _keep_mask(sparse_depth, K, T_cam_lidar, config, lidar)
    return ip_basic(jnp.where(keep, sparse_depth, 0.0))


METHODS = {"sgm": _sgm, "nearest": _nearest, "ip-basic": _ip_basic}


@functools.partial(entry_jit, static_argnames=("method", "config", "lidar"))
def complete_with(sparse_depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array | None = None, *,
                  method: str = "sgm", config: SGMConfig = DEFAULT_CONFIG,
                  lidar: LidarSpec = presets.KITTI_HDL64) -> jax.Array:
    """Dense depth by ``method`` ("sgm", "nearest" or "ip-basic"); outlier removal per ``config``.

    Args:
      sparse_depth: (H, W) float32 metres, 0 = empty.
      K: (3, 3) intrinsics. T_cam_lidar: (4, 4), KITTI camera 2 by default.

    Returns:
      (H, W) float32 metres.
    """
    if method not in METHODS:
        raise ValueError(f"complete_with: field 'method' expected one of {sorted(METHODS)}, got {method!r}")
    if T_cam_lidar is None:
        T_cam_lidar = presets.KITTI_T_CAM2_LIDAR
    sparse_depth = jnp.asarray(sparse_depth, jnp.float32)
    sparse_depth = jnp.where(jnp.isfinite(sparse_depth) & (sparse_depth > 0), sparse_depth, 0.0)
    return METHODS[method](sparse_depth, jnp.asarray(K, jnp.float32), jnp.asarray(T_cam_lidar, jnp.float32),
                           config=config, lidar=lidar)
