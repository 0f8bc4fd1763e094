"""Digital twins (jaxdepth.research.twins): geometry against analytic oracles and the real data's tables."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxdepth.research import twin_measure, twin_tables
from jaxdepth.research.twin_rigs import RIG_BUILDERS, RASTER_UNITS
from jaxdepth.research.twin_scene import twin_scene, twin_spheres
from jaxdepth.research.twin_sensors import NO_EFFECTS, SensorEffects
from jaxdepth.research.twins import TWIN_RIGS, make_twin, write_twin
from tests.conftest import require_shared

SCALE = 0.1
# One worker for the module: its twins' renders (render_twin_depth, _cast_unit) are shared by tests that, on two
# workers, both compiled them (suite12's profile; docs/testing.md, "Compiled programs").
pytestmark = pytest.mark.xdist_group("twins")


@pytest.fixture(scope="module")
def kitti_exact():
    return make_twin("kitti", sweeps=2, seed=3, scale=SCALE, effects=False)


@pytest.fixture(scope="module")
def raster_exact():
    return make_twin("raster", sweeps=2, seed=1, scale=SCALE, effects=False)


@pytest.fixture(scope="module")
def av2_exact():
    return make_twin("av2", sweeps=1, seed=0, scale=SCALE, effects=False)


def _to_world(twin, points):
    """Reference-frame points -> the world frame (the reference sweep's ego frame, ground z = 0)."""
    T = RIG_BUILDERS[twin.name](NO_EFFECTS).T_ego_points
    return np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]


def _surface_distance(p, scene, spheres):
    """(N,) distance of world points to the nearest primitive surface, and (N,) depth inside any solid
    (NumPy oracle, independent of the JAX ray caster)."""
    best = np.full(p.shape[0], np.inf)
    inside = np.zeros(p.shape[0])
    for n0, n1, n2, off in np.asarray(scene.planes, np.float64):
        best = np.minimum(best, np.abs(p @ np.array([n0, n1, n2]) - off))
    for cx, cy, cz, hx, hy, hz, yaw in np.asarray(scene.boxes, np.float64):
        c, s = math.cos(yaw), math.sin(yaw)
        rx, ry = p[:, 0] - cx, p[:, 1] - cy
        q = np.abs(np.stack([c * rx + s * ry, -s * rx + c * ry, p[:, 2] - cz], 1)) - [hx, hy, hz]
        outside = np.linalg.norm(np.maximum(q, 0), axis=1)
        depth = -np.minimum(q.max(axis=1), 0)
        best = np.minimum(best, np.where(outside > 0, outside, depth))
        inside = np.maximum(inside, np.where(outside > 0, 0, depth))
    for cx, cy, cz, r in np.asarray(spheres, np.float64):
        radial = np.linalg.norm(p - [cx, cy, cz], axis=1) - r
        best = np.minimum(best, np.abs(radial))
        inside = np.maximum(inside, np.maximum(-radial, 0))
    for cx, cy, r, z0, z1 in np.asarray(scene.cylinders, np.float64):
        radial = np.hypot(p[:, 0] - cx, p[:, 1] - cy) - r
        axial = np.maximum(z0 - p[:, 2], p[:, 2] - z1)
        q = np.stack([radial, axial], 1)
        outside = np.linalg.norm(np.maximum(q, 0), axis=1)
        depth = -np.minimum(q.max(axis=1), 0)
        best = np.minimum(best, np.where(outside > 0, outside, depth))
        inside = np.maximum(inside, np.where(outside > 0, 0, depth))
    return best, inside


