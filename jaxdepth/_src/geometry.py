"""Camera geometry: rigid transforms, pinhole projection with a z-buffer, back-projection.

Conventions: ``p_cam = T_cam_lidar @ p_lidar``; the camera looks along +z with x
right and y down; ``u`` is the column and ``v`` the row; a point projects to the
pixel ``(round(fx x/z + s y/z + cx), round(fy y/z + cy))`` (pixel centres sit on
integer coordinates, as in KITTI's ``velodyne_raw``).

The projection (:func:`camera_points`, :func:`project_pixels`, hence :func:`project_to_image`)
computes every product of two float32 numbers from their 12-bit halves (:func:`fixed_dot`), so
each product is exact and a fused multiply-add gives the same float32 as a multiply then an add.
XLA:CPU contracts ``a * b + c`` into an FMA at its default optimisation level (not at level 0),
and whether it does depends on how the program is fused, which differs between a vmapped and an
unbatched call (a (C, N, 3) x (C, 3, 3) batched product is not the (N, 3) x (3, 3) one either).
With exact products the float32 result no longer depends on that: the pixel and depth of a point
are the same bits in a rig's camera, in its single-camera call, at any optimisation level and in
the NumPy oracle (``tests/test_projection_rounding.py``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import lax

from jaxdepth._src.xla_tuning import scatter_onto_fill, small_matmul

#: int32 mask that clears the low 12 of a float32's 23 stored significand bits.
_HIGH_HALF = -4096   # 0xFFFFF000


def scatter_argmin(slot: jax.Array, key: jax.Array, size: int, *, fill, full: bool = False):
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
      the order in which duplicates are applied. ``full``: both (size + 1,), the dump
      slot's last (its key ``fill`` when no entry went there; a caller that slices
      inside its own stage saves the slices' kernels).
    """
    n = slot.shape[0]
    best = jnp.full((size + 1,), fill, key.dtype).at[slot].min(key, mode="promise_in_bounds")
    win = key == best.at[slot].get(mode="promise_in_bounds")
    ids = jnp.arange(n, dtype=jnp.int32)
    idx = jnp.full((size + 1,), n, jnp.int32).at[jnp.where(win, slot, size)].min(ids, mode="promise_in_bounds")
    return (best, idx) if full else (best[:size], idx[:size])


def scatter_winners(slot: jax.Array, key: jax.Array, size: int) -> jax.Array:
    """Each entry's slot where it wins :func:`scatter_argmin` (smallest key, then smallest index), else ``size``.

    Args: ``slot`` (N,) int32 in ``[0, size]`` (``size``: the dump slot, no winner there); ``key`` (N,)
    float32, > 0 (or ``inf``) wherever ``slot < size``.

    One int32 canvas of ``size + 1`` where :func:`scatter_argmin` fills two: the minima of the keys' bits
    (a float32 > 0 orders as its bits do), and then, in place, the minimum of ``index + INT32_MIN`` over
    the entries that hold a slot's minimum. That tag is negative, below the bits of any key, so it
    replaces the key at every slot with a winner, and an entry won its slot when the slot holds its own
    tag: the same winners.
    """
    n = slot.shape[0]
    bits = lax.bitcast_convert_type(jnp.asarray(key, jnp.float32), jnp.int32)
    best = jnp.full((size + 1,), lax.bitcast_convert_type(jnp.float32(jnp.inf), jnp.int32), jnp.int32)
    best = best.at[slot].min(bits, mode="promise_in_bounds")
    win = bits == best.at[slot].get(mode="promise_in_bounds")
    tag = jnp.arange(n, dtype=jnp.int32) + jnp.int32(jnp.iinfo(jnp.int32).min)
    owner = best.at[jnp.where(win, slot, size)].min(tag, mode="promise_in_bounds")
    won = owner.at[slot].get(mode="promise_in_bounds") == tag
    return jnp.where(won & (slot < size), slot, size)


def split_halves(x: jax.Array):
    """``x = hi + lo`` exactly, each part with at most 12 significant bits (float32).

    ``hi`` is ``x`` with the low 12 stored significand bits cleared (an integer mask, so no
    float rounding and no FMA is involved), ``lo = x - hi`` is exact. The product of two such
    parts has at most 24 significant bits: exact in float32 (Dekker's product; barring
    under- or overflow, far outside metres and pixels).
    """
    x = jnp.asarray(x, jnp.float32)
    hi = lax.bitcast_convert_type(lax.bitcast_convert_type(x, jnp.int32) & jnp.int32(_HIGH_HALF), jnp.float32)
    return hi, x - hi


