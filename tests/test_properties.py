"""Property-based tests of the core on random sparse images (hypothesis, fixed shapes: one compile each)."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from jaxdepth import SGMConfig, complete, complete_stages
from scenes import SMALL_LIDAR as LIDAR

# The size, LiDAR and configuration of the pipeline rows of tests/stage_table.py: the same compiled programs.
H, W = 32, 48
CONFIG = SGMConfig()
T = np.array([[0, -1, 0, 0.0], [0, 0, -1, -0.3], [1, 0, 0, -0.3], [0, 0, 0, 1]], np.float32)
SETTINGS = settings(deadline=None, max_examples=12, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def sparse_frames(draw):
    seed = draw(st.integers(0, 2**31 - 1))
    density = draw(st.sampled_from([0.0, 0.01, 0.05, 0.3, 1.0]))
    rng = np.random.default_rng(seed)
    depth = np.where(rng.random((H, W)) < density, rng.uniform(0.5, 120.0, (H, W)), 0.0).astype(np.float32)
    f = draw(st.floats(40.0, 400.0))
    K = np.array([[f, 0, draw(st.floats(0, W))], [0, f * draw(st.floats(0.8, 1.2)), draw(st.floats(0, H))],
                  [0, 0, 1]], np.float32)
    return depth, K


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
@SETTINGS
@given(sparse_frames())
def test_outputs_finite_clipped_and_seeds_keep_depth(frame):
    depth, K = frame
    stages = complete_stages(depth, K, T, config=CONFIG, lidar=LIDAR)
    for name, value in stages._asdict().items():
        assert np.all(np.isfinite(np.asarray(value))), name
    out = np.asarray(stages.depth)
    keep = np.asarray(stages.inlier_mask)
    if depth.any():
        assert out.min() >= CONFIG.min_depth_m and out.max() <= CONFIG.max_depth_m
        np.testing.assert_array_equal(out[keep], np.clip(depth[keep], CONFIG.min_depth_m, CONFIG.max_depth_m))
    else:
        assert np.all(out == 0)
    assert not np.any(keep & (depth <= 0))  # padding / empty pixels never become seeds


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
@settings(deadline=None, max_examples=4, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(sparse_frames(), min_size=3, max_size=3))
def test_vmap_equals_loop(frames):
    depths = np.stack([d for d, _ in frames])
    Ks = np.stack([k for _, k in frames])
    f = lambda d, k: complete(d, k, T, config=CONFIG, lidar=LIDAR)
    loop = np.stack([np.asarray(f(d, k)) for d, k in frames])
    np.testing.assert_allclose(np.asarray(jax.vmap(f)(depths, Ks)), loop, rtol=1e-5, atol=1e-4)


# jit == eager of complete: row complete of tests/stage_table.py.
