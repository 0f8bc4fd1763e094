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

No reference oracle exists for the scene itself; the ray caster is checked
against analytic plane / box / cylinder intersections in the tests.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src import geometry
from jaxdepth._src.presets import KITTI_HDL64, KITTI_K_CAM2
from jaxdepth._src.types import Camera, LidarSpec

# Hits closer than this ray parameter are ignored (guards against self hits).
_T_MIN = 1e-6
# Direction components with a smaller magnitude count as parallel to a face.
_TINY = 1e-12

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


class SceneArrays(NamedTuple):
    """The primitives of a scene, float32, LiDAR frame, metres (a pytree).

    Attributes:
      planes: (Q, 4) ``[nx, ny, nz, offset]``: the surface ``n . p = offset``
        with a unit normal n (two sided).
      boxes: (B, 7) ``[cx, cy, cz, half_x, half_y, half_z, yaw]``: a solid box
        centred at c with half extents along its own axes, rotated by ``yaw``
        radians about +z (counter-clockwise seen from above).
      cylinders: (P, 5) ``[cx, cy, radius, z_min, z_max]``: a closed solid
        vertical cylinder (side and both caps).
    """

    planes: jax.Array
    boxes: jax.Array
    cylinders: jax.Array


def scene_arrays(*, planes=None, boxes=None, cylinders=None) -> SceneArrays:
    """Builds a :class:`SceneArrays` from array-likes (missing kinds become empty).

    Args:
      planes: (Q, 4) or None. boxes: (B, 7) or None. cylinders: (P, 5) or None.
        See :class:`SceneArrays` for the layouts. Normals are normalised here.

    Returns:
      SceneArrays of NumPy float32 arrays (valid jit inputs).
    """
    def check(name, value, width):
        if value is None:
            return np.zeros((0, width), np.float32)
        arr = np.asarray(value, np.float64)
        if arr.ndim != 2 or arr.shape[1] != width:
            raise ValueError(f"scene_arrays: field {name!r} expected shape (n, {width}), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"scene_arrays: field {name!r} expected finite values, got non-finite entries")
        return arr

    planes = check("planes", planes, 4)
    norms = np.linalg.norm(planes[:, :3], axis=1)
    if np.any(norms == 0):
        raise ValueError("scene_arrays: field 'planes' expected non-zero normals, got a zero normal")
    planes = np.concatenate([planes[:, :3] / norms[:, None], planes[:, 3:] / norms[:, None]], axis=1)
    boxes = check("boxes", boxes, 7)
    if np.any(boxes[:, 3:6] < 0):
        raise ValueError("scene_arrays: field 'boxes' expected non-negative half extents, got a negative one")
    cylinders = check("cylinders", cylinders, 5)
    if np.any(cylinders[:, 2] < 0) or np.any(cylinders[:, 4] < cylinders[:, 3]):
        raise ValueError("scene_arrays: field 'cylinders' expected radius >= 0 and z_max >= z_min")
    return SceneArrays(planes.astype(np.float32), boxes.astype(np.float32), cylinders.astype(np.float32))


# --------------------------------------------------------------------------- ray casting


def _safe_inverse(x):
    ok = jnp.abs(x) > _TINY
    return ok, 1.0 / jnp.where(ok, x, 1.0)


def _first_hit_planes(o, d, planes):
    """o (M, 3) with M in {1, N}; d (N, 3) -> (N,) nearest plane hit or inf."""
    n = planes[:, :3]
    denom = d @ n.T                               # (N, Q)
    numer = planes[:, 3] - o @ n.T                # (M, Q)
    ok, inv = _safe_inverse(denom)
    t = numer * inv
    t = jnp.where(ok & (t > _T_MIN), t, jnp.inf)
    return jnp.min(t, axis=1, initial=jnp.inf)


def _first_hit_boxes(o, d, boxes):
    """Slab test in each box's own (yawed) frame -> (N,) nearest hit or inf."""
    c = boxes[:, 0:3]
    half = boxes[:, 3:6]
    cos, sin = jnp.cos(boxes[:, 6]), jnp.sin(boxes[:, 6])
    rx = o[:, 0:1] - c[:, 0]                      # (M, B)
    ry = o[:, 1:2] - c[:, 1]
    local_o = (cos * rx + sin * ry, -sin * rx + cos * ry, o[:, 2:3] - c[:, 2])
    dx, dy = d[:, 0:1], d[:, 1:2]                 # (N, 1)
    local_d = (cos * dx + sin * dy, -sin * dx + cos * dy, jnp.broadcast_to(d[:, 2:3], (d.shape[0], 1)))
    t_near = jnp.float32(-jnp.inf)
    t_far = jnp.float32(jnp.inf)
    for axis in range(3):
        oc, dc, hc = local_o[axis], local_d[axis], half[:, axis]
        ok, inv = _safe_inverse(dc)
        t1 = (-hc - oc) * inv
        t2 = (hc - oc) * inv
        inside = jnp.abs(oc) <= hc
        lo = jnp.where(ok, jnp.minimum(t1, t2), jnp.where(inside, -jnp.inf, jnp.inf))
        hi = jnp.where(ok, jnp.maximum(t1, t2), jnp.where(inside, jnp.inf, -jnp.inf))
        t_near = jnp.maximum(t_near, lo)
        t_far = jnp.minimum(t_far, hi)
    hit = (t_near <= t_far) & (t_far > _T_MIN)
    t = jnp.where(hit, jnp.where(t_near > _T_MIN, t_near, t_far), jnp.inf)
    return jnp.min(t, axis=1, initial=jnp.inf)


def _first_hit_cylinders(o, d, cylinders):
    """Closed vertical cylinders (side + caps) -> (N,) nearest hit or inf.

    The side hit uses the closest-approach form (no b^2 - 4ac cancellation):
    t = t_c -+ sqrt((r^2 - m^2) / a) with m the horizontal miss distance.
    """
    cx, cy, r, z0, z1 = (cylinders[:, i] for i in range(5))
    ox = o[:, 0:1] - cx                           # (M, P)
    oy = o[:, 1:2] - cy
    oz = o[:, 2:3]
    dx, dy, dz = d[:, 0:1], d[:, 1:2], d[:, 2:3]  # (N, 1)
    a = dx * dx + dy * dy
    ok_a, inv_a = _safe_inverse(a)
    t_c = -(ox * dx + oy * dy) * inv_a            # (N, P)
    mx = ox + t_c * dx
    my = oy + t_c * dy
    h2 = (r * r - (mx * mx + my * my)) * inv_a
    ok_side = ok_a & (h2 >= 0)
    half_chord = jnp.sqrt(jnp.where(ok_side, h2, 0.0))
    t_in = t_c - half_chord
    t_side = jnp.where(t_in > _T_MIN, t_in, t_c + half_chord)
    z_side = oz + t_side * dz
    best = jnp.where(ok_side & (t_side > _T_MIN) & (z_side >= z0) & (z_side <= z1), t_side, jnp.inf)
    ok_z, inv_dz = _safe_inverse(dz)
    for zc in (z0, z1):
        t_cap = (zc - oz) * inv_dz
        px = ox + t_cap * dx
        py = oy + t_cap * dy
        on_cap = ok_z & (t_cap > _T_MIN) & (px * px + py * py <= r * r)
        best = jnp.minimum(best, jnp.where(on_cap, t_cap, jnp.inf))
    return jnp.min(best, axis=1, initial=jnp.inf)


def _checked_rays(origins, directions, *, where: str):
    """(origins (M, 3) with M = 1 or N, directions (N, 3)) as float32, shapes checked."""
    d = jnp.asarray(directions, jnp.float32)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"{where}: field 'directions' expected shape (N, 3), got {d.shape}")
    o = jnp.asarray(origins, jnp.float32)
    if o.shape not in ((3,), d.shape):
        raise ValueError(f"{where}: field 'origins' expected shape (3,) or {d.shape}, got {o.shape}")
    return o.reshape(-1, 3), d


