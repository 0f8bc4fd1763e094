"""Listing the True entries of a mask without ``nonzero``: bit-packed compaction.

Under jit a mask's True entries can only be listed into a static number of
slots. ``jnp.nonzero(size=...)`` does it with a scatter over every entry, and
XLA:CPU scatters and gathers cost ~2-5 ns per element while elementwise work
costs far less, so here the mask is packed into 32-bit words
(:func:`pack_bits`), the words' population counts are prefix-summed
(:func:`inclusive_prefix`, exact small matrix products), and each output slot
finds its word from those sums and then its bit inside the word
(:func:`nth_set_bit`, a 5-step binary search on population counts).

Two forms share these pieces:

* :func:`compact_indices` lists the first ``capacity`` True entries at once
  (the image-plane normals list the pixels with depth);
* :func:`word_locator` finds the entry of any slot on demand, by a binary
  search over the words' prefix sums (the outlier test visits its candidates
  chunk by chunk, their number unbounded).

Both list entries in increasing (raster) order; the results are integers, so
they are exact.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.xla_tuning import fence, stage

#: Bits per word of a packed mask (one uint32), also the group size of :func:`inclusive_prefix`.
WORD_BITS = 32


def pack_bits(mask: jax.Array) -> jax.Array:
    """Packs a bool mask into uint32 words along its last axis.

    Args:
      mask: (..., n) bool.

    Returns:
      (..., ceil(n / 32)) uint32: bit i of word m is ``mask[..., 32 m + i]``
      (the last word is padded with zeros). An OR of 32 strided slices (one
      loop fusion, faster on XLA:CPU than a sum over a minor axis of 32).

    Examples:
      >>> import numpy as np
      >>> pack_bits(np.array([True, False, True] + [False] * 30)).tolist()
      [5, 0]
    """
    mask = jnp.asarray(mask)
    n = mask.shape[-1]
    words = -(-n // WORD_BITS)
    bits = jnp.pad(mask, [(0, 0)] * (mask.ndim - 1) + [(0, words * WORD_BITS - n)])
    packed = jnp.zeros(mask.shape[:-1] + (words,), jnp.uint32)
    for i in range(WORD_BITS):
        strided = jax.lax.slice_in_dim(bits, i, words * WORD_BITS, WORD_BITS, axis=mask.ndim - 1)
        packed = packed | (strided.astype(jnp.uint32) << i)
    return packed


def _upper_ones(n: int):
    return jnp.asarray(np.triu(np.ones((n, n), np.float32)))


def inclusive_prefix(x: jax.Array) -> jax.Array:
    """Inclusive prefix sum of a (n,) float32 array of non-negative integers whose total is below 2^24.

    Written as small matrix products with a triangular matrix of ones (groups of
    32, recursively over the group totals): exact in float32 for such
    integers, and far faster on XLA:CPU than ``cumsum`` (a reduce-window).

    Examples:
      >>> import numpy as np
      >>> inclusive_prefix(np.arange(40, dtype=np.float32))[-3:].tolist()
      [703.0, 741.0, 780.0]
    """
    n = x.shape[0]
    if n <= WORD_BITS:
        return x @ _upper_ones(n)
    groups = -(-n // WORD_BITS)
    within = jnp.pad(x, (0, groups * WORD_BITS - n)).reshape(groups, WORD_BITS) @ _upper_ones(WORD_BITS)
    totals = within[:, -1]
    return (within + (inclusive_prefix(totals) - totals)[:, None]).reshape(-1)[:n]


def nth_set_bit(word: jax.Array, rank: jax.Array) -> jax.Array:
    """Position of the ``rank``-th set bit (0-based, from the least significant) of each word.

    Args:
      word: uint32 words, any shape.
      rank: int32 of the same shape, in ``[0, popcount(word))``.

    Returns:
      int32 bit positions in [0, 31] (a 5-step binary search on the population
      counts of the lower 16, 8, 4, 2, 1 bits).

    Examples:
      >>> import numpy as np
      >>> int(nth_set_bit(np.uint32(0b101100), np.int32(2)))
      5
    """
    m = jnp.asarray(word)
    rank = jnp.asarray(rank)
    bit = jnp.zeros_like(rank)
    for w in (16, 8, 4, 2, 1):
        low = m & jnp.uint32((1 << w) - 1)
        pc = jax.lax.population_count(low).astype(jnp.int32)
        up = rank >= pc
        rank = jnp.where(up, rank - pc, rank)
        m = jnp.where(up, m >> w, low)
        bit = bit + jnp.where(up, w, 0)
    return bit


def compact_indices(valid: jax.Array, capacity: int, token):
    """Flat indices of the first ``capacity`` True entries of ``valid`` (increasing), and their count.

    Args:
      valid: (n,) bool, n < 2^24.
      capacity: static number of output slots.
      token: traced int32 scalar that fences the stages (:func:`~jaxdepth._src.staging.stage`).

    Returns:
      ``(pix, total)``: (capacity,) int32 indices of the True entries in order,
      ``n`` in the slots at or after ``total``; int32 number of True entries
      (may exceed ``capacity``: then only the first ``capacity`` are listed).

    Each output slot m finds its word as the number of words whose inclusive
    prefix is <= m (a scatter-add of a 1 per word at its prefix, then a prefix
    sum: a scatter over the words, not the entries), then its bit by
    :func:`nth_set_bit`.
    """
    n = valid.shape[0]
    # The words as a buffer: unfenced, XLA:CPU packed the mask twice, in the population counts' fusion and
    # again in the (start, word) pairs' (compact_indices alone 0.69x CPU; docs/speed.md, "A fair frame bench").
    mask, = fence(pack_bits(valid), token=token)
    words = mask.shape[0]
    count = jax.lax.population_count(mask).astype(jnp.int32)
    incl = inclusive_prefix(count.astype(jnp.float32)).astype(jnp.int32)
    hits = jnp.zeros((capacity,), jnp.float32).at[incl].add(1.0, mode="drop")
    word = jnp.minimum(inclusive_prefix(hits).astype(jnp.int32), words - 1)
    packed = jnp.stack([incl - count, jax.lax.bitcast_convert_type(mask, jnp.int32)], axis=1)
    # Materialised before the gather (fused, the gather would re-run the prefix sums).
    word, packed, total = stage(lambda *a: a, (word, packed, incl[-1]), token)
    start_mask = stage(lambda p, w: (p.at[w].get(mode="promise_in_bounds"),), (packed, word), token)[0]
    slot = jnp.arange(capacity, dtype=jnp.int32)
    bit = nth_set_bit(jax.lax.bitcast_convert_type(start_mask[:, 1], jnp.uint32), slot - start_mask[:, 0])
    return jnp.where(slot < total, word * WORD_BITS + bit, n), total


def word_locator(words: jax.Array, *, runs: int = 1):
    """Slots for the set bits of packed words, found on demand.

    Args:
      words: (..., m) uint32 packed masks (:func:`pack_bits`), read in raster order.
      runs: static; the flat words as this many runs of equal length (e.g. several images' words one
        after another): past 2^24 bits in all, the prefix sums run per run in float32 when each run's
        bits are fewer, plus the runs' offsets (``cumsum`` of the words was ~6x slower on XLA:CPU).

    Returns:
      ``(count, locate)``: int32 number of set bits, and ``locate(slot)``
      mapping int32 slots in ``[0, count)`` (any shape) to the flat bit index
      ``32 w + b`` of the slot-th set bit (word w of the flattened words, bit b).
      ``locate`` finds the word by a binary search over the words' inclusive
      prefix sums of population counts, then the bit by :func:`nth_set_bit`.
    """
    words = words.reshape(-1)
    popc = jax.lax.population_count(words).astype(jnp.int32)
    if popc.shape[0] * WORD_BITS < 2 ** 24:  # exact in float32
        word_end = inclusive_prefix(popc.astype(jnp.float32)).astype(jnp.int32)
    elif runs > 1 and popc.shape[0] // runs * WORD_BITS < 2 ** 24:
        ends = jax.vmap(inclusive_prefix)(popc.reshape(runs, -1).astype(jnp.float32)).astype(jnp.int32)
        word_end = (ends + (jnp.cumsum(ends[:, -1]) - ends[:, -1])[:, None]).reshape(-1)
    else:
        word_end = jnp.cumsum(popc)
    n_words = word_end.shape[0]
    count = word_end[-1]

    def locate(slot):
        get = lambda a, i: a.at[i].get(mode="promise_in_bounds")
        top = n_words.bit_length() - 1

        def halve(i, pos):  # one step of the search, step 2^(top - i): one small loop body to compile
            nxt = pos + (jnp.int32(1) << (top - i))
            ok = (nxt <= n_words) & (get(word_end, jnp.minimum(nxt, n_words) - 1) <= slot)
            return jnp.where(ok, nxt, pos)

        # pos: number of words ending at or before slot
        pos = jax.lax.fori_loop(0, top + 1, halve, jnp.zeros_like(slot))
        w = jnp.minimum(pos, n_words - 1)
        rank = slot - get(word_end, w) + get(popc, w)  # wanted set bit, 0-based
        return w * WORD_BITS + nth_set_bit(get(words, w), rank)

    return count, locate
