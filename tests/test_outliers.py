"""Step 2, occlusion outlier removal: against the paper's double loop, an analytic
occlusion scene, the real KITTI frame, and the jit / vmap / shape invariants."""

from __future__ import annotations

import math

import cv2
import hypothesis
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth._src import outliers as outliers_module
from jaxdepth._src.geometry import invert_rigid, project_to_image, transform_points
from jaxdepth._src.outliers import outlier_keep_mask, window_half_sizes

from oracles.outliers_dense_sweep import frozen_keep_mask


#: The window caps of most small cases here and of the stage table's rows (tests/stage_table.py): with
#: (24, 40) images and 6 beams they all run one compiled program per (test, points_cam given or not).
CAPS = dict(max_half_width_px=4, max_half_height_px=24)

SETTINGS = dict(deadline=None, max_examples=12, derandomize=True,
                suppress_health_check=[hypothesis.HealthCheck.too_slow])


# ----------------------------------------------------------------------------- oracle
def paper_double_loop(depth, K, T_cam_lidar, *, beams, epsilon_m=1.0, max_half_width_px=None,
                      max_half_height_px=None, points_cam=None):
    """The paper's Algorithm 1 as written: for i, for j in S(i), test, remove, break.

    float64 throughout, true atan2 angles of q = p_cam - t (camera-aligned axes at
    the LiDAR origin): theta = atan2(q_x, q_z), phi = atan2(q_y, q_z). The static
    caps (the implementation's documented deviation) apply when given.
    """
    depth = np.asarray(depth, np.float64)
    height, width = depth.shape
    valid = np.isfinite(depth) & (depth > 0)
    vs, us = np.nonzero(valid)
    n = len(vs)
    keep = valid.copy()
    if n == 0:
        return keep
    t = np.asarray(T_cam_lidar, np.float64)[:3, 3]
    if points_cam is None:
        rays = np.linalg.inv(np.asarray(K, np.float64)) @ np.stack([us, vs, np.ones(n)]).astype(np.float64)
        p = rays * depth[vs, us]
    else:
        p = np.asarray(points_cam, np.float64)[:, vs, us]
    q = p - t[:, None]
    theta = np.arctan2(q[0], q[2])
    phi = np.arctan2(q[1], q[2])
    z = depth[vs, us]
    bound_u = width * beams / n
    bound_v = height / beams
    for i in range(n):
        du = np.abs(us - us[i])
        dv = np.abs(vs - vs[i])
        in_s = (du < bound_u) & (dv < bound_v)
        if max_half_width_px is not None:
            in_s &= du <= max_half_width_px
        if max_half_height_px is not None:
            in_s &= dv <= max_half_height_px
        for j in np.nonzero(in_s)[0]:
            condition_1 = ((us[i] - us[j]) * (theta[i] - theta[j]) < 0
                           or (vs[i] - vs[j]) * (phi[i] - phi[j]) < 0)
            condition_2 = z[i] > z[j] + epsilon_m
            if condition_1 and condition_2:
                keep[vs[i], us[i]] = False
                break
    return keep


def footprint_double_loop(depth, K, T_cam_lidar, *, beams, epsilon_m=1.0, max_half_width_px=None,
                          max_half_height_px=None, points_cam=None, tol=1e-6):
    """Algorithm 1 with the footprint form of condition 1, written directly, float64.

    For i and j in S(i): a = pixel of the point seen from the LiDAR origin with
    the camera's axes and K, b = its camera pixel (exact for given points, the
    pixel centre otherwise); a move |m| under 1e-3 px does not count; in cells (W L / N by H / L
    pixels) ra = a_i - a_j, rb = b_i - b_j, m = rb - ra. i passes behind j
    through j's footprint when ra.m < 0 < rb.m and |ra x m| / |m| < 1/2.

    Returns (keep, unsure): ``unsure`` marks points whose decision rests on a
    comparison within ``tol`` (relative) of its threshold, where float32 and
    float64 may disagree.
    """
    depth = np.asarray(depth, np.float64)
    height, width = depth.shape
    valid = np.isfinite(depth) & (depth > 0)
    vs, us = np.nonzero(valid)
    n = len(vs)
    keep, unsure = valid.copy(), np.zeros_like(valid)
    if n == 0:
        return keep, unsure
    K = np.asarray(K, np.float64)
    t = np.asarray(T_cam_lidar, np.float64)[:3, 3]
    if points_cam is None:
        p = (np.linalg.inv(K) @ np.stack([us, vs, np.ones(n)])) * depth[vs, us]
        bu, bv = us.astype(np.float64), vs.astype(np.float64)
    else:
        p = np.asarray(points_cam, np.float64)[:, vs, us]
        bu = (K[0, 0] * p[0] + K[0, 1] * p[1]) / p[2] + K[0, 2]
        bv = K[1, 1] * p[1] / p[2] + K[1, 2]
    q = p - t[:, None]
    ok = q[2] > 1e-3
    qz = np.where(ok, q[2], 1.0)
    au = (K[0, 0] * q[0] + K[0, 1] * q[1]) / qz + K[0, 2]
    av = K[1, 1] * q[1] / qz + K[1, 2]
    z = depth[vs, us]
    cell_u, cell_v = width * beams / n, height / beams
    for i in range(n):
        du, dv = us - us[i], vs - vs[i]
        in_s = (np.abs(du) < cell_u) & (np.abs(dv) < cell_v) & (np.arange(n) != i)
        if max_half_width_px is not None:
            in_s &= np.abs(du) <= max_half_width_px
        if max_half_height_px is not None:
            in_s &= np.abs(dv) <= max_half_height_px
        js = np.nonzero(in_s & ok & ok[i] & (z[i] > z + epsilon_m))[0]
        if len(js) == 0:
            continue
        ra = np.stack([(au[i] - au[js]) / cell_u, (av[i] - av[js]) / cell_v])
        rb = np.stack([(bu[i] - bu[js]) / cell_u, (bv[i] - bv[js]) / cell_v])
        m = rb - ra
        mm = np.sum(m * m, 0)
        margins = np.stack([-np.sum(ra * m, 0), np.sum(rb * m, 0), mm - 4 * (ra[0] * m[1] - ra[1] * m[0]) ** 2])
        scale = np.maximum(mm, 1e-300)
        moved = mm * cell_u * cell_v > 1e-6
        margins = np.where(moved, margins, -1.0)
        firm = np.all(margins > tol * scale, 0)
        maybe = np.all(margins > -tol * scale, 0)
        if firm.any():
            keep[vs[i], us[i]] = False
        elif maybe.any():
            unsure[vs[i], us[i]] = True
    return keep, unsure


