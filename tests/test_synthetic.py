"""Tests of the synthetic street scene and its ray caster.

Oracles: float64 NumPy ray/plane, slab (box) and quadratic (cylinder)
intersections; analytic ground-plane depth; a NumPy z-buffer with
scipy.ndimage.maximum_filter for the parallax-outlier mask; exact visibility by
casting a ray from the camera to each LiDAR point. Invariants: determinism,
jit == eager, vmap == loop, no retrace across seeds.
"""

from __future__ import annotations

import functools
import math

import hypothesis
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.ndimage

from jaxdepth._src import geometry, synthetic
from jaxdepth._src.presets import KITTI_HDL64
from jaxdepth._src.types import Camera, LidarSpec

# One worker for the module: its tests share the scene's render and ray programs (on two workers, two tests
# compiled one at the same time).
pytestmark = pytest.mark.xdist_group("synthetic")
SETTINGS = dict(deadline=None, max_examples=8, derandomize=True)
N_RAYS = 512
_cast = jax.jit(synthetic.cast_rays)
_BUCKET = 32768  # rays per visibility query (padded) so every query shares one compilation


@pytest.fixture(scope="module")
def frame():
    return synthetic.make_street_scene(0)


@pytest.fixture(scope="module")
def frame_no_offset():
    return synthetic.make_street_scene(0, lidar_offset_m=(0.0, 0.0, 0.0))


# --------------------------------------------------------------------------- NumPy float64 oracles


def _np_plane(o, d, plane):
    n, off = plane[:3] / np.linalg.norm(plane[:3]), plane[3] / np.linalg.norm(plane[:3])
    denom = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (off - o @ n) / denom
    return np.where((denom != 0) & (t > 0), t, np.inf)


def _np_box(o, d, box):
    """Brute-force slab test in the box frame; returns (t, margin) with margin = t_far - t_near."""
    c, h, yaw = box[:3], box[3:6], box[6]
    R = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    lo_, ld = (o - c) @ R, d @ R                  # rows are R^T (p - c)
    t_near = np.full(len(d), -np.inf)
    t_far = np.full(len(d), np.inf)
    for k in range(3):
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (-h[k] - lo_[:, k]) / ld[:, k]
            b = (h[k] - lo_[:, k]) / ld[:, k]
        t_near = np.maximum(t_near, np.minimum(a, b))
        t_far = np.minimum(t_far, np.maximum(a, b))
    hit = (t_near <= t_far) & (t_far > 0)
    t = np.where(hit, np.where(t_near > 0, t_near, t_far), np.inf)
    return t, t_far - t_near


def _np_cylinder(o, d, cyl):
    cx, cy, r, z0, z1 = cyl
    ox, oy = o[:, 0] - cx, o[:, 1] - cy
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (ox * d[:, 0] + oy * d[:, 1])
    c = ox ** 2 + oy ** 2 - r * r
    disc = b * b - 4 * a * c
    best = np.full(len(d), np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        for sign in (-1.0, 1.0):
            t = (-b + sign * np.sqrt(disc)) / (2 * a)
            z = o[:, 2] + t * d[:, 2]
            ok = (disc >= 0) & (t > 0) & (z >= z0) & (z <= z1)
            best = np.where(ok, np.minimum(best, t), best)
        for zc in (z0, z1):
            t = (zc - o[:, 2]) / d[:, 2]
            ok = (t > 0) & ((ox + t * d[:, 0]) ** 2 + (oy + t * d[:, 1]) ** 2 <= r * r)
            best = np.where(ok, np.minimum(best, t), best)
    return best


def _random_rays(rng, target_lo, target_hi):
    """N_RAYS rays from random origins in a 40 m cube aimed at random points of a target box."""
    o = rng.uniform(-20.0, 20.0, (N_RAYS, 3))
    target = rng.uniform(target_lo, target_hi, (N_RAYS, 3))
    d = target - o
    d *= rng.uniform(0.2, 3.0, (N_RAYS, 1)) / np.linalg.norm(d, axis=1, keepdims=True)  # non-unit lengths
    return o.astype(np.float32), d.astype(np.float32)


def _assert_t_close(t, t_ref, skip=None):
    t = np.asarray(t, np.float64)
    if skip is None:
        skip = np.zeros(len(t), bool)
    np.testing.assert_array_equal(np.isfinite(t)[~skip], np.isfinite(t_ref)[~skip])
    both = np.isfinite(t) & np.isfinite(t_ref)
    np.testing.assert_allclose(t[both], t_ref[both], rtol=2e-5, atol=2e-4)


# --------------------------------------------------------------------------- ray caster: analytic oracles


@hypothesis.settings(**SETTINGS)
@hypothesis.given(st.integers(0, 2**31 - 1))
def test_cast_rays_plane_matches_numpy(seed):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=3)
    plane = np.concatenate([n / np.linalg.norm(n), [rng.uniform(-5.0, 5.0)]])
    o, d = _random_rays(rng, -10.0, 10.0)
    t = _cast(o, d, synthetic.scene_arrays(planes=plane[None]))
    t_ref = _np_plane(o.astype(np.float64), d.astype(np.float64), plane)
    # Beyond scene scale (100 m) near-parallel rays are ill-conditioned in float32; count them as misses.
    far = np.isfinite(t_ref) & (t_ref * np.linalg.norm(d, axis=1) > 100.0)
    _assert_t_close(np.where(far, np.inf, t), np.where(far, np.inf, t_ref))


