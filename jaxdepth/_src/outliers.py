"""Step 2: occlusion outlier removal (the paper's Algorithm 1), as a fixed-shape mask.

Contract: one sparse depth image in, one boolean mask out. This module only
decides which LiDAR pixels to keep; it never edits a depth value.

The paper (Zhao et al., RA-L 2021, Sec. III-A) removes a projected LiDAR point
``i`` when some point ``j`` of its image neighbourhood

    S(i) = {j : |u_j - u_i| < W L / N  and  |v_j - v_i| < H / L}

(``W x H`` image, ``L`` beams, ``N`` points projected into the image) meets both

    condition 1:  (u_i - u_j)(theta_i - theta_j) < 0  or  (v_i - v_j)(phi_i - phi_j) < 0
    condition 2:  z_i > z_j + epsilon

i.e. the two points are ordered differently seen from the LiDAR than on the
image (parallax: the LiDAR saw ``i`` past the edge of something nearer), and
``i`` is more than ``epsilon`` behind ``j``.

Condition 1, two forms (static option ``test``):

* ``"paper"``: the paper's axis-aligned flips, as written. They stand for
  "i slid behind j" when the LiDAR sits beside the camera (KITTI), where the
  parallax moves points along image rows. When the LiDAR sits behind or ahead
  of the camera (nuScenes' roof LiDAR is 0.4-1.0 m behind its cameras), the
  parallax is radial: points of neighbouring scan lines swap their u order
  on open ground, where nothing can hide anything (tests/test_outliers.py,
  ``test_radial_offset_over_open_ground_removes_nothing``).
* ``"footprint"`` (default): the same flip, measured along the direction in
  which ``i`` actually moves relative to ``j`` between the two views, and only
  when that move passes through ``j``'s own footprint. Let ``a`` be where a
  point is seen by a camera with this camera's axes and K placed at the LiDAR
  origin, ``b`` its camera pixel; in cells of ``W L / N`` by ``H / L`` pixels
  (the paper's point spacings, the sides of S) let ``ra = a_i - a_j``,
  ``rb = b_i - b_j`` and ``m = rb - ra``. Then ``i`` passes behind ``j`` when
  ``ra . m < 0 < rb . m`` (it crosses over ``j``) and ``|ra x m| / |m| < 1/2``
  (it crosses within half a cell of ``j``: through the part of the image that
  ``j``'s surface covers). For a sideways LiDAR this is the paper's u flip
  between points less than half a line apart; a deeper occluder's region is
  the union of its points' cells, so a hidden point crosses some cell of it.

Implementation: an exact prefilter, then the full test at the candidates it
leaves.

1. Prefilter (dense, :func:`_prefilter`): condition 2, which both forms need: a pixel more than
   epsilon nearer in the window (separable window minimum of uint16 depth keys: rows by doubling,
   columns by k). On the KITTI frame ~4.7k of 18.9k points pass. The prefilter only has to keep
   every removed pixel (a superset); the exact test decides. (Earlier versions also bounded the
   footprint form's parallax here, from window extrema of ``1 / (Z - t_z)``: ~1.5k candidates on
   the KITTI frame, but three more keys' minima and a float pass over every pixel cost more than
   the exact test spends on the extra candidates; docs/speed.md, "Step 2's cost (branch step2cut)".)
   The footprint form on image input (one LiDAR origin, the exact path) adds its reach bound
   (:class:`_Reach`, from the same key and window minimum, no pass of its own): a pixel whose
   relative parallax move is small must have its nearer pixel within a small box (KITTI: ~1.4k
   candidates instead of ~4.7k; docs/speed.md, "Step 2's reach bound").
   Tall windows (the rigs' cameras, 49 rows): the minima over blocks of 4-8 rows and each block's
   largest key instead, one pass over the depth; a pixel with depth is a candidate when its block's
   largest key passes against the minimum over the blocks covering its block's windows (a superset:
   5-7 % more candidates on the Argoverse 2 cameras; docs/speed.md, "The prefilter in row blocks").
2. Compaction (:func:`_compact`). The candidate mask is packed into 32-bit words; a
   prefix sum of their popcounts gives every candidate a slot, found back from the
   slot by a binary search over the words and one within the word (no scatter, no
   ``nonzero``; :mod:`jaxdepth._src.compaction`, shared with the image-plane normals). The words
   run along the rows, or down the columns on the tall windows' path (the slots' order changes, not the set).
3. Exact test (:mod:`jaxdepth._src.outlier_exact`), per chunk of candidate slots: walk the points
   of each candidate's window (pixels with depth packed down the columns into words, visited rank
   by rank), gather their depths (and points) from the image, recompute the LiDAR view, and
   evaluate conditions 1 and 2 in float32; removed candidates are cleared in the mask. Every
   (candidate, point) pair gets the float32 operations of a dense sweep over the window, so the
   ``"paper"`` form is bit-identical to the dense sweep of earlier versions. A rig's size groups run
   phases 1-2 each (``_keep_mask(..., defer=True)``) and phase 3 once for all cameras
   (:mod:`jaxdepth._src.outlier_groups`).

The prefilter's key is computed on the image and padded as uint16 (``_ZNONE``); nothing is
padded in float32.

Run-time bounds: ``|du| <= k`` with ``k = (W L - 1) // N`` is known only at run
time; the horizontal prefilter pass takes ``k`` as data, reading
the static cap's columns and keeping those within ``k`` (:func:`_window_min`: one
compiled pass for every ``k``, under ``vmap`` each member its own), and the exact
test masks its window columns to ``|du| <= k``. The key, row and column passes are each
one fusion, fenced (``staging.stage``) so that shifted reads hit buffers instead of
re-running the producer.
"""