# ----------------------------------------------------------------------------- helpers
def _camera(rng, height, width):
    f = rng.uniform(0.6, 1.2) * width
    K = np.array([[f, 0, width / 2 + rng.uniform(-3, 3)],
                  [0, f * rng.uniform(0.9, 1.1), height / 2 + rng.uniform(-3, 3)],
                  [0, 0, 1]], np.float32)
    T = np.eye(4, dtype=np.float32)
    T[:3, :3] = cv2.Rodrigues(rng.normal(0, 0.05, 3))[0]
    T[:3, 3] = rng.normal(0, 0.4, 3)
    return K, T


def _random_sparse(rng, height, width, density):
    """Two depth layers (near blobs over a far background) at a given pixel density."""
    depth = rng.uniform(12.0, 40.0, (height, width))
    near = cv2.resize((rng.random((3, 4)) < 0.4).astype(np.uint8), (width, height),
                      interpolation=cv2.INTER_NEAREST).astype(bool)
    depth[near] = rng.uniform(2.0, 8.0, near.sum())
    depth[rng.random((height, width)) >= density] = 0.0
    return depth.astype(np.float32)


def _points_near_pixels(rng, K, depth, spread=0.5):
    """(3, H, W) camera-frame points at each pixel's depth, off the pixel centre by up to ``spread`` px."""
    shape = depth.shape
    v, u = np.mgrid[0:shape[0], 0:shape[1]]
    jitter = rng.uniform(-spread, spread, (2, *shape))
    rays = np.linalg.inv(K.astype(np.float64)) @ np.stack(
        [u + jitter[0], v + jitter[1], np.ones(shape)]).reshape(3, -1)
    return (rays.reshape(3, *shape) * depth).astype(np.float32)


#: Image size, beams and (default) caps of the analytic scenes below, of the KITTI windows and of the
#: frozen-oracle configuration with many removals: one compiled program per (form, path) serves them all.
SCENE_SHAPE = (96, 160)
SCENE_BEAMS = 32


def _kitti_window(kitti, cam, r0, c0):
    """A 96 x 160 window of the benchmark crop of camera ``cam``'s sparse input, its K, camera 2's T."""
    K = kitti.K[cam].copy()
    K[0, 2] -= c0
    K[1, 2] -= r0
    height, width = SCENE_SHAPE
    return kitti.sparse[cam][r0:r0 + height, c0:c0 + width], K, kitti.T_cam_lidar[2].copy()


# ----------------------------------------------------------------------------- oracle tests
@pytest.mark.xdist_group("outliers_24x40")  # the stage table's 24 x 40 CAPS keep-mask programs: one worker
@hypothesis.settings(**SETTINGS)
@hypothesis.given(seed=st.integers(0, 2**31 - 1), density=st.sampled_from([0.04, 0.1, 0.25]))
def test_matches_paper_double_loop_random(seed, density):
    """(24, 40) images, CAPS: the stage table's program. Other shapes of the paper form (widths not a
    multiple of 32, half height 0, small caps) are the frozen-oracle configurations below."""
    shape = (24, 40)
    rng = np.random.default_rng(seed)
    K, T = _camera(rng, *shape)
    depth = _random_sparse(rng, *shape, density)
    kw = dict(beams=6, epsilon_m=1.0, **CAPS)
    got = np.asarray(outlier_keep_mask(depth, K, T, test="paper", **kw))
    want = paper_double_loop(depth, K, T, **kw)
    assert got.dtype == np.bool_ and got.shape == shape
    np.testing.assert_array_equal(got, want)


@pytest.mark.xdist_group("outliers_24x40")  # the stage table's 24 x 40 CAPS keep-mask programs: one worker
@hypothesis.settings(**SETTINGS)
@hypothesis.given(seed=st.integers(0, 2**31 - 1))
def test_matches_paper_double_loop_points_cam(seed):
    """Raw-sweep path: angles from given camera-frame points, not from pixel centres (CAPS: the
    stage table's program)."""
    rng = np.random.default_rng(seed)
    shape = (24, 40)
    K, T = _camera(rng, *shape)
    depth = _random_sparse(rng, *shape, 0.1)
    points = _points_near_pixels(rng, K, depth)
    kw = dict(beams=6, epsilon_m=0.5, **CAPS)
    got = np.asarray(outlier_keep_mask(depth, K, T, points_cam=points, test="paper", **kw))
    np.testing.assert_array_equal(got, paper_double_loop(depth, K, T, points_cam=points, **kw))