def fixed_dot(weights, values, offset=None) -> jax.Array:
    """``offset + sum_k weights[k] * values[k]`` in float32 with every product exact.

    Each product is formed from the 12-bit halves of its factors (:func:`split_halves`): four
    exact products, summed in a fixed order (the high x high terms and ``offset``, then the
    cross terms, then the low x low terms). Whether the compiler fuses a multiply and an add
    into an FMA cannot change the result, so the same inputs give the same bits in every
    program (vmapped or not, any fusion, any XLA optimisation level). About as accurate as a
    plain float32 dot (a few ulps).

    Args:
      weights: sequence of K float32 scalars or arrays; values: sequence of K float32 arrays;
        all broadcastable. offset: optional float32 scalar or array.

    Returns:
      float32 array of the broadcast shape.
    """
    high, cross, low = [], [], []
    for w, x in zip(weights, values, strict=True):
        wh, wl = split_halves(w)
        xh, xl = split_halves(x)
        high.append(wh * xh)
        cross.append(wh * xl + wl * xh)
        low.append(wl * xl)
    total = functools.reduce(jnp.add, high)
    if offset is not None:
        total = total + jnp.asarray(offset, jnp.float32)
    return total + (functools.reduce(jnp.add, cross) + functools.reduce(jnp.add, low))


def camera_points(T: jax.Array, points: jax.Array, *, translate: bool = True) -> jax.Array:
    """``R p + t`` of (N, 3) points by a (4, 4) rigid transform with :func:`fixed_dot` (exact products).

    The projection's transform: the same bits under ``vmap`` as unbatched. ``translate=False``
    rotates only (normals). Returns (N, 3) float32.
    """
    T = jnp.asarray(T, jnp.float32)
    points = jnp.asarray(points, jnp.float32)
    cols = (points[:, 0], points[:, 1], points[:, 2])
    rows = [fixed_dot((T[i, 0], T[i, 1], T[i, 2]), cols, T[i, 3] if translate else None) for i in range(3)]
    return jnp.stack(rows, axis=-1)


def transform_points(T: jax.Array, points: jax.Array) -> jax.Array:
    """Applies a (4, 4) rigid transform to (N, 3) points; returns (N, 3).

    A plain float32 product (its rounding may differ between a vmapped and an unbatched call);
    the projection uses :func:`camera_points`. The product as ``xla_tuning.small_matmul`` (the dot's bits,
    without XLA:CPU's slow small-K dot).
    """
    T = jnp.asarray(T, jnp.float32)
    return small_matmul(points, T[:3, :3].T) + T[:3, 3]


def invert_rigid(T: jax.Array) -> jax.Array:
    """Inverse of a (4, 4) rigid transform [R | t] as [R^T | -R^T t]."""
    T = jnp.asarray(T, jnp.float32)
    R = T[:3, :3]
    t = T[:3, 3]
    top = jnp.concatenate([R.T, (-R.T @ t)[:, None]], axis=1)
    return jnp.concatenate([top, jnp.array([[0.0, 0.0, 0.0, 1.0]], jnp.float32)], axis=0)


