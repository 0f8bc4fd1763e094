"""Column bracket and blended hypotheses (Step 4b, beyond the paper): a brute-force NumPy
oracle, exactness on analytic planes, the bound on a wrong normal, jit / vmap via _harness."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdepth
from jaxdepth._src.hypotheses import column_hypotheses, column_neighbours
from jaxdepth._src.residual import plane_residual


#: column_neighbours compiled: these tests check its values; called plainly, each image shape would run
#: op by op and compile every primitive (its jit == eager is the column_hypotheses rows' of the stage table).
_column_neighbours = jax.jit(column_neighbours, static_argnames="max_gap")
#: Value tests call the stages through one jit each (called plainly, each primitive compiles op by op);
#: jit == eager is the stage table's rows.
_plane_residual = jax.jit(plane_residual, static_argnames=("min_abs_denom", "max_residual_ratio"))
_column_hypotheses = jax.jit(column_hypotheses, static_argnames=("window_px", "blend", "materialise",
                                                                 "min_abs_denom", "max_residual_ratio"))

K = np.array([[300.0, 0.0, 31.5], [0.0, 280.0, 20.2], [0.0, 0.0, 1.0]], np.float32)
H, W = 40, 64


def sparse_rows(h, w, rng, *, every=5, keep=0.6):
    """A mask of scan-line-like rows (every ``every`` rows, random columns kept)."""
    mask = np.zeros((h, w), bool)
    mask[2::every] = rng.random((len(range(2, h, every)), w)) < keep
    return mask


def numpy_neighbour(kept, v, u, step):
    """(gap, depth) of the nearest kept pixel from (v, u) walking rows by ``step``."""
    r = v
    while 0 <= r < kept.shape[0]:
        if kept[r, u] > 0:
            return abs(r - v), kept[r, u]
        r += step
    return -1, 0.0


def numpy_bracket(depth_raw, kept, window):
    out = depth_raw.astype(np.float64).copy()
    for v in range(kept.shape[0]):
        for u in range(kept.shape[1]):
            gu, zu = numpy_neighbour(kept, v, u, -1)
            gd, zd = numpy_neighbour(kept, v, u, +1)
            if 0 <= gu <= window and 0 <= gd <= window and depth_raw[v, u] > 0:
                out[v, u] = min(max(out[v, u], min(zu, zd)), max(zu, zd))
    return out


def test_column_neighbours_match_a_walk():
    """Rows exactly; depths to within half the packed keys' quantisation step."""
    rng = np.random.default_rng(0)
    for h in (H, 352):
        kept = np.where(sparse_rows(h, W, rng), rng.uniform(0.5, 149, (h, W)), 0.0).astype(np.float32)
        row_up, z_up, row_dn, z_dn = (np.asarray(a) for a in _column_neighbours(jnp.asarray(kept), max_gap=7))
        step = 256.0 / 2 ** (31 - int(np.ceil(np.log2(h))))
        for rows, depths, direction in ((row_up, z_up, -1), (row_dn, z_dn, 1)):
            for v in range(h):
                for u in range(W):
                    g, z = numpy_neighbour(kept, v, u, direction)
                    found = 0 <= g <= 7
                    assert rows[v, u] == (v + direction * g if found else -1)
                    assert abs(depths[v, u] - (z if found else 0.0)) <= step / 2 + 1e-5



