"""The parallax and local-spacing cover tests of benchmarks/studies/cover_scan2.py: the parallax shift against
the projection of a point slid along the LiDAR ray, the test against a per-target brute force on small random
scenes, analytic cases, and the row spacing of a known line pattern."""

import numpy as np
import pytest

from benchmarks.studies import cover_scan2 as cs2


def _project(K, X):
    return np.array([K[0, 0] * X[0] / X[2] + K[0, 2], K[1, 1] * X[1] / X[2] + K[1, 2]])


@pytest.mark.parametrize("c", [(0.0, -0.3, 0.0), (0.06, -0.08, -0.27), (-0.5, 0.2, 0.4)])
def test_parallax_shift_is_the_projection_along_the_lidar_ray(c):
    """A point Q on the LiDAR ray through P (camera frame, LiDAR origin c) projects at P's pixel plus
    shift * (toward-LiDAR unit vector), shift = |toward| (z_P - z_Q) / ((z_P - c_z) z_Q)."""
    from benchmarks.studies.cover_tests import toward_lidar
    K = np.array([[600.0, 0, 400], [0, 620.0, 220], [0, 0, 1]])
    c = np.asarray(c)
    rng = np.random.default_rng(1)
    for _ in range(20):
        P = np.array([rng.uniform(-8, 8), rng.uniform(-3, 3), rng.uniform(6, 40)])
        t = rng.uniform(0.05, 0.8)
        Q = P + t * (c - P)
        u, v = _project(K, P)
        du, dv = toward_lidar(u, v, K, np.eye(4), c)
        norm = np.hypot(du, dv)
        shift = norm * (P[2] - Q[2]) / ((P[2] - c[2]) * Q[2])
        np.testing.assert_allclose(_project(K, Q) - (u, v), shift * np.array([du, dv]) / norm, atol=1e-9)


def _brute(target, full, K, T, origin, ks, reach, width):
    """Per target: per line across offset p and side, walk out to the first sweep point (not the target's own
    pixel) and test its place against its parallax shift."""
    from benchmarks.studies.cover_tests import toward_lidar
    H, W = target.shape
    c = np.asarray(T, np.float64)[:3, :3] @ origin + np.asarray(T, np.float64)[:3, 3]
    out = {k: np.zeros((H, W), bool) for k in ks}
    for y, x in zip(*np.nonzero(target > 0)):
        z = float(target[y, x])
        du, dv = toward_lidar(x, y, K, T, origin)
        n = np.hypot(du, dv)
        ux, uy = du / n, dv / n
        for p in range(-width, width + 1):
            for side in (-1, 1):
                for a in range(1, reach + 1):
                    s = side * a
                    qx, qy = int(np.rint(x + s * ux - p * uy)), int(np.rint(y + s * uy + p * ux))
                    if not (0 <= qx < W and 0 <= qy < H) or full[qy, qx] <= 0 or (qx, qy) == (x, y):
                        continue
                    zq = float(full[qy, qx])
                    if zq < z - max(1.0, 0.05 * z):
                        shift = n * (z - zq) / ((z - c[2]) * zq)
                        for k in ks:
                            out[k][y, x] |= -k * shift - 0.5 <= s <= shift + 0.5
                    break
    return out


@pytest.mark.parametrize("seed, width", [(0, 1), (1, 2), (2, 0)])
def test_parallax_cover_brute_force(seed, width):
    """Scan lines every 3 rows (a point kept with probability 0.8) over two depth layers, every third point
    held out as a target; a LiDAR 1.5 m above, 0.4 m beside and 0.3 m behind the camera."""
    rng = np.random.default_rng(seed)
    full = np.zeros((22, 29), np.float32)
    rows = np.arange(1, 22, 3)
    depth = np.where(rng.random((len(rows), 29)) < 0.4, rng.uniform(2.0, 8.0, (len(rows), 29)),
                     rng.uniform(12.0, 40.0, (len(rows), 29)))
    full[rows] = np.where(rng.random((len(rows), 29)) < 0.8, depth, 0.0)
    target = np.where((full > 0) & (rng.random(full.shape) < 0.34), full, 0.0).astype(np.float32)
    K = np.array([[30.0, 0.0, 14.0], [0.0, 30.0, 11.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, 3] = [0.4, -1.5, -0.3]
    origin = np.zeros(3)
    got = cs2.parallax_cover(target, full, K, T, origin, (0.5, 1), 6, width)
    want = _brute(target, full, K, T, origin, (0.5, 1), 6, width)
    assert 0 < want[1].sum() < (target > 0).sum()
    for k in (0.5, 1):
        np.testing.assert_array_equal(got[k], want[k], err_msg=str(k))


def test_parallax_cases():
    """LiDAR 1 m above the camera (c_y = -1), f = 100 px, target at 20 m on the optical axis's column: the
    toward-LiDAR direction is up (-v). A point at 5 m 10 px below (away side; shift 100 (20 - 5) / (20 * 5)
    = 15 px) drops it; the same 40 px below (beyond k shift) does not; with a point of 19.5 m (not nearer)
    met first on that line it does not either; the same 5 m point 10 px above (towards the LiDAR, within the
    shift) drops it."""
    H, W = 90, 21
    K = np.array([[100.0, 0, 10], [0, 100.0, 45], [0, 0, 1]])
    T = np.eye(4)
    T[:3, 3] = [0.0, -1.0, 0.0]
    target = np.zeros((H, W), np.float32)
    target[45, 10] = 20.0

    def dropped(points, k=1):
        full = np.zeros((H, W), np.float32)
        for (y, x), z in points.items():
            full[y, x] = z
        full[45, 10] = 20.0
        return bool(cs2.parallax_cover(target, full, K, T, np.zeros(3), (k,), 44, 0)[k][45, 10])
    assert dropped({(55, 10): 5.0})
    assert not dropped({(85, 10): 5.0})
    assert dropped({(65, 10): 5.0}, k=2)
    assert not dropped({(52, 10): 19.5, (55, 10): 5.0})
    assert dropped({(35, 10): 5.0})
    assert not dropped({(25, 10): 5.0})


def test_row_spacing_of_a_line_pattern():
    """Lines every 4 rows above row 20 and every 8 rows below: the spacing is 4 there and 8 here (the row a
    line sits on takes both gaps: their median)."""
    full = np.zeros((60, 10), np.float32)
    for y in list(range(0, 20, 4)) + list(range(20, 60, 8)):
        full[y, :] = 10.0
    s = cs2.row_spacing(full, 16)
    assert np.all(s[1:16] == 4) and np.all(s[21:52] == 8)
    assert s[20] == 6.0
