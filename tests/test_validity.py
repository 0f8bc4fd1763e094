"""Validity masks (jaxdepth/_src/validity.py) and the depth preview with a scale bar.

Oracles: a NumPy float64 loop over every pixel for the ray elevation; a brute-force
minimum over all seeds for the seed distance; the analytic row where the elevation
of a level camera crosses fov_up; jit == eager; vmap == loop.
"""

from __future__ import annotations

import math

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth.batch import extras
from jaxdepth._src import colorize as cz
from jaxdepth._src import validity as vd
from jaxdepth._src.distance import gather_at_seed, nearest_seed
from jaxdepth._src.types import LidarSpec, Stages

H, W = 11, 17
LIDAR = LidarSpec(beams=16, fov_up_deg=4.0, fov_down_deg=-9.0, columns=64)
# LiDAR (x forward, y left, z up) -> camera (x right, y down, z forward), no translation needed.
R_LEVEL = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], np.float64)


def _rot(axis, angle):
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (0, 2), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _camera(seed: int):
    """A random K (with skew) and a level camera tilted by a few degrees, as float32."""
    rng = np.random.default_rng(seed)
    K = np.array([[rng.uniform(8, 14), rng.uniform(-0.5, 0.5), rng.uniform(6, 10)],
                  [0, rng.uniform(8, 14), rng.uniform(3, 7)], [0, 0, 1]])
    tilt = _rot(0, rng.uniform(-0.1, 0.1)) @ _rot(1, rng.uniform(-0.2, 0.2)) @ _rot(2, rng.uniform(-0.05, 0.05))
    T = np.eye(4)
    T[:3, :3] = tilt @ R_LEVEL
    T[:3, 3] = rng.uniform(-0.5, 0.5, 3)
    return K.astype(np.float32), T.astype(np.float32)


def _elevation_loop(K, T, h, w):
    """float64 NumPy oracle: elevation of R^T K^-1 [u, v, 1], one pixel at a time."""
    Kinv = np.linalg.inv(K.astype(np.float64))
    R = T[:3, :3].astype(np.float64)
    out = np.zeros((h, w))
    for v in range(h):
        for u in range(w):
            d = R.T @ (Kinv @ np.array([u, v, 1.0]))
            out[v, u] = math.atan2(d[2], math.hypot(d[0], d[1]))
    return out


def _seed_distance_loop(seeds, metric):
    """Brute-force distance from every pixel to the nearest True pixel (inf when none)."""
    vs, us = np.nonzero(seeds)
    out = np.full(seeds.shape, np.inf)
    for v in range(seeds.shape[0]):
        for u in range(seeds.shape[1]):
            if len(vs):
                dv, du = vs - v, us - u
                d = np.abs(du) + np.abs(dv) if metric == "l1" else np.sqrt(du * du + dv * dv)
                out[v, u] = d.min()
    return out


def _stages(seed_mask, metric, rng):
    """Stages fields of a seed mask: du, dv from nearest_seed, seed_depth gathered (others zero)."""
    depth = np.where(seed_mask, rng.uniform(2.0, 40.0, seed_mask.shape), 0.0).astype(np.float32)
    ns = nearest_seed(jnp.asarray(seed_mask), metric=metric)
    seed_depth = gather_at_seed(jnp.asarray(depth), ns.du, ns.dv)
    z = jnp.zeros(seed_mask.shape, jnp.float32)
    return Stages(sparse_depth=jnp.asarray(depth), normals=jnp.zeros((3,) + seed_mask.shape, jnp.float32),
                  inlier_mask=jnp.asarray(seed_mask), seed_depth=seed_depth, du=ns.du, dv=ns.dv, residual=z,
                  depth_raw=z, depth=z)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ray_elevation_and_fov_mask_match_a_numpy_loop(seed):
    K, T = _camera(seed)
    elev = np.asarray(vd.ray_elevation(K, T, height=H, width=W))
    oracle = _elevation_loop(K, T, H, W)
    assert elev.dtype == np.float32 and elev.shape == (H, W)
    np.testing.assert_allclose(elev, oracle, atol=20 * np.finfo(np.float32).eps)
    mask = np.asarray(vd.fov_mask(K, T, height=H, width=W, lidar=LIDAR))
    want = (oracle >= math.radians(LIDAR.fov_down_deg)) & (oracle <= math.radians(LIDAR.fov_up_deg))
    near_edge = np.minimum(np.abs(oracle - math.radians(LIDAR.fov_down_deg)),
                           np.abs(oracle - math.radians(LIDAR.fov_up_deg))) < 1e-5
    assert mask.dtype == bool
    np.testing.assert_array_equal(mask[~near_edge], want[~near_edge])
    assert want.any() and not want.all()  # the case really cuts the image


def test_level_camera_crosses_fov_up_at_cy_minus_fy_tan():
    """Analytic: a camera looking along the LiDAR's x axis sees elevation atan((cy - v) / fy) in column cx."""
    h, w = 120, 41
    fy, cx, cy = 100.0, 20.0, 60.3
    K = np.array([[100.0, 0, cx], [0, fy, cy], [0, 0, 1]], np.float32)
    T = np.eye(4, dtype=np.float32)
    T[:3, :3] = R_LEVEL
    lidar = LidarSpec(fov_up_deg=10.0, fov_down_deg=-20.0)
    col = np.asarray(vd.fov_mask(K, T, height=h, width=w, lidar=lidar))[:, int(cx)]
    top = cy - fy * math.tan(math.radians(lidar.fov_up_deg))  # 42.67
    bottom = cy - fy * math.tan(math.radians(lidar.fov_down_deg))  # 96.70
    rows = np.nonzero(col)[0]
    assert rows[0] == math.ceil(top) and rows[-1] == math.floor(bottom)
    assert np.all(np.diff(rows) == 1)
    elev = np.asarray(vd.ray_elevation(K, T, height=h, width=w))[:, int(cx)]
    np.testing.assert_allclose(elev, np.arctan((cy - np.arange(h)) / fy), atol=1e-6)