def cast_rays(origins: jax.Array, directions: jax.Array, scene: SceneArrays) -> jax.Array:
    """First-hit ray parameter against every primitive of a scene (pure JAX, jittable).

    The primitives are visited by ``lax.scan`` (one vectorised pass over the rays
    per primitive), which keeps the working set at O(N) and compiles one body per
    primitive kind.

    Args:
      origins: (N, 3) or (3,) float32 ray origins, metres (a (3,) origin is
        shared by all rays).
      directions: (N, 3) float32 ray directions; need not be unit length.
      scene: :class:`SceneArrays`.

    Returns:
      (N,) float32 ``t`` of the nearest surface ``origin + t * direction`` with
      ``t > 1e-6``; ``inf`` when the ray hits nothing. ``t`` is in metres only for
      unit directions. A ray starting inside a solid returns its exit point.
    """
    o, d = _checked_rays(origins, directions, where="cast_rays")
    return nearest_hits(o, d, scene, labelled=False)[0]


def nearest_hits(o: jax.Array, d: jax.Array, scene: SceneArrays, *, labelled: bool):
    """(t, label) of :func:`cast_rays` for checked rays (``o`` (1, 3) or (N, 3), ``d`` (N, 3)).

    ``label`` (N,) int32 is the hit primitive's index in the concatenation
    planes, boxes, cylinders (the first one in that order on an exact tie), -1
    where nothing is hit; None unless ``labelled`` (static).
    """
    t = jnp.full(d.shape[:1], jnp.inf, jnp.float32)
    label = jnp.full(d.shape[:1], -1, jnp.int32) if labelled else None
    start = 0
    for first_hit, prims in zip((_first_hit_planes, _first_hit_boxes, _first_hit_cylinders), scene):
        prims = jnp.asarray(prims, jnp.float32)
        if prims.shape[0] == 0:
            continue

        def body(carry, item, first_hit=first_hit):
            t_best, label_best = carry
            prim, index = item
            t_prim = first_hit(o, d, prim[None])
            if label_best is not None:
                label_best = jnp.where(t_prim < t_best, index, label_best)
            return (jnp.minimum(t_best, t_prim), label_best), None

        indices = start + jnp.arange(prims.shape[0], dtype=jnp.int32) if labelled else None
        (t, label), _ = jax.lax.scan(body, (t, label), (prims, indices))
        start += prims.shape[0]
    return t, label


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


