"""Which pixels the LiDAR can support: its vertical field of view and the distance to a seed.

One camera image per call, fixed shapes, jit-compiled; ``vmap`` over cameras and
frames. Inputs are :class:`~jaxdepth._src.types.Stages` fields (``du``, ``dv``,
``seed_depth``), the camera's ``K`` and ``T_cam_lidar`` (traced) and the static
:class:`~jaxdepth._src.types.LidarSpec`.

* Field of view: the *direction* of pixel ``(u, v)``'s ray, ``K^-1 [u, v, 1]``,
  rotated into the LiDAR frame (``R^T`` of ``T_cam_lidar``), has elevation
  ``atan2(z, hypot(x, y))``; the pixel is inside when
  ``fov_down_rad <= elevation <= fov_up_rad``. This is the elevation of the ray's
  point at infinity: the camera-LiDAR baseline (0.27 m on KITTI) is ignored, so
  near the edge of the field of view a close surface may be a fraction of a
  degree off.
* Seed distance: ``|du| + |dv|`` (``"l1"``) or ``sqrt(du**2 + dv**2)`` (``"l2"``),
  the metric of the nearest-seed step (:func:`~jaxdepth._src.distance.nearest_seed`),
  in pixels; ``+inf`` where the image has no seed (``seed_depth == 0``).
* Validity: inside the field of view and ``seed distance <= max_seed_distance_px``; or,
  anywhere, within one scan-line spacing of a seed (at most ``max_seed_distance_px``): the
  rows just beyond the outermost scan lines are as near to a LiDAR pixel as the pixels
  between two scan lines, though their rays leave the nominal field of view.
* The default limit follows from the sensor (:func:`sensor_max_seed_distance_px`):
  ``SCAN_LINE_FACTOR`` times the camera's scan-line spacing, ``fy`` times the LiDAR's
  vertical beam spacing ``(fov_up - fov_down) / (beams - 1)`` in radians. KITTI's
  HDL-64E (26.9 deg over 64 beams) with fy = 721.5 gives 5.38 px and a limit of 16.1 px;
  nuScenes' HDL-32E (41.3 deg over 32 beams) with fy = 1266 gives 29.5 px and 88.4 px.
  Why 3: in the L1 metric of the seed search a pixel between two scan lines is at most
  half a spacing from one of them vertically; one scan line missing its returns there
  (dark or specular surfaces, points removed as occluded) doubles the gap, so the pixel
  is up to one spacing away vertically, and the nearest return on that line may be up
  to one more spacing away sideways (gaps along the line of the same kind), 2 spacings
  in all; the last spacing is slack for the scan lines' tilt and curvature in the image
  (a camera rolled or pitched against the LiDAR, lines bending away from the centre).

Oracle: a NumPy loop over pixels (tests/test_validity.py); analytic case: a
camera looking along the LiDAR's x axis with no rotation between them crosses
``fov_up`` at row ``v = cy - fy tan(fov_up)`` in column ``cx``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from jaxdepth._src.config import DISTANCE_METRICS, SGMConfig
from jaxdepth._src.geometry import pixel_rays
from jaxdepth._src.types import LidarSpec, Stages

_DEFAULT_METRIC = SGMConfig().distance_metric
DEFAULT_MAX_SEED_DISTANCE_PX = 16.0  # KITTI's 64 beams at fy 721.5 under the sensor rule (16.1 px)
#: The validity limit is this many scan-line spacings (see module docs).
SCAN_LINE_FACTOR = 3.0


def scan_line_spacing_px(K: jax.Array, lidar: LidarSpec) -> jax.Array:
    """Vertical distance between neighbouring scan lines in the image, pixels.

    ``fy * (fov_up_rad - fov_down_rad) / (beams - 1)``: the beams' mean elevation step
    seen by a camera of focal length ``fy = K[1, 1]`` (near its principal row). A
    single-beam LiDAR has no spacing; its field of view is used.

    Args:
      K: (3, 3) intrinsics (traced). lidar: static :class:`LidarSpec`.

    Returns:
      () float32 pixels.
    """
    step = (lidar.fov_up_rad - lidar.fov_down_rad) / max(int(lidar.beams) - 1, 1)
    return jnp.asarray(K, jnp.float32)[1, 1] * jnp.float32(step)


def sensor_max_seed_distance_px(K: jax.Array, lidar: LidarSpec) -> jax.Array:
    """The default validity limit: ``SCAN_LINE_FACTOR * scan_line_spacing_px(K, lidar)``, () float32 pixels."""
    return jnp.float32(SCAN_LINE_FACTOR) * scan_line_spacing_px(K, lidar)


@functools.partial(jax.jit, static_argnames=("height", "width"))
def ray_elevation(K: jax.Array, T_cam_lidar: jax.Array, *, height: int, width: int) -> jax.Array:
    """Elevation of every pixel's viewing ray in the LiDAR frame.

    Args:
      K: (3, 3) float32 intrinsics, pixels (skew ``K[0, 1]`` honoured).
      T_cam_lidar: (4, 4) float32, ``p_cam = T_cam_lidar @ p_lidar``; only its
        rotation is used (the ray's direction, not its origin).
      height, width: static image size.

    Returns:
      (H, W) float32 radians, ``atan2(d_z, hypot(d_x, d_y))`` of
      ``d = R^T K^-1 [u, v, 1]`` (positive up when the LiDAR's z is up).
    """
    K = jnp.asarray(K, jnp.float32)
    R = jnp.asarray(T_cam_lidar, jnp.float32)[:3, :3]
    v, u = jnp.meshgrid(jnp.arange(height, dtype=jnp.float32), jnp.arange(width, dtype=jnp.float32),
                        indexing="ij")
    x, y = pixel_rays(K, v, u)
    # d_lidar = R^T d_cam: component i is column i of R dotted with (x, y, 1).
    d = x[None] * R[0][:, None, None] + y[None] * R[1][:, None, None] + R[2][:, None, None]
    return jnp.arctan2(d[2], jnp.hypot(d[0], d[1]))


@functools.partial(jax.jit, static_argnames=("height", "width", "lidar"))
def fov_mask(K: jax.Array, T_cam_lidar: jax.Array, *, height: int, width: int, lidar: LidarSpec) -> jax.Array:
    """(H, W) bool: the pixel's ray lies inside the LiDAR's vertical field of view.

    True where ``lidar.fov_down_rad <= ray_elevation <= lidar.fov_up_rad``
    (see :func:`ray_elevation` for K, T_cam_lidar, height, width).
    """
    elev = ray_elevation(K, T_cam_lidar, height=height, width=width)
    return (elev >= jnp.float32(lidar.fov_down_rad)) & (elev <= jnp.float32(lidar.fov_up_rad))


@functools.partial(jax.jit, static_argnames="metric")
def seed_distance(du: jax.Array, dv: jax.Array, seed_depth: jax.Array, *, metric: str = _DEFAULT_METRIC) -> jax.Array:
    """(H, W) float32 pixel distance from every pixel to its nearest seed.

    Args:
      du, dv: (H, W) int32 offsets of :class:`Stages` (the seed is at ``(u + du, v + dv)``).
      seed_depth: (H, W) float32 metres of :class:`Stages`; 0 where no seed exists.
      metric: static, ``"l1"`` (``|du| + |dv|``) or ``"l2"`` (``sqrt(du**2 + dv**2)``),
        the ``SGMConfig.distance_metric`` the seeds were found with.

    Returns:
      (H, W) float32 pixels; ``+inf`` where ``seed_depth <= 0``.
    """
    if metric not in DISTANCE_METRICS:
        raise ValueError(f"seed_distance: field 'metric' expected one of {DISTANCE_METRICS}, got {metric!r}")
    du = jnp.asarray(du, jnp.int32)
    dv = jnp.asarray(dv, jnp.int32)
    if metric == "l1":
        dist = (jnp.abs(du) + jnp.abs(dv)).astype(jnp.float32)
    else:
        dist = jnp.sqrt((du * du + dv * dv).astype(jnp.float32))
    return jnp.where(jnp.asarray(seed_depth) > 0, dist, jnp.inf)


@functools.partial(jax.jit, static_argnames=("lidar", "metric", "max_seed_distance_px"))
def validity_and_distance(stages: Stages, K: jax.Array, T_cam_lidar: jax.Array, *, lidar: LidarSpec,
                          metric: str = _DEFAULT_METRIC,
                          max_seed_distance_px: float | None = None) -> tuple[jax.Array, jax.Array]:
    """Validity mask and seed distance of one completed camera image.

    Args:
      stages: :class:`Stages` of one image ((H, W) fields; only ``du``, ``dv`` and
        ``seed_depth`` are read).
      K: (3, 3) float32. T_cam_lidar: (4, 4) float32 (traced).
      lidar: static :class:`LidarSpec` (``fov_up_deg``, ``fov_down_deg``).
      metric: static, the seeds' ``SGMConfig.distance_metric``.
      max_seed_distance_px: static, pixels; farther pixels are not supported. None
        (default): :func:`sensor_max_seed_distance_px` of this camera and LiDAR.

    Returns:
      ``(valid, distance)``: (H, W) bool, :func:`fov_mask` and
      ``distance <= max_seed_distance_px``, or ``distance <= min(scan_line_spacing_px,
      max_seed_distance_px)`` anywhere; (H, W) float32 :func:`seed_distance`.
    """
    h, w = stages.du.shape
    distance = seed_distance(stages.du, stages.dv, stages.seed_depth, metric=metric)
    inside = fov_mask(K, T_cam_lidar, height=h, width=w, lidar=lidar)
    limit = (sensor_max_seed_distance_px(K, lidar) if max_seed_distance_px is None
             else jnp.float32(max_seed_distance_px))
    near = distance <= jnp.minimum(scan_line_spacing_px(K, lidar), limit)  # also beyond the outermost scan lines
    return (inside & (distance <= limit)) | near, distance


def rig_validity_and_distance(stages: Stages, cameras, *, lidar: LidarSpec, metric: str = _DEFAULT_METRIC,
                              max_seed_distance_px: float | None = None):
    """:func:`validity_and_distance` of every camera of a rig: ``stages`` with (C, H, W) fields
    (:func:`jaxdepth.complete_rig_stages`) and ``cameras`` a :class:`~jaxdepth.RigCameras`;
    returns (C, H, W) ``(valid, distance)``."""
    per_camera = functools.partial(validity_and_distance, lidar=lidar, metric=metric,
                                   max_seed_distance_px=max_seed_distance_px)
    return jax.vmap(per_camera)(stages, cameras.K, cameras.T_cam_lidar)


def validity_mask(stages: Stages, K: jax.Array, T_cam_lidar: jax.Array, *, lidar: LidarSpec,
                  metric: str = _DEFAULT_METRIC,
                  max_seed_distance_px: float | None = None) -> jax.Array:
    """(H, W) bool of the pixels the sensor supports; see :func:`validity_and_distance`."""
    return validity_and_distance(stages, K, T_cam_lidar, lidar=lidar, metric=metric,
                                 max_seed_distance_px=max_seed_distance_px)[0]