from __future__ import annotations

import functools
import math
import numbers
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.compaction import WORD_BITS, pack_bits, word_locator
from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.outlier_exact import CHUNK as _CHUNK  # noqa: F401  (candidate slots per step; tests read it here)
from jaxdepth._src.outlier_exact import ExactTest, exact_test, pack_columns
from jaxdepth._src.xla_tuning import stage, stage_token


#: Condition-1 forms of the exact test (static option ``test``).
TESTS = ("footprint", "paper")


def window_half_sizes(height: int, width: int, *, beams: int, max_half_width_px: int,
                      max_half_height_px: int) -> tuple[int, int]:
    """Static (half_width, half_height) of the window visited, pixels.

    The vertical bound ``|dv| < H / L`` is static: for integer ``dv`` it is
    ``|dv| <= ceil(H / L) - 1``. The horizontal bound depends on ``N`` at run
    time, so only its cap is static. Both are also clipped to the image.
    """
    half_height = min(int(max_half_height_px), math.ceil(height / beams) - 1, height - 1)
    half_width = min(int(max_half_width_px), width - 1)
    return max(half_width, 0), max(half_height, 0)


def _sliding_mins(x: jax.Array, halves: tuple, axis: int) -> tuple:
    """``out[i] = min(x[i + h0 - h:i + h0 + h + 1])`` along ``axis`` for each half size ``h`` of ``halves``
    (``h0 = halves[0]``, the largest: ``x`` is padded by ``h0``; each output's length shrinks by ``2 h0``).

    Doubling: minima over 1, 2, 4, ... elements, then two overlapping runs of
    the largest power of two within a window cover it (about log2(size) passes instead
    of ``size``); the smaller windows reuse the larger one's runs.
    """
    h0 = halves[0]
    n = x.shape[axis] - 2 * h0
    take = lambda a, start, length: jax.lax.slice_in_dim(a, start, start + length, axis=axis)
    runs, width = {1: x}, 1
    while 2 * width <= 2 * h0 + 1:
        run = runs[width]
        runs[2 * width] = jnp.minimum(take(run, 0, run.shape[axis] - width), take(run, width, run.shape[axis] - width))
        width *= 2
    out = []
    for h in halves:
        size, w = 2 * h + 1, 1 << (2 * h + 1).bit_length() - 1
        out.append(jnp.minimum(take(runs[w], h0 - h, n), take(runs[w], h0 - h + size - w, n)))
    return tuple(out)


def _window_min(padded: jax.Array, k: jax.Array, *, hw: int, width: int) -> jax.Array:
    """``out[:, u] = min(padded[:, hw + u - k .. hw + u + k])``, the run-time half window ``k`` as data.

    ``padded``: (..., H, W + 2 hw) with ``width = W``; ``k``: int32 scalar in [0, hw] (under ``vmap``, one
    per member). One pass: the 2 hw + 1 columns of the static cap are read as hw mirrored pairs, each
    taken when its offset is within k (a minimum is exact in any order, so this equals the minimum over
    exactly those columns). Compiled once for every k (no branch per window width).
    """
    out = padded[..., hw:hw + width]
    for d in range(1, hw + 1):
        pair = jnp.minimum(padded[..., hw - d:hw - d + width], padded[..., hw + d:hw + d + width])
        out = jnp.where(d <= k, jnp.minimum(out, pair), out)
    return out


#: Depth keys of the prefilter: uint16 ``floor(z * _ZQ)`` (1/256 m steps, as KITTI's PNGs), saturating
#: at _ZSAT (256 m); _ZNONE marks a pixel that takes no part (the minima ignore it).
_ZQ = 256.0
_ZSAT = 65534
_ZNONE = 65535


def _z_key(z, part):
    return jnp.where(part, jnp.clip(jnp.floor(z * np.float32(_ZQ)), 0.0, float(_ZSAT)), float(_ZNONE)
                     ).astype(jnp.uint16)


def _prefilter_key(depth, *, hh, hw):
    """The uint16 depth key (see :data:`_ZQ`) of each pixel of the (H, W) float32 ``depth``, ``_ZNONE``
    where it has none, padded by ``_ZNONE``: (H + 2 hh, Wp + 2 hw) with ``Wp = 32 ceil(W / 32)`` (one
    fenced stage). The columns past W (no depth: never candidates) make the words pass's mask a whole
    number of words wide, so it packs with no pad of its own (a pad fused with the window minima ran
    ~8x slower than the minima alone on the 1550-wide portrait camera; docs/speed.md, "Step 2, kernel
    by kernel")."""
    key = _z_key(depth, (depth > 0) & jnp.isfinite(depth))
    extra = -depth.shape[1] % WORD_BITS
    return jnp.pad(key, ((hh, hh), (hw, hw + extra)), constant_values=np.uint16(_ZNONE))


def _prefilter_rows(padded, *, hh, hs=None):
    """Column (vertical) minima of the padded depth key over the window's 2 hh + 1 rows (doubling,
    :func:`_sliding_mins`): (H, Wp + 2 hw); with ``hs`` (static, <= hh) also over the 2 hs + 1 rows of the
    reach box (:class:`_Reach`): a tuple of one or two arrays. (The two packed in one uint32 output, one
    pass instead of two, made the prefilter slower: 1.05 against 0.89 ms CPU on the KITTI frame.)"""
    return _sliding_mins(padded, (hh,) if hs is None else (hh, hs), axis=0)


