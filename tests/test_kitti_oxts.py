"""KITTI raw OXTS poses and sweep accumulation (jaxdepth.io.kitti_oxts) on analytic inputs.

Oracles: a straight drive east at known speed on a circle of latitude (translations known in
closed form: the Mercator x of a scaled projection at the scale's own latitude is arc length),
a drive north (arc length on the meridian, to the Mercator's second order), a quarter turn,
round trips (T_ab @ T_ba = I), and a synthetic drive written to disk whose static scene, seen
from every pose, must land on itself in the reference frame.
"""

from __future__ import annotations

import math
import pathlib

import numpy as np
import pytest

from jaxdepth.io import kitti_oxts as ko
from jaxdepth.io.errors import InputError

LAT0, LON0 = 49.011, 8.4169  # Karlsruhe, where KITTI drove
R_EARTH = ko.EARTH_RADIUS_M


def _east_lon(metres: float, lat_deg: float = LAT0) -> float:
    """Longitude step (deg) of ``metres`` along the circle of latitude ``lat_deg``."""
    return math.degrees(metres / (R_EARTH * math.cos(math.radians(lat_deg))))


def _packet(lat, lon, alt=115.0, roll=0.0, pitch=0.0, yaw=0.0):
    return [lat, lon, alt, roll, pitch, yaw]


def test_straight_drive_east_at_known_speed():
    speed, dt = 12.5, 0.1  # m/s, 10 Hz
    packets = [_packet(LAT0, LON0 + _east_lon(k * speed * dt)) for k in range(11)]
    poses = ko.oxts_poses(packets)
    np.testing.assert_allclose(poses[:, :3, 3], [[k * speed * dt, 0, 0] for k in range(11)], atol=1e-6)
    np.testing.assert_allclose(poses[:, :3, :3], np.tile(np.eye(3), (11, 1, 1)))
    # Heading east (yaw 0): relative poses between sweeps are pure forward steps of 1.25 m.
    rel = ko.relative_velo_poses(poses, np.eye(4), ref=5)
    np.testing.assert_allclose(rel[:, :3, 3], [[(k - 5) * speed * dt, 0, 0] for k in range(11)], atol=1e-6)


def test_drive_north_and_altitude():
    """North by d metres: the Mercator y grows by d (scale cos(lat0) cancels sec(lat) to second order)."""
    d = 100.0
    lat1 = LAT0 + math.degrees(d / R_EARTH)
    poses = ko.oxts_poses([_packet(LAT0, LON0), _packet(lat1, LON0, alt=117.0)])
    np.testing.assert_allclose(poses[1, :3, 3], (0.0, d, 2.0), rtol=1e-5, atol=2e-3)


def test_yaw_turn_moves_forward_in_the_car_frame():
    """A car heading north (yaw +90 deg, counter-clockwise from east) that drives 5 m north moved 5 m
    forward (+x) in its own frame; turning in place by +90 deg rotates points by -90 deg about z."""
    north = math.degrees(5.0 / R_EARTH)
    poses = ko.oxts_poses([_packet(LAT0, LON0, yaw=math.pi / 2), _packet(LAT0 + north, LON0, yaw=math.pi / 2),
                           _packet(LAT0 + north, LON0, yaw=math.pi)])
    rel = ko.relative_velo_poses(poses, np.eye(4), ref=0)
    np.testing.assert_allclose(rel[1, :3, 3], (5.0, 0.0, 0.0), atol=1e-3)
    np.testing.assert_allclose(rel[1, :3, :3], np.eye(3), atol=1e-12)
    # Frame 2 turned left by 90 deg: its x axis (forward) is frame 0's y axis (left).
    np.testing.assert_allclose(rel[2, :3, 0], (0.0, 1.0, 0.0), atol=1e-12)


