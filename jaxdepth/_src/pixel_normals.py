"""Step 1 on image input: normals of the pixels of a sparse depth image.

This is where :func:`jaxdepth.complete` (``pipeline.complete_stages``) runs Step 1;
sweep input (``complete_points``, ``complete_rig``) runs it in
:func:`jaxdepth._src.normals.point_normals`. Both read the cell normals of
:func:`jaxdepth._src.normals.cell_normals`.

:func:`pixel_normals` takes what the KITTI benchmark gives (a sparse depth
image, ``K`` and the LiDAR-camera transform) instead of a sweep. Each pixel
with depth is back-projected through ``K``
(:func:`~jaxdepth._src.geometry.backproject`), carried into the LiDAR frame,
binned into the spherical range image (:mod:`jaxdepth._src.range_image`) and
reads its cell's normal (:mod:`jaxdepth._src.normals`); the normal is rotated
back into the camera frame. It equals ``point_normals`` of the back-projected
pixels up to float32 rounding (tests/test_normals.py).

Performance notes: gathers and scatters cost far more per element than
elementwise work on XLA:CPU, so the few % of pixels with depth are listed first
(:func:`~jaxdepth._src.compaction.compact_indices`: elementwise passes, small
triangular matrix products and a scatter over the 32-pixel words of the mask
only); back-projection, ``atan2`` binning, the scatter-mins and the gathers
then run on those points only (the back-projection and both ``atan2`` in one
stage with three complex outputs, the binning in a second). The range image is
built on a window of columns around the camera's central ray when every point
fits inside it with the margin of the neighbour search and smoothing (and keeps
that margin from the 360-degree seam, where the window's azimuths jump), which
gives the whole image's normals exactly.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxdepth._src.compaction import compact_indices
from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.fastmath import PI
from jaxdepth._src.geometry import backproject, pixel_rays, scatter_argmin
from jaxdepth._src.normals import cell_normals, check_options, normals_at_points
from jaxdepth._src.range_image import RangeImage, angles_xyz, cell_centres, check_lidar, row_col
from jaxdepth._src.xla_tuning import any_true, cond_all, stage, stage_token
from jaxdepth._src.types import LidarSpec


def _pixel_lidar_xyz(depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array, v: jax.Array, u: jax.Array):
    """LiDAR-frame (x, y, z) of back-projected pixels, three arrays of ``depth``'s shape, metres.

    ``p_cam = depth K^-1 (u, v, 1)`` (:func:`~jaxdepth._src.geometry.backproject`) and
    ``p_lidar = R^T (p_cam - t)`` (as ``transform_points(invert_rigid(T), .)``),
    written per channel so no (..., 3) array is formed. ``v``, ``u``: float32
    row and column of each depth value.
    """
    xc, yc, zc = backproject(depth, K, v, u)
    R, t = T_cam_lidar[:3, :3], T_cam_lidar[:3, 3]
    ti = -(R.T @ t)
    return tuple(R[0, i] * xc + R[1, i] * yc + R[2, i] * zc + ti[i] for i in range(3))


class _PixelPoints(NamedTuple):
    """Per listed pixel (P,) arrays from :func:`_pixel_points` (stage outputs, real buffers)."""

    thph: jax.Array  # complex64 (theta, phi), radians
    xy: jax.Array  # complex64 LiDAR-frame (x, y), metres
    zr: jax.Array  # complex64 (z, range r), metres; r = 0 for no point
    slot: jax.Array  # int32 flat window cell row * window_cols + col; L window_cols for none / outside
    key: jax.Array  # int32 range bits; INT32_MAX for no point
    edge: jax.Array | None  # bool: a point within `margin` columns of the window's edges or of the seam (or outside
    # it); None when such points were sent to the dump slot instead (``dump_edge``)


def _pixel_points(pix, depth, K, T, col0, token, *, lidar: LidarSpec, window_cols: int, margin: int,
                  dump_edge: bool = False):
    """Per listed pixel: back-projected LiDAR-frame point, range-image window cell and scatter key.

    Args:
      pix: (P,) int32 flat pixel indices into ``depth`` (``H W`` or a pixel
        without depth: no point).
      depth: (H, W) float32 camera depth; only finite positive values are depth.
      col0: int32 first range-image column of the window (0 for the whole image).
      margin: static number of columns a point must keep from the window's edges and from the
        360-degree seam when the window spans it.
      dump_edge: static; points that do not keep it go to the dump slot (``edge`` is None): the
        range image is then exact only when no point did, which the dump slot's key tells
        (:func:`window_range_image`), so the fit test needs no reduction of its own.

    Returns a :class:`_PixelPoints`. The float32 expressions are those of
    :func:`~jaxdepth._src.range_image.range_image` applied to ``unproject_depth`` + ``transform_points``.
    Two stages: the back-projection and the two ``atan2`` run in one stage
    with three complex outputs (each output is a fusion that redoes what it
    needs, so fewer outputs is less work), the cheap binning in a second.
    """
    h, w = depth.shape
    n_rows, n_cols = lidar.beams, lidar.columns
    n_win = n_rows * window_cols

    def per_point(pix, depth, K, T):
        listed = pix < h * w
        safe = jnp.where(listed, pix, 0)
        g = depth.reshape(-1).at[safe].get(mode="promise_in_bounds")
        d = jnp.where(listed & jnp.isfinite(g) & (g > 0), g, 0.0)
        v = safe // w
        u = (safe - v * w).astype(jnp.float32)
        x, y, z = _pixel_lidar_xyz(d, K, T, v=v.astype(jnp.float32), u=u)
        r, theta, phi, _ = angles_xyz(x, y, z, d > 0)
        return jax.lax.complex(theta, phi), jax.lax.complex(x, y), jax.lax.complex(z, r)

    def binning(thph, zr, col0):
        theta, phi, r = jnp.real(thph), jnp.imag(thph), jnp.imag(zr)
        ok = r > 0  # r >= MIN_RANGE_M for a point, exactly 0 otherwise
        row, col = row_col(theta, phi, lidar)
        col = col - col0
        col = jnp.where(col < 0, col + n_cols, col)
        inside = ok & (col < window_cols)
        slot = jnp.where(inside, row * window_cols + col, n_win)
        key = jnp.where(ok, jax.lax.bitcast_convert_type(r, jnp.int32), jnp.iinfo(jnp.int32).max)
        # A window that spans the 360-degree seam holds azimuths that jump by 2 pi there (the
        # whole range image unwraps them in its column padding): points near it need the whole.
        seam = n_cols - col0
        near_seam = (col >= seam - margin) & (col < seam + margin)
        edge = ok & ((col < margin) | (col >= window_cols - margin) | near_seam)
        if dump_edge:
            return jnp.where(edge, n_win, slot), key
        return slot, key, edge

    thph, xy, zr = stage(per_point, (pix, depth, K, T), token)
    binned = stage(binning, (thph, zr, col0), token)
    return _PixelPoints(thph, xy, zr, *binned, *((None,) if dump_edge else ()))


def _pixel_normals_of_points(pix, pts, col0, R, shape, token, *, lidar: LidarSpec, window_cols: int,
                             smoothing: int, fill_max_gap: int, identity: bool, with_dump: bool = False,
                             slots: bool = False):
    """Camera-frame (3, H, W) normals of the listed pixels (from :func:`_pixel_points`), zeros elsewhere.

    Every point's cell must lie in the window ``col0 .. col0 + window_cols - 1``
    (mod C) at least ``max(1 + fill_max_gap, smoothing)`` columns from its edges
    (unless the window is the whole image): then the neighbour search and the
    smoothing never reach the edges and the result equals that of the whole
    range image. ``identity``: ``pix`` is ``arange(H W)`` (the output needs no scatter). ``with_dump``:
    returns ``(normals, dump_key)`` (:func:`window_range_image`). ``slots``: the normals kept listed,
    ``(slot, table)`` of :class:`ListedNormals`, in place of the (3, H, W) image.
    """
    slot, key = pts.slot, pts.key
    ok = key != jnp.iinfo(jnp.int32).max
    n_cols = lidar.columns
    window = None if window_cols == n_cols else (col0, n_cols)
    ri, dump_key = window_range_image(pts, col0, token, lidar=lidar, window_cols=window_cols, with_dump=True)
    # Points only sit in measured cells, so the filling of empty cells is skipped.
    nxy, nz = cell_normals(ri, smoothing, fill_max_gap, window, token)
    xyz = (jnp.real(pts.xy), jnp.imag(pts.xy), jnp.real(pts.zr))
    px, py, pz, sign = normals_at_points(nxy, nz, slot, ok, xyz, token)
    n_cam = jnp.stack([(R[i, 0] * px + R[i, 1] * py + R[i, 2] * pz) * sign for i in range(3)])
    h, w = shape
    if slots:  # (H, W) int32 slot image (1.7 MB on KITTI) in place of the (3, H W) float32 fill (5 MB)
        n = n_cam.shape[1]
        slot = jnp.full((h * w,), n, jnp.int32).at[jnp.where(ok, pix, h * w)].set(
            jnp.arange(n, dtype=jnp.int32), mode="drop")
        out = (slot.reshape(h, w), jnp.concatenate([n_cam, jnp.zeros((3, 1), jnp.float32)], 1))
    elif identity:
        out = n_cam.reshape(3, h, w)
    else:
        out = jnp.zeros((3, h * w), jnp.float32).at[:, jnp.where(ok, pix, h * w)].set(n_cam, mode="drop")
        out = out.reshape(3, h, w)
    return (out, dump_key) if with_dump else out


def window_range_image(pts: _PixelPoints, col0, token, *, lidar: LidarSpec, window_cols: int,
                       with_dump: bool = False) -> RangeImage:
    """The (L, window_cols) range image of the listed points (from :func:`_pixel_points`): per cell the
    nearest point's range and angles and its index (-1 and the cell centre's angles where none; ``cell``
    empty). Nearest range wins a cell (scatter-min of the range bits), ties the smaller point index = the
    smaller pixel index (points are listed in pixel order). ``with_dump``: returns ``(image, dump_key)``,
    the smallest key of the points without a cell (``INT32_MAX`` when none is a point)."""
    n_pts = pts.slot.shape[0]
    n_rows = lidar.beams
    # Slot L window_cols collects points without a cell.
    best, idx = scatter_argmin(pts.slot, pts.key, n_rows * window_cols, fill=jnp.iinfo(jnp.int32).max, full=True)

    def per_cell(idx, thph, zr, col0):
        idx = idx[:-1]  # (the dump slot; sliced here, not in a kernel of its own)
        has = idx < n_pts
        safe = jnp.where(has, idx, 0)
        theta_c, phi_c = cell_centres(lidar)
        theta_c = jax.lax.dynamic_slice(jnp.concatenate([theta_c, theta_c[:, :window_cols]], axis=1),
                                        (0, col0), (1, window_cols))
        img_shape = (n_rows, window_cols)
        tp = thph.at[safe].get(mode="promise_in_bounds")
        r = jnp.imag(zr).at[safe].get(mode="promise_in_bounds")
        th = jnp.where(has, jnp.real(tp), jnp.broadcast_to(theta_c, img_shape).reshape(-1))
        ph = jnp.where(has, jnp.imag(tp), jnp.broadcast_to(phi_c, img_shape).reshape(-1))
        return (jnp.where(has, r, 0.0).reshape(img_shape), th.reshape(img_shape), ph.reshape(img_shape),
                jnp.where(has, idx, -1).reshape(img_shape))

    r_img, th_img, ph_img, index = stage(per_cell, (idx, pts.thph, pts.zr, col0), token)
    ri = RangeImage(r=r_img, theta=th_img, phi=ph_img, index=index, cell=jnp.zeros((0,), jnp.int32))
    return (ri, best[-1]) if with_dump else ri


def default_window_columns(lidar: LidarSpec) -> int:
    """Static width of the range-image window used for camera images: 100 degrees
    of azimuth (a multiple of 8 columns), or all columns for a coarse LiDAR."""
    cols = -(-lidar.columns * 100 // 360)
    cols = -(-cols // 8) * 8
    return min(cols, lidar.columns)


def _window_start(K, T, height: int, width: int, lidar: LidarSpec, window_cols: int):
    """Range-image column (int32) at which a window of ``window_cols`` columns centred on the image's central ray starts.

    Only speed depends on it: the listed path checks that every point fits
    inside the window and falls back to the whole range image otherwise.
    """
    x, y = pixel_rays(K, jnp.float32((height - 1) / 2), jnp.float32((width - 1) / 2))
    # R^T (x, y, 1) written out (scalars in one kernel; a dot and a stack were kernels of their own)
    theta = jnp.arctan2(T[0, 1] * x + T[1, 1] * y + T[2, 1], T[0, 0] * x + T[1, 0] * y + T[2, 0])
    n_cols = lidar.columns
    centre = jnp.floor((PI - theta) * (n_cols / (2 * PI))).astype(jnp.int32)
    return jnp.mod(centre - window_cols // 2, n_cols).astype(jnp.int32)


class ListedNormals(NamedTuple):
    """Step 1's normals kept listed (the frame's tail, :func:`pixel_normals_slots`): pixel ``p``'s normal is
    ``table[:, slot[p]]`` where ``fits``; ``dense(*inputs)`` gives :func:`pixel_normals`' (3, H, W) otherwise."""
    slot: jax.Array  # (H, W) int32: the pixel's column of table; the last column (zeros) where it has no normal
    table: jax.Array  # (3, capacity + 1) float32 camera-frame normals of the listed pixels, then a zero column
    fits: jax.Array  # () bool: the listed path holds (pixel_normals' fallback choice)
    inputs: tuple  # (depth, K, T) of the fallback
    dense: object  # the fallback: (depth, K, T) -> (3, H, W), :func:`dense_pixel_normals` with its options