@pytest.mark.xdist_group("outliers_scene")  # the analytic scenes' keep-mask program: one worker
@pytest.mark.parametrize("r0, c0", [(110, 150), (100, 880)])   # 96 x 320 with removals, two 96 x 160 windows
def test_matches_paper_double_loop_kitti_crop(kitti, r0, c0):
    """Real KITTI points against the double loop, in windows of the analytic scenes' size, beams and caps
    (their compiled program; the oracle takes the same window). 64 beams on the whole frame: the
    frozen-oracle and removal tests below."""
    kw = dict(beams=SCENE_BEAMS, epsilon_m=1.0, max_half_width_px=12, max_half_height_px=24)
    points = removed = 0
    for c in (c0, c0 + SCENE_SHAPE[1]):
        crop, K, T = _kitti_window(kitti, 2, r0, c)
        got = np.asarray(outlier_keep_mask(crop, K, T, test="paper", **kw))
        want = paper_double_loop(crop, K, T, **kw)
        np.testing.assert_array_equal(got, want)
        points += (crop > 0).sum()
        removed += (~want & (crop > 0)).sum()
    assert points > 1000 and removed > 5   # a non-trivial case


def _assert_matches_footprint(got, want, unsure):
    sure = ~unsure
    np.testing.assert_array_equal(got[sure], want[sure])
    assert unsure.sum() <= 2


@pytest.mark.xdist_group("outliers_24x40")  # the stage table's 24 x 40 CAPS keep-mask programs: one worker
@hypothesis.settings(**SETTINGS)
@hypothesis.given(seed=st.integers(0, 2**31 - 1), density=st.sampled_from([0.04, 0.1, 0.25]), raw=st.booleans())
def test_matches_footprint_double_loop_random(seed, density, raw):
    """(24, 40) images, CAPS: the stage table's programs (an odd shape: the test below)."""
    shape = (24, 40)
    rng = np.random.default_rng(seed)
    K, T = _camera(rng, *shape)
    depth = _random_sparse(rng, *shape, density)
    points = _points_near_pixels(rng, K, depth) if raw else None
    kw = dict(beams=6, epsilon_m=1.0, **CAPS)
    got = np.asarray(outlier_keep_mask(depth, K, T, points_cam=points, **kw))
    assert got.dtype == np.bool_ and got.shape == shape
    _assert_matches_footprint(got, *footprint_double_loop(depth, K, T, points_cam=points, **kw))


def test_matches_footprint_double_loop_odd_shape():
    """A shape narrower than a 32-bit word and of odd height, image path: several inputs, one program."""
    shape = (31, 23)
    kw = dict(beams=6, epsilon_m=1.0, **CAPS)
    removed = 0
    for seed, density in enumerate((0.04, 0.1, 0.25, 0.1, 0.25, 0.4)):
        rng = np.random.default_rng(100 + seed)
        K, T = _camera(rng, *shape)
        depth = _random_sparse(rng, *shape, density)
        got = np.asarray(outlier_keep_mask(depth, K, T, **kw))
        assert got.dtype == np.bool_ and got.shape == shape
        want, unsure = footprint_double_loop(depth, K, T, **kw)
        _assert_matches_footprint(got, want, unsure)
        removed += (~want & (depth > 0)).sum()
    assert removed > 0


@pytest.mark.xdist_group("outliers_24x40")  # the stage table's 24 x 40 CAPS keep-mask programs: one worker
@pytest.mark.parametrize("seed, far, t_z", [(0, 400.0, 0.0), (1, 300.0, 1.2), (2, 40.0, 2.5), (3, 260.0, -1.0)])
def test_footprint_prefilter_edge_depths(seed, far, t_z):
    """The prefilter keys saturate at 256 m and the parallax bound divides by Z - t_z: depths past
    256 m, a LiDAR ahead of the camera (points closer than it are never compared) and points just
    in front of it must not lose a removal."""
    rng = np.random.default_rng(seed)
    shape = (24, 40)
    K, T = _camera(rng, *shape)
    T[:3, 3] = (0.5, -0.3, t_z)
    depth = rng.uniform(0.6 * far, far, shape)
    near = rng.random(shape) < 0.3
    depth[near] = rng.uniform(max(t_z, 0.0) + 0.0005, max(t_z, 0.0) + 6.0, near.sum())
    depth[rng.random(shape) >= 0.2] = 0.0
    depth = depth.astype(np.float32)
    for raw in (False, True):
        points = None
        if raw:
            v, u = np.mgrid[0:shape[0], 0:shape[1]]
            rays = np.linalg.inv(K.astype(np.float64)) @ np.stack([u + 0.3, v - 0.2, np.ones(shape)]).reshape(3, -1)
            points = (rays.reshape(3, *shape) * depth).astype(np.float32)
        kw = dict(beams=6, epsilon_m=1.0, points_cam=points, **CAPS)
        got = np.asarray(outlier_keep_mask(depth, K, T, **kw))
        _assert_matches_footprint(got, *footprint_double_loop(depth, K, T, **kw))


@pytest.mark.xdist_group("outliers_scene")  # shared keep-mask programs: one worker
@pytest.mark.parametrize("r0, c0", [(110, 150), (100, 880)])
def test_matches_footprint_double_loop_kitti_crop(kitti, r0, c0):
    """As the paper form's KITTI test: two 96 x 160 windows, the analytic scenes' program."""
    kw = dict(beams=SCENE_BEAMS, epsilon_m=1.0, max_half_width_px=12, max_half_height_px=24)
    points = removed = 0
    for c in (c0, c0 + SCENE_SHAPE[1]):
        crop, K, T = _kitti_window(kitti, 3, r0, c)
        T[0, 3] -= 0.54          # camera 3 sits 0.54 m right of camera 2: more parallax, more removals
        got = np.asarray(outlier_keep_mask(crop, K, T, **kw))
        want, unsure = footprint_double_loop(crop, K, T, **kw)
        _assert_matches_footprint(got, want, unsure)
        points += (crop > 0).sum()
        removed += (~want & (crop > 0)).sum()
    assert points > 1000 and removed > 5


