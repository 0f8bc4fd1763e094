"""The optimised pipeline equals a plain composition of the public stage functions.

``complete_stages`` bins image pixels straight into the range image
(``pixel_normals``, on a window of range-image columns), packs gathers, and
fences intermediates so XLA does not re-run them. None of that may change the
result beyond float32 rounding. The reference here is the straightforward
composition: every pixel back-projected as an (N, 3) point for
``point_normals``, ``outlier_keep_mask``, ``nearest_seed``, two
``gather_at_seed`` calls, ``plane_residual``, and OpenCV's Gaussian blur (an
independent oracle for the smoothing). Timings live in benchmarks/, never here.

Tolerances: normals 1e-4 (ranges computed in a different fusion differ by an
ulp, which finite differences over ~1 % range steps amplify ~100x); the
residual and depths inherit that through ``z' du / fu / denominator``
(measured on KITTI: up to 1e-3 m on 8 m residuals far from their seed), so
1e-3 relative plus 2e-3 m; masks, seed offsets and seed depths are exact.
"""

from __future__ import annotations

import functools

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth import SGMConfig
from jaxdepth._src import presets
from jaxdepth._src.distance import gather_at_seed, nearest_seed
from jaxdepth._src.geometry import invert_rigid, transform_points, unproject_depth
from jaxdepth._src.normals import point_normals
from jaxdepth._src.outliers import outlier_keep_mask
from jaxdepth._src.pipeline import complete, complete_stages
from jaxdepth._src.residual import plane_residual
from jaxdepth._src.types import LidarSpec

from helpers import numpy_column_hypotheses
from test_above_scan import numpy_above_scan
from scenes import NON_DEFAULT, SMALL_LIDAR, thinned_for_listed_normals, tiny_frame



def reference_stages(sparse, K, T, *, config: SGMConfig, lidar: LidarSpec) -> dict:
    """Steps 1-4 composed from the public stage functions, one after the other."""
    sparse = np.where(np.isfinite(sparse) & (sparse > 0), sparse, 0).astype(np.float32)
    K = jnp.asarray(K, jnp.float32)
    T = jnp.asarray(T, jnp.float32)
    h, w = sparse.shape
    points = transform_points(invert_rigid(T), unproject_depth(jnp.asarray(sparse), K).reshape(-1, 3))
    n_lidar = point_normals(points, jnp.asarray(sparse > 0).reshape(-1), lidar=lidar,
                            smoothing=config.normal_smoothing, fill_max_gap=config.range_fill_max_gap)
    normals = (T[:3, :3] @ n_lidar.T).reshape(3, h, w)
    if config.outlier_removal:
        keep = outlier_keep_mask(sparse, K, T, beams=lidar.beams, epsilon_m=config.epsilon_m,
                                 max_half_width_px=config.outlier_max_half_width_px,
                                 max_half_height_px=config.outlier_max_half_height_px)
    else:
        keep = jnp.asarray(sparse > 0)
    seeds = nearest_seed(keep, metric=config.distance_metric)
    seed_depth = gather_at_seed(jnp.where(keep, sparse, 0.0), seeds.du, seeds.dv)
    seed_normal = gather_at_seed(normals, seeds.du, seeds.dv)
    residual = plane_residual(seed_depth, seed_normal, seeds.du, seeds.dv, K, min_abs_denom=config.min_abs_denom,
                              max_residual_ratio=config.max_residual_ratio)
    seed_depth, residual, keep = (np.asarray(a) for a in (seed_depth, residual, keep))
    has_seed = seed_depth > 0
    depth_raw = np.where(has_seed, np.clip(seed_depth + residual, config.min_depth_m, config.max_depth_m), 0.0)
    if config.column_bracket:
        du, dv = np.asarray(seeds.du, np.float64), np.asarray(seeds.dv, np.float64)
        distance = np.abs(du) + np.abs(dv) if config.distance_metric == "l1" else np.hypot(du, dv)
        depth_raw = numpy_column_hypotheses(
            depth_raw.astype(np.float32), np.where(keep, sparse, 0.0), h / lidar.beams, seed_distance=distance,
            normals=np.asarray(normals), K=np.asarray(K), blend=config.blend_hypotheses,
            min_abs_denom=config.min_abs_denom, max_residual_ratio=config.max_residual_ratio)
    depth_raw = depth_raw.astype(np.float32)
    if config.above_scan == "background":
        depth_raw = numpy_above_scan(depth_raw, seed_depth, keep, sparse > 0, beams=lidar.beams,
                                     max_half_width_px=config.outlier_max_half_width_px)
    r = config.smoothing_radius_px
    depth = cv2.GaussianBlur(depth_raw, (2 * r + 1, 2 * r + 1), config.smoothing_sigma_px,
                             borderType=cv2.BORDER_REFLECT_101) if config.smoothing_sigma_px > 0 else depth_raw
    if config.keep_measured_depth:
        depth = np.where(keep, sparse, depth)
    depth = np.where(has_seed, np.clip(depth, config.min_depth_m, config.max_depth_m), 0.0)
    return dict(sparse_depth=sparse, normals=np.asarray(normals), inlier_mask=keep, seed_depth=seed_depth,
                du=np.asarray(seeds.du), dv=np.asarray(seeds.dv), residual=residual, depth_raw=depth_raw,
                depth=depth)


