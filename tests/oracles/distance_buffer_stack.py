"""FROZEN ORACLE: the l2 column pass with a buffer stack, superseded by the linked stack.

``_l2_column_pass`` as it was in jaxdepth/_src/distance.py, where it served shapes whose stack
entries need two int32; the linked-stack pass now serves every shape.
tests/test_distance.py checks that the linked pass makes the same decisions (bit-identical seed
rows, horizontal distances and right flags). Do not edit.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from jaxdepth._src.distance import _PIB, _bits, _stack_layout


def _l2_column_pass(row_key_t: jax.Array, far: int):
    """Exact 1-D squared-Euclidean transform along every column (lower envelope).

    Meijster's algorithm on ``f_r(v) = g(r)**2 + (v - r)**2`` for the rows r
    that have a seed, in exact int32 arithmetic, all columns vectorised: a
    ``lax.scan`` over the rows; at each row an inner ``lax.while_loop`` pops,
    in every column at once, stack tops that lose to the new parabola at their
    start row, then the new parabola is pushed with the first row where it is
    strictly lower.  The stack top is kept in the carry, the entries below it
    in a flat ``(H + 1) * W`` buffer (slot row H is a sink for columns that do
    not push).  A second scan walks each column's envelope segments.

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
    hk = row_key_t.T.astype(jnp.int32)
    col = jnp.arange(w, dtype=jnp.int32)
    sink = h * w + col

    def loses(top, i, g):
        # The top parabola is not below parabola i at the top's start row t:
        # it can never be lowest again (equal values keep the smaller row).
        t, s, _, g_s = unpack(top)
        return (t - s) ** 2 + g_s * g_s > (t - i) ** 2 + g * g

    def row_step(state, xs):
        n, top, buf = state
        i, x = xs
        g = x >> 1
        valid = g < far

        def pop_body(inner):
            pop, n, top = inner
            at = jnp.maximum(n - 2, 0) * w + col
            below = tuple(b.at[at].get(mode=_PIB) for b in buf)
            top = tuple(jnp.where(pop, b, c) for b, c in zip(below, top))
            n = jnp.where(pop, n - 1, n)
            return pop & (n > 0) & loses(top, i, g), n, top

        pop = valid & (n > 0) & loses(top, i, g)
        _, n, top = lax.while_loop(lambda inner: jnp.any(inner[0]), pop_body, (pop, n, top))
        _, s, _, g_s = unpack(top)
        nonempty = n > 0
        # First row where parabola i is strictly below the top one; i > s and,
        # after the pops, the numerator is >= 0, so truncation is floor.
        num = jnp.maximum(i * i - s * s + g * g - g_s * g_s, 0)
        start = 1 + lax.div(num, 2 * jnp.maximum(i - s, 1))
        push = valid & (~nonempty | (start < h))
        at = jnp.where(push & nonempty, (n - 1) * w + col, sink)
        buf = tuple(b.at[at].set(c, mode=_PIB, unique_indices=True) for b, c in zip(buf, top))
        new = pack(jnp.where(nonempty, start, 0), jnp.broadcast_to(i, (w,)), x & 1, g)
        top = tuple(jnp.where(push, a, c) for a, c in zip(new, top))
        n = jnp.where(push, n + 1, n)
        return (n, top, buf), None

    zero = jnp.zeros((w,), jnp.int32)
    buf0 = tuple(jnp.zeros(((h + 1) * w,), jnp.int32) for _ in range(n_arrays))
    (n, top, buf), _ = lax.scan(row_step, (zero, (zero,) * n_arrays, buf0),
                                (jnp.arange(h, dtype=jnp.int32), hk))

    def entry(k):
        at = jnp.minimum(k, h) * w + col
        is_top = k == n - 1
        return tuple(jnp.where(is_top, c, b.at[at].get(mode=_PIB)) for c, b in zip(top, buf))

    def walk(carry, v):
        k, current = carry
        following = entry(k + 1)
        advance = (k + 1 < n) & (unpack(following)[0] == v)
        k = jnp.where(advance, k + 1, k)
        current = tuple(jnp.where(advance, a, c) for a, c in zip(following, current))
        _, s, right, g = unpack(current)
        # Fits in int32: g < W <= 2**15 and s < 2**rb <= 2**15.
        return (k, current), (g << (rb + 1)) | (s << 1) | right

    _, packed = lax.scan(walk, (zero, entry(zero)), jnp.arange(h, dtype=jnp.int32))
    return (packed >> 1) & ((1 << rb) - 1), packed >> (rb + 1), packed & 1, n[0] > 0