@pytest.mark.xdist_group("outliers_scene")  # shared keep-mask programs: one worker
@pytest.mark.parametrize("t_lidar", [(0.0, -0.3, -1.0), (0.2, -0.3, -0.5), (0.0, -0.3, 0.8)])
def test_radial_offset_over_open_ground_removes_nothing(t_lidar):
    """A LiDAR behind (or ahead of) and above the camera over bare ground (as
    nuScenes' roof LiDAR before its back camera): no point can hide another,
    yet points of neighbouring scan lines swap their u order between the two
    views (the radial parallax of a forward offset). The footprint test removes
    nothing; the paper's axis-aligned test removes ground points. (The image size, beams and
    options of the analytic occlusion scene below: the same compiled programs.)"""
    height, width = SCENE_SHAPE
    K = np.array([[80.0, 0, 79.5], [0, 80.0, 47.5], [0, 0, 1]], np.float32)
    o = np.asarray(t_lidar, np.float64)
    ground_y = 1.5                                       # ground plane y = 1.5 m below the camera
    elev = np.deg2rad(np.linspace(29.0, -29.0, 32))     # beams span the image height: H / L = beam spacing
    az = np.deg2rad(np.arange(-70.0, 70.0, 0.35))
    el, a = np.meshgrid(elev, az, indexing="ij")
    d = np.stack([np.cos(el) * np.sin(a), -np.sin(el), np.cos(el) * np.cos(a)], -1).reshape(-1, 3)
    with np.errstate(divide="ignore"):
        s_hit = np.where(d[:, 1] > 1e-6, (ground_y - o[1]) / np.maximum(d[:, 1], 1e-6), np.inf)
    p_cam = o + np.where(np.isfinite(s_hit), s_hit, 0.0)[:, None] * d
    T = np.eye(4, dtype=np.float32)
    T[:3, 3] = o
    p_lidar = (p_cam - o).astype(np.float32)
    depth, index = project_to_image(jnp.asarray(p_lidar), jnp.asarray(s_hit < 80.0), K, T, height=height, width=width)
    depth, index = np.asarray(depth), np.asarray(index)
    assert (depth > 0).sum() > 1500
    p_back = np.asarray(transform_points(T, jnp.asarray(p_lidar)))
    points = np.moveaxis(np.where((index >= 0)[..., None], p_back[np.maximum(index, 0)], 0.0), -1, 0)
    for raw in (None, points.astype(np.float32)):
        keep = np.asarray(outlier_keep_mask(depth, K, T, beams=SCENE_BEAMS, points_cam=raw))
        np.testing.assert_array_equal(keep, depth > 0)
    if t_lidar[2] < -0.7:
        paper = np.asarray(outlier_keep_mask(depth, K, T, beams=SCENE_BEAMS, points_cam=points.astype(np.float32),
                                             test="paper"))
        assert (paper != (depth > 0)).sum() > 10


# ----------------------------------------------------------------------------- frozen dense sweep
@pytest.mark.slow  # frozen oracle
def test_equals_frozen_dense_sweep_kitti(kitti):
    """Bit-identical to the previous implementation (the dense sweep over all
    window offsets) on the real frame: official sparse input of both cameras
    (image-only path) and the raw HDL-64E sweep projected with the camera-2
    calibration (image-only and raw-sweep paths)."""
    frozen = frozen_keep_mask
    K, T = kitti.K[2], kitti.T_cam_lidar[2]
    for name, sparse in (("camera 2", kitti.sparse[2]), ("camera 3", kitti.sparse[3])):
        got = np.asarray(outlier_keep_mask(sparse, K, T, beams=64, test="paper"))
        assert (~got & (sparse > 0)).sum() > 50
        np.testing.assert_array_equal(got, np.asarray(frozen(sparse, K, T, beams=64)), err_msg=name)
    scan = kitti.scan
    depth, index = project_to_image(jnp.asarray(scan), jnp.ones(len(scan), bool), K, T, height=352, width=1216)
    depth, index = np.asarray(depth), np.asarray(index)
    p_cam = np.asarray(transform_points(T, jnp.asarray(scan)))
    points = np.moveaxis(np.where((index >= 0)[..., None], p_cam[np.maximum(index, 0)], 0.0), -1, 0)
    points = points.astype(np.float32)
    np.testing.assert_array_equal(np.asarray(outlier_keep_mask(depth, K, T, beams=64, test="paper")),
                                  np.asarray(frozen(depth, K, T, beams=64)), err_msg="sweep, image path")
    np.testing.assert_array_equal(np.asarray(outlier_keep_mask(depth, K, T, beams=64, points_cam=points, test="paper")),
                                  np.asarray(frozen(depth, K, T, beams=64, points_cam=points)),
                                  err_msg="sweep, raw path")


