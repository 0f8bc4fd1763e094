"""Step 2, phase 3: Algorithm 1's exact test at the candidates, visiting only the window's points.

Contract: candidates (pixels with depth, listed by :mod:`jaxdepth._src.outliers`' prefilter and
compaction) in, the (H, W) keep mask out; a candidate is cleared when some pixel ``j`` with depth
in its window ``|du| <= k_max, |dv| <= hh`` meets conditions 1 and 2 (the forms and their
derivation: :mod:`jaxdepth._src.outliers`).

A LiDAR image is sparse (KITTI 4 %, an Argoverse 2 camera 0.5 % of its pixels), so a window of
``(2 hh + 1) x (2 k + 1)`` pixels (49 x 15 on the Argoverse 2 cameras) holds a handful of points.
Each candidate therefore walks the points of its window column by column: the pixels with depth
are packed down the columns into uint32 words (:func:`pack_columns`); for every column offset the
two or three words that cover rows ``v - hh .. v + hh`` are masked to those rows, and a loop over
ranks ``m = 0, 1, ...`` up to the chunk's largest count visits the ``m``-th point of every
candidate's window column at once (:func:`~jaxdepth._src.compaction.nth_set_bit`), gathering its
depth (and point) from the image itself: no padded canvas. Each (candidate, point) pair is tested
with the same float32 operations as a dense sweep over the window would use, and empty pixels never
pass condition 2, so the mask is the same, bit for bit.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxdepth._src.compaction import WORD_BITS, nth_set_bit
from jaxdepth._src.fastmath import pseudo_angle
from jaxdepth._src.geometry import backproject
from jaxdepth._src.xla_tuning import fence, shared_loop_bounds

#: Candidate slots tested per loop step.
CHUNK = 512
#: Column offsets per side of a block of the window walked at once (B = 2 G + 1 columns).
_GROUP = 4
#: Smallest parallax move that counts, pixels: below it a crossing is float rounding.
_MIN_MOVE_PX = 1e-3
_PIB = "promise_in_bounds"


def _camera_points(depth: jax.Array, K: jax.Array, points_cam, v: jax.Array, u: jax.Array):
    """Camera-frame (x, y, z) of points, metres, three arrays of ``depth``'s shape.

    ``points_cam`` None: each pixel's point back-projected from its centre
    ``(u, v)`` (float32 columns and rows broadcastable to ``depth``) at
    ``depth`` (:func:`~jaxdepth._src.geometry.backproject`); otherwise the given
    camera-frame points, a (3, ...) array or three arrays of ``depth``'s shape.
    """
    if points_cam is None:
        return backproject(depth, K, v, u)
    return points_cam[0], points_cam[1], points_cam[2]


def lidar_angles(depth: jax.Array, K: jax.Array, t: jax.Array, points_cam, v: jax.Array, u: jax.Array):
    """Order keys (h, g) of points seen from the LiDAR origin ``t`` (camera axes), "paper" form.

    ``h`` orders ``atan2(q_x, q_z)`` and ``g`` orders ``atan2(q_y, q_z)`` for
    ``q = p_cam - t`` (:func:`~jaxdepth._src.fastmath.pseudo_angle`, float32 of
    ``depth``'s shape). Arguments as :func:`_camera_points`; ``t``: (3, ...) float32
    LiDAR origin in the camera frame, metres.
    """
    px, py, pz = _camera_points(depth, K, points_cam, v, u)
    qx, qy, qz = px - t[0], py - t[1], pz - t[2]
    return pseudo_angle(qx, qz), pseudo_angle(qy, qz)


def lidar_view(depth: jax.Array, K: jax.Array, t: jax.Array, points_cam, v: jax.Array, u: jax.Array):
    """Where each point is seen from the LiDAR origin and from the camera, pixels ("footprint" form).

    ``(a_u, a_v)``: the pixel of a camera with the same orientation and
    intrinsics placed at the LiDAR origin ``t``; ``(b_u, b_v)``: the point's own
    camera pixel, exact (sub-pixel) for given ``points_cam``, the pixel centre
    (u, v) for back-projected pixels. ``ok`` is False where the point is not in
    front of the LiDAR's virtual camera (q_z <= 1 mm). Arguments as
    :func:`lidar_angles`; every output is float32 (``ok`` bool) of ``depth``'s shape.
    """
    px, py, pz = _camera_points(depth, K, points_cam, v, u)
    if points_cam is None:
        b_u, b_v = u, v
    else:
        inv_p = 1.0 / jnp.where(pz > 0, pz, 1.0)
        b_u, b_v = K[0, 0] * px * inv_p + K[0, 1] * py * inv_p + K[0, 2], K[1, 1] * py * inv_p + K[1, 2]
    qx, qy, qz = px - t[0], py - t[1], pz - t[2]
    ok = qz > 1e-3
    inv = 1.0 / jnp.where(ok, qz, 1.0)
    return K[0, 0] * qx * inv + K[0, 1] * qy * inv + K[0, 2], K[1, 1] * qy * inv + K[1, 2], b_u, b_v, ok


def condition_1(test, view_p, view_q, du, dv, cell_u, cell_v):
    """Condition 1 between centre points p and window points q at pixel offset (du, dv) = q - p.

    ``view_*`` are what :func:`lidar_angles` ("paper") or :func:`lidar_view`
    ("footprint") return; "nearer": always True (condition 2 alone).
    """
    if test == "nearer":        # condition 2 alone (points already known to sit in a LiDAR's shadow)
        return jnp.ones_like(view_q[0], bool)
    if test == "paper":
        (h_p, g_p), (h_q, g_q) = view_p, view_q
        return (jnp.where(du > 0, h_p > h_q, (du < 0) & (h_p < h_q))
                | jnp.where(dv > 0, g_p > g_q, (dv < 0) & (g_p < g_q)))
    (au_p, av_p, bu_p, bv_p, ok_p), (au_q, av_q, bu_q, bv_q, ok_q) = view_p, view_q
    # Offsets of p from q in cells (W L / N by H / L pixels): seen from the
    # LiDAR (ra), on the image (rb), and p's move relative to q between them (m).
    ra_u, ra_v = (au_p - au_q) / cell_u, (av_p - av_q) / cell_v
    rb_u, rb_v = (bu_p - bu_q) / cell_u, (bv_p - bv_q) / cell_v
    m_u, m_v = rb_u - ra_u, rb_v - ra_v
    m2 = m_u * m_u + m_v * m_v
    passes = (ra_u * m_u + ra_v * m_v < 0) & (rb_u * m_u + rb_v * m_v > 0)
    cross = ra_u * m_v - ra_v * m_u
    through_cell = 4.0 * cross * cross < m2
    moved = m2 * (cell_u * cell_v) > _MIN_MOVE_PX ** 2
    return ok_p & ok_q & moved & passes & through_cell


def pack_columns(valid: jax.Array) -> jax.Array:
    """(H, W) bool -> (ceil(H / 32), W) uint32: bit b of word m in column c is ``valid[32 m + b, c]``.

    Bit b of every word is the strided row slice ``valid[b::32]``; a slice one word short (H not a multiple
    of 32) is padded by one row of zeros as uint32 (a pad of the whole (H, W) mask to 32 rows a word ran as
    a kernel of its own, ~3 % of the rig's Step 2 on its 1550-row cameras).
    """
    height, width = valid.shape
    n_words = -(-height // WORD_BITS)
    packed = jnp.zeros((n_words, width), jnp.uint32)
    if height % WORD_BITS == 0:     # whole words: rows b of each 32 as a reshape (no slice is short)
        bits = valid.reshape(n_words, WORD_BITS, width)
        for i in range(WORD_BITS):
            packed = packed | (bits[:, i, :].astype(jnp.uint32) << i)
        return packed
    for i in range(min(WORD_BITS, height)):
        bits = jax.lax.slice_in_dim(valid, i, height, WORD_BITS, axis=0).astype(jnp.uint32) << i
        packed = packed | jnp.pad(bits, ((0, n_words - bits.shape[0]), (0, 0)))
    return packed


class ExactTest(NamedTuple):
    """Everything phase 3 reads (traced arrays) and its static options."""

    depth: jax.Array          # (H, W) float32 metres; read only where ``columns`` has a bit
    points: object            # (3, H, W) float32 camera-frame x, y, z, three (H, W) channels, or None (back-projected)
    columns: jax.Array        # (ceil(H / 32), W) uint32: pixels with depth packed down the columns
    K: jax.Array
    t: jax.Array              # (3,) LiDAR origin, (3, H, W) each pixel's own, or (S, 3) with ``source`` (camera frame)
    eps: jax.Array
    k_max: jax.Array          # int32 largest |du| in S(i)
    cell_u: jax.Array
    cell_v: jax.Array
    h_max: jax.Array | None   # int32 largest |dv| of a window of a canvas (None: hh)
    count: jax.Array          # int32 number of candidates
    locate: object            # slot -> (row, column) of a candidate
    hh: int
    hw: int
    test: str
    nearer: jax.Array | None = None   # (H, W) bool: pixels removed by condition 2 alone (or None)
    source: jax.Array | None = None   # (H, W) int32: each pixel's row of ``t``, then the (S, 3) origins (or None)
    shape: tuple | None = None        # traced int32 (h, w) of a camera of :class:`Grouped` images (None: depth's)
    grouped: Grouped | None = None    # images of several size groups (:class:`Grouped`), or None


class Grouped(NamedTuple):
    """Where one camera's images sit among several size groups' (one exact-test loop for a rig's cameras,
    :mod:`~jaxdepth._src.outlier_groups`).

    With it, ``depth``, ``nearer``, ``source`` and each channel of ``points`` are tuples with one flat
    (n_g h_g w_g,) array per group (the group's cameras one after another; not copied together), ``columns``
    every camera's words flat, the camera's ((ceil(h / 32) w,)) from ``columns_at``, and ``shape`` its traced (h, w).
    """

    group: jax.Array       # int32: the camera's group
    member: jax.Array      # int32: its index within the group
    pixels: tuple          # static h_g w_g of each group
    columns_at: jax.Array  # int32: where the camera's column words start in ``columns``


def _shape(ex: ExactTest):
    """(height, width) of the image: static ints, or the camera's traced ones (:class:`Grouped`)."""
    return ex.depth.shape if ex.grouped is None else ex.shape


def _read(ex: ExactTest, image, flat):
    """``image`` at int32 flat pixel indices ``flat``: an (H, W) array's element, or (:class:`Grouped`) the
    camera's own from its group's flat array (each group read at an index of its own, 0 for the other groups'
    cameras, then the camera's value selected: no copy of the groups' images into one)."""
    if ex.grouped is None:
        return image.reshape(-1).at[flat].get(mode=_PIB)
    out = None
    for g, (array, pixels) in enumerate(zip(image, ex.grouped.pixels)):
        here = ex.grouped.group == g
        value = array.at[jnp.where(here, ex.grouped.member * pixels + flat, 0)].get(mode=_PIB)
        out = value if out is None else jnp.where(here, value, out)
    return out


def _view(ex: ExactTest, flat, row, col):
    """LiDAR view of the pixels at flat indices ``flat`` (rows ``row``, columns ``col``, int32) and their
    z (inf where empty)."""
    d = _read(ex, ex.depth, flat)
    # One element gather per channel. A stacked (3, H, W) array is read through its flat view at
    # ``flat + c H W``: slicing the channels apart first would copy each (3 passes over the image), and one
    # gather of (3, 1) slices is not vectorised by XLA:CPU (~7x the rank step's time on an Argoverse 2
    # crop; docs/speed.md, "Step 2, kernel by kernel"). Channels given apart (rigs' views): one by one.
    if isinstance(ex.points, tuple):
        p = tuple(_read(ex, channel, flat) for channel in ex.points)
    elif ex.points is not None:
        size = ex.depth.size
        p = tuple(ex.points.reshape(-1).at[flat + c * size].get(mode=_PIB) for c in range(3))
    else:
        p = None
    view_fn = lidar_view if ex.test == "footprint" else lidar_angles
    return view_fn(d, ex.K, ex.t, p, row.astype(jnp.float32), col.astype(jnp.float32)), \
        jnp.where(d > 0, d, jnp.float32(jnp.inf))


def _window_words(ex: ExactTest, row, col, start=None, block=None):
    """The column words of a block of each candidate's window columns, masked to its rows: (J, B, n) uint32,
    the J words covering rows ``row - hh .. row + hh``, with each word's first row (J, 1, n) int32, and
    the block's columns: (B, 1) offsets ``start .. start + B - 1`` and (B, n) indices. The candidates are
    the minor axis (see :func:`_column_block`). Default: the whole window, ``start = -hw``, ``B = 2 hw + 1``."""
    if ex.grouped is None:
        n_words, width = ex.columns.shape
    else:
        width, n_words = ex.shape[1], (ex.shape[0] + WORD_BITS - 1) // WORD_BITS
    start = -ex.hw if start is None else start
    block = 2 * ex.hw + 1 if block is None else block
    du = start + jnp.arange(block, dtype=jnp.int32)[:, None]
    col_q = col[None, :] + du
    in_cols = (jnp.abs(du) <= ex.k_max) & (col_q >= 0) & (col_q < width)
    col_q = jnp.clip(col_q, 0, width - 1)
    top, bottom = (row - ex.hh)[None, :], (row + ex.hh + 1)[None, :]
    first = jnp.floor_divide(top, WORD_BITS)

    def below(n):  # uint32 with the lowest n bits set, n in [0, 32]
        return jnp.where(n >= WORD_BITS, jnp.uint32(0xFFFFFFFF), (jnp.uint32(1) << n.astype(jnp.uint32)) - 1)

    # Every word at once, stacked on a leading axis (one gather, one mask: fewer kernels than a list).
    m = first[None] + jnp.arange(-(-(2 * ex.hh + 1) // WORD_BITS) + 1, dtype=jnp.int32)[:, None, None]
    bases = m * WORD_BITS
    if ex.grouped is None:
        word = ex.columns.at[jnp.clip(m, 0, n_words - 1), col_q[None]].get(mode=_PIB)
    else:           # the camera's words flat: row m of its (ceil(h / 32), w) words
        word = ex.columns.at[ex.grouped.columns_at + jnp.clip(m, 0, n_words - 1) * width + col_q[None]].get(mode=_PIB)
    keep = below(jnp.clip(bottom - bases, 0, WORD_BITS)) & ~below(jnp.clip(top - bases, 0, WORD_BITS))
    words = jnp.where(in_cols & (m >= 0) & (m < n_words), word & keep, jnp.uint32(0))
    return words, bases, du, col_q


def origins_of(table, source):
    """Each pixel's LiDAR origin from the sources' (S, 3) ``table`` and the int32 ``source`` index (any
    shape): a tuple of three float arrays of ``source``'s shape (x, y, z), one ``take`` per axis (an index
    out of range is clipped)."""
    return tuple(jnp.take(table[:, a], source, mode="clip") for a in range(3))


def _test_chunk(c, keep, *, ex: ExactTest):
    """Exact test of the candidate slots ``c CHUNK ...`` (int32 chunk index ``c``); clears the removed
    ones in ``keep``, the (H W,) bool mask."""
    width = ex.depth.shape[1]
    slot = c * CHUNK + jnp.arange(CHUNK, dtype=jnp.int32)
    row, col = ex.locate(jnp.minimum(slot, jnp.maximum(ex.count - 1, 0)))
    flat_p = row * width + col
    removed = candidates_removed(ex, row, col, flat_p)
    flat = jnp.where(slot < ex.count, flat_p, keep.shape[0])
    return keep.at[flat].set(~removed, mode="drop")


def candidates_removed(ex: ExactTest, row, col, flat_p):
    """(CHUNK,) bool: which candidates at int32 rows ``row``, columns ``col`` (flat pixel ``flat_p``) the
    paper's conditions remove (:func:`_column_block` over their window's blocks of columns)."""
    if ex.source is not None:   # each candidate's own LiDAR origin (its source's), shared by its window
        src = _read(ex, ex.source, flat_p)
        ex = ex._replace(t=jnp.stack(origins_of(ex.t, src))[:, None, :])
    elif ex.t.ndim == 3:        # each candidate's own LiDAR origin, shared by its window
        ex = ex._replace(t=ex.t.reshape(3, -1).at[:, flat_p].get(mode=_PIB)[:, None, :])
    nearer_p = None if ex.nearer is None else _read(ex, ex.nearer, flat_p)[None, :]
    view_p, z_p = _view(ex, flat_p[None, :], row[None, :], col[None, :])
    group = max(min(ex.hw, _GROUP), 0)
    block = 2 * group + 1
    n_blocks = jnp.maximum((2 * ex.k_max + block) // block, 1)       # ceil((2 k + 1) / B)
    removed = jax.lax.fori_loop(0, n_blocks, functools.partial(
        _column_block, ex=ex, row=row, col=col, view_p=view_p, z_p=z_p, nearer_p=nearer_p, group=group),
        jnp.zeros((CHUNK,), bool))
    return removed


def _column_block(b, removed, *, ex: ExactTest, row, col, view_p, z_p, nearer_p, group):
    """Conditions 1 and 2 of a chunk of candidates against the points of one block of B = 2 G + 1 window
    columns, starting at du = -k + b B (clipped to the static window: a clipped block overlaps the
    previous one, harmless), visited rank by rank; ``removed``: (CHUNK,) bool, updated.

    Every (point, candidate) array is (B, CHUNK), the candidates on the minor axis, and the hits are carried
    as such through the rank loop and reduced over the columns once after it: XLA:CPU then vectorises the
    fused pair test over the candidates (laid out (CHUNK, B), it looped over the B columns of each
    candidate in scalar code: ~8x the time per rank step on the KITTI frame; docs/speed.md, "Step 2's cost").
    """
    width = _shape(ex)[1]
    block = 2 * group + 1
    start = jnp.clip(b * block - ex.k_max, -ex.hw, ex.hw - 2 * group)
    words, bases, du, col_q = _window_words(ex, row, col, start, block)
    counts = jax.lax.population_count(words).astype(jnp.int32)
    total = functools.reduce(jnp.add, list(counts))

    def point(m, removed):
        # The m-th point (in row order) of each window column: its word, then its bit.
        word, rank, base, before = words[0], jnp.full_like(total, m), bases[0], jnp.zeros_like(total)
        for w, n, first_row in zip(words, counts, bases):
            here = (m >= before) & (m < before + n)
            word, rank = jnp.where(here, w, word), jnp.where(here, m - before, rank)
            base, before = jnp.where(here, first_row, base), before + n
        present = m < total
        row_q = base + nth_set_bit(word, jnp.where(present, rank, 0))
        flat_q = jnp.where(present, row_q * width + col_q, 0)
        if ex.points is not None:   # several gathers at flat_q: each would re-run the bit search (XLA fuses it)
            row_q, flat_q = fence(row_q, flat_q, token=m)
        view_q, z_q = _view(ex, flat_q, row_q, col_q)
        dv = row_q - row[None, :]
        flip = condition_1(ex.test, view_p, view_q, du, dv, ex.cell_u, ex.cell_v)
        if nearer_p is not None:
            flip = flip | nearer_p
        hit = present & flip & (z_p > z_q + ex.eps)
        if ex.h_max is not None:     # a window of a canvas: the image's own |dv| < h / L
            hit = hit & (jnp.abs(dv) <= ex.h_max)
        return removed | hit

    hits = jax.lax.fori_loop(0, jnp.max(total), point, jnp.zeros(total.shape, bool))
    return removed | jnp.any(hits, axis=0)


def exact_test(valid: jax.Array, ex: ExactTest) -> jax.Array:
    """Phase 3: the paper's conditions at every candidate, per chunk of :data:`CHUNK` slots.

    Returns the (H, W) bool keep mask: ``valid`` with the removed candidates cleared (``valid`` flat, as
    :class:`Grouped` cameras' (the padding past the camera's pixels never read): flat).
    """
    # Under vmap, the batch's largest chunk count for every member (a member's extra chunks test no slot):
    # a batched trip count would select the whole (B, H W) mask between old and new after every chunk.
    first, n_chunks = shared_loop_bounds(jnp.int32(0), (ex.count + CHUNK - 1) // CHUNK)
    keep = jax.lax.fori_loop(first, n_chunks, functools.partial(_test_chunk, ex=ex), valid.reshape(-1))
    return keep.reshape(valid.shape)