#: The footprint form's reach bound on image input (:class:`_Reach`): a pixel whose relative move is at most
#: this many cells can only be removed by a nearer pixel within ``_reach_radius()`` cells of it.
_REACH_MOVE = 0.5
#: Static cap on the reach box's half width, pixels (its run-time half width is ~0.72 W L / N: 2 on KITTI).
_REACH_HALF_WIDTH = 4
#: Slack of the reach bound, cells (float32 rounding of the exact test is ~1e-4 cells).
_REACH_SLACK = 0.01


def _reach_radius() -> float:
    """Cells: a pair the footprint form can remove lies within this of the removed pixel when its move is
    at most ``_REACH_MOVE`` (``|rb|^2 < |m|^2 + 1/4``, slack added; :class:`_Reach`)."""
    return math.sqrt((_REACH_MOVE + _REACH_SLACK) ** 2 + 0.25 + _REACH_SLACK)


class _Reach(NamedTuple):
    """The footprint form's reach bound on image input (one LiDAR origin ``t``, points back-projected).

    For such a pixel ``p = z K^-1 (q, 1)`` (``q = (u, v)``, K upper triangular as :func:`~jaxdepth._src.
    geometry.pixel_rays` inverts it) the camera pixel is ``b = q`` and the LiDAR view's
    ``a = (z q - C) / (z - t_z)`` with ``C = (K t)_{u, v}``, so its parallax is ``b - a = (C - q t_z) w``,
    ``w = 1 / (z - t_z)``. For a removed ``i`` and its ``j`` (``z_j < z_i``, both ``z - t_z > 1 mm``) the
    relative move is ``m = (C - q_i t_z)(w_i - w_j) + (q_j - q_i) t_z w_j`` (pixels), so, with ``w_j <= W``
    (the window's smallest depth key) and ``w_i >= 1 / ((key_i + 1) / 256 - t_z)``,
    ``|m_u| <= |C_u - u_i t_z| (W - w_i) + |t_z| k W`` and ``|m_v| <= |C_v - v_i t_z| (W - w_i) + |t_z| hh W``.
    The exact test's conditions (``ra . m < 0 < rb . m``, ``|ra x m| < |m| / 2``, in cells) put ``rb`` at
    ``alpha m_hat + beta n_hat`` with ``0 < alpha < |m|`` and ``|beta| < 1/2``: ``|rb|^2 < |m|^2 + 1/4``.
    So a pixel whose bound on ``|m|`` (cells) is at most ``_REACH_MOVE`` is removed only by a nearer pixel
    within :func:`_reach_radius` cells, inside the box ``|du| <= a``, ``|dv| <= hs``; the prefilter then
    asks condition 2 in that box instead of the whole window (a superset of the removed pixels: the
    float32 rounding of the bound and of the exact test is covered by ``slack`` and ``_REACH_SLACK``).
    """

    c_u: jax.Array    # float32 (K t)_u = K00 t_x + K01 t_y + K02 t_z, pixel metres
    c_v: jax.Array    # float32 (K t)_v = K11 t_y + K12 t_z
    t_z: jax.Array    # float32
    slack: jax.Array  # float32 pixel metres: bound on the rounding of C - q t_z (added times W)
    cell_u: jax.Array
    cell_v: jax.Array
    a: jax.Array      # int32 half width of the reach box, <= k


def _reach(K, t, bounds: _Bounds, *, shape: tuple, beams: int, hh: int) -> tuple:
    """(:class:`_Reach`, hs) of an image of static ``shape`` (H, W) ((3, 3) float32 K, (3,) LiDAR origin
    ``t`` in the camera frame): the reach box is ``|du| <= a`` (int32 data, ``<= k``) by ``|dv| <= hs``
    (static, ``<= hh``), every offset within :func:`_reach_radius` cells (``W L / N`` by ``H / L`` pixels)."""
    height, width = shape
    radius = _reach_radius() * (1 + 1e-5)
    c_u, c_v = K[0, 0] * t[0] + K[0, 1] * t[1] + K[0, 2] * t[2], K[1, 1] * t[1] + K[1, 2] * t[2]
    size = jnp.sum(jnp.abs(K)) + (width + height)
    slack = np.float32(1e-5) * size * (jnp.abs(t[0]) + jnp.abs(t[1]) + jnp.abs(t[2]))
    a = jnp.minimum(jnp.floor(np.float32(radius) * bounds.cell_u).astype(jnp.int32), bounds.k_max)
    hs = min(math.floor(radius * height / beams), hh)
    return _Reach(c_u, c_v, t[2], slack, bounds.cell_u, bounds.cell_v, a), hs


