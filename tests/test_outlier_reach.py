"""The footprint form's reach bound (``outliers._Reach``): the prefilter's candidates on image input.

The bound only narrows the candidates the exact test visits, so it must keep every pixel the footprint
test removes. Oracle: the float64 double loop of tests/test_outliers.py (``footprint_double_loop``), its
removed and its borderline ("unsure") pixels, on random scenes whose LiDAR sits beside, behind and ahead of
the camera, with skewed intrinsics, depths past the keys' 256 m, and on KITTI windows; and the bound must
cut candidates where the parallax is small (KITTI: it is the point of it).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from test_outliers import CAPS, SCENE_BEAMS, SCENE_SHAPE, _camera, _kitti_window, _random_sparse, footprint_double_loop

from jaxdepth._src import outliers as O


def _candidates(depth, K, T, *, beams, max_half_width_px, max_half_height_px, reach=True):
    """(H, W) bool: the prefilter's candidates as ``_keep_mask`` makes them on image input."""
    depth = jnp.asarray(depth, jnp.float32)
    height, width = depth.shape
    hw, hh = O.window_half_sizes(height, width, beams=beams, max_half_width_px=max_half_width_px,
                                 max_half_height_px=max_half_height_px)
    bounds = O._bounds((depth > 0) & jnp.isfinite(depth), beams=beams, half_width=hw, half_height=hh)
    box, hs = O._reach(jnp.asarray(K, jnp.float32), jnp.asarray(T, jnp.float32)[:3, 3], bounds, shape=(height, width),
                       beams=beams, hh=hh) if reach else (None, 0)
    words = np.asarray(O._prefilter(depth, jnp.float32(1.0), bounds, hh=hh, hw=hw, reach=box, hs=hs))
    return np.unpackbits(words.view(np.uint8), bitorder="little").reshape(height, -1)[:, :width].astype(bool)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("t_lidar, skew", [((0.5, -0.3, 0.0), 0.0), ((0.06, -0.08, -0.27), 0.0),
                                           ((0.2, -0.3, -1.0), 3.0), ((-0.3, 0.1, 0.8), -2.0)])
def test_reach_candidates_cover_every_removal(seed, t_lidar, skew):
    """Random two-layer scenes, (24, 40), CAPS: every pixel the float64 footprint loop removes (or leaves
    within its rounding tolerance) is a candidate; and the candidates are within those of condition 2 alone."""
    rng = np.random.default_rng(seed)
    shape = (24, 40)
    K, T = _camera(rng, *shape)
    K[0, 1] = skew
    T[:3, 3] = t_lidar
    depth = _random_sparse(rng, *shape, (0.1, 0.25, 0.5)[seed % 3])
    if seed % 2:           # far layer past the keys' saturation (256 m)
        depth = np.where(depth > 10.0, depth * 12.0, depth).astype(np.float32)
    kw = dict(beams=6, **CAPS)
    want, unsure = footprint_double_loop(depth, K, T, epsilon_m=1.0, **kw)
    cand, plain = _candidates(depth, K, T, **kw), _candidates(depth, K, T, reach=False, **kw)
    removed = ~want & (depth > 0)
    assert not (removed & ~cand).any() and not (unsure & ~cand).any()
    assert not (cand & ~plain).any()


@pytest.mark.parametrize("r0, c0", [(110, 150), (100, 880)])
def test_reach_candidates_kitti_windows(kitti, r0, c0):
    """KITTI windows (camera 2's calibration, and camera 3 moved 0.54 m for more parallax): every removal
    of the float64 loop is a candidate, and the bound leaves fewer candidates than condition 2 alone."""
    kw = dict(beams=SCENE_BEAMS, max_half_width_px=12, max_half_height_px=24)
    fewer = 0
    for cam, shift in ((2, 0.0), (3, -0.54)):
        crop, K, T = _kitti_window(kitti, cam, r0, c0)
        T[0, 3] += shift
        assert crop.shape == SCENE_SHAPE
        want, unsure = footprint_double_loop(crop, K, T, epsilon_m=1.0, **kw)
        cand, plain = _candidates(crop, K, T, **kw), _candidates(crop, K, T, reach=False, **kw)
        assert not ((~want & (crop > 0)) & ~cand).any() and not (unsure & ~cand).any()
        assert not (cand & ~plain).any()
        fewer += plain.sum() - cand.sum()
    assert fewer > 0


@pytest.mark.slow  # the real KITTI frame at its own size, two keep-mask programs; the quick tests above check the bound
def test_reach_cuts_the_kitti_frame(kitti, monkeypatch):
    """The whole frame (64 beams, the library's caps): the bound leaves under half the candidates of
    condition 2 alone (4,658 -> 1,361 on camera 2's shared frame), and the keep mask equals the one of the
    same program with the bound off (its candidates: condition 2 alone)."""
    import jax
    sparse, K, T = kitti.sparse[2], kitti.K[2], kitti.T_cam_lidar[2]
    kw = dict(beams=64, max_half_width_px=O.DEFAULT_CONFIG.outlier_max_half_width_px,
              max_half_height_px=O.DEFAULT_CONFIG.outlier_max_half_height_px)
    cand, plain = _candidates(sparse, K, T, **kw), _candidates(sparse, K, T, reach=False, **kw)
    assert not (cand & ~plain).any() and 2 * cand.sum() < plain.sum()
    keep = np.asarray(O.outlier_keep_mask(sparse, K, T, **kw))
    assert (~keep & (sparse > 0)).sum() > 20
    hw, hh = O.window_half_sizes(*sparse.shape, **kw)
    monkeypatch.setattr(O, "_reach", lambda *args, **kwargs: (None, 0))
    plain_program = jax.jit(O._keep_mask.__wrapped__, static_argnames=("beams", "half_width", "half_height", "test"))
    without = plain_program(jnp.asarray(sparse), jnp.asarray(K), jnp.asarray(T), None, jnp.float32(1.0), beams=64,
                            half_width=hw, half_height=hh)
    np.testing.assert_array_equal(keep, np.asarray(without))