def camera_rays(camera: Camera):
    """Rays through every pixel centre of a camera, in the LiDAR frame.

    Args:
      camera: :class:`Camera` (K, T_cam_lidar traced; height, width static).

    Returns:
      (origin, directions): origin (3,) float32, the optical centre in the
      LiDAR frame; directions (H * W, 3) float32 row major (v, u), scaled so the
      camera-frame z component is 1 (a hit's ray parameter is its depth z).
    """
    K = jnp.asarray(camera.K, jnp.float32)
    T = jnp.asarray(camera.T_cam_lidar, jnp.float32)
    v, u = geometry.pixel_grid(camera.height, camera.width)
    x, y = geometry.pixel_rays(K, v, u)
    d_cam = jnp.stack([x, y, jnp.ones_like(x)], axis=-1).reshape(-1, 3)
    R, t = T[:3, :3], T[:3, 3]
    return -(R.T @ t), d_cam @ R


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
    yaw = math.radians(yaw_deg)
    R_yaw = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    R = _R_CAM_FORWARD @ R_yaw.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.asarray(centre_lidar, np.float64)
    return Camera(K=jnp.asarray(K, jnp.float32), T_cam_lidar=jnp.asarray(T, jnp.float32),
                  height=int(height), width=int(width))


def _scaled_K(fx, fy, cx, cy, scale):
    # Pixel i covers [i - 0.5, i + 0.5]: x' + 0.5 = s (x + 0.5).
    return np.array([[fx * scale, 0.0, scale * cx + 0.5 * (scale - 1.0)],
                     [0.0, fy * scale, scale * cy + 0.5 * (scale - 1.0)],
                     [0.0, 0.0, 1.0]])


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


def _box(x, y, z_bottom, length, width, height, yaw):
    return [x, y, z_bottom + 0.5 * height, 0.5 * length, 0.5 * width, 0.5 * height, yaw]