def _moves_far(key, low, k, reach: _Reach, *, hh):
    """(H, Wp) bool: False only where :class:`_Reach`'s bound on the relative move is at most ``_REACH_MOVE``
    cells. ``key``: each pixel's int32 depth key, ``low``: the window's smallest (int32, :func:`_window_min`).

    With ``n = low / 256 - t_z <= z_j - t_z`` and ``o = (key + 1) / 256 - t_z > z_i - t_z``: ``W = 1 / n``,
    ``W - w_i <= (o - n) / (n o)`` (``W`` for a saturated key), so the bound times ``n o`` needs no division:
    ``|m_u| n o <= |C_u - u t_z| (o - n) + (|t_z| k + slack) o`` (likewise v with ``hh``), compared squared
    with ``(_REACH_MOVE n o)^2``, inflated by 0.2 % + 1e-3 cells^2 against its own float32 rounding."""
    rows, cols = key.shape
    inv_q = np.float32(1.0 / _ZQ)
    near = low.astype(jnp.float32) * inv_q - reach.t_z
    own = (key + 1).astype(jnp.float32) * inv_q - reach.t_z
    bounded = near > np.float32(2e-3)
    gap = jnp.where(key >= _ZSAT, own, own - near)
    tz = jnp.abs(reach.t_z)
    a_u = jnp.abs(reach.c_u - jnp.arange(cols, dtype=jnp.float32)[None, :] * reach.t_z) / reach.cell_u
    a_v = jnp.abs(reach.c_v - jnp.arange(rows, dtype=jnp.float32)[:, None] * reach.t_z) / reach.cell_v
    m_u = a_u * gap + (tz * k.astype(jnp.float32) + reach.slack) / reach.cell_u * own
    m_v = a_v * gap + (tz * np.float32(hh) + reach.slack) / reach.cell_v * own
    scale = near * own
    move2 = (m_u * m_u + m_v * m_v) * np.float32(1.002) + np.float32(1e-3) * scale * scale
    return ~bounded | ~(move2 <= np.float32(_REACH_MOVE ** 2) * scale * scale)


def _prefilter_words(k, low, key, eps, *, hw, width, hh=0, reach=None, low_reach=None):
    """Candidate mask for the run-time horizontal half window k, packed into uint32 words (H, ceil(W / 32)).

    ``width``: Wp, a multiple of 32 (:func:`_prefilter_key`). ``low``: the row minima of
    :func:`_prefilter_rows`; their minima over columns ``|du| <= k``
    (:func:`_window_min`, ``k`` int32 data: one program for every k) give each pixel's window minimum.
    Both forms of condition 1 need condition 2: a pixel more than ``eps`` nearer in the window,
    ``z_i > min_window(z) + eps``, tested on uint16 keys ``floor(z * 256)``: ``key_i >= min key +
    floor(256 eps)`` follows from it (a superset; a saturated key always passes).
    ``reach`` (:class:`_Reach`, the footprint form on image input) with ``low_reach`` (the row minima over
    the reach box's rows, :func:`_prefilter_rows`): a pixel whose move bound is small must pass the same
    test in the reach box too.
    """
    low = _window_min(low, k, hw=hw, width=width).astype(jnp.int32)
    key = key.astype(jnp.int32)
    margin = jnp.floor(eps * np.float32(_ZQ)).astype(jnp.int32)
    cand = (key < _ZNONE) & (low < _ZNONE) & ((key >= low + margin) | (key == _ZSAT))
    if reach is not None:
        hb = min(hw, _REACH_HALF_WIDTH)     # the box's static cap; wider at run time: every pixel is "far"
        box = _window_min(low_reach[:, hw - hb:hw + hb + width], reach.a, hw=hb, width=width).astype(jnp.int32)
        far = _moves_far(key, low, k, reach, hh=hh) | (reach.a > hb)
        cand = cand & (far | (key >= box + margin) | (key == _ZSAT))
    return pack_bits(cand)


