"""Argoverse 2 reader (jaxdepth.io.av2) on the shared log and on broken copies of its tables.

Oracles: the spinning-LiDAR geometry itself (each laser keeps one elevation about its own
LiDAR's origin and axes, not about the other LiDAR's), the two LiDARs' laser tables agreeing in
their own frames, the city poses' displacement, OpenCV's projectPoints for the cameras, and
analytic poses for the interpolation.
"""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from tests.conftest import require_shared

pa = pytest.importorskip("pyarrow")
import pyarrow.feather as feather  # noqa: E402

from jaxdepth.io import av2  # noqa: E402
from jaxdepth.io.errors import InputError  # noqa: E402

LOG = ("av2", "sensor", "val", "7fab2350-7eaf-3b7e-a39d-6937a4c1bede")


@pytest.fixture(scope="module")
def log():
    return av2.read_log(require_shared(*LOG))


def _elevations_deg(cloud, s, T_ref_lidar):
    """Elevation (deg) of source ``s``'s points about the LiDAR pose ``T_ref_lidar``, and their range."""
    m = cloud.source == s
    q = (cloud.points[m].astype(np.float64) - T_ref_lidar[:3, 3]) @ T_ref_lidar[:3, :3]
    r = np.linalg.norm(q, axis=1)
    return np.degrees(np.arcsin(q[:, 2] / r)), r, cloud.ring[m]


def _laser_spread(cloud, s, T_ref_lidar):
    """(32,) std of each laser's elevation (points farther than 2 m), and (32,) median elevation."""
    el, r, ring = _elevations_deg(cloud, s, T_ref_lidar)
    spread, median = np.zeros(32), np.zeros(32)
    for k in range(32):
        e = el[(ring == k) & (r > 2.0)]
        spread[k], median[k] = np.std(e), np.median(e)
    return spread, median


def test_log_tables(log):
    assert len(log.sweeps) == 2 and log.sweeps[1] - log.sweeps[0] == 100_196_000
    assert {"up_lidar", "down_lidar", *av2.RING_CAMERAS} <= set(log.sensor_poses)
    assert log.city_poses.shape == (2706, 4, 4)
    np.testing.assert_allclose(log.sensor_pose("up_lidar")[:3, 3], (1.35, 0.0, 1.64), atol=0.01)
    np.testing.assert_allclose(log.sensor_pose("down_lidar")[:3, 3], (1.35, 0.0, 1.53), atol=0.01)
    assert log.sensor_pose("down_lidar")[2, 2] < -0.99  # upside down: its z axis points down


def test_one_sweep_two_lidars(log):
    cloud = av2.read_cloud(log)
    table = feather.read_table(log.sweep_path(log.sweeps[0]))
    laser = table.column("laser_number").to_numpy()
    assert cloud.names == ("up_lidar@0", "down_lidar@0") and cloud.sweep.tolist() == [0, 0]
    assert cloud.points.shape == (99_229, 3)
    assert np.bincount(cloud.source).tolist() == [int((laser < 32).sum()), int((laser >= 32).sum())]
    assert cloud.ring.min() == 0 and cloud.ring.max() == 31
    np.testing.assert_array_equal(cloud.T_ref_source[0], log.sensor_pose("up_lidar"))
    np.testing.assert_array_equal(cloud.T_ref_source[1], log.sensor_pose("down_lidar"))


def test_each_laser_is_a_cone_about_its_own_lidar(log):
    """The oracle that the laser split and the calibrated poses are right: about its own LiDAR each
    laser's elevation varies by hundredths of a degree; about the other LiDAR's pose it smears."""
    cloud = av2.read_cloud(log)
    own = [_laser_spread(cloud, s, cloud.T_ref_source[s]) for s in (0, 1)]
    other = [_laser_spread(cloud, s, cloud.T_ref_source[1 - s]) for s in (0, 1)]
    for s in (0, 1):
        assert np.median(own[s][0]) < 0.07, own[s][0]
        assert np.median(other[s][0]) > 0.14, other[s][0]
        assert own[s][0].max() < 0.17
        assert np.mean(own[s][0] < other[s][0]) > 0.9  # laser by laser, own origin wins
    # Both VLP-32C, each in its own (upside-down for down_lidar) frame, show the same laser table:
    # -25 .. +15 deg, laser by laser within 0.05 deg.
    np.testing.assert_allclose(own[0][1], own[1][1], atol=0.05)
    assert own[0][1].min() == pytest.approx(-25.0, abs=0.1) and own[0][1].max() == pytest.approx(15.0, abs=0.1)


