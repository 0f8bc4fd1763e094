"""The parallax cover test from each target's own LiDAR origin (benchmarks/studies/cover_scan3.py): a
two-origin analytic case, the per-source test against the one-origin test of each source's targets (and
exactly the one-origin test when every target has source 0), and the per-pixel source map."""

import types

import numpy as np

from benchmarks.studies import cover_scan2 as cs2
from benchmarks.studies import cover_scan3 as cs3

H, W = 90, 90
K = np.array([[100.0, 0, 45], [0, 100.0, 45], [0, 0, 1]])
ORIGINS = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])     # camera frame = reference frame (T = I)


def test_two_origin_analytic_case():
    """LiDAR 0 1 m above the camera (toward-LiDAR direction up, -v), LiDAR 1 1 m to its right (+u); a target
    at 20 m at the image centre, f = 100 px. A point at 5 m 10 px left of it lies on the side away from
    LiDAR 1 within its parallax shift 100 (20 - 5) / (20 * 5) = 15 px: it drops the target when the target
    came from LiDAR 1 and not when it came from LiDAR 0 (that line runs up and down); the same point 10 px
    below does the opposite. The first-origin test (origin 0 for every target) sees only the second."""
    target = np.zeros((H, W), np.float32)
    target[45, 45] = 20.0

    def dropped(point, source):
        full = target.copy()
        full[point] = 5.0
        src = np.full((H, W), source, np.int64)
        own = cs2.parallax_cover(target, full, K, np.eye(4), ORIGINS, (1,), 44, 0, source=src)[1][45, 45]
        first = cs2.parallax_cover(target, full, K, np.eye(4), ORIGINS[0], (1,), 44, 0)[1][45, 45]
        return bool(own), bool(first)
    assert dropped((45, 35), 1) == (True, False)
    assert dropped((45, 35), 0) == (False, False)
    assert dropped((55, 45), 1) == (False, True)
    assert dropped((55, 45), 0) == (True, True)
    assert dropped((45, 20), 1) == (False, False)      # 25 px away: beyond the shift


def test_own_origin_is_each_sources_one_origin_test():
    """Random two-layer scene, targets split between two LiDARs: the per-source test equals, at each target,
    the one-origin test run with that target's LiDAR; with every target from source 0 it is exactly the
    first-origin test (the one-origin twins give coverscan2's masks)."""
    rng = np.random.default_rng(3)
    full = np.zeros((H, W), np.float32)
    rows = np.arange(1, H, 3)
    depth = np.where(rng.random((len(rows), W)) < 0.4, rng.uniform(2.0, 8.0, (len(rows), W)),
                     rng.uniform(12.0, 40.0, (len(rows), W)))
    full[rows] = np.where(rng.random((len(rows), W)) < 0.8, depth, 0.0)
    target = np.where((full > 0) & (rng.random(full.shape) < 0.3), full, 0.0).astype(np.float32)
    src = (rng.random((H, W)) < 0.5).astype(np.int64)
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.05]
    for width in (0, 1, 2):
        own = cs2.parallax_cover(target, full, K, T, ORIGINS, (0.5, 1), 12, width, source=src)
        each = [cs2.parallax_cover(target, full, K, T, o, (0.5, 1), 12, width) for o in ORIGINS]
        zero = cs2.parallax_cover(target, full, K, T, ORIGINS, (0.5, 1), 12, width, source=np.zeros_like(src))
        for k in (0.5, 1):
            np.testing.assert_array_equal(own[k], np.where(src == 1, each[1][k], each[0][k]))
            np.testing.assert_array_equal(zero[k], each[0][k])
            assert (own[k] != each[0][k]).any()


def test_source_maps_take_the_nearest_points_source():
    """Two points on one camera ray (pixel (45, 45)) from sources 0 and 1: the nearer one's source; a lone
    source-1 point elsewhere: 1; empty pixels: 0."""
    cam = types.SimpleNamespace(K=K, T_cam_lidar=np.eye(4), height=H, width=W)
    rig = types.SimpleNamespace(cameras=[cam])
    points = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 6.0], [2.0, 0.0, 10.0], [0.0, 3.0, 10.0]], np.float32)
    for near_source in (0, 1):
        source = np.array([1 - near_source, near_source, 1, 0])
        m = cs3.source_maps(points, source, rig)[0]
        assert m[45, 45] == near_source and m[45, 65] == 1 and m[75, 45] == 0 and m[10, 10] == 0