def test_rotation_convention():
    """R = Rz(yaw) Ry(pitch) Rx(roll): roll positive lifts the left side (y axis tilts up), pitch
    positive puts the front down (x axis tilts down)."""
    assert ko.rotation_rpy(0.1, 0.0, 0.0)[2, 1] > 0  # the y axis gains +z
    assert ko.rotation_rpy(0.0, 0.1, 0.0)[2, 0] < 0  # the x axis gains -z
    R = ko.rotation_rpy(0.3, -0.2, 1.1)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_round_trips_and_calibration_conjugation():
    rng = np.random.default_rng(0)
    packets = [_packet(LAT0 + rng.normal(0, 1e-4), LON0 + rng.normal(0, 1e-4), 110 + rng.normal(),
                       *rng.normal(0, 0.05, 2), rng.uniform(-math.pi, math.pi)) for _ in range(6)]
    poses = ko.oxts_poses(packets)
    T_velo_imu = np.eye(4)
    T_velo_imu[:3, :3] = ko.rotation_rpy(0.01, -0.02, 0.03)
    T_velo_imu[:3, 3] = (-0.81, 0.32, -0.80)  # KITTI's IMU sits behind and below the Velodyne
    a = ko.relative_velo_poses(poses, T_velo_imu, ref=1)
    b = ko.relative_velo_poses(poses, T_velo_imu, ref=4)
    np.testing.assert_allclose(a[4] @ b[1], np.eye(4), atol=1e-9)  # 1 <- 4 <- 1
    np.testing.assert_allclose(a[1], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(a[3], a[4] @ b[3], atol=1e-9)  # 1 <- 3 == 1 <- 4 <- 3


def _write_drive(root: pathlib.Path, world_T_imu: list, T_velo_imu: np.ndarray, scene: np.ndarray) -> pathlib.Path:
    """A synthetic KITTI raw drive: OXTS packets of the given IMU poses (yaw about z only, translations
    in metres east/north/up of the first), velodyne sweeps of a static ``scene`` (world points)."""
    date = root / "2011_09_26"
    drive = date / "2011_09_26_drive_0099_sync"
    (drive / "oxts" / "data").mkdir(parents=True)
    (drive / "velodyne_points" / "data").mkdir(parents=True)
    R, t = T_velo_imu[:3, :3], T_velo_imu[:3, 3]
    (date / "calib_imu_to_velo.txt").write_text(
        "calib_time: synthetic\nR: " + " ".join(f"{v:.12e}" for v in R.reshape(-1)) + "\nT: "
        + " ".join(f"{v:.12e}" for v in t) + "\n")
    scale = math.cos(math.radians(LAT0))
    y0 = scale * R_EARTH * math.log(math.tan(math.radians(90 + LAT0) / 2))
    for k, (x, y, z, yaw) in enumerate(world_T_imu):
        lat = math.degrees(2 * math.atan(math.exp((y0 + y) / (scale * R_EARTH)))) - 90
        lon = LON0 + math.degrees(x / (scale * R_EARTH))
        values = [lat, lon, 100.0 + z, 0.0, 0.0, yaw] + [0.0] * 24
        (drive / "oxts" / "data" / f"{k:010d}.txt").write_text(" ".join(f"{v:.15g}" for v in values) + "\n")
        T_w_imu = np.eye(4)
        T_w_imu[:3, :3] = ko.rotation_rpy(0, 0, yaw)
        T_w_imu[:3, 3] = (x, y, z)
        T_w_velo = T_w_imu @ np.linalg.inv(T_velo_imu)
        local = (scene - T_w_velo[:3, 3]) @ T_w_velo[:3, :3]  # inv(T_w_velo) @ scene
        rec = np.concatenate([local, np.ones((len(local), 1))], axis=1).astype(np.float32)
        rec.tofile(drive / "velodyne_points" / "data" / f"{k:010d}.bin")
    return drive


def test_synthetic_drive_accumulates_onto_the_static_scene(tmp_path):
    rng = np.random.default_rng(1)
    scene = rng.uniform((-30, -30, -2), (60, 30, 5), size=(2000, 3))
    path = [(1.2 * k, 0.05 * k * k, 0.01 * k, 0.04 * k) for k in range(7)]  # forward, curving left
    T_velo_imu = np.eye(4)
    T_velo_imu[:3, :3] = ko.rotation_rpy(0.0, 0.0, 0.02)
    T_velo_imu[:3, 3] = (-0.81, 0.32, -0.80)
    drive = _write_drive(tmp_path, path, T_velo_imu, scene)
    cloud = ko.read_drive_cloud(drive, "0000000003", sweeps=2)
    assert cloud.sweep.tolist() == [0, -1, 1, -2, 2]
    assert cloud.names[0] == "velodyne@0" and cloud.num_sources == 5
    ref_points = cloud.points[cloud.source == 0].astype(np.float64)
    for s in range(1, 5):
        np.testing.assert_allclose(cloud.points[cloud.source == s], ref_points, atol=2e-3)
    # The sources' LiDAR origins trace the drive: sweep offset k sits 1.2 k m back/forward (+ the curve).
    T_w_velo = []
    for x, y, z, yaw in path:
        T = np.eye(4)
        T[:3, :3] = ko.rotation_rpy(0, 0, yaw)
        T[:3, 3] = (x, y, z)
        T_w_velo.append(T @ np.linalg.inv(T_velo_imu))
    for s, o in enumerate(cloud.sweep):
        expect = np.linalg.inv(T_w_velo[3]) @ T_w_velo[3 + o]
        np.testing.assert_allclose(cloud.T_ref_source[s], expect, atol=2e-3)
    # At the start of the drive there are fewer neighbours; sweeps=0 needs no OXTS at all.
    assert ko.read_drive_cloud(drive, "0000000000", sweeps=2).sweep.tolist() == [0, 1, 2]
    (drive / "oxts" / "data" / "0000000004.txt").unlink()
    assert ko.read_drive_cloud(drive, "0000000003", sweeps=0).num_sources == 1
    with pytest.raises(InputError, match="0000000004.txt: OXTS packet not found"):
        ko.read_drive_cloud(drive, "0000000003", sweeps=1)


def test_bad_oxts_and_calibration_name_file_and_field(tmp_path):
    bad = tmp_path / "0000000000.txt"
    bad.write_text("49.0 8.4 100 0 0\n")
    with pytest.raises(InputError, match="0000000000.txt: field 'packet' expected 30 numbers"):
        ko.read_oxts(bad)
    bad.write_text("49.0 east " + "0 " * 28)
    with pytest.raises(InputError, match="field 'lon' expected a number"):
        ko.read_oxts(bad)
    bad.write_text("95.0 8.4 " + "0 " * 28)
    with pytest.raises(InputError, match="field 'lat' expected a latitude"):
        ko.read_oxts(bad)
    calib = tmp_path / "calib_imu_to_velo.txt"
    calib.write_text("R: 1 0 0 0 1 0 0 0 1\n")
    with pytest.raises(InputError, match="calib_imu_to_velo.txt: missing field 'T'"):
        ko.read_imu_to_velo(calib)
    calib.write_text("R: 2 0 0 0 1 0 0 0 1\nT: 0 0 0\n")
    with pytest.raises(InputError, match="field 'R' expected a rotation"):
        ko.read_imu_to_velo(calib)
