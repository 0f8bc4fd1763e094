"""Containers shared by every stage: sensor descriptions and the stage outputs.

Nothing here computes. Units: metres, radians, pixels. Images are ``(H, W)``;
points are ``(N, 3)`` float32 plus a ``(N,)`` bool validity mask.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax


@dataclasses.dataclass(frozen=True)
class LidarSpec:
    """Static description of a spinning multi-beam LiDAR (hashable: usable as a jit static).

    Attributes:
      beams: number of laser beams L (rows of the range image; the paper's L).
      fov_up_deg: elevation of the highest beam, degrees (positive up).
      fov_down_deg: elevation of the lowest beam, degrees (negative down).
      columns: azimuth cells of the range image over 360 degrees.
    """

    beams: int = 64
    fov_up_deg: float = 2.0
    fov_down_deg: float = -24.9
    columns: int = 2048

    def __post_init__(self):
        if int(self.beams) < 1:
            raise ValueError(f"LidarSpec: field 'beams' expected a positive integer, got {self.beams!r}")
        if int(self.columns) < 4:
            raise ValueError(f"LidarSpec: field 'columns' expected an integer >= 4, got {self.columns!r}")
        if not self.fov_up_deg > self.fov_down_deg:
            raise ValueError(
                "LidarSpec: field 'fov_up_deg' expected to exceed 'fov_down_deg', "
                f"got {self.fov_up_deg!r} <= {self.fov_down_deg!r}")

    @property
    def fov_up_rad(self) -> float:
        return math.radians(self.fov_up_deg)

    @property
    def fov_down_rad(self) -> float:
        return math.radians(self.fov_down_deg)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Camera:
    """One pinhole camera.

    Attributes:
      K: (3, 3) float32 intrinsics, pixels.
      T_cam_lidar: (4, 4) float32 rigid transform, ``p_cam = T_cam_lidar @ p_lidar``
        (camera looks along +z, x right, y down).
      height, width: static image size in pixels (pytree metadata, not traced).
    """

    K: jax.Array
    T_cam_lidar: jax.Array
    height: int = dataclasses.field(metadata=dict(static=True))
    width: int = dataclasses.field(metadata=dict(static=True))


class Stages(NamedTuple):
    """Every intermediate product of the SGM pipeline for one camera image.

    All fields are (H, W) unless noted.

    Attributes:
      sparse_depth: float32 metres, 0 = empty: the input depth image.
      normals: (3, H, W) float32 unit surface normals of the sparse pixels in the
        camera frame (zero where the pixel is empty).
      inlier_mask: bool, sparse pixels kept by outlier removal (Step 2).
      seed_depth: float32 metres, z' of the nearest kept LiDAR pixel (Step 3).
      du, dv: int32 pixels; the nearest seed sits at (u + du, v + dv).
      residual: float32 metres, the paper's Delta z (Step 4).
      depth_raw: float32 metres, z' + Delta z before smoothing.
      depth: float32 metres, the final dense depth.
    """

    sparse_depth: jax.Array
    normals: jax.Array
    inlier_mask: jax.Array
    seed_depth: jax.Array
    du: jax.Array
    dv: jax.Array
    residual: jax.Array
    depth_raw: jax.Array
    depth: jax.Array