@pytest.mark.parametrize("name", ["kitti_exact", "raster_exact", "av2_exact"])
def test_exact_points_lie_on_scene_surfaces(name, request):
    twin = request.getfixturevalue(name)
    rng = np.random.default_rng(0)
    for k in np.unique(twin.cloud.sweep):
        mine = np.flatnonzero(np.isin(twin.cloud.source, np.flatnonzero(twin.cloud.sweep == k)))
        pick = rng.choice(mine, size=min(3000, mine.size), replace=False)
        p = _to_world(twin, twin.cloud.points[pick])
        scene = twin_scene(twin.seed, -int(k), dt_s=RIG_BUILDERS[twin.name](NO_EFFECTS).dt_s)
        dist, inside = _surface_distance(p, scene, twin_spheres(twin.seed))
        rng_m = np.linalg.norm(twin.cloud.points[pick] - twin.point_origin[pick], axis=1)
        tol = 1e-4 + 2e-6 * rng_m          # float32 ray casting
        assert np.all(dist <= tol), (k, float(dist.max()))
        assert np.all(inside <= tol)
        np.testing.assert_array_equal(twin.cloud.points, twin.point_exact)
        assert not twin.point_mixed.any()


def test_exact_depth_equals_the_ground_planes_analytic_depth(kitti_exact):
    """No pixel sees beyond the ground plane z = 0, and the open lane ahead is seen at the plane's depth."""
    T_ego_points = RIG_BUILDERS["kitti"](NO_EFFECTS).T_ego_points
    for cam, depth in zip(kitti_exact.rig.cameras, kitti_exact.depths):
        T_cam_world = np.asarray(cam.T_cam_lidar, np.float64) @ np.linalg.inv(T_ego_points)
        R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
        centre = -R.T @ t
        v, u = np.mgrid[0:cam.height, 0:cam.width]
        K = np.asarray(cam.K, np.float64)
        rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1) @ R
        with np.errstate(divide="ignore"):
            ground = np.where(rays[..., 2] < 0, -centre[2] / rays[..., 2], np.inf)    # camera z of the hit
        hit = depth > 0
        assert np.all(depth[hit] <= ground[hit] * (1 + 1e-5) + 1e-4)
        # Where the ground hit lies in the open lane ahead (|y| < 1 m, x < 7 m: no object is placed
        # there), the camera sees the ground exactly.
        hit_xy = centre[:2] + rays[..., :2] * np.where(np.isfinite(ground), ground, 0.0)[..., None]
        lane = np.isfinite(ground) & (np.abs(hit_xy[..., 1]) < 1.0) & (hit_xy[..., 0] < 7.0)
        assert lane.sum() > 20
        np.testing.assert_allclose(depth[lane], ground[lane], rtol=1e-5)


def test_effects_follow_their_rates():
    rates = SensorEffects(noise_m=0.05, dropout=0.1, mixed=0.5)
    exact = make_twin("kitti", sweeps=1, seed=2, scale=SCALE, effects=False)
    noisy = make_twin("kitti", sweeps=1, seed=2, scale=SCALE, effects=rates)
    assert noisy.cloud.points.shape[0] == pytest.approx(0.9 * exact.cloud.points.shape[0], rel=0.02)
    plain = ~noisy.point_mixed
    err = np.linalg.norm(noisy.cloud.points - noisy.point_exact, axis=1)[plain]
    assert np.std(err * np.sign(np.sum((noisy.cloud.points - noisy.point_exact)[plain]
                                       * (noisy.point_exact[plain] - noisy.point_origin[plain]), 1))) \
        == pytest.approx(0.05, rel=0.05)
    mixed_err = np.linalg.norm(noisy.cloud.points - noisy.point_exact, axis=1)[noisy.point_mixed]
    assert 0.001 < noisy.point_mixed.mean() < 0.1 and np.median(mixed_err) > 0.3


def test_av2_per_laser_elevations_match_the_measured_table(av2_exact):
    cloud = av2_exact.cloud
    for s, name in enumerate(cloud.names):
        lidar = name.split("@")[0]
        mine = cloud.source == s
        T = np.linalg.inv(cloud.T_ref_source[s])
        q = cloud.points[mine].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        el = np.degrees(np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])))
        ring = cloud.ring[mine]
        table = np.asarray(twin_tables.AV2_ELEVATIONS_DEG[lidar])
        for laser in np.unique(ring):
            np.testing.assert_allclose(el[ring == laser], table[laser], atol=2e-3)
    # down_lidar is upside down: its +15 deg laser points below the horizon of the ego frame.
    down = cloud.names.index("down_lidar@0")
    top_laser = int(np.argmax(twin_tables.AV2_ELEVATIONS_DEG["down_lidar"]))
    sel = (cloud.source == down) & (cloud.ring == top_laser)
    rel = cloud.points[sel] - cloud.T_ref_source[down][:3, 3]
    assert np.all(rel[:, 2] < 0)