@pytest.mark.parametrize("max_gap", [0, 3, 24, 60])
def test_column_keys_equal_a_window_max(max_gap):
    """The running max cut at ``max_gap`` equals the max over a window of ``max_gap + 1`` rows
    (``lax.reduce_window``, the plain formulation) bit for bit, also for a window of a canvas (the
    image's top rows kept, ``height`` traced) and a search range longer than the image."""
    from jax import lax

    from jaxdepth._src.hypotheses import _column_keys
    rng = np.random.default_rng(max_gap)
    kept = np.where(sparse_rows(H, W, rng, every=7), rng.uniform(0.5, 149, (H, W)), 0.0).astype(np.float32)
    for height in (None, 29):
        if height is not None:
            kept[height:] = 0.0
        up, down, bits, scale, top, last = _column_keys(jnp.asarray(kept), max_gap=max_gap, height=height)
        rows = np.arange(H)[:, None]
        level = np.clip(np.round(kept * np.float32(scale)), 1, int(top)).astype(np.int32)
        for got, order, padding in ((up, rows, (max_gap, 0)), (down, int(last) - rows, (0, max_gap))):
            key = jnp.asarray(np.where(kept > 0, (order << int(bits)) | level, -1).astype(np.int32))
            want = lax.reduce_window(key, -1, lax.max, (max_gap + 1, 1), (1, 1), [padding, (0, 0)])
            np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def numpy_hypothesis(z, n, gap, v, u, K, sign):
    """The paper's z' + Delta z from a seed ``gap`` rows above (sign -1) or below (+1), float64."""
    dv = sign * gap
    numer = z * dv * n[1] / K[1, 1]
    denom = (u - K[0, 2]) / K[0, 0] * n[0] + (v - K[1, 2]) / K[1, 1] * n[1] + n[2]
    dz = numer / denom if abs(denom) > 0.01 else 0.0
    return z + np.clip(dz, -0.5 * z, 0.5 * z)


def numpy_blend(depth_raw, kept, dist, normals, K, window):
    out = numpy_bracket(depth_raw, kept, window)
    for v in range(kept.shape[0]):
        for u in range(kept.shape[1]):
            gu, zu = numpy_neighbour(kept, v, u, -1)
            gd, zd = numpy_neighbour(kept, v, u, +1)
            if not (0 <= gu <= window and 0 <= gd <= window and depth_raw[v, u] > 0) or dist[v, u] <= 0:
                continue
            lo, hi = min(zu, zd), max(zu, zd)
            total, weight = out[v, u] / dist[v, u], 1.0 / dist[v, u]
            for g, z, sign in ((gu, zu, -1), (gd, zd, 1)):
                hyp = numpy_hypothesis(z, normals[:, v + sign * g, u].astype(np.float64), g, v, u, K, sign)
                if lo <= hyp <= hi:
                    total, weight = total + hyp / max(g, 1), weight + 1.0 / max(g, 1)
            out[v, u] = total / weight
    return out


# numpy_bracket / numpy_blend as the oracle, jit == eager, vmap == loop, no retrace (and the vectorised
# helpers.numpy_column_hypotheses against the walk): rows column_hypotheses-* of tests/stage_table.py.


def plane_depth(n, d):
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)])
    return d / np.tensordot(n, rays, axes=1)


@pytest.mark.parametrize("blend", [False, True])
@pytest.mark.parametrize("normal", [(0.0, -0.95, -0.3), (0.3, -0.2, -0.9)])
def test_plane_stays_exact(normal, blend):
    """A plane with exact normals: every hypothesis is the plane, the bracket and the blend change nothing."""
    n = np.asarray(normal) / np.linalg.norm(normal)
    depth = plane_depth(n, -8.0)
    rng = np.random.default_rng(3)
    mask = sparse_rows(H, W, rng, every=4, keep=1.0)
    kept = np.where(mask, depth, 0.0).astype(np.float32)
    # the nearest seed of every pixel: the nearest row of the mask in its column (du = 0)
    rows = np.flatnonzero(mask.any(1))
    v = np.arange(H)
    seed_row = rows[np.abs(v[:, None] - rows[None]).argmin(1)]
    dv = np.broadcast_to((seed_row - v)[:, None], (H, W)).astype(np.int32)
    seed = depth[seed_row][:, :]
    normals = np.broadcast_to(n[:, None, None], (3, H, W)).astype(np.float32)
    raw = seed + np.asarray(_plane_residual(jnp.float32(seed), jnp.asarray(normals), jnp.zeros((H, W), jnp.int32),
                                           jnp.asarray(dv), K, min_abs_denom=1e-6, max_residual_ratio=10.0))
    out = _column_hypotheses(jnp.float32(raw), jnp.asarray(kept), jnp.abs(jnp.float32(dv)), jnp.asarray(normals), K,
                            window_px=4.0, blend=blend, min_abs_denom=1e-6, max_residual_ratio=10.0)
    inner = (v >= rows[0]) & (v <= rows[-1])
    np.testing.assert_allclose(np.asarray(out)[inner], depth[inner], rtol=3e-5)


