"""Several cameras from one sweep: the range image and normals once, the cameras vmapped.

Cameras of different sizes share one padded (H, W) canvas; each keeps a traced
``image_size`` window, points outside it are not projected, and the output
outside it is 0. Outlier removal uses the canvas size for the paper's window
bounds (W L / N, H / L), which equals the camera's own size when all cameras
have the same size (KITTI stereo, nuScenes).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src import presets
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.normals import point_normals
from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.pipeline import camera_stages_from_points
from jaxdepth._src.types import Camera, LidarSpec, Stages


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RigCameras:
    """C cameras stacked on a common canvas.

    Attributes:
      K: (C, 3, 3) float32. T_cam_lidar: (C, 4, 4) float32.
      image_size: (C, 2) int32 (height, width) of each real image (<= canvas).
      height, width: static canvas size.
    """

    K: jax.Array
    T_cam_lidar: jax.Array
    image_size: jax.Array
    height: int = dataclasses.field(metadata=dict(static=True))
    width: int = dataclasses.field(metadata=dict(static=True))

    @property
    def count(self) -> int:
        return self.K.shape[0]


def stack_cameras(cameras) -> RigCameras:
    """Stacks :class:`Camera` objects (any sizes) into :class:`RigCameras` on the largest canvas."""
    cameras = list(cameras)
    if not cameras:
        raise ValueError("stack_cameras: expected at least one camera, got none")
    height = max(int(c.height) for c in cameras)
    width = max(int(c.width) for c in cameras)
    return RigCameras(
        K=jnp.asarray(np.stack([np.asarray(c.K, np.float32) for c in cameras])),
        T_cam_lidar=jnp.asarray(np.stack([np.asarray(c.T_cam_lidar, np.float32) for c in cameras])),
        image_size=jnp.asarray(np.array([[c.height, c.width] for c in cameras], np.int32)),
        height=height, width=width)


@functools.partial(jax.jit, static_argnames=("config", "lidar"))
def _complete_rig_stages(points, valid, cameras, *, config, lidar):
    points = jnp.asarray(points, jnp.float32)
    valid = jnp.asarray(valid, bool) & jnp.all(jnp.isfinite(points), axis=-1)
    points = jnp.where(valid[:, None], points, 0.0)
    normals_lidar = point_normals(points, valid, lidar=lidar, smoothing=config.normal_smoothing,
                                  fill_max_gap=config.range_fill_max_gap)
    def per_camera(K, T, size):
        return camera_stages_from_points(points, valid, normals_lidar, K, T, height=cameras.height,
                                         width=cameras.width, lidar=lidar, config=config, image_size=size)

    return jax.vmap(per_camera)(cameras.K, cameras.T_cam_lidar, cameras.image_size)


def complete_rig_stages(points: jax.Array, valid: jax.Array, cameras: RigCameras, *,
                        config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64) -> Stages:
    """SGM completion of one sweep for C cameras; every :class:`Stages` field gains a leading C axis.

    Args:
      points: (N, 3) float32 LiDAR-frame points. valid: (N,) bool.
      cameras: :class:`RigCameras` (see :func:`stack_cameras`).

    Returns:
      :class:`Stages` with (C, H, W) fields ((C, 3, H, W) normals).
    """
    return _complete_rig_stages(points, valid, cameras, config=config, lidar=lidar)


def complete_rig(points: jax.Array, valid: jax.Array, cameras: RigCameras, *,
                 config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64) -> jax.Array:
    """(C, H, W) float32 dense depth for every camera of the rig; see :func:`complete_rig_stages`."""
    return complete_rig_stages(points, valid, cameras, config=config, lidar=lidar).depth
