"""Step 2's exact test walks each candidate's window through column-packed bits: the packing and the
walk against NumPy brute force (every pixel with depth in the window, nothing else), window heights
across word boundaries, half widths from 0 to the cap, candidates at the image's borders. The whole
test (conditions 1 and 2) is checked against the paper's double loops in tests/test_outliers.py."""

from __future__ import annotations

import functools

import hypothesis
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.compaction import nth_set_bit
from jaxdepth._src.outlier_exact import ExactTest, _window_words, pack_columns

SETTINGS = dict(deadline=None, max_examples=10, derandomize=True,
                suppress_health_check=[hypothesis.HealthCheck.too_slow])


def _pack_columns_numpy(valid):
    height, width = valid.shape
    words = np.zeros((-(-height // 32), width), np.uint64)
    for r, c in zip(*np.nonzero(valid)):
        words[r // 32, c] |= np.uint64(1) << np.uint64(r % 32)
    return words.astype(np.uint32)


@hypothesis.settings(**SETTINGS)
@hypothesis.given(seed=st.integers(0, 2**31 - 1), height=st.sampled_from([1, 31, 32, 33, 70]),
                  density=st.sampled_from([0.0, 0.05, 0.5, 1.0]))
def test_pack_columns_matches_numpy(seed, height, density):
    valid = np.random.default_rng(seed).random((height, 7)) < density
    want = _pack_columns_numpy(valid)
    np.testing.assert_array_equal(np.asarray(pack_columns(jnp.asarray(valid))), want)
    np.testing.assert_array_equal(np.asarray(jax.jit(pack_columns)(jnp.asarray(valid))), want)


@functools.partial(jax.jit, static_argnames=("hh", "hw"))
def _window_words_jit(valid, row, col, k_max, *, hh, hw):
    """``_window_words`` of a footprint ExactTest on ``valid``, and each word's set bits: one compiled program
    per (shape, hh, hw) (called plainly, every primitive of each new window shape compiles op by op)."""
    ex = ExactTest(jnp.zeros(valid.shape), None, pack_columns(valid), jnp.eye(3), jnp.zeros(3),
                   jnp.float32(1.0), k_max, jnp.float32(1.0), jnp.float32(1.0), None,
                   jnp.int32(row.shape[0]), None, hh=hh, hw=hw, test="footprint")
    words, bases, du, col_q = _window_words(ex, row, col)
    return words, bases, col_q, [jax.lax.population_count(w) for w in words]


_nth_set_bit = jax.jit(nth_set_bit)


def _walk(valid, row, col, *, hh, hw, k_max):
    """{(candidate, row_q, col_q)} visited by the rank loop of the exact test (all ranks at once)."""
    words, bases, col_q, counts = _window_words_jit(jnp.asarray(valid), jnp.asarray(row, jnp.int32),
                                                    jnp.asarray(col, jnp.int32), jnp.int32(k_max), hh=hh, hw=hw)
    counts = [np.asarray(n) for n in counts]
    words, bases, col_q = [np.asarray(w) for w in words], [np.asarray(b) for b in bases], np.asarray(col_q)
    seen = set()
    for j, (w, n, b) in enumerate(zip(words, counts, bases)):
        for rank in range(32):
            bit = np.asarray(_nth_set_bit(jnp.asarray(w), jnp.full(w.shape, rank, jnp.int32)))
            for d, i in zip(*np.nonzero(rank < n)):     # (B, n): the candidates on the minor axis
                seen.add((int(i), int(b[0, i] + bit[d, i]), int(col_q[d, i])))
    return seen


@hypothesis.settings(**SETTINGS)
@hypothesis.given(seed=st.integers(0, 2**31 - 1), hh=st.sampled_from([0, 1, 15, 16, 31, 33]),
                  hw=st.sampled_from([0, 1, 4]), density=st.sampled_from([0.05, 0.4, 1.0]))
def test_window_walk_visits_exactly_the_window_points(seed, hh, hw, density):
    rng = np.random.default_rng(seed)
    height, width = 70, 11
    valid = rng.random((height, width)) < density
    k_max = int(rng.integers(0, hw + 1))
    row = np.concatenate([[0, height - 1, 0, height - 1], rng.integers(0, height, 12)])
    col = np.concatenate([[0, 0, width - 1, width - 1], rng.integers(0, width, 12)])
    want = {(i, r, c) for i in range(len(row)) for r, c in zip(*np.nonzero(valid))
            if abs(r - row[i]) <= hh and abs(c - col[i]) <= k_max}
    assert _walk(valid, row, col, hh=hh, hw=hw, k_max=k_max) == want