@pytest.mark.parametrize("seed, shape, beams, density, caps", [
    (1, (96, 160), 32, 0.02, (12, 24)),   # k = 12, the cap: the capped small box (the scenes' programs)
    (2, (8, 70), 8, 0.3, (12, 24)),       # half height 0; width not a multiple of 32
    (3, (96, 160), 32, 0.3, (12, 24)),    # > _CHUNK removals: several chunks (the analytic scenes' programs)
    (4, (60, 90), 16, 0.1, (3, 2)),       # small caps
])
@pytest.mark.slow  # frozen oracle
def test_equals_frozen_dense_sweep_configurations(seed, shape, beams, density, caps):
    frozen = frozen_keep_mask
    rng = np.random.default_rng(seed)
    K, T = _camera(rng, *shape)
    depth = _random_sparse(rng, *shape, density)
    depth[1, 1] = depth[2, 3] = 5.0
    kw = dict(beams=beams, max_half_width_px=caps[0], max_half_height_px=caps[1])
    mode = dict(test="paper")
    n = int((depth > 0).sum())
    half_width, _ = window_half_sizes(*shape, beams=beams, max_half_width_px=caps[0], max_half_height_px=caps[1])
    k = min((shape[1] * beams - 1) // n, half_width)
    assert k == half_width if seed == 1 else k > 0
    points = np.stack([rng.normal(0, 3, shape), rng.normal(0, 1, shape), depth]).astype(np.float32)
    points[:, 1, 1] = np.nan                 # a valid pixel with a NaN point: no comparison holds
    points[0, 2, 3] = np.inf
    got = np.asarray(outlier_keep_mask(depth, K, T, **kw, **mode))
    np.testing.assert_array_equal(got, np.asarray(frozen(depth, K, T, **kw)))
    if seed == 3:
        assert (~got & (depth > 0)).sum() > outliers_module._CHUNK
    if seed in (2, 4):
        # window shapes (half height 0, small caps) that the raw-sweep path shares with the image path;
        # its own angles (and NaN / inf points) are compared on configurations 1 and 3 and on KITTI's sweep
        return
    got_raw = np.asarray(outlier_keep_mask(depth, K, T, points_cam=points, **kw, **mode))
    assert (got_raw != (depth > 0)).any()
    np.testing.assert_array_equal(got_raw, np.asarray(frozen(depth, K, T, points_cam=points, **kw)))


# ----------------------------------------------------------------------------- analytic scene
def _box_scene(t_lidar, *, box, wall_z, beams, elev_deg, az_step_deg):
    """Ray-casts a LiDAR at camera-frame position ``t_lidar`` (camera-aligned axes)
    against an axis-aligned box and a wall plane z = wall_z; returns LiDAR-frame
    points, T_cam_lidar, and a per-point flag "hit the box"."""
    elev = np.deg2rad(np.linspace(*elev_deg, beams))
    az = np.deg2rad(np.arange(-60.0, 60.0 + 1e-9, az_step_deg))
    el, a = np.meshgrid(elev, az, indexing="ij")
    d = np.stack([np.cos(el) * np.sin(a), -np.sin(el), np.cos(el) * np.cos(a)], -1).reshape(-1, 3)
    o = np.asarray(t_lidar, np.float64)
    lo, hi = np.asarray(box[0], np.float64), np.asarray(box[1], np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        s1, s2 = (lo - o) / d, (hi - o) / d
    s_near = np.nanmax(np.minimum(s1, s2), axis=1)
    s_far = np.nanmin(np.maximum(s1, s2), axis=1)
    hits_box = (s_near <= s_far) & (s_near > 0)
    s_wall = (wall_z - o[2]) / d[:, 2]
    s = np.where(hits_box, s_near, s_wall)
    p_cam = o + s[:, None] * d
    # A KITTI-like mounting: LiDAR x forward, y left, z up.
    R_cam_lidar = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], np.float64)
    T = np.eye(4)
    T[:3, :3] = R_cam_lidar
    T[:3, 3] = o
    p_lidar = (p_cam - o) @ R_cam_lidar      # R^T (p - o), row vectors
    return p_lidar.astype(np.float32), T.astype(np.float32), hits_box


def _camera_sees(p_cam, box):
    """True where the segment camera centre -> point does not pass through the box first."""
    lo, hi = np.asarray(box[0]), np.asarray(box[1])
    d = p_cam
    with np.errstate(divide="ignore", invalid="ignore"):
        s1, s2 = lo / d, hi / d
    s_near = np.nanmax(np.minimum(s1, s2), axis=-1)
    s_far = np.nanmin(np.maximum(s1, s2), axis=-1)
    return ~((s_near <= s_far) & (s_near > 0) & (s_near < 0.99))