def test_two_sweeps_in_the_reference_frame(log):
    cloud = av2.read_cloud(log, sweeps=1)
    assert cloud.names == ("up_lidar@0", "down_lidar@0", "up_lidar@1", "down_lidar@1")
    assert cloud.sweep.tolist() == [0, 0, 1, 1]
    # The vehicle moved 6.6 cm forward between the sweeps: both LiDARs moved with it.
    step = cloud.T_ref_source[2] @ np.linalg.inv(cloud.T_ref_source[0])
    assert np.linalg.norm(step[:3, 3]) == pytest.approx(0.0663, abs=0.002)
    assert step[0, 3] > 0.06
    np.testing.assert_allclose(cloud.T_ref_source[3] @ np.linalg.inv(cloud.T_ref_source[1]), step, atol=1e-9)
    # The later sweep, moved into the reference frame, is still a set of tight cones about its moved LiDARs.
    for s in (2, 3):
        spread, _ = _laser_spread(cloud, s, cloud.T_ref_source[s])
        assert np.median(spread) < 0.07
    # Reading from the second sweep with sweeps=1 gives the first sweep as offset -1, moved by the inverse step.
    back = av2.read_cloud(log, log.sweeps[1], sweeps=1)
    assert back.sweep.tolist() == [0, 0, -1, -1]
    np.testing.assert_allclose(back.T_ref_source[2] @ np.linalg.inv(back.T_ref_source[0]), np.linalg.inv(step),
                               atol=1e-9)
    first = av2.read_cloud(log)
    moved = back.points[back.source == 2].astype(np.float64)
    np.testing.assert_allclose(moved, (first.points[first.source == 0].astype(np.float64)
                                       @ np.linalg.inv(step)[:3, :3].T + np.linalg.inv(step)[:3, 3]), atol=1e-4)


def test_ring_cameras_see_the_sweep(log):
    """Projection through the rig agrees with OpenCV's projectPoints of the calibrated camera poses and
    puts 11,000-18,500 points into each ring camera (the README's 9,000-14,600 is 80 % of that: the
    input of a 20 % hold-out)."""
    cv2 = pytest.importorskip("cv2")
    rig = av2.read_rig(log)
    assert [c.name for c in rig.cameras] == list(av2.RING_CAMERAS)
    sizes = {c.name: (c.width, c.height) for c in rig.cameras}
    assert sizes["ring_front_center"] == (1550, 2048) and sizes["ring_side_left"] == (2048, 1550)
    pts = av2.read_cloud(log).points.astype(np.float64)
    for cam in rig.cameras:
        ego_T_cam = log.sensor_pose(cam.name)
        # camera looks along +z, x right, y down: its optical axis is horizontal, its y axis points down
        assert ego_T_cam[2, 1] < -0.99 and abs(ego_T_cam[2, 2]) < 0.1  # within 6 deg of level
        T = cam.T_cam_lidar.astype(np.float64)
        q = pts @ T[:3, :3].T + T[:3, 3]
        front = q[:, 2] > 0.1
        uv = q[front, :2] / q[front, 2:] @ cam.K[:2, :2].T.astype(np.float64) + cam.K[:2, 2]
        R_cam_ego = np.linalg.inv(ego_T_cam)
        rvec, _ = cv2.Rodrigues(R_cam_ego[:3, :3])
        ref, _ = cv2.projectPoints(pts[front], rvec, R_cam_ego[:3, 3], cam.K.astype(np.float64), None)
        np.testing.assert_allclose(uv, ref[:, 0], rtol=1e-4, atol=0.05)  # float32 rig vs float64
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        assert 11_000 <= inside.sum() <= 18_500, (cam.name, inside.sum())


