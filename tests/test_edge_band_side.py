"""The edge-band side study's helpers (benchmarks/studies/edge_band_side.py): the scaled window against a
brute force, the window gather against a loop, and the edge line on an analytic two-plane scene."""

import numpy as np
import pytest

from benchmarks.studies import edge_band_side as eb
from jaxdepth import LidarSpec


def _K(f, n=2):
    return np.stack([np.array([[f, 0.0, 600.0], [0.0, f, 180.0], [0.0, 0.0, 1.0]])] * n)


def _brute_radii(mode, f_px, lidar, scale):
    """Written out per mode: the factor on 24 px (rows, columns) and the band's 3 px half size."""
    import math
    line_deg = (lidar.fov_up_deg - lidar.fov_down_deg) / (lidar.beams - 1)
    fac = {"pixels": (1.0, 1.0), "image": (scale, scale), "angle": (f_px / 1260.18, f_px / 1260.18),
           "scanline": (f_px * line_deg / 1260.18 / (41.34 / 31), f_px * 360 / lidar.columns / 1260.18 / (360 / 1088))}
    rows, cols = fac[mode]
    half = lambda r, x: max(1, math.floor(r * x + 0.5))  # noqa: E731
    return half(24, rows), half(24, cols), 2 * half(3, rows) + 1


HDL32 = LidarSpec(beams=32, fov_up_deg=10.67, fov_down_deg=-30.67, columns=1088)
HDL64 = LidarSpec(beams=64, fov_up_deg=2.0, fov_down_deg=-24.9, columns=2048)


@pytest.mark.parametrize("mode", eb.WINDOW_MODES)
@pytest.mark.parametrize("f_px, lidar, scale", [(1260.18, HDL32, 1.0), (630.09, HDL32, 0.5),
                                                (721.5377, HDL64, 1.0), (180.384, HDL64, 0.25)])
def test_window_radii_brute_force(mode, f_px, lidar, scale):
    got = eb.window_radii(mode, _K(f_px), lidar, scale)
    assert got == _brute_radii(mode, f_px, lidar, scale)
    if lidar is HDL32 and mode != "pixels":   # the reference rig: 49 x 49 and 7 x 7 times the scale
        assert got == (round(24 * scale), round(24 * scale), 2 * round(3 * scale + 0.01) + 1)


def test_window_radii_known_values():
    assert eb.window_radii("image", _K(180.384), HDL64, 0.25) == (6, 6, 3)
    assert eb.window_radii("angle", _K(721.5377), HDL64, 1.0) == (14, 14, 5)
    assert eb.window_radii("scanline", _K(721.5377), HDL64, 1.0) == (4, 7, 3)
    with pytest.raises(ValueError):
        eb.window_radii("metres", _K(700.0), HDL64, 1.0)


@pytest.mark.parametrize("rv, ru", [(1, 2), (3, 3), (24, 24)])
def test_window_gather_matches_loop(rv, ru):
    rng = np.random.default_rng(rv * 10 + ru)
    h, w = 30, 40
    kept = np.where(rng.random((h, w)) < 0.3, rng.uniform(2, 50, (h, w)), 0.0)
    normals = rng.normal(size=(3, h, w))
    v, u = rng.integers(0, h, 25), rng.integers(0, w, 25)
    z, n, qv, qu = eb._window(kept, normals, v, u, rv, ru)
    for i in range(len(v)):
        k = 0
        for dv in range(-rv, rv + 1):
            for du in range(-ru, ru + 1):
                y, x = v[i] + dv, u[i] + du
                inside = 0 <= y < h and 0 <= x < w
                assert z[i, k] == (kept[y, x] if inside else 0.0)
                if inside:
                    assert (qv[i, k], qu[i, k]) == (y, x)
                    np.testing.assert_array_equal(n[i, k], normals[:, y, x])
                k += 1


def test_edge_line_takes_the_pixels_side():
    """Two fronto-parallel planes (10 m left of column 20, 30 m right), seeds every 4th row and column: a band
    pixel takes its own side's depth under the edge line at any window, whatever its own seed says."""
    h, w = 40, 40
    depth = np.where(np.arange(w)[None] < 20, 10.0, 30.0) * np.ones((h, 1))
    kept = np.zeros((h, w))
    kept[::4, 2::4] = depth[::4, 2::4]
    normals = np.zeros((3, h, w))
    normals[2] = 1.0
    K = _K(500.0, 1)[0]
    v = np.array([20, 20, 21, 21])
    u = np.array([17, 19, 20, 23])
    wrong = np.where(u < 20, 30.0, 10.0)                        # own seed on the other side
    seed = (wrong, np.tile([0.0, 0.0, 1.0], (4, 1)), v.astype(float), u.astype(float))
    for rv, ru in [(3, 5), (8, 8), (24, 24)]:
        got = eb.choose(kept, normals, K, v, u, wrong, seed, depth[v, u], rv, ru)
        np.testing.assert_allclose(got["edge_line"], depth[v, u])
        np.testing.assert_allclose(got["own"], wrong)


def test_edge_class_brute_force():
    rng = np.random.default_rng(3)
    c, h, w, rv, ru = 2, 23, 31, 6, 8
    sparse = np.where(rng.random((c, h, w)) < 0.2, rng.choice([5.0, 5.1, 12.0, 30.0], (c, h, w)), 0.0)
    z = np.where(rng.random((c, h, w)) < 0.3, rng.choice([5.0, 12.0, 29.0], (c, h, w)), 0.0)
    got = eb.edge_class(sparse, z, rv, ru)
    for i, y, x in np.ndindex(c, h, w):
        if z[i, y, x] == 0:
            assert got[i, y, x] == -1
            continue
        t = max(1.0, 0.05 * z[i, y, x])

        def edge(a, b):
            win = sparse[i, max(0, y - a):y + a + 1, max(0, x - b):x + b + 1]
            return bool(np.any((win > 0) & (np.abs(win - z[i, y, x]) > t)))
        assert got[i, y, x] == (0 if edge(4, 4) else 1 if edge(rv, ru) else 2)
