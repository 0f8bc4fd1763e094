"""Step 3: nearest-seed distance transform, written as ``lax.scan``-style passes.

For every pixel ``(v, u)`` of an ``(H, W)`` seed mask this module finds the
nearest seed ``(v + dv, u + du)`` and its distance in pixels, under the
city-block (``"l1"``) or the Euclidean (``"l2"``) metric.  Both are exact (no
chamfer approximation) and separable, with one sequential loop per pass along
the leading axis of a row-major array (all other pixels vectorised):

1. *Row pass* (shared).  On the transposed mask, a forward loop over the
   columns writes the distance to the last seed on the left, and a backward
   loop folds in the seed on the right, in place.  Each value is the packed
   integer ``(h << 1) | right``: ``h`` the horizontal distance to the nearest
   seed in the same row, ``right`` set when that seed lies to the right (ties
   go to the left seed, because the integer minimum prefers ``right = 0``).
2. *Column pass*, along every column of the row-pass result:

   - ``"l1"``: ``min_r h(r, u) + |r - v|`` by a forward and a backward
     min-plus loop over the rows, in place.  The carry is one int32 key
     ``(distance << (row_bits + 1)) | (seed_row << 1) | right``: the integer
     minimum picks the smallest distance, then the smallest seed row, and the
     key alone gives ``du`` and ``dv`` (``|du| = distance - |dv|``), so no
     gather is needed.
   - ``"l2"``: ``min_r h(r, u)**2 + (r - v)**2``, the lower envelope of
     parabolas (Meijster, Roerdink and Hesselink 2000; the same 1-D problem as
     Felzenszwalb and Huttenlocher 2012) in exact int32 arithmetic.  Every
     column keeps a stack of parabolas (start row, seed row, ``right``, ``h``
     packed in one int32, or two for shapes too large for one), all columns in
     lock step.  The stack is a linked list keyed by the parabola's row
     (:func:`_l2_column_pass`): the top lives in the loop carry and row ``i``
     of an ``(H, W)`` buffer holds the entry under parabola ``i``, written in
     place when ``i`` is pushed, so a push is a contiguous row write, never a
     scatter, and a pop is one gather of W entries.  A ``fori_loop`` over the
     seeded rows pushes each row's parabola after popping the ones it hides
     (two unrolled pop attempts, then a ``while_loop`` for the rare deeper
     pops); a backward loop walks the envelope, stepping at most one entry
     down per row.  The start row uses a float32 division where that is exact.
     Under ``vmap`` the seeded-row bounds are shared by the batch
     (:func:`~jaxdepth._src.xla_tuning.shared_loop_bounds`), so the loop
     counter stays a scalar and row accesses stay row slices; the rows are
     written by :func:`~jaxdepth._src.xla_tuning.put_row` (one update of the
     batch, not a guarded scatter) and a pop reads the batch by one flat
     gather (:func:`~jaxdepth._src.xla_tuning.take_last`, no (member, index)
     pairs).  What remains is ~2 gathers per seeded row in the build and one
     per row in the walk.

The forward/backward loops are ``lax.fori_loop`` over one buffer updated in
place (the backward loop reads the forward result and overwrites it): on CPU
faster than ``lax.scan`` with stacked outputs followed by a minimum of the
two directions (benchmarks/bench_distance.py), and packing every decision into one int32
key keeps each step to a couple of fused ops. The first loop of each pass
builds its values from the narrow input row by row (the row pass from the
mask's columns, with the tricks on packed 32 to a uint32 before their transpose
(:func:`~jaxdepth._src.xla_tuning.mask_columns`); the L1 column pass from the
row keys transposed as int16, with the tricks on and on images of >= 2**20
pixels two rows' keys an int32 word (:func:`~jaxdepth._src.xla_tuning.key_rows`)),
not from a full-image pass before the loop (docs/speed.md, "The distance
transform's full-image passes", "The distance transform's transposes", "The
distance transform's int16 row keys as int32 pairs").

Oracles: ``cv2.distanceTransform(src, cv2.DIST_L1, 3)`` (OpenCV's L1 mask is
exact) and ``scipy.ndimage.distance_transform_edt``.  Both measure the distance
to the nearest *zero* pixel, so they are called on ``~seed_mask``.  Distances
agree exactly (L2: to float32 rounding of the square root); the chosen seed can
differ from their labels/indices when several seeds are equally near, see the
tie rule in :func:`nearest_seed`.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxdepth._src.config import DEFAULT_CONFIG, DISTANCE_METRICS
from jaxdepth._src.xla_tuning import (key_row, key_rows, mask_column, mask_columns, put_row, shared_loop_bounds,
                                      take_last)

_INT32_MAX = 2**31 - 1
_INT16_MAX = 2**15 - 1
_L2_MAX_SIDE = 2**15  # squared distances (H - 1)**2 + (W - 1)**2 must fit in int32
_PIB = "promise_in_bounds"
_UNROLLED_POPS = 2  # KITTI: most seeded rows pop twice in some column


class NearestSeed(NamedTuple):
    """Result of :func:`nearest_seed` for an ``(H, W)`` mask.

    Attributes:
      distance: (H, W) float32 pixels, distance to the nearest seed under the
        chosen metric (L1 or Euclidean); ``+inf`` where no seed exists.
      du: (H, W) int32, the nearest seed is at column ``u + du``.
      dv: (H, W) int32, the nearest seed is at row ``v + dv``.
      has_seed: () bool, False when the mask has no seed (then du = dv = 0).
    """

    distance: jax.Array
    du: jax.Array
    dv: jax.Array
    has_seed: jax.Array


def _bits(n: int) -> int:
    """Bits needed to store the integers 0 .. n - 1 (0 for n <= 1)."""
    return max(n - 1, 0).bit_length()


def _check(seed_mask: jax.Array, metric: str, horizontal_cost: int = 1) -> None:
    if metric not in DISTANCE_METRICS:
        raise ValueError(f"nearest_seed: field 'metric' expected one of {DISTANCE_METRICS}, got {metric!r}")
    if isinstance(horizontal_cost, bool) or int(horizontal_cost) != horizontal_cost or horizontal_cost < 1 \
            or (metric != "l1" and horizontal_cost != 1):
        raise ValueError(f"nearest_seed: field 'horizontal_cost' expected an integer >= 1 (1 unless metric "
                         f"'l1'), got {horizontal_cost!r} with metric {metric!r}")
    if seed_mask.ndim != 2:
        raise ValueError(
            f"nearest_seed: field 'seed_mask' expected shape (H, W), got shape {tuple(seed_mask.shape)}")
    if seed_mask.dtype != jnp.bool_:
        raise ValueError(f"nearest_seed: field 'seed_mask' expected dtype bool, got {seed_mask.dtype}")
    h, w = seed_mask.shape
    if h < 1 or w < 1:
        raise ValueError(f"nearest_seed: field 'seed_mask' expected H >= 1 and W >= 1, got shape {(h, w)}")
    if metric == "l1":
        cb = _bits(h) + 1
        c = int(horizontal_cost)
        if (c * (h + w) + h + 1) << cb > _INT32_MAX:
            raise ValueError(
                f"nearest_seed: seed_mask shape {(h, w)} too large for metric 'l1' (horizontal_cost {c}): the "
                f"packed key needs (c (H + W) + H + 1) * 2**{cb} <= 2**31 - 1, got {(c * (h + w) + h + 1) << cb}")
    elif h > _L2_MAX_SIDE or w > _L2_MAX_SIDE:
        raise ValueError(
            f"nearest_seed: seed_mask shape {(h, w)} too large for metric 'l2': expected "
            f"H <= {_L2_MAX_SIDE} and W <= {_L2_MAX_SIDE} (int32 squared distances)")


def _sweep(buf: jax.Array, init: jax.Array, step, *, reverse: bool = False,
           source: jax.Array | None = None, read=None, unroll: int = 1) -> jax.Array:
    """``buf`` with row i replaced by ``carry = step(i, source[i], carry)``, rows in order (or reversed), in place.

    Args:
      buf: (N, ...) array, written row by row; init: the first carry, ``buf[0]``'s shape and dtype; step:
        elementwise ``(i, row, carry) -> carry`` (``i`` the int32 row index); source: (N, ...) array read row
        by row, any dtype (default ``buf`` itself); read: ``(source, i) -> row`` (default: row ``i`` of
        ``source``); unroll: ``lax.fori_loop``'s (more than 1 made XLA:CPU copy ``buf`` every iteration:
        docs/speed.md, "The seed search's loops, the capped tail's gather and the L2 pass under vmap").

    XLA:CPU runs each scalar op of a loop step as a kernel of its own, and a sweep has N steps: the row
    read and write skip ``lax``'s negative-index wrap (a compare and select per index; every index here
    is in range), which cut the L1 transform's CPU by ~10 % on the KITTI frame (docs/speed.md, "One frame").
    A ``source`` apart from ``buf`` lets the first sweep of a pass read its input in the narrow dtype and
    build each row's value inside the loop: ``buf`` is then only written, and the full-image pass that
    would build it (an elementwise fusion, then XLA:CPU's transposing copy of its result) is gone
    (docs/speed.md, "The distance transform's full-image passes").
    """
    n = buf.shape[0]

    def body(j, state):
        carry, buf = state
        i = n - 1 - j if reverse else j
        if read is None:
            row = lax.dynamic_index_in_dim(buf if source is None else source, i, 0, keepdims=False,
                                           allow_negative_indices=False)
        else:
            row = read(source, i)
        carry = step(i, row, carry)
        return carry, put_row(buf, carry, i)

    return lax.fori_loop(0, n, body, (init, buf), unroll=unroll)[1]


def _row_pass(seed_mask: jax.Array) -> jax.Array:
    """Nearest seed within each row.

    Args:
      seed_mask: (H, W) bool.

    Returns:
      (W, H) int16 or int32 (the transposed layout), ``(h << 1) | right`` with
      ``h`` the distance from ``(v, u)`` to the nearest seed in row ``v``
      (``>= H + W`` when the row has none) and ``right`` set when that seed is
      at a larger column (ties: the smaller column).
    """
    h, w = seed_mask.shape
    far = h + w
    dtype = jnp.int16 if 2 * (far + w) + 1 <= _INT16_MAX else jnp.int32
    init = jnp.full((h,), 2 * far, dtype)
    no_seed = jnp.asarray(2 * (far + w) + 1, dtype)
    # Forward, on the mask's columns (xla_tuning.mask_columns: 32 columns' bits a uint32, so the transposing
    # copy moves 1/32 of the elements; plain: the transposed bool mask), into a fresh buffer: 0 at a seed, else
    # the carry + 2; the carry never exceeds 2 (far + w), so a seed's 0 and a non-seed's
    # 2 (far + w) + 1 under a minimum give exactly that.
    buf = _sweep(jnp.zeros((w, h), dtype), init,
                 lambda i, row, carry: jnp.minimum(jnp.where(row, jnp.zeros((), dtype), no_seed), carry + 2),
                 source=mask_columns(seed_mask), read=mask_column)
    # Backward: moving one column left from the seed of column i + 1 puts it on the right; a left
    # seed of column i + 1 can never win here.
    return _sweep(buf, init, lambda i, row, carry: jnp.minimum(row, (carry + 2) | 1), reverse=True)


def _l1_column_pass(row_key_t: jax.Array, far: int, horizontal_cost: int = 1) -> tuple[jax.Array, int]:
    """Exact 1-D L1 transform along every column of the row-pass result.

    Args:
      row_key_t: (W, H) row-pass result.
      far: ``horizontal_cost * (H + W)``, larger than any finite distance.
      horizontal_cost: static int, the cost of one column of ``|du|`` (one row of ``|dv|`` costs 1).

    Returns:
      (key, cb): key (H, W) int32 ``(distance << cb) | (seed_row << 1) | right``
      (distance ``horizontal_cost |du| + |dv|``) and the static shift ``cb``;
      ``distance >= far`` only for an empty mask.
    """
    w, h = row_key_t.shape
    cb = _bits(h) + 1
    step = 1 << cb
    init = jnp.full((w,), far << cb, jnp.int32)

    def forward(i, hk, carry):
        # Row i's keys built inside the loop from the row keys transposed in their narrow dtype (widened by
        # key_row; xla_tuning.key_rows: on large images two int16 rows a word, transposed as int32).
        g = hk >> 1 if horizontal_cost == 1 else horizontal_cost * (hk >> 1)
        return jnp.minimum((jnp.minimum(g, far) << cb) | (i << 1) | (hk & 1), carry + step)

    key = _sweep(jnp.zeros((h, w), jnp.int32), init, forward, source=key_rows(row_key_t),
                 read=functools.partial(key_row, h=h))
    key = _sweep(key, init, lambda i, row, carry: jnp.minimum(row, carry + step), reverse=True)
    return key, cb


def _stack_layout(h: int, w: int):
    """Static packing of a stack entry (start row t, seed row s, right, g).

    Returns (n_arrays, pack, unpack): one int32 per entry when
    ``2 * row_bits + 1 + col_bits <= 31`` (e.g. 352 x 1216), else two.
    """
    rb = max(_bits(h), 1)
    gb = max(_bits(w), 1)
    if 2 * rb + 1 + gb <= 31:
        def pack(t, s, right, g):
            return ((((t << rb) | s) << 1 | right) << gb) | g,

        def unpack(entry):
            (e,) = entry
            g = e & ((1 << gb) - 1)
            e = e >> gb
            return e >> (rb + 1), (e >> 1) & ((1 << rb) - 1), e & 1, g

        return 1, pack, unpack

    def pack2(t, s, right, g):
        return ((t << rb) | s) << 1 | right, g

    def unpack2(entry):
        e, g = entry
        return e >> (rb + 1), (e >> 1) & ((1 << rb) - 1), e & 1, g

    return 2, pack2, unpack2


def _floor_div_exact_f32(h: int, w: int) -> bool:
    """float32 ``floor(num / den)`` is exact when ``num + den < 2**24`` for every step.

    ``num <= (H - 1)**2 + (W - 1)**2`` and ``den <= 2 (H - 1)``: both operands
    are exact in float32 and the correctly rounded quotient of ``k + f``
    (``1/den <= f < 1``) cannot reach ``k + 1`` because its rounding error is
    below ``(k + 1) 2**-24 <= (num + den) 2**-24 / den < 1 / den``.
    """
    return (h - 1) ** 2 + (w - 1) ** 2 + 2 * h < 2**24


def _l2_column_pass(row_key_t: jax.Array, far: int):
    """Exact 1-D squared-Euclidean transform along every column (Meijster, linked stack).

    Meijster's algorithm on ``f_s(v) = g(s)**2 + (v - s)**2`` for the rows s
    that have a seed, in exact int32 arithmetic, all columns vectorised. The
    stack is a linked list keyed by the parabola's row so that no step scatters:

    - ``top``: the packed stack top (start row t, seed row s, right, g) per
      column, one or two (W,) int32 arrays (:func:`_stack_layout`), the first
      -1 for an empty stack;
    - ``below``: (H, W) int32 array(s) alike; row ``i`` holds the entry that was
      under parabola ``i`` when it was pushed. Step ``i`` writes row ``i`` in
      place (a contiguous ``dynamic_update_slice``), so pushing costs no
      scatter; a pop reads ``below[s(top), u]`` (one gather over the W columns).

    The row-pass keys are transposed in their narrow dtype (int16 for
    KITTI-sized images) and widened one row per step, which halves the
    transpose's memory traffic.

    Build: a ``fori_loop`` from the first to the last seeded row (runtime
    bounds; seedless rows push nothing); two pop attempts are unrolled (on
    KITTI most seeded rows pop twice in some column, and a gather is cheaper
    than one more ``while_loop`` round) and a ``while_loop`` pops the rest
    (the top loses when it is not below parabola i at its own start row t;
    equal values keep the smaller row), then the new parabola is pushed with
    the first row where it is strictly lower (a float32 division when exact,
    see :func:`_floor_div_exact_f32`). Walk: a backward ``fori_loop`` from the
    last row, following ``below`` once whenever the current entry starts after
    the row (starts strictly increase along the stack, so one step back per row
    suffices).

    Args:
      row_key_t: (W, H) row-pass result ``(g << 1) | right``; rows with
        ``g >= far`` have no seed and are skipped.
      far: ``H + W``.

    Returns:
      (seed_row, g, right, has_seed): (H, W) int32 each, the row of the lowest
      parabola at every pixel (ties: the smaller row), its horizontal distance
      ``g`` and right flag (unspecified when the mask is empty); has_seed ()
      bool.
    """
    w, h = row_key_t.shape
    rb = max(_bits(h), 1)
    n_arrays, pack, unpack = _stack_layout(h, w)
    use_f32 = _floor_div_exact_f32(h, w)
    hk = row_key_t.T  # (H, W) in the row pass's dtype; widened per row
    col = jnp.arange(w, dtype=jnp.int32)

    def follow(below, entry):
        # Entry under ``entry`` (garbage where it is empty; callers select it away).
        at = unpack(entry)[1] * w + col
        return tuple(take_last(b.reshape(-1), at) for b in below)

    def select(pred, a, b):
        return tuple(jnp.where(pred, x, y) for x, y in zip(a, b))

    def build(i, state):
        top, below = state
        x = hk[i].astype(jnp.int32)
        g = x >> 1
        valid = g < far
        g2 = g * g

        def loses(top):
            t, s, _, g_s = unpack(top)
            return valid & (top[0] >= 0) & ((t - s) ** 2 + g_s * g_s > (t - i) ** 2 + g2)

        def pop(top):
            return select(loses(top), follow(below, top), top)

        for _ in range(_UNROLLED_POPS):
            top = pop(top)
        top = lax.while_loop(lambda top: jnp.any(loses(top)), pop, top)
        nonempty = top[0] >= 0
        _, s, _, g_s = unpack(top)
        num = jnp.maximum(i * i - s * s + g2 - g_s * g_s, 0)
        den = 2 * jnp.maximum(i - s, 1)
        if use_f32:
            quot = jnp.floor(num.astype(jnp.float32) / den.astype(jnp.float32)).astype(jnp.int32)
        else:
            quot = lax.div(num, den)
        start = 1 + quot
        push = valid & (~nonempty | (start < h))
        below = tuple(put_row(b, e, i, wrap=True) for b, e in zip(below, top))
        new = pack(jnp.where(nonempty, start, 0), jnp.broadcast_to(i, (w,)), x & 1, g)
        return select(push, new, top), below

    # Rows without any seed push nothing: the build runs from the first to the
    # last seeded row only (runtime bounds; ``below`` rows outside are never read).
    seeded = row_key_t[0] < (far << 1)
    first = jnp.argmax(seeded).astype(jnp.int32)
    stop = jnp.where(jnp.any(seeded), h - jnp.argmax(seeded[::-1]).astype(jnp.int32), 0)
    # XLA:CPU: under vmap the batch shares the widest bounds, so row accesses stay row slices.
    first, stop = shared_loop_bounds(first, stop)
    empty = (jnp.full((w,), -1, jnp.int32),) + tuple(jnp.zeros((w,), jnp.int32) for _ in range(n_arrays - 1))
    zeros = tuple(jnp.zeros((h, w), jnp.int32) for _ in range(n_arrays))
    top, below = lax.fori_loop(first, stop, build, (empty, zeros))

    def walk(k, state):
        current, out = state
        v = h - 1 - k
        current = select(unpack(current)[0] > v, follow(below, current), current)
        _, s, right, g = unpack(current)
        # Fits in int32: g < W <= 2**15 and s < 2**rb <= 2**15.
        return current, put_row(out, (g << (rb + 1)) | (s << 1) | right, v, wrap=True)

    _, packed = lax.fori_loop(0, h, walk, (top, jnp.zeros((h, w), jnp.int32)))
    return (packed >> 1) & ((1 << rb) - 1), packed >> (rb + 1), packed & 1, top[0][0] >= 0


@functools.partial(jax.jit, static_argnames=("metric", "horizontal_cost"))
def nearest_seed(seed_mask: jax.Array, *, metric: str = DEFAULT_CONFIG.distance_metric,
                 horizontal_cost: int = DEFAULT_CONFIG.seed_horizontal_cost) -> NearestSeed:
    """Nearest seed and its distance for every pixel (exact distance transform).

    Args:
      seed_mask: (H, W) bool, True at seed pixels.  Any H, W >= 1.
      metric: static; ``"l1"`` (city block, ``|du| + |dv|``) or ``"l2"``
        (Euclidean, ``sqrt(du**2 + dv**2)``).  Both are exact.  Default:
        ``SGMConfig().distance_metric`` (``"l1"``).
      horizontal_cost: static int >= 1, ``"l1"`` only: the seed minimises
        ``horizontal_cost |du| + |dv|`` (``SGMConfig.seed_horizontal_cost``; 1 = city
        block). ``distance`` is then that weighted cost.

    Returns:
      :class:`NearestSeed`: ``distance`` (H, W) float32 pixels; ``du``, ``dv``
      (H, W) int32 offsets to the chosen seed ``(v + dv, u + du)``, which is
      always a seed at exactly ``distance``; ``has_seed`` () bool.  A seed is
      its own nearest seed (0, 0, 0).  With no seed at all, ``distance`` is
      ``+inf`` and ``du = dv = 0``.

    Tie rule: among all seeds at the minimal distance, the first in raster
    order wins: the smallest seed row ``v + dv``, then the smallest seed column
    ``u + du``.  OpenCV's labels and SciPy's indices may name another of the
    equally near seeds; compare distances, not indices.

    Oracles: ``"l1"`` equals ``cv2.distanceTransform((~seed_mask).astype(np.uint8),
    cv2.DIST_L1, 3)``; ``"l2"`` equals
    ``scipy.ndimage.distance_transform_edt(~seed_mask)`` up to float32 rounding.
    For an empty mask OpenCV and SciPy return large finite values; this returns
    ``+inf``.

    Raises:
      ValueError (at trace time): a metric other than ``"l1"``/``"l2"``, a mask
      that is not 2-D bool with H, W >= 1, a ``horizontal_cost`` that is not an
      integer >= 1 (or not 1 with ``"l2"``), or a shape too large for the int32
      keys: ``"l1"`` needs ``(c (H + W) + H + 1) * 2**(ceil(log2 H) + 1) < 2**31``
      with c = ``horizontal_cost`` (e.g. 8192 x 8192 fits at c = 1), ``"l2"``
      needs ``H, W <= 32768``.

    Examples:
      Two seeds in a row of four pixels; each empty pixel points at the nearer one:

      >>> import jax.numpy as jnp
      >>> from jaxdepth._src.distance import nearest_seed
      >>> seeds = nearest_seed(jnp.array([[True, False, False, True]]))
      >>> seeds.distance
      Array([[0., 1., 1., 0.]], dtype=float32)
      >>> seeds.du
      Array([[ 0, -1,  1,  0]], dtype=int32)
    """
    _check(seed_mask, metric, horizontal_cost)
    h, w = seed_mask.shape
    far = h + w
    row_key_t = _row_pass(seed_mask)
    v = jnp.arange(h, dtype=jnp.int32)[:, None]
    if metric == "l1":
        key, cb = _l1_column_pass(row_key_t, horizontal_cost * far, horizontal_cost)
        has_seed = key[0, 0] < ((horizontal_cost * far) << cb)
        dist = key >> cb
        dv = ((key >> 1) & ((1 << (cb - 1)) - 1)) - v
        abs_du = dist - jnp.abs(dv)
        if horizontal_cost != 1:
            abs_du = abs_du // horizontal_cost
        du = jnp.where((key & 1) == 1, abs_du, -abs_du)
        distance = dist.astype(jnp.float32)
    else:
        seed_row, g, right, has_seed = _l2_column_pass(row_key_t, far)
        dv = seed_row - v
        du = jnp.where(right == 1, g, -g)
        distance = jnp.sqrt((du * du + dv * dv).astype(jnp.float32))
    du = jnp.where(has_seed, du, 0)
    dv = jnp.where(has_seed, dv, 0)
    distance = jnp.where(has_seed, distance, jnp.inf)
    return NearestSeed(distance=distance, du=du, dv=dv, has_seed=has_seed)


@jax.jit
def gather_at_seed(field: jax.Array, du: jax.Array, dv: jax.Array) -> jax.Array:
    """Reads ``field`` at every pixel's seed: ``out[..., v, u] = field[..., v + dv, u + du]``.

    Args:
      field: (H, W) or (C, H, W) array of any dtype (seed depth, normals, ...).
      du, dv: (H, W) integer offsets, e.g. from :func:`nearest_seed`.
        ``(v + dv, u + du)`` must lie inside the image, which nearest_seed's
        output always does; out-of-range targets are not checked (XLA clamps
        the flat index).

    Returns:
      Array with ``field``'s shape and dtype, equal to NumPy's
      ``field[..., v + dv, u + du]`` with ``v, u`` the pixel grids.

    Examples:
      Spread two seed depths to their nearest pixels:

      >>> import jax.numpy as jnp
      >>> from jaxdepth._src.distance import gather_at_seed, nearest_seed
      >>> depth = jnp.array([[5.0, 0.0, 0.0, 7.0]])
      >>> seeds = nearest_seed(depth > 0)
      >>> gather_at_seed(depth, seeds.du, seeds.dv)
      Array([[5., 5., 7., 7.]], dtype=float32)
    """
    if field.ndim not in (2, 3):
        raise ValueError(
            f"gather_at_seed: field expected shape (H, W) or (C, H, W), got {tuple(field.shape)}")
    h, w = field.shape[-2:]
    for name, offset in (("du", du), ("dv", dv)):
        if offset.shape != (h, w):
            raise ValueError(
                f"gather_at_seed: {name} expected shape {(h, w)}, got {tuple(offset.shape)}")
    flat = field.reshape(field.shape[:-2] + (h * w,))
    return flat.at[..., seed_index(du, dv)].get(mode=_PIB)


def seed_index(du: jax.Array, dv: jax.Array) -> jax.Array:
    """(H, W) int32 flat index ``(v + dv) W + (u + du)`` of every pixel's seed (``du``, ``dv``: (H, W) integer
    offsets as :func:`gather_at_seed` takes them); :func:`seed_offsets` inverts it."""
    h, w = du.shape
    v = jnp.arange(h, dtype=jnp.int32)[:, None]
    u = jnp.arange(w, dtype=jnp.int32)[None, :]
    return (v + dv.astype(jnp.int32)) * w + (u + du.astype(jnp.int32))


def seed_offsets(index: jax.Array) -> jax.Array:
    """``(du, dv)`` (H, W) int32 of a flat seed index of :func:`seed_index`; exact (the index is >= 0)."""
    h, w = index.shape
    v = jnp.arange(h, dtype=jnp.int32)[:, None]
    u = jnp.arange(w, dtype=jnp.int32)[None, :]
    return jax.lax.rem(index, jnp.int32(w)) - u, jax.lax.div(index, jnp.int32(w)) - v