def dense_pixel_normals(depth, K, T, *, lidar: LidarSpec, smoothing: int, fill_max_gap: int):
    """:func:`pixel_normals`' dense path: every pixel is a point slot and the whole range image is used
    (as fast as the listed path only when most pixels have depth)."""
    h, w = depth.shape
    token = stage_token(depth)  # (a branch may not close over tracers)
    pix = jnp.arange(h * w, dtype=jnp.int32)
    options = dict(lidar=lidar, smoothing=smoothing, fill_max_gap=fill_max_gap)
    pts = _pixel_points(pix, depth, K, T, jnp.int32(0), token, lidar=lidar, window_cols=lidar.columns, margin=0)
    return _pixel_normals_of_points(pix, pts, jnp.int32(0), T[:3, :3], (h, w), token, window_cols=lidar.columns,
                                    identity=True, **options)


@functools.partial(jax.jit, static_argnames=("lidar", "smoothing", "fill_max_gap", "window_columns", "max_points"))
def pixel_normals(sparse_depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array, *, lidar: LidarSpec,
                  smoothing: int = DEFAULT_CONFIG.normal_smoothing,
                  fill_max_gap: int = DEFAULT_CONFIG.range_fill_max_gap, window_columns: int | None = None,
                  max_points: int | None = None) -> jax.Array:
    """Camera-frame unit normal of every pixel of a sparse depth image (Step 1 on image input).

    Each pixel with depth is back-projected through ``K`` (pixel centre) and
    carried into the LiDAR frame with ``T_cam_lidar``; these points are binned
    into the spherical range image and read their cell's normal, exactly as

        R @ point_normals(transform_points(invert_rigid(T), unproject_depth(d, K).reshape(-1, 3)),
                          (d > 0).reshape(-1), ...).T

    reshaped to (3, H, W) (``R = T_cam_lidar[:3, :3]``), up to float32 rounding.

    Fast path (a LiDAR image has depth at a few % of its pixels): the pixels
    with depth are listed first in pixel order (:func:`~jaxdepth._src.compaction.compact_indices`, no
    per-pixel scatter or gather), and only those points are back-projected,
    binned (scatter-min; ties go to the smaller pixel index as in the
    composition), given their cell's normal and scattered into the output.
    The normals are computed on a window of ``window_columns`` range-image
    columns around the camera's central ray when every point lies inside it
    (with the margin of the neighbour search and smoothing), which gives the
    whole image's normals exactly. Otherwise (more than ``max_points`` pixels
    with depth, points outside the window, or points near the 360-degree seam
    inside it: a camera facing backwards) a dense path takes every pixel as a
    point slot and uses the whole range image: same result, slower.

    Args:
      sparse_depth: (H, W) float camera depth z, metres; 0 (or any value that
        is not a finite positive number) marks an empty pixel.
      K: (3, 3) float32 intrinsics of that image.
      T_cam_lidar: (4, 4) float32 LiDAR -> camera transform.
      lidar: static :class:`~jaxdepth.LidarSpec` of the range image.
      smoothing, fill_max_gap: static, see :func:`range_image_normals`.
      window_columns: static width of the range-image window (default
        :func:`default_window_columns`: 100 degrees of azimuth).
      max_points: static capacity of the listed path (default ``ceil(H W / 16)``,
        6.25 % of the pixels); frames with more pixels with depth take the
        dense path. Only speed depends on it.

    Returns:
      (3, H, W) float32 camera-frame normals (x, y, z): unit length and facing
      the LiDAR (``n . (p_cam - t) <= 0``) at pixels with depth, zeros elsewhere.
    """
    return _pixel_normals(sparse_depth, K, T_cam_lidar, lidar=lidar, smoothing=smoothing, fill_max_gap=fill_max_gap,
                          window_columns=window_columns, max_points=max_points, listed_only=False)