def test_wrong_normal_is_bounded_by_the_scan_lines():
    """A fronto-parallel wall at 10 m given a badly tilted normal: the paper's extrapolation leaves
    the wall by metres between scan lines, the bracket puts it back."""
    depth = np.full((H, W), 10.0)
    mask = sparse_rows(H, W, np.random.default_rng(4), every=6, keep=1.0)
    kept = np.where(mask, depth, 0.0).astype(np.float32)
    rows = np.flatnonzero(mask.any(1))
    v = np.arange(H)
    seed_row = rows[np.abs(v[:, None] - rows[None]).argmin(1)]
    dv = np.broadcast_to((seed_row - v)[:, None], (H, W)).astype(np.int32)
    wrong = np.broadcast_to((np.array([0.0, -0.97, -0.2431]))[:, None, None], (3, H, W)).astype(np.float32)
    seed = np.full((H, W), 10.0, np.float32)
    raw = seed + np.asarray(_plane_residual(jnp.asarray(seed), jnp.asarray(wrong), jnp.zeros((H, W), jnp.int32),
                                           jnp.asarray(dv), K))
    inner = (v >= rows[0]) & (v <= rows[-1])
    assert np.abs(raw - depth)[inner].max() > 0.3
    for blend in (False, True):
        out = _column_hypotheses(jnp.asarray(raw, jnp.float32), jnp.asarray(kept), jnp.abs(jnp.float32(dv)),
                                jnp.asarray(wrong), K, window_px=6.0, blend=blend)
        np.testing.assert_allclose(np.asarray(out)[inner], 10.0, rtol=1e-6)


def test_window_limits_the_bracket():
    """Scan lines further apart than the window bound nothing."""
    rng = np.random.default_rng(5)
    kept = np.where(sparse_rows(H, W, rng, every=9, keep=1.0), 5.0, 0.0).astype(np.float32)
    raw = np.full((H, W), 20.0, np.float32)
    dist = np.ones((H, W), np.float32)
    normals = np.zeros((3, H, W), np.float32)
    out = np.asarray(_column_hypotheses(jnp.asarray(raw), jnp.asarray(kept), jnp.asarray(dist),
                                       jnp.asarray(normals), K, window_px=4.0))
    np.testing.assert_allclose(out, numpy_bracket(raw, kept, 4.0), rtol=0, atol=1e-5)   # bounds quantised
    np.testing.assert_allclose(out[kept > 0], 5.0, atol=1e-5)   # a LiDAR pixel is its own bracket
    assert np.any(out == 20.0)                   # rows more than 4 from a line on either side keep theirs


def test_blend_needs_the_bracket():
    with pytest.raises(ValueError, match="blend_hypotheses"):
        jaxdepth.SGMConfig(column_bracket=False, blend_hypotheses=True)


@pytest.mark.parametrize("blend", [False, True])
def test_fences_do_not_change_the_result(blend):
    """materialise (stage fences, a speed choice) gives the same bits with and without, compiled (the fences
    act on what XLA fuses; op by op there is nothing to fence)."""
    rng = np.random.default_rng(7)
    kept = np.where(sparse_rows(H, W, rng), rng.uniform(2, 40, (H, W)), 0.0).astype(np.float32)
    raw = rng.uniform(0.5, 60, (H, W)).astype(np.float32)
    dist = rng.integers(0, 8, (H, W)).astype(np.float32)
    normals = rng.normal(size=(3, H, W)).astype(np.float32)
    outs = [np.asarray(_column_hypotheses(raw, kept, dist, normals, K, window_px=7.0, blend=blend, materialise=m))
            for m in (True, False)]
    np.testing.assert_array_equal(outs[0], outs[1])