def test_fronto_parallel_wall_depth_is_exact():
    # A wall x = 7.25 m in front of a camera at the LiDAR origin: every pixel's depth is 7.25 exactly.
    cam = synthetic.rig_cameras("kitti", lidar_offset_m=(0.0, 0.0, 0.0), image_scale=0.125)[0]
    scene = synthetic.scene_arrays(planes=[[1.0, 0.0, 0.0, 7.25]])
    depth = np.asarray(synthetic.render_depth(cam, scene))
    np.testing.assert_array_equal(depth, np.full((cam.height, cam.width), 7.25, np.float32))


def test_ground_plane_depth_is_analytic():
    # Camera h metres above a ground plane, looking horizontally: z(v) = h fy / (v - cy) below the horizon.
    h = 1.43
    cam = synthetic.rig_cameras("kitti", lidar_offset_m=(0.0, 0.0, 0.0), image_scale=0.125)[0]
    scene = synthetic.scene_arrays(planes=[[0.0, 0.0, 1.0, -h]])
    depth = np.asarray(synthetic.render_depth(cam, scene, max_range_m=1e6))
    K = np.asarray(cam.K, np.float64)
    v = np.arange(cam.height, dtype=np.float64)
    below = v > K[1, 2]
    expected = np.where(below, h * K[1, 1] / np.where(below, v - K[1, 2], 1.0), 0.0)
    np.testing.assert_allclose(depth, np.broadcast_to(expected[:, None], depth.shape), rtol=1e-5)
    assert np.all(depth[~below] == 0) and np.all(depth[below] > 0)


@hypothesis.settings(**SETTINGS)
@hypothesis.given(st.integers(0, 2**31 - 1))
def test_cast_rays_box_matches_numpy_slab_test(seed):
    rng = np.random.default_rng(seed)
    box = np.concatenate([rng.uniform(-3.0, 3.0, 3), rng.uniform(0.05, 4.0, 3), [rng.uniform(-math.pi, math.pi)]])
    reach = np.linalg.norm(box[3:6])
    o, d = _random_rays(rng, box[:3] - 1.3 * reach, box[:3] + 1.3 * reach)
    scene = synthetic.scene_arrays(boxes=box[None])
    t = np.asarray(_cast(o, d, scene), np.float64)
    t_ref, margin = _np_box(o.astype(np.float64), d.astype(np.float64), box)
    grazing = np.abs(margin) < 1e-3  # rays through an edge: hit/miss is float-rounding dependent
    _assert_t_close(t, t_ref, skip=grazing)
    assert np.isfinite(t_ref).sum() > N_RAYS // 8  # the rays really test hits
    # Independent check: every hit lies on the box surface.
    hit = np.isfinite(t)
    yaw = box[6]
    R = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    local = (o[hit] + t[hit, None] * d[hit] - box[:3]) @ R
    excess = np.abs(local) - box[3:6]
    np.testing.assert_allclose(np.max(excess, axis=1), 0.0, atol=5e-4)