def test_interpolated_ego_pose():
    """Between two rows: translation linear, rotation the half-angle for a yaw of 90 degrees."""
    T0, T1 = np.eye(4), np.eye(4)
    T1[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T1[:3, 3] = (4.0, 2.0, 0.0)
    mid = av2.interpolate_pose(np.array([100, 200]), np.stack([T0, T1]), 150)
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    np.testing.assert_allclose(mid[:3, :3], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(mid[:3, 3], (2.0, 1.0, 0.0))
    np.testing.assert_array_equal(av2.interpolate_pose(np.array([100, 200]), np.stack([T0, T1]), 200), T1)
    with pytest.raises(InputError, match="timestamp_ns"):
        av2.interpolate_pose(np.array([100, 200]), np.stack([T0, T1]), 201, path="city_SE3_egovehicle.feather")


def _copy_log(tmp_path, log):
    dst = tmp_path / "log"
    shutil.copytree(log.folder, dst)
    return dst


def test_missing_column_names_file_and_field(tmp_path, log):
    dst = _copy_log(tmp_path, log)
    path = dst / "calibration" / "intrinsics.feather"
    table = feather.read_table(path)
    feather.write_feather(table.drop(["fy_px"]), path)
    with pytest.raises(InputError, match=r"intrinsics\.feather: field 'fy_px' expected a column of floats"):
        av2.read_log(dst)


def test_wrong_dtype_names_file_and_field(tmp_path, log):
    dst = _copy_log(tmp_path, log)
    ts = log.sweeps[0]
    path = dst / "sensors" / "lidar" / f"{ts}.feather"
    table = feather.read_table(path)
    i = table.column_names.index("laser_number")
    table = table.set_column(i, "laser_number", pa.array(table.column("laser_number").to_numpy().astype(np.float32)))
    feather.write_feather(table, path)
    fresh = av2.read_log(dst)
    with pytest.raises(InputError, match=rf"{ts}\.feather: field 'laser_number' expected a column of integers"):
        av2.read_cloud(fresh)


def test_bad_laser_number_and_missing_sensor(tmp_path, log):
    dst = _copy_log(tmp_path, log)
    path = dst / "sensors" / "lidar" / f"{log.sweeps[0]}.feather"
    table = feather.read_table(path)
    lasers = table.column("laser_number").to_numpy().copy()
    lasers[5] = 64
    i = table.column_names.index("laser_number")
    feather.write_feather(table.set_column(i, "laser_number", pa.array(lasers)), path)
    with pytest.raises(InputError, match="field 'laser_number' expected laser numbers in \\[0, 64\\), got 64"):
        av2.read_cloud(av2.read_log(dst))
    cal = dst / "calibration" / "egovehicle_SE3_sensor.feather"
    table = feather.read_table(cal)
    keep = pa.array([n != "ring_rear_left" for n in table.column("sensor_name").to_pylist()])
    feather.write_feather(table.filter(keep), cal)
    with pytest.raises(InputError, match="egovehicle_SE3_sensor.feather: field 'sensor_name' expected a row for "
                                         "'ring_rear_left'"):
        av2.read_rig(av2.read_log(dst))


def test_not_a_log(tmp_path):
    with pytest.raises(InputError, match="not an Argoverse 2 sensor log"):
        av2.read_log(tmp_path)
    assert not av2.is_av2_log(tmp_path)


def test_implausible_sweep_is_refused_unless_forced(tmp_path, log):
    """y and z swapped (a wrong column mapping) puts ~half the points at steep angles: refused, named."""
    dst = _copy_log(tmp_path, log)
    path = dst / "sensors" / "lidar" / f"{log.sweeps[0]}.feather"
    table = feather.read_table(path)
    y, z = table.column("y"), table.column("z")
    table = table.set_column(table.column_names.index("y"), "y", z)
    table = table.set_column(table.column_names.index("z"), "z", y)
    feather.write_feather(table, path)
    fresh = av2.read_log(dst)
    with pytest.raises(InputError, match=rf"{log.sweeps[0]}\.feather: not a plausible LiDAR sweep"):
        av2.read_cloud(fresh)
    assert av2.read_cloud(fresh, force=True).points.shape == (99_229, 3)


def test_each_lidar_gets_one_row_per_laser(log):
    """The job's default input (issue 37 item 5): no spec stated, so every laser of each LiDAR has a row of
    its own, ranked by its median elevation about its own LiDAR (oracle: the elevations of the points)."""
    from jaxdepth._src.presets import AV2_VLP32C
    from jaxdepth.batch.sources_job import cloud_sources

    cloud = av2.read_cloud(log)
    assert cloud.lidars == (None, None)
    sources, index = cloud_sources(cloud, fallback=AV2_VLP32C)
    rows = np.asarray(sources.rows)
    for s in (0, 1):
        _, median = _laser_spread(cloud, s, cloud.T_ref_source[s])
        mine = index[s] >= 0
        ring = cloud.ring[index[s][mine]]
        assert np.unique(rows[s][mine]).size == 32
        row_of_ring = np.empty(32, int)
        row_of_ring[np.argsort(-median)] = np.arange(32)
        np.testing.assert_array_equal(rows[s][mine], row_of_ring[ring])
