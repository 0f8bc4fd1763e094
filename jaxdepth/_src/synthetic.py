"""A procedural street scene with exact depth: the built-in test and demo data.

Contract:
- Every coordinate is in the LiDAR frame (x forward along the street, y left,
  z up), metres. The LiDAR sits at the origin, the ground is the plane
  ``z = -lidar_height_m``.
- The scene is a small set of primitives held in fixed-size float32 arrays
  (:class:`SceneArrays`): planes, boxes rotated about the vertical axis (yaw),
  and closed vertical cylinders. Placement is drawn on the host from
  ``numpy.random.default_rng(seed)``; ray casting (:func:`cast_rays`) is pure,
  jit-compiled JAX with fixed shapes, so one frame is a deterministic function
  of ``seed`` and the options.
- A LiDAR sweep (:func:`lidar_sweep`) is ``beams * columns`` rays, row major
  (beam 0 is the highest), returned as ``(N, 3)`` float32 points plus an
  ``(N,)`` bool mask: rays that hit nothing within ``max_range_m`` are invalid
  and hold ``(0, 0, 0)``.
- A camera's dense depth (:func:`render_depth`) casts one ray through every
  pixel centre (pixel centres sit on integer ``(u, v)``, as in
  :mod:`jaxdepth._src.geometry`) and stores the camera-frame z of the first hit,
  float32 metres; 0 where nothing is hit within ``max_range_m`` (sky).
- The cameras sit at an offset from the LiDAR, so the LiDAR sees surfaces the
  cameras cannot (over car roofs, behind poles): those points still project into
  the image behind the occluder. :func:`count_parallax_outliers` counts them
  against the exact dense depth.

The primitives, the ray caster and the street's placement are in
:mod:`jaxdepth._src.scene` (re-exported here); this module renders sensors from them.

No reference oracle exists for the scene itself; the ray caster is checked
against analytic plane / box / cylinder intersections in the tests.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src import geometry
from jaxdepth._src.poses import rigid, rotation_rpy
from jaxdepth._src.presets import KITTI_HDL64, KITTI_K_CAM2
# The scene and its ray caster live one layer down (shared with synthetic_images); re-exported here.
from jaxdepth._src.scene import SceneArrays as SceneArrays, camera_rays as camera_rays, cast_rays as cast_rays
from jaxdepth._src.scene import scene_arrays as scene_arrays, street_scene_arrays as street_scene_arrays
from jaxdepth._src.types import Camera, LidarSpec


# Scene preset for the "kitti" camera: the KITTI depth-completion benchmark crop
# (bottom 352 rows, centre 1216 columns of the 375 x 1242 image) shifts the
# principal point of camera 2 by (13, 23) pixels.
_KITTI_CROP_HW = (352, 1216)
_KITTI_CROP_OFFSET_UV = (13.0, 23.0)
# Baseline between KITTI's colour cameras 2 and 3, metres.
_KITTI_STEREO_BASELINE_M = 0.54
# nuScenes-like surround rig: 1600 x 900 images; per camera (name, yaw in degrees
# (positive = to the left), optical centre relative to the front camera in the
# LiDAR axes, metres). Rounded from the public nuScenes sensor layout.
_SURROUND_HW = (900, 1600)
_SURROUND_FX = 1266.4
_SURROUND_CXY = (816.3, 491.5)
_SURROUND_RIG = (
    ("front", 0.0, (0.0, 0.0, 0.0)),
    ("front_left", 55.0, (-0.25, 0.50, 0.0)),
    ("front_right", -55.0, (-0.10, -0.50, 0.0)),
    ("back", 180.0, (-1.45, 0.0, 0.07)),
    ("back_left", 110.0, (-0.35, 0.48, 0.08)),
    ("back_right", -110.0, (-0.55, -0.48, 0.05)),
)
# Camera axes (x right, y down, z forward) for a camera looking along +x_lidar.
_R_CAM_FORWARD = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


@functools.partial(jax.jit, static_argnums=0)
def lidar_rays(lidar: LidarSpec) -> jax.Array:
    """Unit ray directions of one spinning-LiDAR sweep, LiDAR frame.

    Beams are spaced uniformly in elevation from ``fov_up_deg`` (beam 0) to
    ``fov_down_deg`` (beam L-1). Column j points at azimuth
    ``pi - 2 pi (j + 0.5) / columns`` (0 = +x, positive towards +y): the sweep
    starts behind the sensor and turns clockwise seen from above.

    Args:
      lidar: static :class:`LidarSpec`.

    Returns:
      (beams * columns, 3) float32 unit vectors, row major (beam, column).
    """
    if lidar.beams == 1:
        elevation = jnp.full((1,), lidar.fov_up_rad, jnp.float32)
    else:
        elevation = jnp.linspace(lidar.fov_up_rad, lidar.fov_down_rad, lidar.beams, dtype=jnp.float32)
    j = jnp.arange(lidar.columns, dtype=jnp.float32)
    azimuth = jnp.float32(math.pi) - jnp.float32(2.0 * math.pi / lidar.columns) * (j + 0.5)
    ce, se = jnp.cos(elevation)[:, None], jnp.sin(elevation)[:, None]
    rays = jnp.stack(jnp.broadcast_arrays(ce * jnp.cos(azimuth), ce * jnp.sin(azimuth), se), axis=-1)
    return rays.reshape(-1, 3)


@functools.partial(jax.jit, static_argnames=("lidar",))
def lidar_sweep(scene: SceneArrays, range_noise_m: jax.Array | None = None, *, lidar: LidarSpec,
                max_range_m: float = 120.0):
    """Ray-casts one LiDAR sweep from the origin of the LiDAR frame.

    Args:
      scene: :class:`SceneArrays`.
      range_noise_m: optional (beams * columns,) float32 metres added to each
        measured range (not clipped). Validity uses the noise-free range.
      lidar: static :class:`LidarSpec`.
      max_range_m: rays without a hit within this range are invalid.

    Returns:
      (points, valid): (N, 3) float32 LiDAR-frame points (0 where invalid) and
      (N,) bool, N = beams * columns, row major (beam, column).
    """
    rays = lidar_rays(lidar)
    t = cast_rays(jnp.zeros((3,), jnp.float32), rays, scene)
    return _sweep_points(rays, t, range_noise_m, max_range_m)


def _sweep_points(rays, t, range_noise_m, max_range_m):
    valid = t <= max_range_m
    r = t if range_noise_m is None else t + jnp.asarray(range_noise_m, jnp.float32)
    points = jnp.where(valid[:, None], rays * jnp.where(valid, r, 0.0)[:, None], 0.0)
    return points, valid


@jax.jit
def render_depth(camera: Camera, scene: SceneArrays, *, max_range_m: float = 120.0) -> jax.Array:
    """Exact dense depth of one camera by casting a ray through every pixel centre.

    Args:
      camera: :class:`Camera`.
      scene: :class:`SceneArrays`.
      max_range_m: surfaces farther than this along the pixel ray count as no hit.

    Returns:
      (H, W) float32 camera-frame z, metres; 0 where nothing is hit.
    """
    origin, d = camera_rays(camera)
    t = cast_rays(origin, d, scene)
    hit = t * jnp.linalg.norm(d, axis=1) <= max_range_m
    return jnp.where(hit, t, 0.0).reshape(camera.height, camera.width)


# --------------------------------------------------------------------------- parallax outliers


@functools.partial(jax.jit, static_argnames=("window_px",))
def parallax_outlier_mask(points: jax.Array, valid: jax.Array, camera: Camera, dense_depth: jax.Array,
                          *, tolerance_m: float = 0.5, window_px: int = 1) -> jax.Array:
    """Pixels of the projected sweep that lie behind the surface the camera sees.

    The sweep is projected with :func:`jaxdepth._src.geometry.project_to_image`
    (nearest point per pixel). A projected pixel is an outlier when its LiDAR
    depth exceeds the true camera depth by more than ``tolerance_m`` at every
    pixel of the ``(2 window_px + 1)^2`` window around it that has a surface.
    With ``window_px = 0`` this is the plain per-pixel comparison; the default
    ``1`` ignores silhouette pixels where rounding the projection by up to half a
    pixel lands on a foreground object (a LiDAR point whose sub-pixel position is
    visible can then never be flagged), so a camera sharing the LiDAR's optical
    centre gives no outliers.

    Args:
      points: (N, 3) float32 LiDAR-frame points. valid: (N,) bool.
      camera: :class:`Camera`.
      dense_depth: (H, W) float32 true camera depth, 0 = no surface.
      tolerance_m: depth margin, metres.
      window_px: static half width of the comparison window, pixels.

    Returns:
      (H, W) bool mask of outlier pixels.
    """
    if dense_depth.shape != (camera.height, camera.width):
        raise ValueError("parallax_outlier_mask: field 'dense_depth' expected shape "
                         f"{(camera.height, camera.width)}, got {tuple(dense_depth.shape)}")
    sparse, _ = geometry.project_to_image(points, valid, camera.K, camera.T_cam_lidar,
                                          height=camera.height, width=camera.width)
    dense = jnp.asarray(dense_depth, jnp.float32)
    h, w = dense.shape
    padded = jnp.pad(dense, window_px, constant_values=0.0)
    farthest = jnp.zeros_like(dense)
    for dv in range(2 * window_px + 1):
        for du in range(2 * window_px + 1):
            farthest = jnp.maximum(farthest, padded[dv:dv + h, du:du + w])
    return (sparse > 0) & (dense > 0) & (sparse > farthest + tolerance_m)


def count_parallax_outliers(points, valid, camera: Camera, dense_depth, *, tolerance_m: float = 0.5,
                            window_px: int = 1) -> int:
    """Number of projected LiDAR pixels hidden from the camera (see :func:`parallax_outlier_mask`).

    Returns:
      Python int, the number of True pixels of :func:`parallax_outlier_mask`.
    """
    return int(jnp.sum(parallax_outlier_mask(points, valid, camera, dense_depth,
                                             tolerance_m=tolerance_m, window_px=window_px)))


# --------------------------------------------------------------------------- cameras


def _camera(K: np.ndarray, yaw_deg: float, centre_lidar: np.ndarray, height: int, width: int) -> Camera:
    """A camera looking horizontally at ``yaw_deg`` with its optical centre at ``centre_lidar``."""
    R = _R_CAM_FORWARD @ rotation_rpy(0.0, 0.0, yaw_deg, degrees=True).T
    T = rigid(R, -R @ np.asarray(centre_lidar, np.float64))
    return Camera(K=jnp.asarray(K, jnp.float32), T_cam_lidar=jnp.asarray(T, jnp.float32),
                  height=int(height), width=int(width))


def _scaled_K(fx, fy, cx, cy, scale):
    # Pixel i covers [i - 0.5, i + 0.5]: x' + 0.5 = s (x + 0.5).
    return np.array([[fx * scale, 0.0, scale * cx + 0.5 * (scale - 1.0)],
                     [0.0, fy * scale, scale * cy + 0.5 * (scale - 1.0)],
                     [0.0, 0.0, 1.0]])


def scaled_intrinsics(fx: float, fy: float, cx: float, cy: float, scale: float) -> np.ndarray:
    """(3, 3) float64 K of an image resized by ``scale`` (pixel centres at integers: a pixel
    covers ``[i - 0.5, i + 0.5]``, so ``c' + 0.5 = scale (c + 0.5)``)."""
    return _scaled_K(fx, fy, cx, cy, scale)


def rig_cameras(preset: str = "kitti", *, lidar_offset_m: Sequence[float] = (-0.3, 0.0, 0.3),
                image_scale: float = 1.0) -> tuple:
    """Cameras of a named rig, relative to a LiDAR at the origin.

    Args:
      preset: "kitti" (one forward camera, 352 x 1216, KITTI camera-2
        intrinsics after the benchmark crop), "stereo" (KITTI-like cameras 2 and
        3, 0.54 m apart, the second to the right) or "surround" (six
        nuScenes-like 1600 x 900 cameras: front, front-left, front-right, back,
        back-left, back-right).
      lidar_offset_m: position of the LiDAR relative to the first (front)
        camera's optical centre, in the LiDAR axes (x forward, y left, z up),
        metres. The default puts the LiDAR 0.3 m behind and 0.3 m above it.
        ``(0, 0, 0)`` makes the LiDAR share the first camera's optical centre.
      image_scale: scales image size and intrinsics (e.g. 0.25 for fast tests).

    Returns:
      tuple of :class:`Camera`.
    """
    offset = np.asarray(lidar_offset_m, np.float64)
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise ValueError(f"rig_cameras: field 'lidar_offset_m' expected 3 finite floats, got {lidar_offset_m!r}")
    if not (isinstance(image_scale, numbers.Real) and 0 < image_scale <= 4):
        raise ValueError(f"rig_cameras: field 'image_scale' expected a float in (0, 4], got {image_scale!r}")

    def size(hw):
        return max(1, round(hw[0] * image_scale)), max(1, round(hw[1] * image_scale))

    if preset in ("kitti", "stereo"):
        K0 = np.asarray(KITTI_K_CAM2, np.float64)
        K = _scaled_K(K0[0, 0], K0[1, 1], K0[0, 2] - _KITTI_CROP_OFFSET_UV[0],
                      K0[1, 2] - _KITTI_CROP_OFFSET_UV[1], image_scale)
        h, w = size(_KITTI_CROP_HW)
        cams = [_camera(K, 0.0, -offset, h, w)]
        if preset == "stereo":
            cams.append(_camera(K, 0.0, -offset + np.array([0.0, -_KITTI_STEREO_BASELINE_M, 0.0]), h, w))
        return tuple(cams)
    if preset == "surround":
        K = _scaled_K(_SURROUND_FX, _SURROUND_FX, *_SURROUND_CXY, image_scale)
        h, w = size(_SURROUND_HW)
        return tuple(_camera(K, yaw, -offset + np.asarray(pos), h, w) for _, yaw, pos in _SURROUND_RIG)
    raise ValueError(f"rig_cameras: field 'preset' expected one of ('kitti', 'stereo', 'surround'), got {preset!r}")


# --------------------------------------------------------------------------- the street


@functools.partial(jax.jit, static_argnames=("lidar",))
def _render_frame(scene, range_noise_m, cameras, *, lidar, max_range_m):
    """The sweep and every camera's depth from one :func:`cast_rays` (one compilation)."""
    rays = lidar_rays(lidar)
    origins, directions, sizes = [jnp.zeros_like(rays)], [rays], [rays.shape[0]]
    for cam in cameras:
        o, d = camera_rays(cam)
        origins.append(jnp.broadcast_to(o, d.shape))
        directions.append(d)
        sizes.append(d.shape[0])
    directions = jnp.concatenate(directions)
    t = cast_rays(jnp.concatenate(origins), directions, scene)
    parts = jnp.split(t, np.cumsum(sizes)[:-1])
    points, valid = _sweep_points(rays, parts[0], range_noise_m, max_range_m)
    depths = []
    for cam, t_cam, d in zip(cameras, parts[1:], jnp.split(directions, np.cumsum(sizes)[:-1])[1:]):
        hit = t_cam * jnp.linalg.norm(d, axis=1) <= max_range_m
        depths.append(jnp.where(hit, t_cam, 0.0).reshape(cam.height, cam.width))
    return points, valid, tuple(depths)


@dataclasses.dataclass(frozen=True)
class SyntheticFrame:
    """One synthetic frame: a LiDAR sweep, cameras and their exact depth.

    Attributes:
      points: (N, 3) float32 LiDAR-frame points, metres, N = beams * columns
        (row major (beam, column)); (0, 0, 0) where invalid.
      valid: (N,) bool, False where the ray hit nothing within max range.
      cameras: tuple of :class:`Camera`.
      dense_depth: tuple of (H, W) float32 exact depth per camera, metres,
        0 = no surface (sky).
      lidar: the :class:`LidarSpec` of the sweep.
      scene: the :class:`SceneArrays` the frame was cast from.
      images: None, or (with ``make_street_scene(..., images=True)``) a tuple of
        (H, W, 3) uint8 RGB camera images (:func:`render_image` with
        :func:`street_colours` and :func:`street_image_noise`), one per camera.
    """

    points: np.ndarray
    valid: np.ndarray
    cameras: tuple
    dense_depth: tuple
    lidar: LidarSpec
    scene: SceneArrays | None = None
    images: tuple | None = None


def make_street_scene(seed: int = 0, *, lidar: LidarSpec = KITTI_HDL64, cameras: str | Sequence = "kitti",
                      noise_std_m: float = 0.0, lidar_offset_m: Sequence[float] = (-0.3, 0.0, 0.3),
                      image_scale: float = 1.0, max_range_m: float = 120.0,
                      lidar_height_m: float = 1.73, images: bool = False) -> SyntheticFrame:
    """Renders one frame of the procedural street (see :func:`street_scene_arrays`).

    Args:
      seed: scene seed; the same seed and options give byte-identical arrays.
      lidar: the spinning LiDAR (beams, vertical field of view, columns).
      cameras: "kitti", "stereo", "surround" (see :func:`rig_cameras`) or a
        sequence of :class:`Camera` (then ``lidar_offset_m`` and ``image_scale``
        are unused).
      noise_std_m: standard deviation of Gaussian range noise, metres, drawn from
        ``default_rng([seed, 1])`` (a stream separate from the scene's, so noise
        does not move objects); 0 = exact ranges.
      lidar_offset_m: LiDAR position relative to the first camera, LiDAR axes.
      image_scale: image size / intrinsics scale of the preset cameras.
      max_range_m: LiDAR and camera rays without a hit within this range are empty.
      lidar_height_m: LiDAR height above the ground.
      images: also render each camera's RGB image (:attr:`SyntheticFrame.images`;
        colours from :func:`street_colours`, pixel noise N(0, 2) / 255 from
        :func:`street_image_noise` with the camera's index). Does not change
        the other outputs.

    Returns:
      :class:`SyntheticFrame` of NumPy arrays.
    """
    if not isinstance(lidar, LidarSpec):
        raise ValueError(f"make_street_scene: field 'lidar' expected a LidarSpec, got {type(lidar).__name__}")
    if not noise_std_m >= 0:
        raise ValueError(f"make_street_scene: field 'noise_std_m' expected >= 0, got {noise_std_m!r}")
    if not max_range_m > 0:
        raise ValueError(f"make_street_scene: field 'max_range_m' expected > 0, got {max_range_m!r}")
    if isinstance(cameras, str):
        cams = rig_cameras(cameras, lidar_offset_m=lidar_offset_m, image_scale=image_scale)
    else:
        cams = tuple(cameras)
        for i, cam in enumerate(cams):
            if not isinstance(cam, Camera):
                raise ValueError(f"make_street_scene: field 'cameras[{i}]' expected a Camera, "
                                 f"got {type(cam).__name__}")
    scene = street_scene_arrays(seed, lidar_height_m=lidar_height_m)
    # Always an array (zeros without noise: t + 0 == t), so noisy and exact frames share one compilation.
    noise = np.zeros(lidar.beams * lidar.columns, np.float32)
    if noise_std_m > 0:
        rng = np.random.default_rng([seed, 1])
        noise = (noise_std_m * rng.standard_normal(noise.shape[0])).astype(np.float32)
    points, valid, depths = _render_frame(scene, noise, cams, lidar=lidar, max_range_m=float(max_range_m))
    depths = tuple(np.asarray(d) for d in depths)
    rgb = None
    if images:
        from jaxdepth._src.synthetic_images import render_image, street_colours, street_image_noise
        colours = street_colours(seed, scene)
        rgb = tuple(np.asarray(render_image(cam, scene, colours,
                                            street_image_noise(seed, i, cam.height, cam.width),
                                            max_range_m=float(max_range_m)))
                    for i, cam in enumerate(cams))
    return SyntheticFrame(points=np.asarray(points), valid=np.asarray(valid), cameras=cams,
                          dense_depth=depths, lidar=lidar, scene=scene, images=rgb)