@hypothesis.settings(**SETTINGS)
@hypothesis.given(st.integers(0, 2**31 - 1))
def test_cast_rays_cylinder_matches_quadratic(seed):
    rng = np.random.default_rng(seed)
    z0 = rng.uniform(-3.0, 1.0)
    cyl = np.array([rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0), rng.uniform(0.05, 2.0), z0,
                    z0 + rng.uniform(0.2, 6.0)])
    lo = np.array([cyl[0] - 1.3 * cyl[2], cyl[1] - 1.3 * cyl[2], cyl[3] - 0.5])
    hi = np.array([cyl[0] + 1.3 * cyl[2], cyl[1] + 1.3 * cyl[2], cyl[4] + 0.5])
    o, d = _random_rays(rng, lo, hi)
    t = np.asarray(_cast(o, d, synthetic.scene_arrays(cylinders=cyl[None])), np.float64)
    o64, d64 = o.astype(np.float64), d.astype(np.float64)
    t_ref = _np_cylinder(o64, d64, cyl)
    # Hit/miss may flip for rays passing within 1 mm of the rim; compare it elsewhere.
    grow = np.array([0.0, 0.0, 1e-3, -1e-3, 1e-3])
    grazing = np.isfinite(_np_cylinder(o64, d64, cyl + grow)) != np.isfinite(_np_cylinder(o64, d64, cyl - grow))
    _assert_t_close(t, t_ref, skip=grazing)
    assert grazing.sum() < N_RAYS // 50
    assert np.isfinite(t_ref).sum() > N_RAYS // 8


def test_cast_rays_from_inside_returns_exit_and_empty_scene_misses():
    d = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -2.0]], np.float32)
    box = synthetic.scene_arrays(boxes=[[0.0, 0.0, 0.0, 2.0, 1.0, 3.0, 0.0]])
    np.testing.assert_allclose(_cast(np.zeros(3, np.float32), d, box), [2.0, 3.0, 1.5], rtol=1e-6)
    cyl = synthetic.scene_arrays(cylinders=[[0.0, 0.0, 0.5, -1.0, 2.0]])
    np.testing.assert_allclose(_cast(np.zeros(3, np.float32), d, cyl), [0.5, 2.0, 0.5], rtol=1e-6)
    assert np.all(np.isinf(np.asarray(_cast(np.zeros(3, np.float32), d, synthetic.scene_arrays()))))


def test_cast_rays_jit_equals_eager_and_vmap_equals_loop(frame):
    rng = np.random.default_rng(3)
    o = rng.uniform(-2.0, 2.0, (3, N_RAYS, 3)).astype(np.float32)
    d = rng.normal(size=(3, N_RAYS, 3)).astype(np.float32)
    scene = frame.scene
    eager = np.asarray(synthetic.cast_rays(o[0], d[0], scene))  # eager scans retrace: one call
    jitted = np.stack([np.asarray(_cast(o[i], d[i], scene)) for i in range(3)])
    batched = np.asarray(jax.jit(jax.vmap(synthetic.cast_rays, in_axes=(0, 0, None)))(o, d, scene))
    assert np.isfinite(jitted).mean() > 0.5
    np.testing.assert_allclose(jitted[0], eager, rtol=1e-6)
    np.testing.assert_allclose(batched, jitted, rtol=1e-6)
    # A shared (3,) origin is the same as that origin repeated.
    np.testing.assert_array_equal(_cast(o[0, 0], d[0], scene),
                                  _cast(np.broadcast_to(o[0, 0], d[0].shape), d[0], scene))


def test_render_depth_vmap_over_stereo_cameras_equals_loop(frame):
    cams = synthetic.rig_cameras("stereo", image_scale=0.0625)
    left, right = (np.asarray(geometry.invert_rigid(c.T_cam_lidar))[:3, 3] for c in cams)
    np.testing.assert_allclose(left - right, [0.0, 0.54, 0.0], atol=1e-6)
    stacked = Camera(K=jnp.stack([c.K for c in cams]), T_cam_lidar=jnp.stack([c.T_cam_lidar for c in cams]),
                     height=cams[0].height, width=cams[0].width)
    batched = np.asarray(jax.vmap(synthetic.render_depth, in_axes=(0, None))(stacked, frame.scene))
    loop = np.stack([np.asarray(synthetic.render_depth(c, frame.scene)) for c in cams])
    assert loop.shape == (2, 22, 76) and np.mean(loop > 0) > 0.9
    np.testing.assert_allclose(batched, loop, rtol=1e-6)
    eager = np.asarray(synthetic.render_depth.__wrapped__(cams[1], frame.scene))
    np.testing.assert_allclose(eager, loop[1], rtol=1e-6)