def _compact(words: jax.Array, *, down: bool = False):
    """Phase 2: slots for the candidates of the packed (H, ceil(W / 32)) uint32 candidate words
    (``down``: (ceil(H / 32), W) words packed down the columns; the slots then run word row by word row,
    column by column, down each word's 32 rows).

    Returns ``(count, locate)``: the int32 number of candidates, and
    ``locate(slot) -> (row, column)`` (int32 pixel coordinates) of the slot-th
    candidate in raster order, for int32 slots in ``[0, count)`` of any shape
    (:func:`~jaxdepth._src.compaction.word_locator`: no scatter, no ``nonzero``).
    """
    row_bits = words.shape[1] * 32
    count, locate_bit = word_locator(words)

    def locate_down(slot):
        flat = locate_bit(slot)
        word = flat // WORD_BITS
        return (word // words.shape[1]) * WORD_BITS + flat % WORD_BITS, word % words.shape[1]

    def locate(slot):
        flat = locate_bit(slot)
        return flat // row_bits, flat % row_bits

    return count, (locate_down if down else locate)


class _Bounds(NamedTuple):
    """The paper's neighbourhood S(i) of one image, known at run time (traced scalars)."""

    n_points: jax.Array  # int32 N, pixels with depth
    k_max: jax.Array     # int32 largest |du| in S(i): (W L - 1) // N, capped at the static half width
    cell_u: jax.Array    # float32 W L / N, pixels (the horizontal point spacing)
    cell_v: jax.Array    # float32 H / L, pixels (the vertical point spacing)
    h_max: jax.Array | None = None   # int32 largest |dv| in S(i) of a window of a canvas (None: the static one)


def _bounds(valid: jax.Array, *, beams: int, half_width: int, half_height: int, image_size=None,
            columns=None) -> _Bounds:
    """N and the window bounds W L / N, H / L of an (H, W) bool mask of pixels with depth.

    ``columns``: optional, ``valid`` packed down the columns (:func:`~jaxdepth._src.outlier_exact.pack_columns`):
    N is then the sum of their population counts (32x fewer elements than the mask; under ``vmap`` the mask's
    float sum was a materialised (H, W) float32 copy and a reduction, ~11 % of the rig's Step 2, docs/speed.md).

    ``image_size``: optional traced (2,) int32 (h, w) of the image, a window in the top-left
    corner of the (H, W) canvas (rigs of mixed sizes): the bounds are then the image's own,
    ``w L / N`` and ``h / L`` (the same float32 values as for an (h, w) array), and
    ``h_max = min(half_height, ceil(h / L) - 1, h - 1)``, the image's own vertical bound. The
    horizontal bound keeps the canvas's static cap: offsets past the image's edge reach only
    empty pixels.
    """
    height, width = valid.shape
    counted = valid if columns is None else jax.lax.population_count(columns)
    # An exact count (H W < 2**24) in one pass; an int32 sum splits into more.
    n_points = jnp.sum(counted.astype(jnp.float32)).astype(jnp.int32) if height * width < 2 ** 24 else \
        jnp.sum(counted, dtype=jnp.int32)
    h_max = None
    if image_size is None:
        wl, cell_v = width * beams, jnp.float32(height / beams)
    else:
        h, w = jnp.asarray(image_size[0], jnp.int32), jnp.asarray(image_size[1], jnp.int32)
        # float32(h) / float32(L) equals float32(h / L) for every h < 4100, L <= 256 (checked).
        wl, cell_v = w * beams, h.astype(jnp.float32) / jnp.float32(beams)
        h_max = jnp.minimum(jnp.minimum((h + beams - 1) // beams - 1, h - 1), half_height)
    # |du| = k is in S(i) iff k < W L / N, i.e. k <= (W L - 1) // N (integers).
    k_max = jnp.where(n_points > 0, jnp.minimum((wl - 1) // jnp.maximum(n_points, 1), half_width), 0)
    cell_u = jnp.asarray(wl, jnp.float32) / jnp.maximum(n_points, 1).astype(jnp.float32)
    return _Bounds(n_points, k_max, cell_u, cell_v, h_max)


#: Rows per block of the prefilter's vertical minima on tall windows (``hh >= _BLOCK_HALF``, the rigs' cameras:
#: 49 rows): the largest of these that divides the canvas height (none: the exact row minima). The minima run
#: over whole blocks, so each pixel's window is widened to the blocks that cover its block's windows (a
#: superset of the exact window's candidates; docs/speed.md, "The prefilter in row blocks").
_ROW_BLOCKS = (8, 7, 6, 5, 4)
_BLOCK_HALF = 16


def _row_block(height: int, hh: int):
    """Static rows per block of :func:`_prefilter` for an ``height``-row canvas and half window ``hh`` (None: exact)."""
    return next((b for b in _ROW_BLOCKS if height % b == 0), None) if hh >= _BLOCK_HALF else None


def _block_keys(depth, *, block):
    """(H / block, W) uint32: in the low 16 bits the smallest key (:data:`_ZQ`) of each block of ``block``
    image rows ``[block r, block r + block)`` (``_ZNONE`` where a block has no depth), in the high 16 the
    largest key of a pixel with depth (0 where none); ``block`` divides H. One pass over the depth (as two
    outputs, XLA ran two passes)."""
    height, width = depth.shape
    valid = (depth > 0) & jnp.isfinite(depth)
    key = _z_key(depth, valid).reshape(height // block, block, width)
    top = jnp.where(valid, key.reshape(height, width), np.uint16(0)).reshape(key.shape)
    low, high = key[:, 0], top[:, 0]
    for i in range(1, block):
        low, high = jnp.minimum(low, key[:, i]), jnp.maximum(high, top[:, i])
    return low.astype(jnp.uint32) | (high.astype(jnp.uint32) << 16)


def _block_rows(blocks, *, half, hw, width):
    """Vertical minima over ``2 half + 1`` blocks of the block minima (the low halves of :func:`_block_keys`;
    each output block's rows' windows, covered by whole blocks), padded by ``_ZNONE`` to (R, width + 2 hw)
    for the horizontal pass."""
    cols = blocks.shape[1]
    blocks = (blocks & 0xFFFF).astype(jnp.uint16)
    padded = jnp.pad(blocks, ((half, half), (0, 0)), constant_values=np.uint16(_ZNONE))
    low = _sliding_mins(padded, (half,), axis=0)[0]
    return jnp.pad(low, ((0, 0), (hw, hw + width - cols)), constant_values=np.uint16(_ZNONE))


def _block_bits(on, *, block, height):
    """(ceil(height / 32), W) uint32 words packed down the columns (as
    :func:`~jaxdepth._src.outlier_exact.pack_columns`): bit i of word m is ``on[(32 m + i) // block]``, from the
    (height / block, W) bool ``on``. Rows repeat their pattern of blocks in words every lcm(block, 32) rows: each
    word of a period is an OR of its blocks' static bit masks (static slices, no gather)."""
    rows, width = on.shape
    period = block * WORD_BITS // math.gcd(block, WORD_BITS)
    per_words, per_blocks = period // WORD_BITS, period // block
    n = -(-rows // per_blocks)
    on = jnp.pad(on, ((0, n * per_blocks - rows), (0, 0))).reshape(n, per_blocks, width)
    words = []
    for s in range(per_words):
        word = jnp.zeros((n, width), jnp.uint32)
        for q in range(s * WORD_BITS // block, ((s + 1) * WORD_BITS - 1) // block + 1):
            first, last = max(q * block, s * WORD_BITS), min((q + 1) * block, (s + 1) * WORD_BITS)
            mask = np.uint32(sum(1 << (r - s * WORD_BITS) for r in range(first, last)))
            word = word | jnp.where(on[:, q], mask, np.uint32(0))
        words.append(word)
    return jnp.stack(words, axis=1).reshape(n * per_words, width)[:-(-height // WORD_BITS)]


def _block_words(low, keys, columns, eps, *, block, height):
    """Candidate words packed down the columns, (ceil(H / 32), W) (``columns``: the pixels with depth so
    packed), from each block's window minimum ``low`` (R, >= W) and :func:`_block_keys`' ``keys`` (R, W; the
    high halves: each block's largest key): every pixel with depth of a block whose largest key passes
    :func:`_prefilter_words`'s test against the block's minimum (never larger than a pixel's own window's,
    and its key never above the largest: a superset)."""
    width = keys.shape[1]
    low, high = low[:, :width].astype(jnp.int32), (keys >> 16).astype(jnp.int32)
    margin = jnp.floor(eps * np.float32(_ZQ)).astype(jnp.int32)
    on = (low < _ZNONE) & ((high >= low + margin) | (high == _ZSAT))
    return columns & _block_bits(on, block=block, height=height)


def _prefilter(depth, eps, bounds: _Bounds, *, hh: int, hw: int, columns=None, reach: _Reach | None = None,
               hs: int = 0):
    """Phase 1: candidates for removal, exact superset of the removed pixels, as packed words.

    Args:
      depth: (H, W) float32 metres. eps: float32 condition-2 margin, metres. bounds: :class:`_Bounds`.
      hh, hw: static window half sizes (rows, columns).

    Returns:
      (H, ceil(W / 32)) uint32 words: bit i of word m in row v is the pixel
      ``(v, 32 m + i)`` (:func:`~jaxdepth._src.compaction.pack_bits`). Three dense
      passes over the canvas (the key, its row minima, its column minima with the words), each a fenced
      stage; the column minima take the run-time half window k as data: one program for every k.
      Tall windows (:func:`_row_block` not None): (ceil(H / 32), W) words packed down the columns
      (:func:`~jaxdepth._src.outlier_exact.pack_columns`; ``columns``: the pixels with depth so packed, or
      None), from one dense pass over the depth (:func:`_block_keys`) and passes over the blocks.
      ``reach``: optional :class:`_Reach` (exact path only) with ``hs``, the reach box's static row half
      size: pixels whose move bound is small pass only with a nearer pixel in the reach box.
    """
    height, width = depth.shape[0], -(-depth.shape[1] // WORD_BITS) * WORD_BITS
    b = _row_block(height, hh)
    # The stages' token: the depth's bits, as Step 1's and the tail's fences' (one predicate kernel for all)
    token = stage_token(depth)
    if b is not None:
        if columns is None:
            columns = pack_columns((depth > 0) & jnp.isfinite(depth))
        keys = stage(lambda d: (_block_keys(d, block=b),), (depth,), token)[0]
        low = stage(lambda x: (_block_rows(x, half=-(-hh // b), hw=hw, width=width),), (keys,), token)[0]
        low = stage(lambda k, x: (_window_min(x, k, hw=hw, width=width),), (bounds.k_max, low), token)[0]
        # fenced: XLA fused the words (with the columns' packing) into each of the compaction's three readers
        return stage(lambda lo, hi, c, e: _block_words(lo, hi, c, e, block=b, height=height), (low, keys, columns, eps),
                     token)
    padded = stage(lambda d: (_prefilter_key(d, hh=hh, hw=hw),), (depth,), token)[0]
    if reach is None:
        low = stage(lambda x: _prefilter_rows(x, hh=hh), (padded,), token)[0]
        return stage(lambda k, lo, x, e: _prefilter_words(k, lo, x[hh:hh + height, hw:hw + width], e, hw=hw,
                                                          width=width), (bounds.k_max, low, padded, eps), token)
    low, low_reach = stage(lambda x: _prefilter_rows(x, hh=hh, hs=hs), (padded,), token)
    return stage(lambda k, lo, lr, x, e, r: _prefilter_words(k, lo, x[hh:hh + height, hw:hw + width], e, hw=hw,
                                                             width=width, hh=hh, reach=r, low_reach=lr),
                 (bounds.k_max, low, low_reach, padded, eps, reach), token)


class KeepParts(NamedTuple):
    """Phases 1-2 of one image (``_keep_mask(..., defer=True)``): what phase 3 reads, arrays only
    (:class:`~jaxdepth._src.outlier_exact.ExactTest`'s fields; ``words``: the candidates packed as the prefilter's)."""

    valid: jax.Array
    depth: jax.Array
    points: object
    columns: jax.Array
    words: jax.Array
    K: jax.Array
    t: jax.Array
    eps: jax.Array
    k_max: jax.Array
    cell_u: jax.Array
    cell_v: jax.Array
    h_max: jax.Array | None
    nearer: jax.Array | None
    source: jax.Array | None


@functools.partial(jax.jit, static_argnames=("beams", "half_width", "half_height", "test", "defer"))
def _keep_mask(sparse_depth, K, T_cam_lidar, points_cam, epsilon_m, candidates=None, *, beams, half_width,
               half_height, test="footprint", origins=None, nearer=None, image_size=None, window_pixels=None,
               pixel_source=None, defer=False):
    """Algorithm 1 in three phases: prefilter, compaction, exact test (see the module docstring).

    Arguments as :func:`outlier_keep_mask`, already checked: (H, W) depth,
    (3, 3) K, (4, 4) T_cam_lidar, (3, H, W) points_cam (or its three channels) or None, traced float32
    epsilon_m (metres); static beams, half window sizes (pixels) and test form.
    ``candidates``: optional (H, W) bool, the only pixels that may be removed (the
    pixels of one source, whose LiDAR sits at ``T_cam_lidar``'s origin; every
    pixel still serves as a neighbour j). ``origins``: optional (3, H, W) float32, each
    pixel's own LiDAR origin in the camera frame (several sources in one pass: candidate
    ``i`` is tested with its own origin as the viewpoint; ``T_cam_lidar`` is then unused).
    ``nearer``: optional (H, W) bool, pixels removed by condition 2 alone (a nearer pixel in
    S(i)). ``image_size``: optional traced (2,) int32 (h, w), the image as a window in the top-left
    corner of the canvas (rigs of mixed sizes; window bounds from h and w, see :func:`_bounds`).
    ``window_pixels``: optional (H, W) bool, the N of ``W L / N`` (default: ``valid``). ``pixel_source``: optional
    (H, W) int32, clipped to [0, S) where read: ``origins`` is then the (S, 3) table of the sources' origins and pixel i's origin
    ``origins[pixel_source[i]]``, read where used by the exact test (no (3, H, W) map is stored). Returns the
    keep mask; with ``defer`` (static) phases 1-2's :class:`KeepParts` instead (:mod:`~jaxdepth._src.outlier_groups`
    runs phase 3 once for a rig's size groups).
    """
    depth = sparse_depth.astype(jnp.float32)
    if isinstance(points_cam, (tuple, list)):        # three channels apart (rigs' views): kept apart
        points = tuple(jnp.asarray(channel, jnp.float32) for channel in points_cam)
    else:
        points = None if points_cam is None else points_cam.astype(jnp.float32)
    K = K.astype(jnp.float32)
    eps = jnp.asarray(epsilon_m, jnp.float32)
    valid = (depth > 0) & jnp.isfinite(depth)
    if defer:   # the shared loop's keep buffer: one buffer that the packing reads too (not recomputed there)
        valid = stage(lambda v: (v,), (valid,), stage_token(depth))[0]
    t = T_cam_lidar.astype(jnp.float32)[:3, 3] if origins is None else origins.astype(jnp.float32)
    columns = pack_columns(valid)
    bounds = _bounds(valid if window_pixels is None else window_pixels, beams=beams, half_width=half_width,
                     half_height=half_height, image_size=image_size, columns=None if window_pixels is not None
                     else columns)
    down = _row_block(depth.shape[0], half_height) is not None      # the words' layout (:func:`_prefilter`)
    reach, hs = None, 0
    if test == "footprint" and points is None and origins is None and image_size is None and not down:
        reach, hs = _reach(K, t, bounds, shape=depth.shape, beams=beams, hh=half_height)
    words = _prefilter(depth, eps, bounds, hh=half_height, hw=half_width, columns=columns, reach=reach, hs=hs)
    pack = pack_columns if down else pack_bits
    if candidates is not None:
        words = words & pack(candidates)
    if nearer is not None:      # tested even outside ``candidates`` (the prefilter's condition 2 keeps them)
        nearer = nearer & valid
        words = words | pack(nearer)
    if defer:
        return KeepParts(valid, depth, points, columns, words, K, t, eps, bounds.k_max, bounds.cell_u, bounds.cell_v,
                         bounds.h_max, nearer, pixel_source)
    count, locate = _compact(words, down=down)
    ex = ExactTest(depth, points, columns, K, t,
                   eps, bounds.k_max, bounds.cell_u, bounds.cell_v, bounds.h_max, count, locate, hh=half_height,
                   hw=half_width, test=test, nearer=nearer, source=pixel_source)
    return exact_test(valid, ex)


def outlier_keep_mask(sparse_depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array, *, beams: int,
                      epsilon_m: float = DEFAULT_CONFIG.epsilon_m,
                      max_half_width_px: int = DEFAULT_CONFIG.outlier_max_half_width_px,
                      max_half_height_px: int = DEFAULT_CONFIG.outlier_max_half_height_px,
                      points_cam: jax.Array | None = None, test: str = DEFAULT_CONFIG.outlier_test,
                      image_size: jax.Array | None = None) -> jax.Array:
    """Occlusion outlier mask of a sparse LiDAR depth image (the paper's Algorithm 1).

    Args:
      sparse_depth: (H, W) float32 camera depth z, metres; 0 (or any value that
        is not a finite positive number) marks an empty pixel.
      K: (3, 3) float32 camera intrinsics, pixels.
      T_cam_lidar: (4, 4) float32 LiDAR -> camera transform; only the LiDAR
        origin ``t = T_cam_lidar[:3, 3]`` (in the camera frame) is used.
      beams: static number of LiDAR beams L (64 for KITTI's HDL-64E).
      epsilon_m: condition 2's depth margin, metres (paper: 1.0); a traced
        scalar is accepted (changing it does not recompile).
      max_half_width_px: static cap on ``|du|``; offsets with ``|du| >=
        W L / N`` are skipped at run time, offsets beyond the cap never visited.
      max_half_height_px: static cap on ``|dv|``; the window uses
        ``|dv| <= min(cap, ceil(H / L) - 1)``, i.e. the paper's ``|dv| < H / L``.
      points_cam: optional (3, H, W) float32 camera-frame coordinates (x, y, z),
        metres, of the LiDAR point that won each pixel (raw sweep input). When
        None, each pixel's point is back-projected from its centre through
        ``K`` (image-only input: angles then carry the +-0.5 px rounding of
        the projection). Also three (H, W) channels (x, y, z), kept apart (a
        rig's view: no stacked copy); the same mask.
      test: static form of condition 1: "footprint" (default) or "paper" (see
        the module docstring).
      image_size: optional traced (2,) int32 (h, w): the image is the top-left
        h x w window of ``sparse_depth``, a canvas shared by cameras of several
        sizes (the rest empty). The window bounds are then the image's own
        (``w L / N``, ``h / L``), so the mask equals that of the (h, w) image
        alone, bit for bit (tests/test_rig.py).

    Returns:
      (H, W) bool: True where a sparse pixel is kept; False where it is
      removed and where the pixel is empty.

    Angles ("paper" form). The paper uses the spherical angles (theta, phi) of
    each point in the LiDAR frame. Their orientation is a matter of axes, so
    here they are measured from the LiDAR origin in camera-aligned axes,
    ``q = p_cam - t``: theta = atan2(q_x, q_z) grows with u, phi = atan2(q_y,
    q_z) (the tilt of the ray's y-z projection) grows with v; for a zero
    LiDAR-camera offset angle order and pixel order are identical. Only order
    matters, so ``atan2`` is replaced by a strictly increasing stand-in. The
    "footprint" form works with the same rays projected through K (where a
    camera at the LiDAR would see each point); points not in front of that
    virtual camera (q_z <= 1 mm) are never compared.

    Differences from the paper's double loop (the test oracles, one per form):
      * one point per pixel (the projection's z-buffer winner); ``N`` is the
        number of valid pixels, counted at run time;
      * the horizontal window is capped at ``max_half_width_px`` (the paper's
        bound applies below the cap);
      * the test runs on all points at once: ``i`` is removed if any ``j`` in
        S(i) qualifies, whether or not ``j`` itself is removed, which is what
        the paper's loop does too (it never updates S during the loop).

    Condition 2 always uses ``sparse_depth`` as z, also when ``points_cam`` is
    given.

    Under ``vmap`` each member's prefilter uses its own window, and the
    candidate loops run to the largest count and bound in the batch: same
    result per member, a little more work.

    Speed: benchmarks/bench_outliers.py times both forms against the frozen
    dense sweep in one process (results in benchmarks/results/outliers.json).
    """
    sparse_depth = jnp.asarray(sparse_depth)
    if sparse_depth.ndim != 2:
        raise ValueError(f"outlier_keep_mask: field 'sparse_depth' expected shape (H, W), got {sparse_depth.shape}")
    K = jnp.asarray(K)
    if K.shape != (3, 3):
        raise ValueError(f"outlier_keep_mask: field 'K' expected shape (3, 3), got {K.shape}")
    T_cam_lidar = jnp.asarray(T_cam_lidar)
    if T_cam_lidar.shape != (4, 4):
        raise ValueError(f"outlier_keep_mask: field 'T_cam_lidar' expected shape (4, 4), got {T_cam_lidar.shape}")
    if isinstance(points_cam, (tuple, list)):
        points_cam = tuple(jnp.asarray(channel) for channel in points_cam)
        if len(points_cam) != 3 or any(channel.shape != sparse_depth.shape for channel in points_cam):
            raise ValueError(
                f"outlier_keep_mask: field 'points_cam' expected three channels of shape {sparse_depth.shape}, "
                f"got {[channel.shape for channel in points_cam]}")
    elif points_cam is not None:
        points_cam = jnp.asarray(points_cam)
        if points_cam.shape != (3, *sparse_depth.shape):
            raise ValueError(
                f"outlier_keep_mask: field 'points_cam' expected shape {(3, *sparse_depth.shape)}, "
                f"got {points_cam.shape}")
    if int(beams) != beams or beams < 1:
        raise ValueError(f"outlier_keep_mask: field 'beams' expected a positive integer, got {beams!r}")
    if isinstance(epsilon_m, numbers.Real) and not (math.isfinite(epsilon_m) and epsilon_m >= 0):
        raise ValueError(f"outlier_keep_mask: field 'epsilon_m' expected a finite value >= 0, got {epsilon_m!r}")
    if test not in TESTS:
        raise ValueError(f"outlier_keep_mask: field 'test' expected one of {TESTS}, got {test!r}")
    for name, value in (("max_half_width_px", max_half_width_px), ("max_half_height_px", max_half_height_px)):
        if int(value) != value or value < 0:
            raise ValueError(f"outlier_keep_mask: field {name!r} expected a non-negative integer, got {value!r}")
    height, width = sparse_depth.shape
    half_width, half_height = window_half_sizes(
        height, width, beams=int(beams), max_half_width_px=int(max_half_width_px),
        max_half_height_px=int(max_half_height_px))
    return _keep_mask(sparse_depth, K, T_cam_lidar, points_cam, jnp.asarray(epsilon_m, jnp.float32),
                      beams=int(beams), half_width=half_width, half_height=half_height, test=test,
                      image_size=image_size)


def keep_mask_for_config(sparse_depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array, *, beams: int,
                         config, points_cam: jax.Array | None = None, image_size=None) -> jax.Array:
    """Step 2 as an :class:`~jaxdepth.SGMConfig` asks: :func:`outlier_keep_mask`, or every sparse pixel
    when ``config.outlier_removal`` is off. The one place where config fields map to the stage's options.
    """
    if not config.outlier_removal:
        return sparse_depth > 0
    return outlier_keep_mask(sparse_depth, K, T_cam_lidar, beams=beams, epsilon_m=config.epsilon_m,
                             max_half_width_px=config.outlier_max_half_width_px,
                             max_half_height_px=config.outlier_max_half_height_px, points_cam=points_cam,
                             test=config.outlier_test, image_size=image_size)
