"""Shared kernels of the stages: geometry's z-buffer and back-projection, bit-packed compaction,
and the order-only pseudo-angle, each against a brute-force NumPy oracle (plus jit == eager)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth._src import compaction, fastmath, geometry


def _brute_argmin(slot, key, size):
    best = np.full(size, np.inf)
    idx = np.full(size, len(slot), np.int64)
    for i, (s, k) in enumerate(zip(slot, key)):
        if s < size and (k < best[s] or (k == best[s] and i < idx[s])):
            best[s], idx[s] = k, i
    return best, idx


@pytest.mark.parametrize("dtype", [np.float32, np.int32])
def test_scatter_argmin_equals_brute_force_with_lowest_index_on_ties(dtype):
    rng = np.random.default_rng(0)
    n, size = 500, 40
    slot = rng.integers(0, size + 1, n).astype(np.int32)   # size = the dump slot
    key = rng.integers(0, 12, n).astype(dtype)             # many equal keys: ties
    fill = np.inf if dtype == np.float32 else np.iinfo(np.int32).max
    f = lambda s, k: geometry.scatter_argmin(s, k, size, fill=fill)
    best, idx = jax.jit(f)(jnp.asarray(slot), jnp.asarray(key))
    want_best, want_idx = _brute_argmin(slot, key.astype(np.float64), size)
    empty = want_idx == n
    np.testing.assert_array_equal(np.asarray(idx), want_idx)
    np.testing.assert_array_equal(np.asarray(best)[~empty], want_best[~empty].astype(dtype))
    assert np.all(np.asarray(best)[empty] == fill)
    eager_best, eager_idx = f(jnp.asarray(slot), jnp.asarray(key))
    np.testing.assert_array_equal(np.asarray(eager_idx), np.asarray(idx))


def test_scatter_winners_are_the_brute_force_winners_with_lowest_index_on_ties():
    """``scatter_winners`` (one int32 canvas) gives each entry its slot exactly where the NumPy argmin (smallest
    key, then smallest index) picks it: ties, infinite keys, the dump slot; jit == eager."""
    rng = np.random.default_rng(5)
    n, size = 700, 45
    slot = rng.integers(0, size + 1, n).astype(np.int32)   # size = the dump slot
    key = rng.choice(np.float32([0.25, 1.0, np.nextafter(np.float32(1.0), np.float32(2.0)), 3.0, np.inf]), n)
    _, want_idx = _brute_argmin(slot, key.astype(np.float64), size)
    want = np.where((slot < size) & (want_idx[np.minimum(slot, size - 1)] == np.arange(n)), slot, size)
    f = lambda s, k: geometry.scatter_winners(s, k, size)
    np.testing.assert_array_equal(np.asarray(jax.jit(f)(jnp.asarray(slot), jnp.asarray(key))), want)
    np.testing.assert_array_equal(np.asarray(f(jnp.asarray(slot), jnp.asarray(key))), want)


def test_zbuffer_winners_write_the_brute_force_zbuffer_with_lowest_index_on_ties():
    """``winners_image`` of ``zbuffer_winners`` (the rigs' projection, point by point) == a NumPy z-buffer
    (nearest, then lowest index; points at equal depth on one pixel: ties), == ``zbuffer_image``'s depth and
    index bit for bit, jit == eager, vmap == loop."""
    rng = np.random.default_rng(3)
    h, w, n = 7, 9, 400
    K = jnp.asarray(np.array([[4.0, 0.0, 4.0], [0.0, 3.0, 3.0], [0.0, 0.0, 1.0]], np.float32))
    z = rng.integers(1, 6, n).astype(np.float32)                      # few depths: many ties
    u, v = rng.integers(-2, w + 2, n), rng.integers(-2, h + 2, n)      # some outside the image
    points = np.stack([(u - 4.0) * z / 4.0, (v - 3.0) * z / 3.0, z], -1).astype(np.float32)
    points[::37, 2] = -1.0                                             # behind the camera
    valid = rng.random(n) < 0.9
    size = jnp.array([h - 1, w], jnp.int32)                            # a window: the last row dropped

    def run(pts, ok, K, size):
        slot, zz = geometry.zbuffer_winners(pts, ok, K, height=h, width=w, valid_size=size)
        image = lambda x, fill: geometry.winners_image(slot, x, fill, height=h, width=w)
        return image(zz, 0.0), image(jnp.arange(n, dtype=jnp.int32), -1)

    depth, index = (np.asarray(a) for a in jax.jit(run)(points, valid, K, size))
    pu, pv, pz, front = (np.asarray(a) for a in geometry.project_pixels(jnp.asarray(points), K))
    ui, vi = np.round(pu).astype(np.int64), np.round(pv).astype(np.int64)
    inside = front & valid & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h - 1)
    slot = np.where(inside, vi * w + ui, h * w)
    _, want_idx = _brute_argmin(slot, np.where(inside, pz, np.inf).astype(np.float64), h * w)
    want_index = np.where(want_idx == n, -1, want_idx).reshape(h, w)
    np.testing.assert_array_equal(index, want_index)
    np.testing.assert_array_equal(depth, np.where(want_index >= 0, pz[np.maximum(want_index, 0)], 0.0))
    assert len(np.unique(slot[inside])) < np.count_nonzero(inside)     # the case has shared pixels
    ref_depth, ref_index = geometry.zbuffer_image(jnp.asarray(points), valid, K, height=h, width=w, valid_size=size)
    assert depth.tobytes() == np.asarray(ref_depth).tobytes() and index.tobytes() == np.asarray(ref_index).tobytes()
    assert all(np.array_equal(e, g) for e, g in zip(run(points, valid, K, size), (depth, index)))
    perm = rng.permutation(n)                                          # a second camera's view: another point order
    batched = jax.jit(jax.vmap(run, in_axes=(0, 0, None, None)))(np.stack([points, points[perm]]),
                                                                 np.stack([valid, valid[perm]]), K, size)
    second = jax.jit(run)(points[perm], valid[perm], K, size)
    for b, one, two in zip(batched, (depth, index), second):
        np.testing.assert_array_equal(np.asarray(b[0]), one)
        np.testing.assert_array_equal(np.asarray(b[1]), np.asarray(two))


def test_zbuffer_winners_of_cameras_of_two_sizes_in_one_vmap_are_each_cameras_own():
    """``group_size`` (the rigs' projection of every size group in one ``vmap``): a 7 x 9 and a 9 x 5 camera on
    a flat buffer of 63 slots win the pixels of a NumPy z-buffer of their own size (row stride w), the same
    slots as their own ``zbuffer_winners(height=h, width=w)`` (none: 63 against h w), jit == eager."""
    rng = np.random.default_rng(5)
    n = 300
    K = jnp.asarray(np.array([[4.0, 0.0, 4.0], [0.0, 3.0, 3.0], [0.0, 0.0, 1.0]], np.float32))
    sizes = np.array([[7, 9], [9, 5]], np.int32)
    z = rng.integers(1, 6, (2, n)).astype(np.float32)
    u, v = rng.integers(-2, 11, (2, n)), rng.integers(-2, 11, (2, n))    # some outside either image
    points = np.stack([(u - 4.0) * z / 4.0, (v - 3.0) * z / 3.0, z], -1).astype(np.float32)
    valid = rng.random((2, n)) < 0.9

    def shared(pts, ok, group):
        return geometry.zbuffer_winners(pts, ok, K, height=63, width=1, group_size=group)[0]

    slots = np.asarray(jax.jit(jax.vmap(shared))(points, valid, sizes))
    assert np.array_equal(np.asarray(jax.vmap(shared)(points, valid, sizes)), slots)
    own_winners = jax.jit(geometry.zbuffer_winners, static_argnames=("height", "width"))  # not op by op per size
    for c, (h, w) in enumerate(sizes):
        own = np.asarray(own_winners(jnp.asarray(points[c]), valid[c], K, height=int(h), width=int(w))[0])
        np.testing.assert_array_equal(np.where(slots[c] == 63, h * w, slots[c]), own)
        pu, pv, pz, front = (np.asarray(a) for a in geometry.project_pixels(jnp.asarray(points[c]), K))
        ui, vi = np.round(pu).astype(np.int64), np.round(pv).astype(np.int64)
        inside = front & valid[c] & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
        slot = np.where(inside, vi * w + ui, h * w)
        _, idx = _brute_argmin(slot, np.where(inside, pz, np.inf).astype(np.float64), h * w)
        won = np.full(n, h * w)
        won[idx[idx < n]] = np.nonzero(idx < n)[0]                     # each winner's pixel
        np.testing.assert_array_equal(np.where(slots[c] == 63, h * w, slots[c]), won)


def test_backproject_equals_inverse_intrinsics():
    rng = np.random.default_rng(1)
    K = np.array([[500.0, 3.0, 160.5], [0.0, 480.0, 90.25], [0.0, 0.0, 1.0]], np.float32)
    depth = rng.uniform(1.0, 50.0, (6, 9)).astype(np.float32)
    x, y, z = (np.asarray(c) for c in geometry.backproject(jnp.asarray(depth), jnp.asarray(K)))
    v, u = np.mgrid[0:6, 0:9]
    rays = np.linalg.inv(K.astype(np.float64)) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    want = rays * depth.ravel()
    eps = np.finfo(np.float32).eps
    for got, w in zip((x, y, z), want):
        np.testing.assert_allclose(got.ravel(), w, rtol=16 * eps, atol=16 * eps * 50)
    np.testing.assert_array_equal(np.asarray(geometry.unproject_depth(depth, K)), np.stack([x, y, z], -1))


@pytest.mark.parametrize("shape, p", [((37,), 0.3), ((5, 70), 0.1), ((3, 64), 1.0), ((4, 33), 0.0)])
def test_pack_bits_and_word_locator_list_true_entries_in_raster_order(shape, p):
    rng = np.random.default_rng(2)
    mask = rng.random(shape) < p
    words = np.asarray(jax.jit(compaction.pack_bits)(jnp.asarray(mask)))
    n_words = -(-shape[-1] // 32)
    assert words.shape == shape[:-1] + (n_words,) and words.dtype == np.uint32
    padded = np.zeros(shape[:-1] + (32 * n_words,), bool)
    padded[..., :shape[-1]] = mask
    bits = (words[..., None] >> np.arange(32, dtype=np.uint32)) & 1
    np.testing.assert_array_equal(bits.reshape(padded.shape).astype(bool), padded)

    def listed(words):
        count, locate = compaction.word_locator(words)
        return count, locate(jnp.minimum(jnp.arange(max(mask.sum(), 1), dtype=jnp.int32), jnp.maximum(count - 1, 0)))

    count, flat = jax.jit(listed)(jnp.asarray(words))
    assert int(count) == mask.sum()
    want = np.flatnonzero(padded)
    np.testing.assert_array_equal(np.asarray(flat)[:len(want)], want)


def test_nth_set_bit_equals_brute_force():
    rng = np.random.default_rng(3)
    words = rng.integers(1, 2 ** 32, 300, dtype=np.uint64).astype(np.uint32)
    ranks = np.array([rng.integers(0, bin(int(w)).count("1")) for w in words], np.int32)
    got = np.asarray(jax.jit(compaction.nth_set_bit)(jnp.asarray(words), jnp.asarray(ranks)))
    want = [np.flatnonzero((int(w) >> np.arange(32)) & 1)[r] for w, r in zip(words, ranks)]
    np.testing.assert_array_equal(got, want)


def test_pseudo_angle_orders_like_atan2():
    rng = np.random.default_rng(4)
    a, b = rng.normal(size=(2, 4000)).astype(np.float32)
    got = np.asarray(fastmath.pseudo_angle(jnp.asarray(a), jnp.asarray(b)))
    want = np.arctan2(a.astype(np.float64), b.astype(np.float64))
    order = np.argsort(want)
    assert np.all(np.diff(got[order]) >= 0)
    assert float(fastmath.pseudo_angle(jnp.float32(0.0), jnp.float32(0.0))) == 0.0