# --------------------------------------------------------------------------- LiDAR


@pytest.mark.parametrize("beams,fov_up,fov_down,columns", [(64, 2.0, -24.9, 2048), (32, 10.67, -30.67, 1088),
                                                          (16, 15.0, -15.0, 900)])
def test_lidar_rays_follow_the_spec(beams, fov_up, fov_down, columns):
    spec = LidarSpec(beams=beams, fov_up_deg=fov_up, fov_down_deg=fov_down, columns=columns)
    rays32 = np.asarray(synthetic.lidar_rays(spec))
    assert rays32.shape == (beams * columns, 3) and rays32.dtype == np.float32
    rays = rays32.astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-6)
    elevation = np.degrees(np.arcsin(rays[:, 2])).reshape(beams, columns)
    np.testing.assert_allclose(elevation, np.broadcast_to(np.linspace(fov_up, fov_down, beams)[:, None],
                                                          elevation.shape), atol=1e-4)
    azimuth = np.arctan2(rays[:, 1], rays[:, 0]).reshape(beams, columns)
    step = np.angle(np.exp(1j * np.diff(azimuth, axis=1)))
    np.testing.assert_allclose(step, -2 * np.pi / columns, atol=1e-5)


def _distinct_elevations(points, spacing_deg):
    e = np.sort(np.degrees(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))))
    return 1 + int(np.sum(np.diff(e) > 0.5 * spacing_deg))


@pytest.mark.parametrize("beams", [64, 32, 16])
def test_sweep_has_one_ring_per_beam(beams, frame):
    if beams == 64:
        f = frame  # the default HDL-64E frame (2048 columns)
    else:
        f = synthetic.make_street_scene(0, lidar=LidarSpec(beams=beams, fov_up_deg=2.0, fov_down_deg=-24.9,
                                                           columns=512), cameras=())
    columns = f.lidar.columns
    assert f.points.shape == (beams * columns, 3) and f.points.dtype == np.float32
    assert f.valid.shape == (beams * columns,) and f.valid.dtype == bool
    assert _distinct_elevations(f.points[f.valid], 26.9 / (beams - 1)) == beams
    assert np.all(f.points[~f.valid] == 0)
    r = np.linalg.norm(f.points[f.valid], axis=1)
    assert r.max() <= 120.0 + 1e-3 and r.min() > 1.0


def test_ground_only_sweep_is_analytic():
    h, max_range = 1.73, 50.0
    spec = LidarSpec(beams=16, fov_up_deg=2.0, fov_down_deg=-24.9, columns=64)
    points, valid = synthetic.lidar_sweep(synthetic.scene_arrays(planes=[[0.0, 0.0, 1.0, -h]]), lidar=spec,
                                          max_range_m=max_range)
    elevation = np.radians(np.repeat(np.linspace(2.0, -24.9, 16), 64))
    with np.errstate(divide="ignore"):
        r = np.where(elevation < 0, h / np.sin(-elevation), np.inf)
    np.testing.assert_array_equal(np.asarray(valid), r <= max_range)
    np.testing.assert_allclose(np.asarray(points)[np.asarray(valid), 2], -h, rtol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(points)[np.asarray(valid)], axis=1), r[r <= max_range],
                               rtol=1e-5)