def check_equal(got, want):
    for name in ("sparse_depth", "inlier_mask", "du", "dv", "seed_depth"):
        np.testing.assert_array_equal(np.asarray(getattr(got, name)), want[name], err_msg=name)
    np.testing.assert_allclose(np.asarray(got.normals), want["normals"], atol=1e-4, err_msg="normals")
    for name in ("residual", "depth_raw", "depth"):
        np.testing.assert_allclose(np.asarray(getattr(got, name)), want[name], rtol=1e-3, atol=2e-3,
                                   err_msg=name)


# 32 x 48 frames of SMALL_LIDAR, T passed: the programs of the stage table's pipeline rows (default
# configuration); NON_DEFAULT (scenes.py: every non-default code path) is test_pipeline's scaling program.
@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
@pytest.mark.xdist_group("speed_equivalence_synthetic")  # both configurations share the reference's stage programs: one worker
@pytest.mark.parametrize("config", [SGMConfig(), NON_DEFAULT], ids=["default", "non_default"])
def test_synthetic_frame_equals_reference(config):
    sparse, K, T = tiny_frame(0)
    assert (sparse > 0).sum() > 500
    got = complete_stages(sparse, K, T, config=config, lidar=SMALL_LIDAR)
    check_equal(got, reference_stages(sparse, K, T, config=config, lidar=SMALL_LIDAR))


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_wide_camera_takes_the_whole_range_image_and_vmap_agrees():
    """Cameras wider than the normals' 100-degree column window (f = 18 and 16 px on 48 columns: 106 and 113 degrees;
    exact fallback to the whole range image), as projected and thinned to the listed branch, alone and
    in a batch of three (the stage table's vmap of complete: same program)."""
    wide = [tiny_frame(1, f=18.0), tiny_frame(2, f=16.0)]
    sparse, K, T = wide[0]
    wide.append((thinned_for_listed_normals(sparse, keep=1 / 8, min_points=20), K, T))
    want = []
    for sparse, K, T in wide:
        got = complete_stages(sparse, K, T, lidar=SMALL_LIDAR)
        want.append(reference_stages(sparse, K, T, config=SGMConfig(), lidar=SMALL_LIDAR))
        check_equal(got, want[-1])
    depths = np.stack([f[0] for f in wide])
    Ks = np.stack([f[1] for f in wide])
    batched = np.asarray(jax.vmap(functools.partial(complete, config=SGMConfig(), lidar=SMALL_LIDAR),
                                  in_axes=(0, 0, None))(depths, Ks, T))
    for i in range(len(wide)):
        np.testing.assert_allclose(batched[i], want[i]["depth"], rtol=1e-3, atol=2e-3)


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_thinned_frame_takes_the_listed_normals_and_equals_reference():
    """About 1 point in 16 of the 32 x 48 frame: fewer points than the image-plane normals' n_pix / 16
    slots, so they take the listed branch (compacted pixels on a window of range-image columns) that
    KITTI frames take, where the full frame takes the dense one. Same shape: same programs."""
    sparse, K, T = tiny_frame(0)
    thin = thinned_for_listed_normals(sparse, keep=1 / 16, min_points=20)
    got = complete_stages(thin, K, T, lidar=SMALL_LIDAR)
    check_equal(got, reference_stages(thin, K, T, config=SGMConfig(), lidar=SMALL_LIDAR))


# KITTI size: the real density and window; slow. The default configuration: the program of
# test_pipeline's and test_xla_tuning's KITTI runs (l2 and the other non-default paths: NON_DEFAULT above).
@pytest.mark.slow
def test_kitti_frame_equals_reference(kitti):
    sparse, K, T = kitti.sparse[2], kitti.K[2], kitti.T_cam_lidar[2]
    config = SGMConfig()
    got = complete_stages(sparse, K, T, config=config, lidar=presets.KITTI_HDL64)
    check_equal(got, reference_stages(sparse, K, T, config=config, lidar=presets.KITTI_HDL64))