def test_av2_table_is_the_real_logs_measurement():
    log = require_shared("av2", "sensor", "val", twin_measure.AV2_LOG)
    for name, (_, _, el) in twin_measure.av2_sweep_lasers(log).items():
        np.testing.assert_allclose(twin_tables.AV2_ELEVATIONS_DEG[name], el, atol=6e-4)
    cal = twin_measure.av2_calibration(log)
    for name, T in cal["lidars"].items():
        np.testing.assert_allclose(twin_tables.AV2_LIDARS[name], T, atol=1e-5)
    for name, (_, w, h, _) in cal["cameras"].items():
        assert twin_tables.AV2_CAMERAS[name][1:3] == (w, h)
    assert twin_tables.AV2_CAMERAS["ring_front_center"][1:3] == (1550, 2048)    # portrait


def test_kitti_and_nuscenes_tables_are_the_real_sweeps_measurement():
    _, el, apex = twin_measure.kitti_sweep_lasers(require_shared("kitti", "drive_0001_frame05", "lidar_data.bin"))
    np.testing.assert_allclose(twin_tables.KITTI_ELEVATIONS_DEG, el, atol=6e-4)
    assert twin_tables.KITTI_APEX_M == pytest.approx(apex, abs=6e-4)
    sample = require_shared("nuscenes", "sample")
    _, el = twin_measure.nuscenes_sweep_lasers(next(sample.glob("*LIDAR_TOP*.pcd.bin")))
    np.testing.assert_allclose(twin_tables.NUSCENES_ELEVATIONS_DEG, el, atol=6e-4)


def test_raster_is_one_source_per_sweep_but_four_units(raster_exact):
    twin = raster_exact
    cloud = twin.cloud
    assert cloud.T_ref_source.shape[0] == 2 and list(cloud.sweep) == [0, -1]
    assert cloud.lidars == (None, None) and cloud.ring is None
    np.testing.assert_array_equal(np.unique(twin.point_unit), np.arange(4))
    rdef = RIG_BUILDERS["raster"](NO_EFFECTS)
    for u, (yaw_deg, mount) in enumerate(RASTER_UNITS):
        for k in (0, 1):
            sel = (twin.point_unit == u) & (cloud.source == k)
            origins = np.unique(twin.point_origin[sel], axis=0)
            assert origins.shape[0] == 1
            # The unit's origin: its mount carried by the sweep's pose (reference frame = roof frame of sweep 0).
            expect = twin.sweep_poses[k][:3, :3] @ np.asarray(mount) + twin.sweep_poses[k][:3, 3]
            np.testing.assert_allclose(origins[0], expect, atol=1e-5)
            d = cloud.points[sel] - origins[0]
            # Azimuth about the unit's own axis, in the sweep's roof frame: within the unit's 120 degrees.
            d = d @ twin.sweep_poses[k][:3, :3]
            az = np.degrees(np.arctan2(d[:, 1], d[:, 0])) - yaw_deg
            az = (az + 180.0) % 360.0 - 180.0
            assert np.all(np.abs(az) <= 60.0 + 1e-3)
    assert rdef.sensor_class == "raster"


def test_ego_moves_as_stated(kitti_exact, raster_exact):
    for twin in (kitti_exact, raster_exact):
        rdef = RIG_BUILDERS[twin.name](NO_EFFECTS)
        ego = rdef.T_ego_points @ twin.sweep_poses @ np.linalg.inv(rdef.T_ego_points)   # each sweep's ego, reference ego frame
        step = np.linalg.norm(np.diff(ego[:, :3, 3], axis=0), axis=1)
        np.testing.assert_allclose(step, rdef.step_m, rtol=1e-9)
        np.testing.assert_allclose(twin.ego_step_m, rdef.step_m, rtol=1e-9)
        assert 0.5 <= rdef.step_m <= 2.0
        yaw = np.degrees(np.arctan2(ego[:, 1, 0], ego[:, 0, 0]))
        np.testing.assert_allclose(yaw, -rdef.yaw_deg * np.arange(len(yaw)), atol=1e-9)
        assert np.all(ego[1:, 0, 3] < 0)       # earlier sweeps lie behind