def test_range_noise_is_seeded_and_keeps_validity():
    spec = LidarSpec(beams=16, fov_up_deg=2.0, fov_down_deg=-24.9, columns=512)
    clean = synthetic.make_street_scene(4, lidar=spec, cameras=())
    noisy = synthetic.make_street_scene(4, lidar=spec, cameras=(), noise_std_m=0.05)
    again = synthetic.make_street_scene(4, lidar=spec, cameras=(), noise_std_m=0.05)
    np.testing.assert_array_equal(noisy.points, again.points)
    np.testing.assert_array_equal(noisy.valid, clean.valid)
    v = clean.valid
    dr = np.linalg.norm(noisy.points[v], axis=1) - np.linalg.norm(clean.points[v], axis=1)
    assert 0.045 < dr.std() < 0.055 and abs(dr.mean()) < 0.005
    # Noise moves points along their own rays.
    cos = np.sum(noisy.points[v] * clean.points[v], axis=1) / (
        np.linalg.norm(noisy.points[v], axis=1) * np.linalg.norm(clean.points[v], axis=1))
    np.testing.assert_allclose(cos, 1.0, atol=1e-5)


# --------------------------------------------------------------------------- the street frame


def test_same_seed_is_byte_identical_and_seeds_differ(frame):
    again = synthetic.make_street_scene(0)
    other = synthetic.make_street_scene(1)
    assert frame.points.tobytes() == again.points.tobytes()
    assert frame.valid.tobytes() == again.valid.tobytes()
    assert frame.dense_depth[0].tobytes() == again.dense_depth[0].tobytes()
    for a, b in zip(frame.scene, again.scene):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()
    assert not np.array_equal(frame.points, other.points)
    assert not np.array_equal(frame.dense_depth[0], other.dense_depth[0])
    # Fixed primitive counts: every seed has the same shapes and shares one compilation.
    assert [np.shape(x) for x in other.scene] == [np.shape(x) for x in frame.scene]
    size = synthetic._render_frame._cache_size()
    synthetic.make_street_scene(2)
    assert synthetic._render_frame._cache_size() == size


def test_default_frame_shapes_and_kitti_camera(frame):
    assert frame.points.shape == (64 * 2048, 3) and frame.points.dtype == np.float32
    assert frame.lidar == KITTI_HDL64
    (cam,) = frame.cameras
    assert (cam.height, cam.width) == (352, 1216)
    np.testing.assert_allclose(np.asarray(cam.K), [[721.5377, 0, 596.5593], [0, 721.5377, 149.854], [0, 0, 1]],
                               rtol=1e-6)
    # The LiDAR sits 0.3 m above and 0.3 m behind the camera.
    centre = np.asarray(geometry.invert_rigid(cam.T_cam_lidar))[:3, 3]
    np.testing.assert_allclose(centre, [0.3, 0.0, -0.3], atol=1e-6)
    # The frame's camera depth is the one render_depth gives.
    np.testing.assert_allclose(synthetic.render_depth(cam, frame.scene), frame.dense_depth[0], rtol=1e-6)
    # Objects at 3-60 m: the sweep sees surfaces from a few metres to far down the street.
    p = frame.points[frame.valid]
    r = np.linalg.norm(p, axis=1)
    assert r.max() > 60.0 and frame.valid.mean() > 0.8
    above_ground = p[:, 2] > -1.73 + 0.2
    assert np.hypot(p[above_ground, 0], p[above_ground, 1]).min() < 8.0


def test_dense_depth_sky_empty_surfaces_positive(frame):
    depth = frame.dense_depth[0]
    K = np.asarray(frame.cameras[0].K)
    assert depth.dtype == np.float32 and np.all(np.isfinite(depth)) and np.all(depth >= 0)
    rows, _ = np.nonzero(depth == 0)
    assert rows.size > 100                        # some sky down the street
    assert rows.max() < K[1, 2]                   # only above the horizon
    # Below the horizon every pixel sees the ground or an object within range.
    assert np.all(depth[int(K[1, 2]) + 15:] > 0)
    assert depth[depth > 0].min() > 1.0


def _visible_from_camera(frame, cam_index, index, margin_m=0.05):
    """Exact visibility of the winning LiDAR point of each pixel: cast from the camera to it."""
    cam = frame.cameras[cam_index]
    origin, _ = synthetic.camera_rays(cam)
    d = (frame.points[index] - np.asarray(origin)).astype(np.float32)
    n = len(d)
    assert n <= _BUCKET
    padded = np.concatenate([d, np.ones((_BUCKET - n, 3), np.float32)])
    t = np.asarray(_cast(np.asarray(origin), padded, frame.scene))[:n]
    return t >= 1.0 - margin_m / np.linalg.norm(d, axis=1)