@pytest.mark.parametrize("metric", ["l1", "l2"])
def test_seed_distance_matches_brute_force_and_is_inf_without_seeds(metric):
    rng = np.random.default_rng(5)
    seeds = rng.random((H, W)) < 0.08
    seeds[3, 4] = True
    st = _stages(seeds, metric, rng)
    dist = np.asarray(vd.seed_distance(st.du, st.dv, st.seed_depth, metric=metric))
    np.testing.assert_allclose(dist, _seed_distance_loop(seeds, metric), rtol=4 * np.finfo(np.float32).eps)
    empty = _stages(np.zeros((H, W), bool), metric, rng)
    assert np.all(np.isinf(np.asarray(vd.seed_distance(empty.du, empty.dv, empty.seed_depth, metric=metric))))
    with pytest.raises(ValueError, match="metric"):
        vd.seed_distance(st.du, st.dv, st.seed_depth, metric="l3")


# validity_and_distance against the FOV loop and the brute-force seed distance, jit == eager, vmap == loop,
# no retrace, and validity_mask its first half: row validity_and_distance of tests/stage_table.py.


def test_cli_default_matches_the_library_default():
    assert extras.DEFAULT_MAX_SEED_DISTANCE_PX == vd.DEFAULT_MAX_SEED_DISTANCE_PX


def test_seed_distance_png_encoding_round_trip():
    d = np.array([[0.0, 1.0, 2.5, np.sqrt(2.0)], [4095.0, 4096.0, np.inf, np.nan]], np.float32)
    enc = extras.encode_seed_distance(d)
    assert enc.dtype == np.uint16
    np.testing.assert_array_equal(enc, [[0, 16, 40, 23], [65520, 65535, 65535, 65535]])
    dec = extras.decode_seed_distance(enc)
    np.testing.assert_allclose(dec[0], np.rint(d[0] * 16) / 16)
    assert np.all(np.isinf(dec[1, 1:]))


def test_extra_paths_and_bad_options():
    assert extras.extra_path("/a/b/0000000005.png", "preview").as_posix() == "/a/b/0000000005_preview.png"
    all_on = extras.ExtraOutputs(preview=True, validity=True, seed_distance=True)
    assert [p.name for p in extras.output_paths("x/CAM_FRONT.png", all_on)] == [
        "CAM_FRONT.png", "CAM_FRONT_preview.png", "CAM_FRONT_validity.png", "CAM_FRONT_seed_distance.png"]
    with pytest.raises(ValueError, match="max_seed_distance_px"):
        extras.ExtraOutputs(max_seed_distance_px=-1)
    with pytest.raises(ValueError, match="preview_range"):
        extras.ExtraOutputs(preview_range=(5.0, 5.0))


def test_nice_ticks_are_round_and_inside():
    for lo, hi in ((3.2, 87.9), (0.0, 1.0), (12.0, 13.1), (1.0, 1000.0)):
        t = cz.nice_ticks(lo, hi)
        assert 2 <= len(t) <= 7 and t[0] >= lo - 1e-9 and t[-1] <= hi + 1e-9
        step = np.diff(t)
        np.testing.assert_allclose(step, step[0])
        mant = step[0] / 10 ** np.floor(np.log10(step[0]))
        assert any(np.isclose(mant, m) for m in (1, 2, 5))


def test_depth_preview_image_rows_bar_colours_and_labels():
    rng = np.random.default_rng(1)
    d = rng.uniform(2.0, 60.0, (40, 300)).astype(np.float32)
    d[rng.random(d.shape) < 0.3] = 0.0
    out = cz.depth_preview(d, vmin=0.0, vmax=50.0, bar_height_px=36)
    assert out.shape == (76, 300, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[:40], cz.colorize_depth(d, vmin=0.0, vmax=50.0))
    lut = cz.colormap_lut("turbo")
    x = np.arange(300)
    np.testing.assert_array_equal(out[41, x], lut[np.rint(x / 299 * 255).astype(int)])  # ramp row, left = vmin
    # ticks at 0, 20, 40 m (nice_ticks with at most 300 // 60 = 5): white marks under the ramp at x = t / 50 * 299
    tick_x = [0, 120, 239]
    np.testing.assert_array_equal(out[40 + 13:40 + 17, tick_x], 255)
    labels = out[40 + 17:].max(axis=(0, 2))  # text columns below the marks
    for x in tick_x:
        assert labels[max(0, x - 12):x + 12].max() > 128  # a label ('0 m', '20 m', '40 m') around each tick
    assert labels[40:90].max() == 0 and labels[165:200].max() == 0  # nothing between the labels
    with pytest.raises(ValueError, match="bar_height_px"):
        cz.depth_preview(d, bar_height_px=4)
    empty = cz.depth_preview(np.zeros((5, 200), np.float32))
    assert (empty[:5] == 0).all() and empty.shape == (41, 200, 3)


def test_preview_is_written_as_rgb_png(tmp_path):
    d = np.linspace(1.0, 30.0, 24 * 200, dtype=np.float32).reshape(24, 200)
    [path, preview] = extras.write_outputs(tmp_path / "f.png", d, extras=extras.ExtraOutputs(preview=True))
    back = cv2.imread(str(preview), cv2.IMREAD_COLOR)[..., ::-1]
    np.testing.assert_array_equal(back, cz.depth_preview(d))  # the computed depth, before PNG rounding
    assert path.name == "f.png" and preview.name == "f_preview.png"