def test_same_arguments_same_bytes_and_seeds_differ():
    a = make_twin("rosette", sweeps=2, seed=4, scale=SCALE)
    b = make_twin("rosette", sweeps=2, seed=4, scale=SCALE)
    c = make_twin("rosette", sweeps=2, seed=5, scale=SCALE)
    assert a.cloud.points.tobytes() == b.cloud.points.tobytes()
    assert a.dense_depth.tobytes() == b.dense_depth.tobytes()
    assert a.cloud.points.shape != c.cloud.points.shape or not np.array_equal(a.cloud.points, c.cloud.points)


@pytest.mark.parametrize("rig", ["av2", "raster", "nuscenes"])
def test_write_twin_reads_back_through_the_rig_and_sweeps_readers(rig, tmp_path):
    from jaxdepth.io import read_depth_png
    from jaxdepth.io.rig import read_rig_json
    from jaxdepth.io.sweeps import read_sweeps_cloud

    twin = make_twin(rig, sweeps=2, seed=0, scale=SCALE)
    paths = write_twin(twin, tmp_path)
    rig_back = read_rig_json(paths["rig"])
    assert rig_back == twin.rig
    cloud = read_sweeps_cloud(paths["sweeps_json"], rig_back)
    np.testing.assert_allclose(cloud.points, twin.cloud.points, atol=2e-5)
    np.testing.assert_array_equal(cloud.source, twin.cloud.source)
    np.testing.assert_allclose(cloud.T_ref_source, twin.cloud.T_ref_source, atol=1e-6)
    assert cloud.names == twin.cloud.names and cloud.lidars == twin.cloud.lidars
    np.testing.assert_array_equal(cloud.sweep, twin.cloud.sweep)      # signed, time order
    if twin.cloud.ring is None:
        assert cloud.ring is None
    else:
        np.testing.assert_array_equal(cloud.ring, twin.cloud.ring)
    for cam, depth in zip(twin.rig.cameras, twin.depths):
        back = read_depth_png(paths["depth"][cam.name])
        assert back.shape == depth.shape
        np.testing.assert_allclose(back, depth, atol=1.0 / 256)


def test_bad_arguments_name_the_field():
    with pytest.raises(ValueError, match="field 'rig'"):
        make_twin("velodyne")
    with pytest.raises(ValueError, match="field 'sweeps'"):
        make_twin("kitti", sweeps=6)
    with pytest.raises(ValueError, match="field 'scale'"):
        make_twin("kitti", scale=0)
    assert set(TWIN_RIGS) == set(RIG_BUILDERS)


def test_raster_lines_are_densest_at_the_horizon():
    from jaxdepth.research.twin_sensors import raster_lines_deg

    lines = raster_lines_deg(64, top_deg=10.0, bottom_deg=-20.0)
    np.testing.assert_allclose(lines[[0, -1]], [10.0, -20.0], atol=1e-9)
    gaps = -np.diff(lines)
    assert np.all(gaps > 0)
    horizon = int(np.argmin(np.abs(lines[:-1] + lines[1:])))     # the gap that straddles 0 deg
    assert np.all(np.diff(gaps[:horizon + 1]) <= 1e-12) and np.all(np.diff(gaps[horizon:]) >= -1e-12)
    assert gaps.max() > 2.5 * gaps.min()


def test_staggered_lasers_keep_elevations_and_spread_their_phases_over_a_column():
    from jaxdepth.research.twin_sensors import spinning_unit, stagger_lasers

    unit = spinning_unit("s", [2.0, 0.0, -5.0, -10.0, -20.0, -24.0], cols=2048)
    out = stagger_lasers(unit, seed=3)
    d0, d1 = (u.directions.reshape(u.rows, u.cols, 3).astype(np.float64) for u in (unit, out))
    np.testing.assert_allclose(d1[..., 2], d0[..., 2], atol=1e-7)                   # elevations unchanged
    turn = np.angle(np.exp(1j * (np.arctan2(d1[..., 1], d1[..., 0]) - np.arctan2(d0[..., 1], d0[..., 0]))))
    per_row = turn.mean(axis=1)
    np.testing.assert_allclose(turn, np.broadcast_to(per_row[:, None], turn.shape), atol=1e-6)   # one turn per laser
    assert np.all(np.abs(per_row) <= math.pi / unit.cols + 1e-9)                    # within half a column
    assert np.ptp(per_row) > 0.5 * 2 * math.pi / unit.cols                          # the lasers differ
    assert np.array_equal(stagger_lasers(unit, seed=3).directions, out.directions)