def _check_visible_points_match(frame, cam_index):
    cam, dense = frame.cameras[cam_index], frame.dense_depth[cam_index]
    sparse, index = (np.asarray(x) for x in geometry.project_to_image(
        frame.points, frame.valid, cam.K, cam.T_cam_lidar, height=cam.height, width=cam.width))
    m = index >= 0
    visible = _visible_from_camera(frame, cam_index, index[m])
    s, d = sparse[m][visible], dense[m][visible]
    # Rounding to the pixel centre can move a point on a silhouette onto the sky.
    assert np.mean(d > 0) > 0.99
    rel = np.abs(s - d)[d > 0] / d[d > 0]
    return m.sum(), visible, rel


def test_visible_lidar_points_match_dense_depth(frame):
    n, visible, rel = _check_visible_points_match(frame, 0)
    assert n > 15000 and visible.mean() > 0.9
    # Projection rounds to the pixel centre (up to half a pixel): on slanted ground that moves the
    # depth by up to ~z / (2 h fy) relatively, so only most points agree to 1 %.
    assert np.median(rel) < 2e-3 and np.mean(rel < 0.01) > 0.95


def test_parallax_outliers_present_and_really_occluded(frame):
    cam, dense = frame.cameras[0], frame.dense_depth[0]
    count = synthetic.count_parallax_outliers(frame.points, frame.valid, cam, dense)
    assert isinstance(count, int) and count > 100
    mask = np.asarray(synthetic.parallax_outlier_mask(frame.points, frame.valid, cam, dense))
    assert mask.sum() == count
    _, index = geometry.project_to_image(frame.points, frame.valid, cam.K, cam.T_cam_lidar,
                                         height=cam.height, width=cam.width)
    # Every flagged point is hidden from the camera by more than the tolerance (exact ray cast).
    assert not np.any(_visible_from_camera(frame, 0, np.asarray(index)[mask], margin_m=0.5))


def test_no_parallax_outliers_without_offset(frame_no_offset):
    f = frame_no_offset
    assert synthetic.count_parallax_outliers(f.points, f.valid, f.cameras[0], f.dense_depth[0]) == 0
    _, visible, rel = _check_visible_points_match(f, 0)
    assert visible.mean() > 0.999


def _np_outlier_mask(points, valid, K, T, dense, tolerance, window):
    p = points[valid].astype(np.float64) @ T[:3, :3].T.astype(np.float64) + T[:3, 3]
    z = p[:, 2]
    front = z > 0.1
    u = np.round(K[0, 0] * p[front, 0] / z[front] + K[0, 2]).astype(int)
    v = np.round(K[1, 1] * p[front, 1] / z[front] + K[1, 2]).astype(int)
    h, w = dense.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    sparse = np.full((h, w), np.inf)
    np.minimum.at(sparse, (v[inside], u[inside]), z[front][inside])
    sparse[np.isinf(sparse)] = 0
    farthest = scipy.ndimage.maximum_filter(dense, size=2 * window + 1, mode="constant", cval=0.0)
    return (sparse > 0) & (dense > 0) & (sparse > farthest + tolerance)


@pytest.mark.parametrize("window", [0, 1, 2])
def test_outlier_mask_matches_numpy_zbuffer(frame, window):
    cam, dense = frame.cameras[0], frame.dense_depth[0]
    got = np.asarray(synthetic.parallax_outlier_mask(frame.points, frame.valid, cam, dense, window_px=window))
    ref = _np_outlier_mask(frame.points, frame.valid, np.asarray(cam.K), np.asarray(cam.T_cam_lidar), dense,
                           0.5, window)
    # float32 vs float64 projection can move a point that sits on a pixel border.
    assert ref.sum() > 100
    assert np.sum(got != ref) <= 0.01 * ref.sum()