@pytest.mark.xdist_group("outliers_scene")  # shared keep-mask programs: one worker
@pytest.mark.parametrize("t_lidar", [(0.4, 0.0, 0.0), (-0.4, 0.0, 0.0), (0.0, -0.5, 0.0), (0.3, -0.3, -0.2)])
@pytest.mark.parametrize("raw", [False, True])
@pytest.mark.parametrize("test", ["footprint", "paper"])
def test_analytic_occlusion_scene(t_lidar, raw, test):
    """A near box (z 6 .. 6.5 m) before a wall (z 20 m); the LiDAR sits beside,
    above, or beside-above-behind the camera and sees wall that the box hides
    from the camera.

    Ground truth from geometry: every wall pixel the camera cannot see must be
    removed and every box pixel kept. The box edges sit just beyond a LiDAR ray
    so that the box's last ray lands on its silhouette (a background point
    mapped beyond the last foreground point, on the very edge, is the exception
    the paper names). Visible wall pixels may be removed only next to the
    silhouette: condition 1 tests u and v order separately, so a wall point
    diagonally beside a box edge point, whose u (or v) order flips by parallax,
    is removed although the camera sees it past the box's end (the paper's rule,
    which the oracle shares). The footprint test removes a hidden point only
    where its path between the two views passes through a box point's cell:
    at a silhouette corner a path can slip between two cells, so up to 10 %
    of the hidden points may be kept there.
    """
    height, width = SCENE_SHAPE
    K = np.array([[100.0, 0, 79.5], [0, 100.0, 47.5], [0, 0, 1]], np.float32)
    beams, az_step = SCENE_BEAMS, 1.0
    elev_deg = (20.0, -20.0)
    elev_step = 40.0 / (beams - 1)
    o = np.asarray(t_lidar)
    # Box face at z = 6 m. Seen from the LiDAR, a ray of azimuth a meets it at
    # x = o_x + (6 - o_z) tan(a) and a ray of elevation e near y = o_y - (6 - o_z) tan(e):
    # put each edge a tenth of a ray step beyond the last ray that hits the box.
    reach = 6.0 - o[2]
    margin = 0.1
    x_lo = o[0] + reach * math.tan(math.radians(-(10 + margin) * az_step))
    x_hi = o[0] + reach * math.tan(math.radians((9 + margin) * az_step))
    elev = lambda k: 20.0 - k * elev_step      # beam k, from the top
    y_lo = o[1] - reach * math.tan(math.radians(elev(8) + margin * elev_step))
    y_hi = o[1] - reach * math.tan(math.radians(elev(24) - margin * elev_step))
    box = ((x_lo, y_lo, 6.0), (x_hi, y_hi, 6.5))
    points, T, hits_box = _box_scene(o, box=box, wall_z=20.0, beams=beams, elev_deg=elev_deg,
                                     az_step_deg=az_step)
    depth, index = project_to_image(jnp.asarray(points), jnp.ones(len(points), bool), K, T,
                                    height=height, width=width)
    depth, index = np.asarray(depth), np.asarray(index)
    p_cam = np.asarray(transform_points(T, jnp.asarray(points)))
    filled = index >= 0
    pix_cam = np.where(filled[..., None], p_cam[np.maximum(index, 0)], 0.0)
    is_box = filled & hits_box[np.maximum(index, 0)]
    hidden = filled & ~_camera_sees(pix_cam, box)
    visible_wall = filled & ~hidden & ~is_box
    assert is_box.sum() > 200 and hidden.sum() > 20 and visible_wall.sum() > 1000

    points_cam = np.moveaxis(pix_cam, -1, 0).astype(np.float32) if raw else None
    keep = np.asarray(outlier_keep_mask(depth, K, T, beams=beams, points_cam=points_cam, test=test))
    if test == "paper":
        np.testing.assert_array_equal(keep & hidden, np.zeros_like(hidden), "occluded wall points kept")
    else:
        assert (keep & hidden).sum() <= 0.1 * hidden.sum(), "occluded wall points kept"
    np.testing.assert_array_equal(keep[is_box], True, "box points removed")
    # Removed visible wall points: few, and each inside the window S of a box pixel.
    n = filled.sum()
    half_w = math.ceil(width * beams / n) - 1
    half_h = math.ceil(height / beams) - 1
    near_box = cv2.dilate(is_box.astype(np.uint8), np.ones((2 * half_h + 1, 2 * half_w + 1), np.uint8)) > 0
    wrongly = visible_wall & ~keep
    assert not (wrongly & ~near_box).any()
    assert wrongly.sum() <= 0.02 * visible_wall.sum()


# ----------------------------------------------------------------------------- real data
def test_kitti_removal_lowers_error(kitti):
    """The paper's Table 1 measurement on one frame: error of the raw sparse input
    against the ground truth, on pixels valid in both, before and after removal."""
    sparse, truth = kitti.sparse[2], kitti.truth[2]
    keep = np.asarray(outlier_keep_mask(sparse, kitti.K[2], kitti.T_cam_lidar[2], beams=64))
    both = (sparse > 0) & (truth > 0)
    err = sparse - truth
    rmse_before = np.sqrt(np.mean(err[both] ** 2))
    rmse_after = np.sqrt(np.mean(err[both & keep] ** 2))
    keep_ratio = keep.sum() / (sparse > 0).sum()
    print(f"KITTI frame: RMSE {1e3 * rmse_before:.0f} -> {1e3 * rmse_after:.0f} mm, keep {100 * keep_ratio:.1f} %")
    assert not keep[sparse == 0].any()
    assert rmse_after < 0.9 * rmse_before
    assert keep_ratio > 0.9
    removed = both & ~keep
    # What is removed is mostly wrong; what is kept is mostly right.
    assert np.median(np.abs(err[removed])) > 10 * np.median(np.abs(err[both & keep]))
    big = np.abs(err) > 1.0
    assert (big & both & keep).sum() < 0.95 * (big & both).sum()


# ----------------------------------------------------------------------------- invariants
def test_empty_and_single_point():
    K = np.array([[50.0, 0, 20], [0, 50.0, 15], [0, 0, 1]], np.float32)
    T = np.eye(4, dtype=np.float32)
    T[:3, 3] = (0.3, -0.2, 0.1)
    empty = np.zeros((24, 40), np.float32)
    out = outlier_keep_mask(empty, K, T, beams=6, **CAPS)
    assert out.dtype == jnp.bool_ and out.shape == (24, 40) and not np.asarray(out).any()
    single = empty.copy()
    single[12, 7] = 5.0
    np.testing.assert_array_equal(np.asarray(outlier_keep_mask(single, K, T, beams=6, **CAPS)), single > 0)
    bad = empty.copy()
    bad[3, 3], bad[4, 4], bad[5, 5] = np.nan, -1.0, np.inf   # not measurements: never kept
    assert not np.asarray(outlier_keep_mask(bad, K, T, beams=6, **CAPS)).any()


@pytest.mark.xdist_group("outliers_scene")  # its 96 x 160 keep-mask programs are the scene tests': one worker
@hypothesis.settings(**SETTINGS)
@hypothesis.given(seed=st.integers(0, 2**31 - 1), raw=st.booleans())
def test_no_parallax_removes_nothing(seed, raw):
    """LiDAR at the camera centre: pixel order and angle order agree, nothing is
    removed, even for a wide camera and the widest window."""
    rng = np.random.default_rng(seed)
    shape = SCENE_SHAPE                          # the analytic scenes' programs
    K, T = _camera(rng, *shape)
    K[0, 0] = K[1, 1] = 0.4 * shape[1]          # ~ 100 degrees horizontal field of view
    T[:3, 3] = 0.0
    depth = _random_sparse(rng, *shape, 0.02)    # few points: |du| < W L / N ~ 17 px, the cap (12) binds
    points = _points_near_pixels(rng, K, depth, spread=0.49) if raw else None
    keep = np.asarray(outlier_keep_mask(depth, K, T, beams=SCENE_BEAMS, epsilon_m=0.0, points_cam=points))
    np.testing.assert_array_equal(keep, depth > 0)