def test_laser_phases_option_moves_only_spinning_twins_rays():
    plain = make_twin("kitti", seed=2, scale=SCALE, effects=False)
    staggered = make_twin("kitti", seed=2, scale=SCALE, effects=False, laser_phases=True)
    assert not np.array_equal(plain.cloud.points, staggered.cloud.points)
    assert np.array_equal(plain.depths[0], staggered.depths[0])                    # the cameras see the same scene
    a, b = (make_twin("rosette", seed=0, scale=SCALE, effects=False, laser_phases=p) for p in (False, True))
    assert np.array_equal(a.cloud.points, b.cloud.points)


def test_rosette_sweeps_do_not_repeat_each_others_rays():
    from scipy.spatial import cKDTree

    from jaxdepth.research.twin_sensors import rosette_unit

    a, b = (rosette_unit("r", points=5000, start=s) for s in (0.0, 5000 * 1.37))
    cos_half_fov = math.cos(math.radians(35.0)) - 1e-6
    assert np.all(a.directions[:, 0] >= cos_half_fov)            # inside the 35 deg cone
    dist, _ = cKDTree(a.directions).query(b.directions)
    assert np.median(dist) > 1e-4                                  # new directions, not the same path again


def test_sphere_hits_match_the_analytic_intersection():
    from jaxdepth.research.twin_sensors import sphere_hits

    rng = np.random.default_rng(0)
    centre, radius = np.array([6.0, -1.0, 0.5]), 1.5
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    aim = centre + rng.uniform(-0.5, 0.5, (50, 3))      # rays from the origin that must hit
    d[:50] = aim / np.linalg.norm(aim, axis=1, keepdims=True)
    spheres = np.array([[*centre, radius], [40.0, 40.0, 40.0, 0.5]], np.float32)
    for origin in (np.zeros(3), centre + [0.2, 0.1, 0.0]):         # outside, then inside the sphere
        t = np.asarray(sphere_hits(origin.astype(np.float32), d.astype(np.float32), spheres), np.float64)
        b = d @ (origin - centre)
        disc = b * b - (np.sum((origin - centre) ** 2) - radius ** 2)
        root = np.sqrt(np.maximum(disc, 0))
        expect = np.where(-b - root > 1e-6, -b - root, -b + root)
        expect = np.where((disc >= 0) & (expect > 1e-6), expect, np.inf)
        assert np.isfinite(expect).sum() >= 50
        np.testing.assert_array_equal(np.isinf(t), np.isinf(expect))
        np.testing.assert_allclose(t[np.isfinite(t)], expect[np.isfinite(expect)], rtol=1e-5, atol=1e-5)


def test_calibration_checks_pass_every_twin_and_refuse_its_swapped_image_size(kitti_exact, raster_exact, av2_exact):
    """The geometry checks (principal point, ground, field of view, projected density: issue 39 item 2)
    accept every twin's own rig and refuse it with the image sizes swapped."""
    from jaxdepth.io.errors import InputError
    from jaxdepth.io.plausibility import check_rig_geometry
    from jaxdepth.io.rig import RigCamera
    for twin in (kitti_exact, raster_exact, av2_exact):
        points = np.asarray(twin.cloud.points)
        check_rig_geometry(points, twin.rig.cameras, path=twin.name)
        swapped = [RigCamera(c.name, c.height, c.width, c.K, c.T_cam_lidar) for c in twin.rig.cameras]
        with pytest.raises(InputError, match="seems swapped"):
            check_rig_geometry(points, swapped, path=twin.name)