def test_outlier_count_hand_case_and_vmap():
    K = np.array([[10.0, 0, 2.0], [0, 10.0, 2.0], [0, 0, 1]], np.float32)
    cam = Camera(K=jnp.asarray(K), T_cam_lidar=jnp.eye(4), height=5, width=5)
    dense = np.full((5, 5), 4.0, np.float32)
    dense[0, :] = 0.0                                   # sky row
    # Points in the camera frame (identity extrinsic): behind the wall, in front of it, on it, in the sky.
    points = np.array([[0.0, 0.0, 6.0], [0.2, 0.0, 2.0], [0.0, 0.35, 4.3], [0.0, -1.8, 9.0]], np.float32)
    valid = np.array([True, True, True, True])
    assert synthetic.count_parallax_outliers(points, valid, cam, dense, window_px=0) == 1
    assert synthetic.count_parallax_outliers(points, valid, cam, dense, tolerance_m=0.2, window_px=0) == 2
    assert synthetic.count_parallax_outliers(points, ~valid, cam, dense, window_px=0) == 0
    batch = np.stack([points, points * np.float32(0.5), points * np.float32(1.5)])
    fn = jax.vmap(functools.partial(synthetic.parallax_outlier_mask, window_px=0), in_axes=(0, None, None, None))
    batched = np.asarray(fn(batch, valid, cam, dense))
    loop = np.stack([np.asarray(synthetic.parallax_outlier_mask(b, valid, cam, dense, window_px=0)) for b in batch])
    assert loop.sum() >= 2
    np.testing.assert_array_equal(batched, loop)
    with jax.disable_jit():
        eager = np.asarray(synthetic.parallax_outlier_mask(points, valid, cam, dense, window_px=0))
    np.testing.assert_array_equal(eager, loop[0])


def test_surround_rig():
    surround = synthetic.make_street_scene(0, cameras="surround", image_scale=0.1)
    assert len(surround.cameras) == 6
    yaws = []
    for i, (cam, depth) in enumerate(zip(surround.cameras, surround.dense_depth)):
        assert depth.shape == (90, 160) and np.mean(depth > 0) > 0.8
        axis = np.asarray(cam.T_cam_lidar)[2, :3]  # optical axis in the LiDAR frame
        yaws.append(round(math.degrees(math.atan2(axis[1], axis[0]))))
        n, visible, rel = _check_visible_points_match(surround, i)
        assert n > 200 and visible.mean() > 0.8 and np.median(rel) < 0.01
    assert yaws == [0, 55, -55, 180, 110, -110]


def test_camera_sequence_and_validation():
    spec = LidarSpec(beams=16, fov_up_deg=2.0, fov_down_deg=-24.9, columns=512)
    cams = synthetic.rig_cameras("kitti", image_scale=0.125)
    f = synthetic.make_street_scene(0, cameras=list(cams), lidar=spec)
    g = synthetic.make_street_scene(0, cameras="kitti", image_scale=0.125, lidar=spec)
    assert len(f.cameras) == 1 and f.cameras[0] is cams[0]
    np.testing.assert_array_equal(f.dense_depth[0], g.dense_depth[0])
    assert f.dense_depth[0].shape == (44, 152) and np.mean(f.dense_depth[0] > 0) > 0.9
    with pytest.raises(ValueError, match="preset.*'kitti'.*got 'fisheye'"):
        synthetic.rig_cameras("fisheye")
    with pytest.raises(ValueError, match="lidar_offset_m"):
        synthetic.rig_cameras("kitti", lidar_offset_m=(0.0, 1.0))
    with pytest.raises(ValueError, match="cameras\\[0\\].*Camera"):
        synthetic.make_street_scene(0, cameras=[np.eye(3)])
    with pytest.raises(ValueError, match="noise_std_m"):
        synthetic.make_street_scene(0, noise_std_m=-1.0)
    with pytest.raises(ValueError, match="boxes.*\\(n, 7\\).*\\(2, 6\\)"):
        synthetic.scene_arrays(boxes=np.zeros((2, 6)))
    with pytest.raises(ValueError, match="directions.*\\(N, 3\\)"):
        synthetic.cast_rays(np.zeros(3), np.zeros((4, 2)), synthetic.scene_arrays())
    with pytest.raises(ValueError, match="dense_depth.*\\(44, 152\\)"):
        synthetic.parallax_outlier_mask(f.points, f.valid, cams[0], np.zeros((10, 10), np.float32))