def test_bracket_bounds_quantisation_is_below_a_fifth_of_a_millimetre():
    """The packed-key bounds equal the exact neighbour depths to within half a quantisation step."""
    rng = np.random.default_rng(8)
    for h in (40, 352, 900):
        kept = np.where(rng.random((h, 16)) < 0.2, rng.uniform(0.5, 149.0, (h, 16)), 0.0).astype(np.float32)
        row_up, z_up_q, row_dn, z_dn_q = (np.asarray(a) for a in _column_neighbours(jnp.asarray(kept), max_gap=6))
        lo, hi, found = np.minimum(z_up_q, z_dn_q), np.maximum(z_up_q, z_dn_q), (row_up >= 0) & (row_dn >= 0)
        walks = [np.array([[numpy_neighbour(kept, v, u, step) for u in range(16)] for v in range(h)])
                 for step in (-1, 1)]
        (gap_up, z_up), (gap_dn, z_dn) = ((np.where(w[..., 0] <= 6, w[..., 0], -1),
                                           np.where(w[..., 0] <= 6, w[..., 1], 0.0)) for w in walks)
        np.testing.assert_array_equal(found, (gap_up >= 0) & (gap_dn >= 0))
        step = 256.0 / 2 ** (31 - int(np.ceil(np.log2(h))))
        assert step < 2e-4
        np.testing.assert_allclose(lo[found], np.minimum(z_up, z_dn)[found], rtol=0, atol=step / 2 + 1e-5)
        np.testing.assert_allclose(hi[found], np.maximum(z_up, z_dn)[found], rtol=0, atol=step / 2 + 1e-5)


def test_one_key_image_equals_two_key_images_bit_for_bit():
    """``one_key_image=True`` (a rig's whole-window tail, H > 128: one key image, the backward running max over
    its copy with each row turned into down keys, the level's int from the float's bits) equals the two key
    images' form bit for bit: neighbours and clipped depth, depths past the keys' 256 m and huge ones included;
    within the keys' quantisation of the NumPy oracle; jit == eager, vmap == loop. H <= 128 keeps two images."""
    from helpers import numpy_column_hypotheses
    rng = np.random.default_rng(38)
    two = jax.jit(column_hypotheses, static_argnames=("window_px", "one_key_image"))
    neighbours = jax.jit(column_neighbours, static_argnames=("max_gap", "one_key_image"))
    for h, w, window in ((129, 16, 3.0), (200, 24, 5.5), (301, 12, 9.9), (900, 16, 28.1), (1550, 8, 24.0), (64, 8, 4.0)):
        for frac in (0.02, 0.3, 0.95):
            kept = np.where(rng.random((h, w)) < frac, rng.uniform(0.01, 150.0, (h, w)), 0.0).astype(np.float32)
            raw = np.where(rng.random((h, w)) < 0.9, rng.uniform(0.1, 150.0, (h, w)), 0.0).astype(np.float32)
            oracle = numpy_column_hypotheses(raw, kept, int(window))
            far = kept.copy()
            far[rng.random((h, w)) < 0.05] = 1e3
            far[0, 0], far[-1, -1] = 1e30, 300.0
            for k in (kept, far):
                a = np.asarray(two(raw, k, None, None, None, window_px=window))
                b = np.asarray(two(raw, k, None, None, None, window_px=window, one_key_image=True))
                np.testing.assert_array_equal(b, a)
                for x, y in zip(neighbours(k, max_gap=int(window)), neighbours(k, max_gap=int(window), one_key_image=True)):
                    np.testing.assert_array_equal(np.asarray(y), np.asarray(x))
            b = np.asarray(two(raw, kept, None, None, None, window_px=window, one_key_image=True))
            np.testing.assert_allclose(b, oracle, rtol=0, atol=150.0 / 2 ** 19)
            assert frac < 0.1 or (b != raw).mean() > 0.05               # the bracket moves pixels
    kept = np.where(rng.random((3, 131, 10)) < 0.2, rng.uniform(0.5, 80.0, (3, 131, 10)), 0.0).astype(np.float32)
    raw = rng.uniform(0.1, 100.0, (3, 131, 10)).astype(np.float32)
    one = functools.partial(column_hypotheses, seed_distance=None, normals=None, K=None, window_px=6.0,
                            one_key_image=True)
    batched = np.asarray(jax.jit(jax.vmap(one))(raw, kept))
    for i in range(3):
        np.testing.assert_array_equal(batched[i], np.asarray(jax.jit(one)(raw[i], kept[i])))
        np.testing.assert_array_equal(batched[i], np.asarray(two(raw[i], kept[i], None, None, None, window_px=6.0)))
    np.testing.assert_array_equal(np.asarray(one(raw[0], kept[0])), batched[0])     # eager
