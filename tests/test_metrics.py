"""KITTI metrics against NumPy oracles written from the devkit's documented behaviour."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxdepth._src import metrics



# ----------------------------------------------------------------------------- oracles
def np_interpolate_background(depth: np.ndarray) -> np.ndarray:
    """Literal double loop over the devkit's documented steps (float64, 0 = empty).

    Works on nested Python lists (fast scalar indexing) so the full KITTI frame is
    cheap enough for a test.
    """
    d = np.where(depth > 0, depth, 0.0).astype(np.float64).tolist()  # NaN -> empty
    H, W = len(d), len(d[0])
    for v in range(H):
        r = d[v]
        run = 0
        for u in range(W):
            if r[u] > 0:
                start = u - run
                if run > 0 and start > 0:  # a gap touching the left border is skipped here
                    fill = min(r[start - 1], r[u])
                    for k in range(start, u):
                        r[k] = fill
                run = 0
            else:
                run += 1
        for u in range(W):  # leading run <- first valid
            if r[u] > 0:
                for k in range(u):
                    r[k] = r[u]
                break
        for u in range(W - 1, -1, -1):  # trailing run <- last valid
            if r[u] > 0:
                for k in range(u + 1, W):
                    r[k] = r[u]
                break
    for u in range(W):
        for v in range(H):  # above the first valid
            if d[v][u] > 0:
                for k in range(v):
                    d[k][u] = d[v][u]
                break
        for v in range(H - 1, -1, -1):  # below the last valid
            if d[v][u] > 0:
                for k in range(v + 1, H):
                    d[k][u] = d[v][u]
                break
    return np.array(d, np.float64).reshape(depth.shape)


def np_errors(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> dict:
    p = pred[mask].astype(np.float64)
    g = gt[mask].astype(np.float64)
    n = int(mask.sum())
    if n == 0:
        return dict(rmse=math.nan, mae=math.nan, irmse=math.nan, imae=math.nan, count=0)
    e = (p - g) * 1000.0
    ie = 1.0 / (p / 1000.0) - 1.0 / (g / 1000.0)
    return dict(rmse=math.sqrt(np.mean(e * e)), mae=np.mean(np.abs(e)),
                irmse=math.sqrt(np.mean(ie * ie)), imae=np.mean(np.abs(ie)), count=n)


def np_depth_metrics(pred, gt, fill=True):
    p = np_interpolate_background(pred) if fill else np.where(pred > 0, pred, 0.0)
    p = np.where(p > 0, p, -1.0)  # devkit's invalid value
    return np_errors(p, gt, gt > 0)


def np_pair_errors(sparse, gt):
    return np_errors(sparse, gt, (sparse > 0) & (gt > 0))


def assert_metrics_close(got, want, rtol=1e-5):
    assert int(got["count"]) == want["count"]
    for k in metrics.METRIC_KEYS:
        g, w = float(got[k]), float(want[k])
        if math.isnan(w):
            assert math.isnan(g), (k, g)
        else:
            assert not math.isnan(g), k
            np.testing.assert_allclose(g, w, rtol=rtol, atol=1e-3, err_msg=k)


def random_sparse(rng, h, w, density, *, empty_rows=0, nan=False):
    d = rng.uniform(0.5, 80.0, (h, w)).astype(np.float32)
    d[rng.random((h, w)) > density] = 0.0
    if empty_rows:
        d[rng.choice(h, size=min(empty_rows, h), replace=False)] = 0.0
    if nan:
        d[rng.random((h, w)) < 0.05] = np.nan
    d[rng.random((h, w)) < 0.03] = -2.0  # negative counts as empty
    return d


#: Image sizes of the random cases (a single pixel, a single row, a single column, odd sizes, the
#: stage table's 6 x 9): each size compiles its own program per function, so the random cases draw the
#: contents freely and the size from these few.
SHAPES = ((1, 1), (1, 12), (9, 1), (2, 3), (6, 9))


# --------------------------------------------------------------- interpolate_background
@settings(deadline=None, max_examples=25)
@given(shape=st.sampled_from(SHAPES), density=st.floats(0.0, 1.0),
       empty_rows=st.integers(0, 3), nan=st.booleans(), seed=st.integers(0, 2**31 - 1))
def test_interpolate_background_matches_double_loop(shape, density, empty_rows, nan, seed):
    h, w = shape
    d = random_sparse(np.random.default_rng(seed), h, w, density, empty_rows=empty_rows, nan=nan)
    got = np.asarray(metrics.interpolate_background(d))
    assert got.dtype == np.float32 and got.shape == (h, w)
    np.testing.assert_array_equal(got, np_interpolate_background(d).astype(np.float32))


def test_interpolate_background_hand_case():
    d = np.array([
        [0, 0, 5, 0, 0, 3, 0, 0],   # leading <- 5, gap -> min(5, 3), trailing <- 3
        [0, 0, 0, 0, 0, 0, 0, 0],   # empty row between rows: stays empty
        [2, 0, 9, 0, 0, 0, 0, 4],   # gaps -> min(2, 9) and min(9, 4)
        [0, 0, 0, 0, 0, 0, 0, 0],   # below the last non-empty row: copied from above
    ], np.float32)
    want = np.array([
        [5, 5, 5, 3, 3, 3, 3, 3],
        [0, 0, 0, 0, 0, 0, 0, 0],
        [2, 2, 9, 4, 4, 4, 4, 4],
        [2, 2, 9, 4, 4, 4, 4, 4],
    ], np.float32)
    np.testing.assert_array_equal(np.asarray(metrics.interpolate_background(d)), want)
    np.testing.assert_array_equal(np_interpolate_background(d), want)


def test_interpolate_background_large():
    """Larger images than the random cases (jit == eager and vmap == loop: the stage table's row
    interpolate_background)."""
    rng = np.random.default_rng(0)
    for dens in (0.02, 0.1, 0.5):
        x = random_sparse(rng, 64, 96, dens, empty_rows=5)
        want = np_interpolate_background(x).astype(np.float32)
        np.testing.assert_array_equal(np.asarray(metrics.interpolate_background(x)), want)


def test_interpolate_background_rejects_bad_rank():
    with pytest.raises(ValueError, match=r"depth: expected shape \(H, W\), got \(2, 3, 4\)"):
        metrics.interpolate_background(np.zeros((2, 3, 4), np.float32))


# ------------------------------------------------------------------------ depth_metrics
@settings(deadline=None, max_examples=20)
@given(shape=st.sampled_from(SHAPES), pd=st.floats(0.0, 1.0), gd=st.floats(0.0, 1.0),
       fill=st.booleans(), seed=st.integers(0, 2**31 - 1))
def test_depth_metrics_matches_oracle(shape, pd, gd, fill, seed):
    h, w = shape
    rng = np.random.default_rng(seed)
    pred = random_sparse(rng, h, w, pd, empty_rows=1, nan=True)
    gt = random_sparse(rng, h, w, gd)
    got = metrics.depth_metrics(pred, gt, fill=fill)
    assert got["count"].dtype == jnp.int32
    assert all(got[k].dtype == jnp.float32 for k in metrics.METRIC_KEYS)
    assert_metrics_close(got, np_depth_metrics(pred, gt, fill=fill))


def test_depth_metrics_constant_offset_is_one_metre():
    rng = np.random.default_rng(1)
    gt = random_sparse(rng, 20, 30, 0.3)
    gt = np.where(gt > 0, np.maximum(gt, 2.0), 0.0).astype(np.float32)
    dense = rng.uniform(2.0, 80.0, gt.shape).astype(np.float32)
    pred = np.where(gt > 0, gt + 1.0, dense).astype(np.float32)
    got = metrics.depth_metrics(pred, gt)
    np.testing.assert_allclose(float(got["rmse"]), 1000.0, rtol=1e-4)
    np.testing.assert_allclose(float(got["mae"]), 1000.0, rtol=1e-4)
    g = gt[gt > 0].astype(np.float64)
    inv = 1000.0 / g - 1000.0 / (g + 1.0)  # analytic 1/km error of a 1 m offset
    np.testing.assert_allclose(float(got["imae"]), inv.mean(), rtol=1e-4)
    np.testing.assert_allclose(float(got["irmse"]), math.sqrt((inv ** 2).mean()), rtol=1e-4)
    assert int(got["count"]) == int((gt > 0).sum())


def test_depth_metrics_perfect_prediction_is_zero():
    rng = np.random.default_rng(2)
    gt = random_sparse(rng, 20, 30, 0.4)   # the size of the tests around: their programs
    got = metrics.depth_metrics(gt, gt)
    for k in metrics.METRIC_KEYS:
        assert float(got[k]) == 0.0


def test_depth_metrics_empty_gt_gives_nan_and_zero_count():
    pred = np.full((20, 30), 3.0, np.float32)
    got = metrics.depth_metrics(pred, np.zeros_like(pred))
    assert int(got["count"]) == 0
    assert all(math.isnan(float(got[k])) for k in metrics.METRIC_KEYS)


def test_depth_metrics_empty_prediction_scored_at_devkit_invalid():
    gt = np.full((20, 30), 10.0, np.float32)
    got = metrics.depth_metrics(np.zeros_like(gt), gt)
    np.testing.assert_allclose(float(got["mae"]), 11000.0, rtol=1e-6)  # |-1 - 10| m
    np.testing.assert_allclose(float(got["imae"]), 1100.0, rtol=1e-6)  # |1/-1 - 1/10| 1/m


# np_depth_metrics as the oracle, jit == eager, vmap == loop, no retrace: row depth_metrics of
# tests/stage_table.py (pair_errors too; keep_ratio below).


def test_depth_metrics_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match=r"pred: expected the shape of gt \(4, 5\), got \(4, 6\)"):
        metrics.depth_metrics(np.zeros((4, 6), np.float32), np.zeros((4, 5), np.float32))


# -------------------------------------------------------------------- pair_errors, keep
@settings(deadline=None, max_examples=15)
@given(shape=st.sampled_from(SHAPES), sd=st.floats(0.0, 1.0), gd=st.floats(0.0, 1.0),
       seed=st.integers(0, 2**31 - 1))
def test_pair_errors_matches_oracle(shape, sd, gd, seed):
    h, w = shape
    rng = np.random.default_rng(seed)
    sparse, gt = random_sparse(rng, h, w, sd, nan=True), random_sparse(rng, h, w, gd)
    got = metrics.pair_errors(sparse, gt)
    assert_metrics_close(got, np_pair_errors(sparse, gt))
    assert int(got["sparse_count"]) == int((sparse > 0).sum())


def test_pair_errors_and_keep_ratio_jit_eager_vmap():
    """keep_ratio jit == eager == vmap; pair_errors beside it (its own jit == eager: the stage table's row)."""
    rng = np.random.default_rng(4)
    sp = np.stack([random_sparse(rng, 20, 30, d) for d in (0.1, 0.4, 0.0)])
    gt = np.stack([random_sparse(rng, 20, 30, d) for d in (0.5, 0.5, 0.5)])
    kept = sp * (rng.random(sp.shape) < 0.7)
    b_err = jax.vmap(metrics.pair_errors)(sp, gt)
    b_keep = np.asarray(jax.vmap(metrics.keep_ratio)(kept, sp))
    for i in range(3):
        want = np_pair_errors(sp[i], gt[i])
        n = (sp[i] > 0).sum()
        want_keep = ((kept[i] > 0) & (sp[i] > 0)).sum() / n if n else math.nan
        with jax.disable_jit():
            eager_keep = metrics.keep_ratio(kept[i], sp[i])
        for got in (metrics.pair_errors(sp[i], gt[i]), {k: v[i] for k, v in b_err.items()}):
            assert_metrics_close(got, want)
        for got in (float(metrics.keep_ratio(kept[i], sp[i])), float(eager_keep), float(b_keep[i])):
            np.testing.assert_allclose(got, want_keep, rtol=1e-6)
    # bool masks are accepted as well as depths
    np.testing.assert_allclose(float(metrics.keep_ratio(kept[0] > 0, sp[0] > 0)), b_keep[0], rtol=1e-6)


# ------------------------------------------------------------------------ mean_metrics
def test_mean_metrics_is_mean_of_per_image_and_skips_empty():
    rng = np.random.default_rng(5)
    preds = np.stack([random_sparse(rng, 20, 30, 0.5) for _ in range(4)])
    gts = np.stack([random_sparse(rng, 20, 30, d) for d in (0.3, 0.0, 0.6, 0.2)])
    per = [metrics.depth_metrics(p, g) for p, g in zip(preds, gts)]
    got = metrics.mean_metrics(per)
    oracle = [np_depth_metrics(p, g) for p, g in zip(preds, gts)]
    used = [o for o in oracle if o["count"] > 0]
    assert got["images"] == 3.0 and got["count"] == sum(o["count"] for o in used)
    for k in metrics.METRIC_KEYS:
        np.testing.assert_allclose(got[k], np.mean([o[k] for o in used]), rtol=1e-5)
    batched = metrics.mean_metrics(jax.vmap(metrics.depth_metrics)(preds, gts))
    for k, v in got.items():
        np.testing.assert_allclose(batched[k], v, rtol=1e-6)
    with pytest.raises(ValueError, match="at least one image, got 0"):
        metrics.mean_metrics([])


# ----------------------------------------------------------------------------- real data
@pytest.mark.shared_data
def test_real_kitti_frame_matches_oracle(kitti):
    sparse, gt = kitti.frame_sparse[2], kitti.frame_truth[2]  # the whole 375 x 1242 frame
    filled = np.asarray(metrics.interpolate_background(sparse))
    np.testing.assert_array_equal(filled, np_interpolate_background(sparse).astype(np.float32))
    got = metrics.depth_metrics(sparse, gt)
    assert_metrics_close(got, np_depth_metrics(sparse, gt), rtol=1e-4)
    assert int(got["count"]) == int((gt > 0).sum()) == 90839
    pair = metrics.pair_errors(sparse, gt)
    assert_metrics_close(pair, np_pair_errors(sparse, gt), rtol=1e-4)
    # Where both are measured the input is mostly right (median difference 0 m), so the
    # raw-input error is far below the error of the devkit-filled sparse map.
    assert float(pair["mae"]) < float(got["mae"])