def test_scale_invariance():
    """Depths, LiDAR offset and epsilon scaled by 2 (exact in float): same mask."""
    rng = np.random.default_rng(3)
    K, T = _camera(rng, 24, 40)
    depth = _random_sparse(rng, 24, 40, 0.15)
    T2 = T.copy()
    T2[:3, 3] *= 2.0
    a = np.asarray(outlier_keep_mask(depth, K, T, beams=6, epsilon_m=1.0, **CAPS))
    b = np.asarray(outlier_keep_mask(2.0 * depth, K, T2, beams=6, epsilon_m=2.0, **CAPS))
    assert (a != (depth > 0)).any()
    np.testing.assert_array_equal(a, b)


def test_raw_and_image_paths_agree_on_exact_pixels():
    """A sweep whose points sit exactly on pixel centres: the raw-sweep path
    (points_cam from the projection's winners) and the image-only path (back-
    projection of each pixel) see the same angles up to float rounding. (Image size, beams and
    caps of the random oracle tests: their compiled programs.)"""
    rng = np.random.default_rng(5)
    height, width = 24, 40
    K = np.array([[50.0, 0, 19.5], [0, 50.0, 11.5], [0, 0, 1]], np.float32)
    T = np.eye(4, dtype=np.float32)
    T[:3, :3] = cv2.Rodrigues(np.array([0.02, -0.03, 0.01]))[0]
    T[:3, 3] = (0.3, -0.2, -0.25)
    depth_true = _random_sparse(rng, height, width, 0.15).astype(np.float64)
    v, u = np.nonzero(depth_true > 0)
    z = depth_true[v, u]
    p_cam = (np.linalg.inv(K.astype(np.float64)) @ np.stack([u, v, np.ones_like(z)])) * z
    p_lidar = np.asarray(transform_points(invert_rigid(T), jnp.asarray(p_cam.T, jnp.float32)))
    depth, index = project_to_image(jnp.asarray(p_lidar), jnp.ones(len(z), bool), K, T,
                                    height=height, width=width)
    depth, index = np.asarray(depth), np.asarray(index)
    assert ((depth > 0) == (depth_true > 0)).all()
    p_back = np.asarray(transform_points(T, jnp.asarray(p_lidar)))
    points_cam = np.moveaxis(np.where((index >= 0)[..., None], p_back[np.maximum(index, 0)], 0.0), -1, 0)
    raw = np.asarray(outlier_keep_mask(depth, K, T, beams=6, points_cam=points_cam.astype(np.float32), **CAPS))
    image = np.asarray(outlier_keep_mask(depth, K, T, beams=6, **CAPS))
    assert (image != (depth > 0)).sum() >= 5
    np.testing.assert_array_equal(raw, image)


@pytest.mark.parametrize("kwargs, message", [
    (dict(sparse_depth=np.zeros((2, 3, 4))), r"'sparse_depth' expected shape \(H, W\), got \(2, 3, 4\)"),
    (dict(K=np.eye(4)), r"'K' expected shape \(3, 3\), got \(4, 4\)"),
    (dict(T_cam_lidar=np.eye(3)), r"'T_cam_lidar' expected shape \(4, 4\), got \(3, 3\)"),
    (dict(beams=0), r"'beams' expected a positive integer, got 0"),
    (dict(epsilon_m=-1.0), r"'epsilon_m' expected a finite value >= 0, got -1.0"),
    (dict(max_half_width_px=2.5), r"'max_half_width_px' expected a non-negative integer, got 2.5"),
    (dict(points_cam=np.zeros((3, 5, 5))), r"'points_cam' expected shape \(3, 8, 9\), got \(3, 5, 5\)"),
])
def test_validation_errors(kwargs, message):
    args = dict(sparse_depth=np.zeros((8, 9), np.float32), K=np.eye(3), T_cam_lidar=np.eye(4), beams=4)
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        outlier_keep_mask(args.pop("sparse_depth"), args.pop("K"), args.pop("T_cam_lidar"), **args)


def test_options_are_keyword_only():
    with pytest.raises(TypeError):
        outlier_keep_mask(np.zeros((4, 4), np.float32), np.eye(3), np.eye(4), 4)  # beams positional


@pytest.mark.xdist_group("outliers_24x40")  # the stage table's 24 x 40 CAPS keep-mask programs: one worker
def test_vmap_over_epsilon_only_equals_loop():
    """A parameter sweep: epsilon batched, the image shared (unbatched operands inside the kernel)."""
    rng = np.random.default_rng(12)
    K, T = _camera(rng, 24, 40)
    depth = _random_sparse(rng, 24, 40, 0.15)
    eps = np.array([0.0, 0.5, 1.0, 3.0], np.float32)
    for test in ("footprint", "paper"):
        fn = lambda e: outlier_keep_mask(depth, K, T, beams=6, epsilon_m=e, test=test, **CAPS)
        batched = np.asarray(jax.vmap(fn)(jnp.asarray(eps)))
        for i, e in enumerate(eps):
            np.testing.assert_array_equal(batched[i], np.asarray(fn(jnp.float32(e))))
        assert (batched[0] != batched[-1]).any()