@functools.partial(jax.jit, static_argnames=("lidar", "smoothing", "fill_max_gap"))
def pixel_normals_listed(sparse_depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array, *, lidar: LidarSpec,
                         smoothing: int, fill_max_gap: int) -> tuple[jax.Array, jax.Array]:
    """(3, H, W) normals of :func:`pixel_normals`' fast path alone, and ``fits``: a () bool, True when
    the frame fits that path (the value its dense-fallback choice reads), when the normals equal
    :func:`pixel_normals`'; otherwise they are not meaningful. Private to the CLI's KITTI jobs
    (:mod:`jaxdepth.batch.listed`): a program without the dense fallback compiles ~2.3 s faster."""
    return _pixel_normals(sparse_depth, K, T_cam_lidar, lidar=lidar, smoothing=smoothing, fill_max_gap=fill_max_gap,
                          window_columns=None, max_points=None, listed_only=True)


def pixel_normals_slots(sparse_depth, K, T_cam_lidar, *, lidar: LidarSpec, smoothing: int,
                        fill_max_gap: int) -> ListedNormals:
    """:func:`pixel_normals` kept listed (traced inside the frame's program, :func:`~jaxdepth._src.pipeline.complete`):
    the listed path's normals as a :class:`ListedNormals` slot image and table, ``fits`` its fallback choice.
    Equal values: ``table[:, slot]`` is :func:`pixel_normals`' output where ``fits`` (docs/speed.md, kitti13).
    Its ops carry the name ``pixel_normals_slots`` (metadata only: ``bench_frame_profile``'s Step 1)."""
    with jax.named_scope("pixel_normals_slots"):
        return _pixel_normals(sparse_depth, K, T_cam_lidar, lidar=lidar, smoothing=smoothing,
                              fill_max_gap=fill_max_gap, window_columns=None, max_points=None, listed_only="slots")