def street_scene_arrays(seed: int = 0, *, lidar_height_m: float = 1.73) -> SceneArrays:
    """The primitives of the procedural street (host side, NumPy).

    The street runs along x. Per seed: a row of 6 buildings on each side
    (fronts 8-11 m from the centre line, 6-20 m tall) with gaps, one building on
    each side turned by 30-45 degrees of yaw, a building closing the street
    85-100 m ahead; 12 parked cars (8 ahead between 3 and 60 m, 4 behind) and 3
    cars in the lanes, each a body and a cabin box; 11 thin poles (radius 6-15 cm,
    3-7 m tall) along the kerbs; 2 cyclists (a thin bike box, a torso box and a
    head cylinder). The counts are fixed, so every seed has the same array
    shapes (49 boxes, 13 cylinders, 1 plane) and shares one compilation.

    Args:
      seed: seed of ``numpy.random.default_rng``.
      lidar_height_m: height of the LiDAR above the ground plane.

    Returns:
      :class:`SceneArrays`.
    """
    rng = np.random.default_rng(seed)
    g = -float(lidar_height_m)
    boxes, cylinders = [], []
    # Building rows along both sides, -50 m to about +90 m.
    for side in (1.0, -1.0):
        front = rng.uniform(8.0, 11.0)
        x = -50.0
        for _ in range(6):
            length, depth = rng.uniform(12.0, 24.0), rng.uniform(8.0, 14.0)
            y_front = front + rng.uniform(-0.5, 1.5)
            boxes.append(_box(x + 0.5 * length, side * (y_front + 0.5 * depth), g, length, depth,
                              rng.uniform(6.0, 20.0), 0.0))
            x += length + rng.uniform(1.0, 5.0)
        # An angled building: its nearest corner about 1.5 m in front of the row.
        yaw = math.radians(rng.uniform(30.0, 45.0))
        length, depth = 14.0, 8.0
        reach = 0.5 * length * math.sin(yaw) + 0.5 * depth * math.cos(yaw)
        boxes.append(_box(rng.uniform(18.0, 40.0), side * (front - 1.5 + reach), g, length, depth,
                          rng.uniform(8.0, 16.0), side * yaw))
    # A building across the end of the street.
    boxes.append(_box(rng.uniform(85.0, 100.0) + 5.0, rng.uniform(-5.0, 5.0), g, 10.0, 70.0,
                      rng.uniform(10.0, 25.0), math.radians(rng.uniform(-10.0, 10.0))))

    def car(x, y, yaw):
        length, width = rng.uniform(3.9, 4.7), rng.uniform(1.7, 1.9)
        body_h, cabin_h = rng.uniform(0.9, 1.1), rng.uniform(0.45, 0.6)
        boxes.append(_box(x, y, g, length, width, body_h, yaw))
        back = -0.15 * length
        boxes.append(_box(x + back * math.cos(yaw), y + back * math.sin(yaw), g + body_h,
                          0.55 * length, width - 0.15, cabin_h, yaw))

    # Parked cars: 8 ahead (one per 7.1 m bin between 3 and 60 m), 4 behind.
    for lo, hi in zip(np.linspace(3.0, 60.0, 9)[:-1], np.linspace(3.0, 60.0, 9)[1:]):
        side = rng.choice([1.0, -1.0])
        car(rng.uniform(lo + 2.4, hi - 2.4), side * rng.uniform(3.8, 4.6), math.radians(rng.uniform(-5, 5)))
    for lo, hi in zip(np.linspace(-44.0, -4.0, 5)[:-1], np.linspace(-44.0, -4.0, 5)[1:]):
        side = rng.choice([1.0, -1.0])
        car(rng.uniform(lo + 2.4, hi - 2.4), side * rng.uniform(3.8, 4.6), math.radians(rng.uniform(-5, 5)))
    # Cars in the lanes: ahead-left, oncoming ahead-right, behind.
    car(rng.uniform(12.0, 30.0), rng.uniform(1.2, 2.0), math.radians(rng.uniform(-3, 3)))
    car(rng.uniform(32.0, 55.0), -rng.uniform(1.2, 2.0), math.pi + math.radians(rng.uniform(-3, 3)))
    car(-rng.uniform(9.0, 25.0), rng.uniform(-0.5, 0.5), math.radians(rng.uniform(-3, 3)))

    # Poles along the kerbs: 8 ahead, 3 behind.
    for lo, hi in list(zip(np.linspace(3.0, 60.0, 9)[:-1], np.linspace(3.0, 60.0, 9)[1:])) + \
            list(zip(np.linspace(-40.0, -3.0, 4)[:-1], np.linspace(-40.0, -3.0, 4)[1:])):
        side = rng.choice([1.0, -1.0])
        cylinders.append([rng.uniform(lo, hi), side * rng.uniform(5.5, 6.2), rng.uniform(0.06, 0.15),
                          g, g + rng.uniform(3.0, 7.0)])

    # Cyclists: one in the right bike lane ahead, one further away on the left.
    for x, y in ((rng.uniform(6.0, 20.0), -rng.uniform(2.2, 3.0)), (rng.uniform(20.0, 40.0), rng.uniform(2.2, 3.0))):
        yaw = math.radians(rng.uniform(-10.0, 10.0))
        boxes.append(_box(x, y, g, 1.75, 0.12, 1.0, yaw))
        back = -0.15
        tx, ty = x + back * math.cos(yaw), y + back * math.sin(yaw)
        boxes.append(_box(tx, ty, g + 1.0, 0.45, 0.4, 0.65, yaw))
        cylinders.append([tx, ty, 0.11, g + 1.65, g + 1.9])

    planes = [[0.0, 0.0, 1.0, g]]
    return scene_arrays(planes=planes, boxes=boxes, cylinders=cylinders)


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
