"""Camera geometry: rigid transforms, pinhole projection with a z-buffer, back-projection.

Conventions: ``p_cam = T_cam_lidar @ p_lidar``; the camera looks along +z with x
right and y down; ``u`` is the column and ``v`` the row; a point projects to the
pixel ``(round(fx x/z + s y/z + cx), round(fy y/z + cy))`` (pixel centres sit on
integer coordinates, as in KITTI's ``velodyne_raw``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp


def scatter_argmin(slot: jax.Array, key: jax.Array, size: int, *, fill):
    """Per-slot minimum of ``key`` and the smallest index that attains it (a z-buffer).

    Args:
      slot: (N,) int32 slot of every entry in ``[0, size]``; ``size`` is a dump
        slot for entries that take no part (it is not returned). Slots are
        promised in bounds (no check).
      key: (N,) keys ordered by ``<`` (float32 depths, or int32 bit patterns of
        non-negative float32 ranges); entries in the dump slot may hold anything.
      size: static number of real slots.
      fill: the key of an empty slot (``inf``, or ``INT32_MAX`` for int32 keys).

    Returns:
      ``(best, index)``: (size,) smallest key per slot (``fill`` where empty) and
      (size,) int32 index of the entry that won the slot: the smallest index among
      equal keys, ``N`` where empty. Scatter-min makes the result independent of
      the order in which duplicates are applied.
    """
    n = slot.shape[0]
    best = jnp.full((size + 1,), fill, key.dtype).at[slot].min(key, mode="promise_in_bounds")
    win = key == best.at[slot].get(mode="promise_in_bounds")
    ids = jnp.arange(n, dtype=jnp.int32)
    idx = jnp.full((size + 1,), n, jnp.int32).at[jnp.where(win, slot, size)].min(ids, mode="promise_in_bounds")
    return best[:size], idx[:size]


def transform_points(T: jax.Array, points: jax.Array) -> jax.Array:
    """Applies a (4, 4) rigid transform to (N, 3) points; returns (N, 3)."""
    T = jnp.asarray(T, jnp.float32)
    return points @ T[:3, :3].T + T[:3, 3]


def invert_rigid(T: jax.Array) -> jax.Array:
    """Inverse of a (4, 4) rigid transform [R | t] as [R^T | -R^T t]."""
    T = jnp.asarray(T, jnp.float32)
    R = T[:3, :3]
    t = T[:3, 3]
    top = jnp.concatenate([R.T, (-R.T @ t)[:, None]], axis=1)
    return jnp.concatenate([top, jnp.array([[0.0, 0.0, 0.0, 1.0]], jnp.float32)], axis=0)


def project_pixels(points_cam: jax.Array, K: jax.Array, *, min_depth_m: float = 0.1):
    """Pinhole projection of (N, 3) camera-frame points.

    Returns:
      (u, v, z, in_front): u, v float32 pixel coordinates (not rounded), z float32
      metres, and a bool mask of points with finite coordinates and z > min_depth_m.
    """
    K = jnp.asarray(K, jnp.float32)
    x, y, z = points_cam[:, 0], points_cam[:, 1], points_cam[:, 2]
    in_front = jnp.isfinite(x) & jnp.isfinite(y) & jnp.isfinite(z) & (z > min_depth_m)
    safe_z = jnp.where(in_front, z, 1.0)
    xs = jnp.where(in_front, x, 0.0) / safe_z
    ys = jnp.where(in_front, y, 0.0) / safe_z
    u = K[0, 0] * xs + K[0, 1] * ys + K[0, 2]
    v = K[1, 1] * ys + K[1, 2]
    return u, v, jnp.where(in_front, z, 0.0), in_front


@functools.partial(jax.jit, static_argnames=("height", "width", "min_depth_m"))
def project_to_image(points: jax.Array, valid: jax.Array, K: jax.Array, T_cam_lidar: jax.Array,
                     *, height: int, width: int, min_depth_m: float = 0.1,
                     valid_size: jax.Array | None = None):
    """Projects a LiDAR sweep into one camera with a nearest-point z-buffer.

    Args:
      points: (N, 3) float32 LiDAR-frame points, metres.
      valid: (N,) bool; invalid (padding) points and non-finite points are ignored.
      K: (3, 3) intrinsics. T_cam_lidar: (4, 4) LiDAR -> camera.
      height, width: static image size.
      min_depth_m: points closer than this (or behind the camera) are dropped.
      valid_size: optional traced (2,) int32 (height, width) of the real image when
        it is padded to a larger (height, width) canvas (multi-camera rigs);
        points outside it are dropped.

    Returns:
      (depth, index): depth (H, W) float32 metres with 0 = empty; index (H, W)
      int32, the point that won each pixel (smallest depth; among equal depths the
      smallest point index), -1 where empty. Scatter-min makes the result
      independent of the order in which duplicates are applied.
    """
    n = points.shape[0]
    p = transform_points(T_cam_lidar, points.astype(jnp.float32))
    u, v, z, ok = project_pixels(p, K, min_depth_m=min_depth_m)
    ok = ok & valid.astype(bool)
    ui = jnp.round(u)
    vi = jnp.round(v)
    inside = ok & (ui >= 0) & (ui <= width - 1) & (vi >= 0) & (vi <= height - 1)
    if valid_size is not None:
        valid_size = jnp.asarray(valid_size)
        inside = inside & (vi <= valid_size[0] - 1) & (ui <= valid_size[1] - 1)
    dump = height * width
    flat = jnp.where(inside, vi.astype(jnp.int32) * width + ui.astype(jnp.int32), dump)
    zbuf, idx = scatter_argmin(flat, jnp.where(inside, z, jnp.inf), dump, fill=jnp.inf)
    depth = jnp.where(jnp.isfinite(zbuf), zbuf, 0.0).reshape(height, width)
    index = jnp.where(idx == n, -1, idx).reshape(height, width)
    return depth, index


def pixel_grid(height: int, width: int):
    """(v, u) float32 pixel coordinate grids of shape (H, W)."""
    v, u = jnp.meshgrid(jnp.arange(height, dtype=jnp.float32),
                        jnp.arange(width, dtype=jnp.float32), indexing="ij")
    return v, u


def pixel_rays(K: jax.Array, v: jax.Array, u: jax.Array):
    """Normalised camera rays through pixels: ``K^-1 (u, v, 1) = (x, y, 1)``.

    Args:
      K: (3, 3) float32 intrinsics (skew ``K[0, 1]`` allowed).
      v, u: float32 pixel rows and columns (pixel centres on integers), any
        broadcastable shapes.

    Returns:
      ``(x, y)``: float32 camera-frame x / z and y / z of the rays, of the
      broadcast shape. The one back-projection of the package: every caller
      gets the same float32 operations in the same order.
    """
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return x, y


def backproject(depth: jax.Array, K: jax.Array, v: jax.Array | None = None, u: jax.Array | None = None):
    """Camera-frame points ``depth K^-1 (u, v, 1)`` as three channels.

    Args:
      depth: float32 depth z, metres, any shape; (H, W) when ``v``, ``u`` are omitted.
      K: (3, 3) float32 intrinsics.
      v, u: float32 row and column of every depth value (broadcastable to
        ``depth``); default: the pixel grid of an (H, W) ``depth``.

    Returns:
      ``(x, y, z)``: float32 metres, each of ``depth``'s shape (``z`` is ``depth``).
    """
    if v is None:
        h, w = depth.shape
        v = jnp.arange(h, dtype=jnp.float32)[:, None]
        u = jnp.arange(w, dtype=jnp.float32)[None, :]
    x, y = pixel_rays(K, v, u)
    return x * depth, y * depth, depth


def unproject_depth(depth: jax.Array, K: jax.Array) -> jax.Array:
    """Back-projects a depth image to camera-frame points.

    Args:
      depth: (H, W) float32 metres (0 = empty gives the camera centre).
      K: (3, 3) intrinsics.

    Returns:
      (H, W, 3) float32 points ``depth * K^-1 [u, v, 1]``.
    """
    K = jnp.asarray(K, jnp.float32)
    h, w = depth.shape
    v, u = pixel_grid(h, w)
    return jnp.stack(backproject(depth, K, v, u), axis=-1)