def _pixel_normals(sparse_depth, K, T_cam_lidar, *, lidar, smoothing, fill_max_gap, window_columns, max_points,
                   listed_only):  # False, True (pixel_normals_listed) or "slots" (pixel_normals_slots)
    check_lidar(lidar)
    check_options(smoothing, fill_max_gap)
    sparse_depth = jnp.asarray(sparse_depth)
    if sparse_depth.ndim != 2:
        raise ValueError(f"pixel_normals: field 'sparse_depth' expected shape (H, W), got {sparse_depth.shape}")
    K = jnp.asarray(K, jnp.float32)
    if K.shape != (3, 3):
        raise ValueError(f"pixel_normals: field 'K' expected shape (3, 3), got {K.shape}")
    T = jnp.asarray(T_cam_lidar, jnp.float32)
    if T.shape != (4, 4):
        raise ValueError(f"pixel_normals: field 'T_cam_lidar' expected shape (4, 4), got {T.shape}")
    # Not sanitised here (a pass over every pixel): the mask below tests
    # finite and positive, and the listed points read their depth through
    # the same test.
    depth = sparse_depth.astype(jnp.float32)
    h, w = depth.shape
    n_pix = h * w
    n_cols = lidar.columns
    token = stage_token(depth)
    R = T[:3, :3]
    options = dict(lidar=lidar, smoothing=smoothing, fill_max_gap=fill_max_gap)
    margin = max(1 + fill_max_gap, smoothing)

    dense = functools.partial(dense_pixel_normals, **options)
    capacity = -(-n_pix // 16) if max_points is None else int(max_points)
    capacity = min(max(capacity, 1), n_pix)
    if capacity == n_pix:
        if listed_only == "slots":  # every pixel its own slot, a zero row last
            table = jnp.concatenate([dense(depth, K, T).reshape(3, n_pix), jnp.zeros((3, 1), jnp.float32)], 1)
            return ListedNormals(jnp.arange(n_pix, dtype=jnp.int32).reshape(h, w), table, jnp.bool_(True),
                                 (depth, K, T), dense)
        return (dense(depth, K, T), jnp.bool_(True)) if listed_only else dense(depth, K, T)
    pix, total = compact_indices((jnp.isfinite(depth) & (depth > 0)).reshape(-1), capacity, token)
    wc = default_window_columns(lidar) if window_columns is None else int(window_columns)
    if wc + 2 * margin > n_cols:  # a window would not save work
        wc = n_cols
        col0 = jnp.int32(0)
        fits = total <= capacity
    else:
        col0 = _window_start(K, T, h, w, lidar, wc)
    # Every point must lie at least `margin` columns inside the window: then the neighbour search and the
    # smoothing never reach its edges and the window gives exactly the whole image's normals. The listed
    # program alone sends the points that do not to the range image's dump slot and reads that slot's key
    # (no reduction of its own: four kernels fewer); the fallback's choice needs the test before its branch.
    dump_edge = listed_only and wc < n_cols
    pts = _pixel_points(pix, depth, K, T, col0, token, lidar=lidar, window_cols=wc, margin=margin,
                        dump_edge=dump_edge)
    if wc < n_cols and not dump_edge:
        fits = (total <= capacity) & ~any_true(pts.edge)  # (a bool any: a large kernel)

    def listed(pix, col0, R, depth, K, T, *pts):
        token = stage_token(depth)
        return _pixel_normals_of_points(pix, _PixelPoints(*pts), col0, R, (h, w), token, window_cols=wc,
                                        identity=False, **options)

    def fallback(pix, col0, R, depth, K, T, *pts):
        return dense(depth, K, T)

    if listed_only:
        normals, dump_key = _pixel_normals_of_points(pix, pts, col0, R, (h, w), token, window_cols=wc,
                                                     identity=False, with_dump=True,
                                                     slots=listed_only == "slots", **options)
        if dump_edge:  # no point in the dump slot: every point kept the margin (and had a cell)
            fits = (total <= capacity) & (dump_key == jnp.iinfo(jnp.int32).max)
        if listed_only == "slots":
            return ListedNormals(*normals, fits, (depth, K, T), dense)
        return normals, fits
    return cond_all(fits, listed, fallback, pix, col0, R, depth, K, T, *pts)