def test_window_min_with_the_half_width_as_data_equals_scipy_minimum_filter():
    """The prefilter's horizontal window minimum, one jitted program for every run-time half width k
    (0, the cap and random ones; also under vmap, one k per member), against scipy.ndimage."""
    import scipy.ndimage

    rng = np.random.default_rng(7)
    hw, height, width = 12, 5, 37
    padded = rng.integers(0, 65536, (3, height, width + 2 * hw), dtype=np.uint16)
    padded[:, :, :3] = 0                      # the minimum sits at the pad's edge for some windows
    fn = jax.jit(lambda a, k: outliers_module._window_min(a, k, hw=hw, width=width))
    ks = [0, hw, *rng.integers(0, hw + 1, 4).tolist()]
    for k in ks:
        want = scipy.ndimage.minimum_filter1d(padded, size=2 * k + 1, axis=2)[:, :, hw:hw + width]
        np.testing.assert_array_equal(np.asarray(fn(padded, jnp.int32(k))), want, err_msg=f"k={k}")
    assert fn._cache_size() == 1
    batched = np.asarray(jax.vmap(fn)(padded, jnp.asarray(ks[:3], jnp.int32)))
    for i, k in enumerate(ks[:3]):
        np.testing.assert_array_equal(batched[i], np.asarray(fn(padded[i], jnp.int32(k))))


@pytest.mark.xdist_group("outliers_24x40")
def test_points_as_three_channels_give_the_same_mask():
    """``points_cam`` as three (H, W) channels (the rig views' form) == the (3, H, W) array, bit for bit, both
    tests, one camera and vmapped over cameras; and the footprint double loop's mask where it is sure."""
    shape = (24, 40)
    rng = np.random.default_rng(11)
    cams = [_camera(rng, *shape) for _ in range(3)]
    depths = [_random_sparse(rng, *shape, 0.25) for _ in range(3)]
    points = [_points_near_pixels(rng, K, d) for (K, _), d in zip(cams, depths)]
    for test in ("footprint", "paper"):
        kw = dict(beams=6, epsilon_m=1.0, test=test, **CAPS)

        def run(depth, K, T, p, apart):
            return outlier_keep_mask(depth, K, T, points_cam=tuple(p) if apart else p, **kw)

        stacked = [np.asarray(run(d, K, T, p, False)) for (K, T), d, p in zip(cams, depths, points)]
        args = [np.stack(x).astype(np.float32) for x in zip(*[(d, K, T, p) for (K, T), d, p in zip(cams, depths, points)])]
        batched = np.asarray(jax.jit(jax.vmap(lambda d, K, T, p: run(d, K, T, p, True)))(*args))
        for c, ((K, T), d, p) in enumerate(zip(cams, depths, points)):
            np.testing.assert_array_equal(np.asarray(run(d, K, T, p, True)), stacked[c], err_msg=f"{test} camera {c}")
            np.testing.assert_array_equal(batched[c], stacked[c], err_msg=f"{test} camera {c}, vmapped")
            if test == "footprint":
                _assert_matches_footprint(stacked[c], *footprint_double_loop(d, K, T, points_cam=p, beams=6,
                                                                             epsilon_m=1.0, **CAPS))


@pytest.mark.parametrize("seed, shape, block", [(5, (40, 70), 8), (6, (45, 64), 5), (7, (42, 96), 7)])
@pytest.mark.slow  # frozen oracle on tall windows
def test_row_blocks_equal_frozen_dense_sweep(seed, shape, block):
    """Tall windows (half height >= 16: the rigs' cameras) take the prefilter in row blocks (a looser superset,
    words packed down the columns): the same masks as the frozen dense sweep, image and raw input, and vmapped;
    a 2-beam LiDAR gives these small images a half height of 19-22 rows."""
    rng = np.random.default_rng(seed)
    K, T = _camera(rng, *shape)
    depths = [_random_sparse(rng, *shape, density) for density in (0.05, 0.2)]
    kw, mode = dict(beams=2, max_half_width_px=12, max_half_height_px=24), dict(test="paper")
    _, hh = window_half_sizes(*shape, beams=2, max_half_width_px=12, max_half_height_px=24)
    assert hh >= 16 and outliers_module._row_block(shape[0], hh) == block
    for depth in depths:
        points = np.stack([rng.normal(0, 3, shape), rng.normal(0, 1, shape), depth]).astype(np.float32)
        got = np.asarray(outlier_keep_mask(depth, K, T, **kw, **mode))
        assert (got != (depth > 0)).any()
        np.testing.assert_array_equal(got, np.asarray(frozen_keep_mask(depth, K, T, **kw)))
        np.testing.assert_array_equal(np.asarray(outlier_keep_mask(depth, K, T, points_cam=points, **kw, **mode)),
                                      np.asarray(frozen_keep_mask(depth, K, T, points_cam=points, **kw)))
    fn = jax.vmap(lambda d: outlier_keep_mask(d, K, T, **kw, **mode))
    batched = np.asarray(fn(jnp.asarray(np.stack(depths))))
    for i, depth in enumerate(depths):
        np.testing.assert_array_equal(batched[i], np.asarray(outlier_keep_mask(depth, K, T, **kw, **mode)))


@pytest.mark.parametrize("block, height", [(5, 1550), (8, 2048), (6, 900), (7, 77), (4, 36)])
def test_block_bits_equal_packed_repeated_rows(block, height):
    """The block path's words (each block's flag on each of its rows, packed down the columns) against the
    flags repeated row by row, packed by NumPy bit by bit (test_outlier_exact's oracle of ``pack_columns``);
    through one jit (op by op each height compiled ~50 primitives: 3 s of CPU per case)."""
    from test_outlier_exact import _pack_columns_numpy
    on = np.random.default_rng(block).random((height // block, 13)) < 0.4
    want = _pack_columns_numpy(np.repeat(on, block, axis=0))
    block_bits = jax.jit(outliers_module._block_bits, static_argnames=("block", "height"))
    np.testing.assert_array_equal(np.asarray(block_bits(jnp.asarray(on), block=block, height=height)), want)
