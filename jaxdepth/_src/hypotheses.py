"""Step 4b (beyond the paper): check each pixel's plane prediction against its column neighbours.

The paper predicts a pixel's depth from one seed, its nearest LiDAR pixel, by
extrapolating that seed's plane (Step 4a, :mod:`~jaxdepth._src.residual`). Far
from the seed, or with a poor normal (sparse beams, object borders), the
extrapolation can run metres past every LiDAR point around the pixel. Two
column neighbours bound it:

* **The bracket** (``SGMConfig.column_bracket``, on by default). Let z_up and
  z_down be the depths of the nearest kept LiDAR pixels straight above and
  below the pixel, each at most ``window_px`` rows away (the paper's vertical
  window H / L: one scan-line spacing). On a plane, inverse depth is affine in
  the pixel coordinates, so along the column the depth of every pixel between
  two points of the plane lies between their depths. The pixel's prediction is
  clipped to [min(z_up, z_down), max(z_up, z_down)]. At a depth edge the pixel
  belongs to one of the two surfaces and the bound still holds; only a surface
  that neither scan line hit (nearer or farther than both) is cut, and such a
  surface is also beyond the nearest seed's reach.
* **Blended hypotheses** (``SGMConfig.blend_hypotheses``, off by default). The
  up and down neighbours' own planes give two more predictions of the pixel;
  those inside the bracket are averaged with the nearest seed's (clipped)
  prediction with inverse-distance weights (1 / image-plane distance to each
  seed, distances in pixels), so a pixel between two scan lines of one surface
  interpolates instead of extrapolating from one side, and a hypothesis from
  across a discontinuity (outside the bracket) is dropped.

Pixels without both neighbours in the window keep the paper's prediction.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from jax import lax

from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.geometry import pixel_grid
from jaxdepth._src.xla_tuning import fence, pack_pair, put_row, take_pair

_DEFAULTS = DEFAULT_CONFIG


_DEPTH_RANGE_M = 256.0


def _depth_bits(h):
    """Bits of the depth in a key for an image of ``h`` rows: 31 - ceil(log2 h) (at least one row bit).

    ``h``: a static int, or a traced int32 scalar (an image that is a window of a canvas); the
    scale ``(2**depth_bits - 1) / 256 m`` is then read from a table of the same float32 values.
    Returns (depth_bits, scale, top): int or int32 scalar, float or float32 scalar, and
    ``2**depth_bits - 1``.
    """
    if isinstance(h, int):
        depth_bits = 31 - max(1, math.ceil(math.log2(h)))
        return depth_bits, (2 ** depth_bits - 1) / _DEPTH_RANGE_M, 2 ** depth_bits - 1
    h = jnp.asarray(h, jnp.int32)
    row_bits = jnp.maximum(1, 32 - lax.clz(jnp.maximum(h - 1, 0)))     # ceil(log2 h) for h >= 2
    depth_bits = 31 - row_bits
    table = jnp.asarray([(2 ** b - 1) / _DEPTH_RANGE_M for b in range(31)], jnp.float32)
    return depth_bits, table[depth_bits], (jnp.int32(1) << depth_bits) - 1


def _column_keys(kept_depth: jax.Array, *, max_gap: int, height=None, one_key_image: bool = False):
    """Packed keys of the nearest kept pixel above and below every pixel (see :func:`column_neighbours`).

    ``height``: optional traced int32 h, the image as the top h rows of ``kept_depth`` (the
    keys are then those of the (h, W) image: its own depth quantisation and row order).
    ``one_key_image`` (static): with ``height`` None and H > 128 (``top < 2**23``), the same keys from one key
    image (see :func:`_running_max_rows`), its integer level read from the float's bits (``round`` then
    ``clip`` to [1, top] give an integral float v < 2**23, whose bits with 2**23 added are ``0x4B000000 +
    v``: the conversion's value without its range checks); else ignored. (For H <= 64, ``top`` rounds up
    to 2**depth_bits in float32, so a depth past 256 m carries into the row bits: the two key images' rule,
    which one image's down keys would not follow.)

    Returns:
      (up, down, depth_bits, scale, top, last): (H, W) int32 keys, -1 where there is no kept
      pixel within ``max_gap`` rows on that side; ``up >> depth_bits`` is the row
      above, ``last - (down >> depth_bits)`` the row below, ``key & top`` (``top =
      2**depth_bits - 1``) the depth times ``scale``; ``last`` is the image's last row.
    """
    h, _ = kept_depth.shape
    depth_bits, scale, top = _depth_bits(h if height is None else height)
    last = h - 1 if height is None else jnp.asarray(height, jnp.int32) - 1
    rows = jnp.arange(h, dtype=jnp.int32)[:, None]
    level = jnp.clip(jnp.round(kept_depth * scale), 1, top)
    one_image = one_key_image and height is None and depth_bits <= 23
    level = (lax.bitcast_convert_type(level + float(2 ** 23), jnp.int32) - 0x4B000000 if one_image
             else level.astype(jnp.int32))
    kept = kept_depth > 0
    # The row sits in the key's high bits, so the max over the rows up to v (from v on) is the key of
    # the nearest kept row above (below); dropping those more than max_gap rows away gives the max
    # over the window of max_gap + 1 rows, bit for bit.
    if one_image:
        up_keys = jnp.where(kept, (rows << depth_bits) | level, -1)
        up, down = _running_max_rows(up_keys, up_keys, down_from_up=(depth_bits, top))
    else:
        up, down = _running_max_rows(jnp.where(kept, (rows << depth_bits) | level, -1),
                                     jnp.where(kept, ((last - rows) << depth_bits) | level, -1))
    g = int(max_gap)
    up = jnp.where(rows - (up >> depth_bits) <= g, up, -1)                 # above: the largest row wins
    down = jnp.where(last - (down >> depth_bits) - rows <= g, down, -1)    # below: the smallest row wins
    return up, down, depth_bits, scale, top, last


def _running_max_rows(forward: jax.Array, backward: jax.Array, *, down_from_up=None):
    """(H, W) int32 running maxima along the rows: of ``forward`` from row 0 down, of ``backward``
    from the last row up. One loop of in-place row updates: its cost is per pixel whatever the search
    range (a ``lax.reduce_window`` over ``max_gap + 1`` rows reads each pixel ``max_gap + 1`` times,
    and on XLA:CPU grew to ~25 ns per pixel at 1550 x 2048, 24 rows, against ~0.6 at 375 x 1242).

    ``down_from_up`` (static ``(depth_bits, top)``): ``backward`` holds up keys (those of
    :func:`_column_keys`), each row's read turned into its down key (the same depth, the row counted from
    the bottom) before the max. With ``backward`` the array ``forward`` is, XLA:CPU copies the one key image
    for the second in-place buffer (a copy, not a second key kernel: docs/speed.md, nusc17).
    """
    h, w = forward.shape
    init = jnp.full((w,), -1, jnp.int32)

    # Indices in range: no negative-index wrap (a compare and select kernel per access and step on XLA:CPU).
    get = functools.partial(lax.dynamic_index_in_dim, axis=0, keepdims=False, allow_negative_indices=False)

    def read_down(bwd, i):
        key = get(bwd, i)
        if down_from_up is None:
            return key
        bits, top = down_from_up
        return jnp.where(key >= 0, ((h - 1 - i) << bits) | (key & top), -1)

    def step(i, state):
        c_fwd, c_bwd, fwd, bwd = state
        c_fwd = jnp.maximum(c_fwd, get(fwd, i))
        c_bwd = jnp.maximum(c_bwd, read_down(bwd, h - 1 - i))
        return c_fwd, c_bwd, put_row(fwd, c_fwd, i), put_row(bwd, c_bwd, h - 1 - i)

    _, _, forward, backward = lax.fori_loop(0, h, step, (init, init, forward, backward))
    return forward, backward


def column_neighbours(kept_depth: jax.Array, *, max_gap: int, height=None, gap=None, one_key_image: bool = False):
    """The nearest kept LiDAR pixels straight above and below every pixel: their rows and depths.

    A LiDAR pixel is its own neighbour (gap 0). Each direction is the max over
    ``max_gap + 1`` rows (a running max down / up the rows, cut at ``max_gap``) of an int32 key that
    packs the row (high bits: the nearest row wins) over the depth quantised to
    ``256 m / 2**(31 - ceil(log2 H))`` (low bits; 0.06 mm for H = 352, 0.12 mm
    for H = 900). The depths returned are those quantised depths, within half a
    step of the exact ones.

    Args:
      kept_depth: (H, W) float32 metres, 0 = no LiDAR pixel (the seeds kept by Step 2).
      max_gap: static search range in rows.
      height, gap: optional traced int32 scalars: the image is the top ``height`` rows of
        ``kept_depth`` (a window of a rig's canvas; the rest is empty) and its search range
        is ``gap <= max_gap`` rows. The result on those rows is that of the
        (height, W) image alone with ``max_gap=gap``, bit for bit.
      one_key_image: static; without ``height`` and for H > 128, the keys from one key image (the same
        values; :func:`_column_keys`); else ignored.

    Returns:
      (row_up, z_up, row_down, z_down): (H, W) int32 rows, -1 where there is no
      kept pixel within ``max_gap`` rows on that side, and (H, W) float32 depths,
      0 there.
    """
    up, down, depth_bits, scale, mask, last = _column_keys(kept_depth, max_gap=max_gap, height=height,
                                                           one_key_image=one_key_image)
    if gap is not None:             # the image's own search range (the keys' row bits give the distance)
        rows = jnp.arange(kept_depth.shape[0], dtype=jnp.int32)[:, None]
        up = jnp.where((up >= 0) & (rows - (up >> depth_bits) <= gap), up, -1)
        down = jnp.where((down >= 0) & (last - (down >> depth_bits) - rows <= gap), down, -1)
    depth = lambda key: jnp.where(key >= 0, (key & mask).astype(jnp.float32) / scale, 0.0)  # noqa: E731
    return (jnp.where(up >= 0, up >> depth_bits, -1), depth(up),
            jnp.where(down >= 0, last - (down >> depth_bits), -1), depth(down))


def column_hypotheses(depth_raw: jax.Array, kept_depth: jax.Array, seed_distance: jax.Array,
                      normals: jax.Array, K: jax.Array, *, window_px: float, blend: bool = False,
                      materialise: bool = True, image_size=None, image_gap=None, one_key_image: bool = False,
                      min_abs_denom: float = _DEFAULTS.min_abs_denom,
                      max_residual_ratio: float = _DEFAULTS.max_residual_ratio) -> jax.Array:
    """The bracket (and optionally the blend) of the module docstring.

    Args:
      depth_raw: (H, W) float32 metres, the nearest seed's plane prediction z' + Delta z
        (0 = no seed).
      kept_depth: (H, W) float32 metres of the LiDAR pixels kept by Step 2 (0 = none).
      seed_distance: (H, W) float32 image-plane distance to the nearest seed, pixels.
      normals: (3, H, W) float32 camera-frame unit normals of the LiDAR pixels.
      K: (3, 3) intrinsics.
      window_px: largest row gap to a column neighbour (the paper's H / L).
      blend: also average in the neighbours' own plane predictions that fall in the bracket.
      materialise: a stage fence after the blend's neighbour search (results are
        the same either way). On XLA:CPU it makes the unguided pipeline's blend
        faster (the gathers otherwise re-run the row search) and the image-guided
        one no faster, so the pipeline turns it off when guided.
      min_abs_denom, max_residual_ratio: as in :func:`~jaxdepth._src.residual.plane_residual`.
      image_size, image_gap: optional traced (2,) int32 (h, w) and int32 ``floor(h / L)``: the
        image is the top-left h x w window of the arrays (a rig's canvas), ``window_px`` is then
        the canvas's H / L (a static bound) and the window used is the image's own
        ``image_gap`` rows (see :func:`column_neighbours`); both or neither.
      one_key_image: static; the neighbour search from one key image (``column_neighbours``'s: the same
        values; without ``image_size``, H > 128). A rig's whole-window tail (docs/speed.md, nusc17).

    Returns:
      (H, W) float32 metres: ``depth_raw`` clipped to the bracket (and blended)
      where both neighbours lie within ``window_px`` rows; ``depth_raw`` elsewhere.
      The bracket and the blend use the neighbour depths of
      :func:`column_neighbours` (quantised to < 0.2 mm).
    """
    max_gap = int(math.floor(window_px))
    h, w = kept_depth.shape
    row_up, z_up, row_dn, z_dn = column_neighbours(kept_depth, max_gap=max_gap, gap=image_gap,
                                                   height=None if image_size is None else image_size[0],
                                                   one_key_image=one_key_image)
    if blend and materialise:
        row_up, z_up, row_dn, z_dn = fence(row_up, z_up, row_dn, z_dn)
    bracketed = (row_up >= 0) & (row_dn >= 0) & (depth_raw > 0)
    lo, hi = jnp.minimum(z_up, z_dn), jnp.maximum(z_up, z_dn)
    depth = jnp.where(bracketed, jnp.clip(depth_raw, lo, hi), depth_raw)
    if not blend:
        return depth
    # Each neighbour's plane, as two numbers per LiDAR pixel: slope = n_y / fv and
    # denom = n . r(u, v_seed), r the pixel's ray (x, y, 1). Step 4a's denominator at
    # the pixel, dv rows from the seed in the same column, is then denom - dv * slope,
    # and its residual z' dv slope / (denom - dv slope): the formula of
    # :func:`~jaxdepth._src.residual.plane_residual` with du = 0.
    K = jnp.asarray(K, jnp.float32)
    fu, fv, pu, pv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    v, u = pixel_grid(h, w)
    slope = normals[1] / fv
    # XLA:CPU: both numbers in one complex64 gather per side, materialised (else the packing re-runs per element).
    plane, = fence(pack_pair(slope.ravel(), ((u - pu) / fu * normals[0] + (v - pv) * slope + normals[2]).ravel()))
    rows = jnp.arange(h, dtype=jnp.int32)[:, None]
    cols = jnp.arange(w, dtype=jnp.int32)[None, :]

    def hypothesis(row, z):
        index = (jnp.where(row >= 0, row, rows) * w + cols).ravel()
        seed_slope, seed_denom = (a.reshape(h, w) for a in take_pair(plane, index))
        dv = (row - rows).astype(jnp.float32)
        denom = seed_denom - dv * seed_slope
        ok = (jnp.abs(denom) > min_abs_denom) & (z > 0)
        residual = jnp.where(ok, z * dv * seed_slope / jnp.where(ok, denom, 1.0), 0.0)
        bound = max_residual_ratio * z
        return z + jnp.clip(residual, -bound, bound)

    h_up = hypothesis(row_up, z_up)
    h_dn = hypothesis(row_dn, z_dn)
    gap_up, gap_dn = rows - row_up, row_dn - rows
    inside = lambda hyp: bracketed & (hyp >= lo) & (hyp <= hi)
    w_up = jnp.where(inside(h_up), 1.0 / jnp.maximum(gap_up, 1).astype(jnp.float32), 0.0)
    w_dn = jnp.where(inside(h_dn), 1.0 / jnp.maximum(gap_dn, 1).astype(jnp.float32), 0.0)
    at_seed = seed_distance <= 0
    w_0 = 1.0 / jnp.where(at_seed, 1.0, seed_distance)
    blended = (w_0 * depth + w_up * h_up + w_dn * h_dn) / (w_0 + w_up + w_dn)
    return jnp.where(at_seed, depth, blended)
