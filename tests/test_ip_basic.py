"""IP_Basic in JAX against the OpenCV oracle (jaxdepth.research.baselines), step by step and whole."""

from __future__ import annotations

import cv2
import jax
import numpy as np
import pytest

from jaxdepth.research import baselines
from jaxdepth._src import ip_basic as ipb
from jaxdepth._src import metrics

EPS = float(np.finfo(np.float32).eps)
FULL = lambda n: np.ones((n, n), np.uint8)  # noqa: E731


def sparse_image(seed: int, h: int, w: int, density: float = 0.05) -> np.ndarray:
    """Sparse depth in metres with LiDAR-like density; top rows empty like KITTI."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(1.0, 90.0, (h, w)).astype(np.float32)
    d[rng.random((h, w)) > density] = 0.0
    d[: h // 4] = 0.0
    return d


def inverted_stage_inputs(seed: int, h: int, w: int) -> list[np.ndarray]:
    """Images like those the steps see: sparse, partly filled, dense."""
    x = np.where(sparse_image(seed, h, w, 0.15) > 0, 100.0 - sparse_image(seed, h, w, 0.15), 0.0)
    x = x.astype(np.float32)
    return [x, cv2.dilate(x, FULL(5)), np.random.default_rng(seed).uniform(0, 99, (h, w)).astype(np.float32)]


def assert_float32_close(got, want, *, ulps=8, scale=None):
    """|got - want| <= ulps float32 ulps of ``scale`` (default: of each value).

    The pipeline blurs inverted depths (max_depth - d, up to ~100) and inverts back, so
    its rounding is a few ulps of max_depth, not of the (smaller) output depth.
    """
    got, want = np.asarray(got), np.asarray(want)
    assert got.dtype == np.float32 and got.shape == want.shape
    ref = np.maximum(np.abs(want), 1.0) if scale is None else scale
    tol = ulps * EPS * ref
    bad = np.abs(got - want) > tol
    assert not bad.any(), f"max abs diff {np.abs(got - want).max()} at {np.argwhere(bad)[:3]}"


# ---------------------------------------------------------------- each step vs OpenCV
EXACT_STEPS = {
    "dilate_diamond5": (ipb.dilate_diamond5, lambda a: cv2.dilate(a, baselines.DIAMOND_KERNEL_5)),
    "dilate_square7": (lambda a: ipb.dilate_square(a, 7), lambda a: cv2.dilate(a, FULL(7))),
    "dilate_square31": (lambda a: ipb.dilate_square(a, 31), lambda a: cv2.dilate(a, FULL(31))),
    "erode_square5": (lambda a: ipb.erode_square(a, 5), lambda a: cv2.erode(a, FULL(5))),
    "close_square5": (lambda a: ipb.close_square(a, 5),
                      lambda a: cv2.morphologyEx(a, cv2.MORPH_CLOSE, FULL(5))),
    "median5": (ipb.median5, lambda a: cv2.medianBlur(a, 5)),
}


@pytest.mark.parametrize("name", sorted(EXACT_STEPS))
@pytest.mark.parametrize("shape", [(37, 53), (6, 40)])
def test_step_equals_opencv_exactly(name, shape):
    ours, oracle = EXACT_STEPS[name]
    for x in inverted_stage_inputs(7, *shape):
        got = np.asarray(jax.jit(ours)(x))
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, oracle(x))


@pytest.mark.parametrize("shape", [(37, 53), (6, 40)])
def test_blurs_match_opencv_to_float32_rounding(shape):
    # OpenCV sums in a different order (and looks the bilateral colour weight up in a
    # table), so these agree to a few ulps, not bit for bit.
    for x in inverted_stage_inputs(8, *shape):
        assert_float32_close(jax.jit(ipb.gaussian5)(x), cv2.GaussianBlur(x, (5, 5), 0), ulps=4)
        assert_float32_close(jax.jit(ipb.bilateral5)(x), cv2.bilateralFilter(x, 5, 1.5, 2.0), ulps=8)


def test_median_network_sorts():
    rng = np.random.default_rng(0)
    for _ in range(100):
        v = list(rng.random(32))
        for a, b in ipb._SORT32:
            if v[a] > v[b]:
                v[a], v[b] = v[b], v[a]
        assert v == sorted(v)


# --------------------------------------------------------------------- whole pipeline
@pytest.mark.xdist_group("ip_basic_synthetic")  # one worker compiles their shared program once
@pytest.mark.parametrize("extrapolate", [False, True])
def test_ip_basic_equals_opencv_synthetic(extrapolate):
    """80 x 80 (the isolated-point test's size: its program without extrapolation; with it, the stage table's
    ip_basic row's program and frames)."""
    for seed in range(3):
        d = sparse_image(seed, 80, 80, density=(0.02, 0.06, 0.3)[seed])
        got = np.asarray(ipb.ip_basic(d, extrapolate=extrapolate, blur_type="gaussian"))
        want = baselines.ip_basic_opencv(d, extrapolate=extrapolate, blur_type="gaussian")
        np.testing.assert_array_equal(got > 0, want > 0)
        assert_float32_close(got, want, ulps=8, scale=100.0)
        if extrapolate:
            assert (got > 0).all()


@pytest.mark.shared_data
def test_ip_basic_equals_opencv_on_kitti_and_scores(kitti):
    sparse, gt = kitti.sparse[2], kitti.truth[2]  # KITTI benchmark crop, 352 x 1216
    got = np.asarray(ipb.ip_basic(sparse, blur_type="gaussian"))
    want = baselines.ip_basic_opencv(sparse, blur_type="gaussian")
    assert got.shape == (352, 1216)
    np.testing.assert_array_equal(got > 0, want > 0)
    assert_float32_close(got, want, ulps=8, scale=100.0)  # measured: bit-identical on this frame
    # Bilateral variant: a few ulps apart (OpenCV's colour look-up table).
    got_b = np.asarray(ipb.ip_basic(sparse, blur_type="bilateral"))
    want_b = baselines.ip_basic_opencv(sparse)
    np.testing.assert_array_equal(got_b > 0, want_b > 0)
    np.testing.assert_allclose(got_b, want_b, rtol=0, atol=1e-4)
    # Scores: JAX and OpenCV agree, and completion beats the devkit's filling of the
    # raw input (rows of nearest values) on every metric.
    ours, ref = metrics.depth_metrics(got, gt), metrics.depth_metrics(want, gt)
    raw = metrics.depth_metrics(sparse, gt)
    for k in metrics.METRIC_KEYS:
        np.testing.assert_allclose(float(ours[k]), float(ref[k]), rtol=1e-5)
        assert float(ours[k]) < float(raw[k]), k


# The OpenCV port as the oracle, jit == eager, vmap == loop, no retrace: row ip_basic of tests/stage_table.py.


@pytest.mark.xdist_group("ip_basic_synthetic")  # one worker compiles their shared program once
def test_ip_basic_keeps_an_isolated_point_and_leaves_far_pixels_empty():
    d = np.zeros((80, 80), np.float32)
    d[40, 40] = 12.5
    out = np.asarray(ipb.ip_basic(d))
    # Diamond, closing, 7x7 and 31x31 dilations reach at most 2 + 3 + 15 px (L_inf).
    assert out[40, 40] == pytest.approx(12.5, abs=1e-5)
    assert (out[:18] == 0).all() and (out[:, :18] == 0).all()
    np.testing.assert_array_equal(out, baselines.ip_basic_opencv(d, blur_type="gaussian"))


def test_ip_basic_validates_options():
    d = np.zeros((8, 8), np.float32)
    with pytest.raises(ValueError, match=r"blur_type: expected one of \('gaussian', 'bilateral'\), got 'box'"):
        ipb.ip_basic(d, blur_type="box")
    with pytest.raises(ValueError, match=r"sparse_depth: expected shape \(H, W\), got \(8,\)"):
        ipb.ip_basic(d[0])
    with pytest.raises(ValueError, match="max_depth: expected a value > 0.1 m, got 0.0"):
        ipb.ip_basic(d, max_depth=0.0)
    with pytest.raises(ValueError, match="blur_type: expected one of"):
        baselines.ip_basic_opencv(d, blur_type="box")