def project_pixels(points_cam: jax.Array, K: jax.Array, *, min_depth_m: float = 0.1):
    """Pinhole projection of (N, 3) camera-frame points.

    ``u = fx x/z + s y/z + cx`` and ``v = fy y/z + cy`` with :func:`fixed_dot` (exact products, the
    same bits in every program).

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
    u = fixed_dot((K[0, 0], K[0, 1]), (xs, ys), K[0, 2])
    v = fixed_dot((K[1, 1],), (ys,), K[1, 2])
    return u, v, jnp.where(in_front, z, 0.0), in_front


def zbuffer_image(points_cam: jax.Array, valid: jax.Array, K: jax.Array, *, height: int, width: int,
                  min_depth_m: float = 0.1, valid_size: jax.Array | None = None):
    """The nearest-point z-buffer of (N, 3) camera-frame points: :func:`project_to_image` after the transform.

    Args and returns as :func:`project_to_image`, with ``points_cam`` already in the camera frame
    (:func:`camera_points`), so a caller that also needs each pixel's point gathers it from the
    same float32 values the z-buffer used.
    """
    u, v, z, ok = project_pixels(points_cam, K, min_depth_m=min_depth_m)
    return pixel_zbuffer(u, v, z, ok & valid.astype(bool), height=height, width=width, valid_size=valid_size)


def zbuffer_winners(points_cam: jax.Array, valid: jax.Array, K: jax.Array, *, height: int, width: int,
                    min_depth_m: float = 0.1, valid_size: jax.Array | None = None, group_size: jax.Array | None = None):
    """:func:`zbuffer_image` per point: the pixel each point wins, for writing values onto the image.

    Args as :func:`zbuffer_image`. Returns ``(slot, z)``: (N,) int32 flat pixel ``v W + u`` of the
    pixel the point won in :func:`zbuffer_image` (the same winners: nearest, then smallest index),
    ``H W`` (past the image) for points that won none; (N,) float32 depth of each point
    (:func:`project_pixels`). :func:`winners_image` of ``z`` (fill 0) is ``zbuffer_image``'s depth
    and of ``arange(N)`` (fill -1) its index, bit for bit; of any per-point value it is that value
    gathered at the index, without a pass that reads the (H, W) index (a rig camera's image has
    ~20x more pixels than points).
    ``group_size``: optional traced (2,) int32 (h, w), the image's own size, its pixels the first h w of
    the H W flat slots (row stride w): slots ``v w + u`` (``H W`` for none), the bounds h and w, the same
    winners as ``height=h, width=w`` (cameras of several sizes in one ``vmap``; ``H W`` >= h w).
    The winners come from :func:`scatter_winners` (one (H W + 1,) canvas, not :func:`scatter_argmin`'s two).
    """
    if not min_depth_m >= 0:    # scatter_winners: every key of a real slot > 0
        raise ValueError(f"zbuffer_winners: field 'min_depth_m' expected >= 0, got {min_depth_m!r}")
    u, v, z, ok = project_pixels(points_cam, K, min_depth_m=min_depth_m)
    inside = ok & valid.astype(bool)
    flat, inside = _pixel_slots(u, v, inside, height=height, width=width, valid_size=valid_size, group_size=group_size)
    return scatter_winners(flat, jnp.where(inside, z, jnp.inf), height * width), z


def winners_image(slot: jax.Array, values: jax.Array, fill, *, height: int, width: int) -> jax.Array:
    """(H, W) image of per-point ``values`` (N,) written at the pixels they won (``slot`` from
    :func:`zbuffer_winners`; slots past the image dropped), ``fill`` (of ``values``' dtype) elsewhere."""
    return scatter_onto_fill(height * width, fill, slot, values).reshape(height, width)


def _pixel_slots(u, v, ok, *, height: int, width: int, valid_size=None, group_size=None):
    """``(flat, inside)``: each point's flat (N,) slot (``H W`` = no pixel) and whether it has one
    (``group_size``: as :func:`zbuffer_winners`)."""
    ui = jnp.round(u)
    vi = jnp.round(v)
    h, w = (height, width) if group_size is None else (group_size[0], group_size[1])
    inside = ok & (ui >= 0) & (ui <= w - 1) & (vi >= 0) & (vi <= h - 1)
    if valid_size is not None:
        valid_size = jnp.asarray(valid_size)
        inside = inside & (vi <= valid_size[0] - 1) & (ui <= valid_size[1] - 1)
    dump = height * width
    return jnp.where(inside, vi.astype(jnp.int32) * w + ui.astype(jnp.int32), dump), inside


def _pixel_argmin(u, v, z, ok, *, height: int, width: int, valid_size=None, group_size=None):
    """:func:`pixel_zbuffer`'s flat (N,) slots (``H W`` = no pixel) and flat (H W,) :func:`scatter_argmin`
    (``group_size``: as :func:`zbuffer_winners`)."""
    flat, inside = _pixel_slots(u, v, ok, height=height, width=width, valid_size=valid_size, group_size=group_size)
    zbuf, idx = scatter_argmin(flat, jnp.where(inside, z, jnp.inf), height * width, fill=jnp.inf)
    return flat, zbuf, idx


def pixel_zbuffer(u: jax.Array, v: jax.Array, z: jax.Array, ok: jax.Array, *, height: int, width: int,
                  valid_size: jax.Array | None = None):
    """(H, W) depth and index images of (N,) points at pixel coordinates ``u``, ``v`` (rounded half to
    even) with depth ``z``, where ``ok``; the nearest wins, then the smallest index (:func:`scatter_argmin`).
    ``valid_size``: as :func:`project_to_image`. Returns ``(depth, index)`` as :func:`project_to_image`."""
    n = u.shape[0]
    _, zbuf, idx = _pixel_argmin(u, v, z, ok, height=height, width=width, valid_size=valid_size)
    depth = jnp.where(jnp.isfinite(zbuf), zbuf, 0.0).reshape(height, width)
    index = jnp.where(idx == n, -1, idx).reshape(height, width)
    return depth, index


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
      independent of the order in which duplicates are applied. The transform and
      the pixel coordinates use exact products (:func:`fixed_dot`): a camera's
      result is the same bits under ``vmap`` (a rig) as in its own call.
    """
    p = camera_points(T_cam_lidar, points.astype(jnp.float32))
    return zbuffer_image(p, valid, K, height=height, width=width, min_depth_m=min_depth_m, valid_size=valid_size)


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
