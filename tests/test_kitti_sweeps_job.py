"""KITTI raw drives with --sweeps (jaxdepth.batch.kitti_sweeps_job) on a synthetic drive.

The drive: the shared 2011_09_26 camera calibration, a static wall 15 m ahead of the first
pose and a ground plane, seen from a car driving 1 m per sweep (OXTS packets written from the
poses). Oracle: the wall's analytic depth along each camera ray in the completed images.
"""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from jaxdepth.batch import kitti_sweeps_job
from jaxdepth.io import kitti_datasets, read_depth_png

from conftest import require_shared
from test_kitti_oxts import _write_drive

WALL_X = 15.0  # world x of the wall (the IMU frame of the first pose: x forward)


def _scene(rng) -> np.ndarray:
    """World points: a wall x = WALL_X (|y| < 12, -1.7 < z < 4) and the ground z = -1.7 in front of it."""
    n = 60_000
    wall = np.stack([np.full(n, WALL_X), rng.uniform(-12, 12, n), rng.uniform(-1.7, 4, n)], axis=1)
    ground = np.stack([rng.uniform(0, WALL_X, n), rng.uniform(-12, 12, n), np.full(n, -1.7)], axis=1)
    return np.concatenate([wall, ground])


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    calib = require_shared("kitti", "drive_0001_frame05")
    root = tmp_path_factory.mktemp("kitti_sweeps")
    T_velo_imu = np.eye(4)
    T_velo_imu[:3, 3] = (-0.81, 0.32, -0.80)
    scene = _scene(np.random.default_rng(3))
    # two sweeps: with one neighbour on each side every frame holds two sources, spread over the job's window
    # of three (0, -1, 1: one compiled completion for every test below, and for a middle frame's three)
    path = [(1.0 * k, 0.0, 0.0, 0.0) for k in range(2)]
    drive = _write_drive(root, path, T_velo_imu, scene)
    for name in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        shutil.copyfile(calib / name, drive.parent / name)
    return drive, T_velo_imu


def _wall_depth(cam_K, T_cam_lidar, T_velo_imu, height, width, frame: int) -> np.ndarray:
    """(H, W) depth (camera z) at which each pixel's ray meets the wall; 0 where it misses it."""
    T_imu_cam = np.linalg.inv(T_velo_imu) @ np.linalg.inv(T_cam_lidar.astype(np.float64))
    v, u = np.mgrid[0:height, 0:width] + 0.5
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam_K.astype(np.float64)).T  # z = 1
    origin = T_imu_cam[:3, 3] + (frame, 0.0, 0.0)  # world = the first IMU pose's frame, car at x = frame
    direction = rays @ T_imu_cam[:3, :3].T
    z = (WALL_X - origin[0]) / direction[..., 0]
    hit = origin + z[..., None] * direction
    ok = (z > 0) & (np.abs(hit[..., 1]) < 10) & (hit[..., 2] > -1.2) & (hit[..., 2] < 3.5)
    return np.where(ok, z, 0.0)


@pytest.fixture(scope="module")
def api_run(drive, tmp_path_factory):
    """(scan, summary, output root) of the job's one API run over the drive (camera 2, one earlier sweep):
    the run the tests below check, and the bytes the command line must write."""
    drive, _ = drive
    out = tmp_path_factory.mktemp("kitti_sweeps_api") / "out"
    scan = kitti_datasets.kitti_raw_jobs(drive, out, camera=2)
    return scan, kitti_sweeps_job.run_kitti_raw_sweeps(scan.jobs, sweeps=1), out


@pytest.mark.xdist_group("jobs_kitti_sweeps_job")  # one worker builds the drive, runs api_run and compiles the sweep program once
@pytest.mark.slow  # 120k-point sweeps completed at KITTI camera size
def test_sweeps_job_completes_the_wall_and_resumes(drive, api_run):
    drive, T_velo_imu = drive
    scan, summary, _ = api_run
    assert not summary.failed and len(summary.done) == 2
    job = next(j for j in scan.jobs if j.sparse_path.stem == "0000000001")
    depth = read_depth_png(job.out_path)
    assert depth.shape == tuple(job.image_size)
    truth = _wall_depth(job.K, job.T_cam_lidar, T_velo_imu, *job.image_size, frame=1)
    on_wall = (truth > 0) & (depth > 0)
    assert on_wall.sum() > 0.5 * (truth > 0).sum()
    err = np.abs(depth[on_wall] - truth[on_wall])
    assert np.median(err) < 0.05 and np.mean(err < 0.3) > 0.95
    # resume: nothing left to do
    again = kitti_sweeps_job.run_kitti_raw_sweeps(scan.jobs, sweeps=1)
    assert len(again.skipped) == 2 and not again.done and not again.failed


@pytest.mark.xdist_group("jobs_kitti_sweeps_job")  # one worker builds the drive, runs api_run and compiles the sweep program once
@pytest.mark.slow  # 120k-point sweeps completed at KITTI camera size
def test_missing_oxts_fails_only_its_sweeps(drive, tmp_path):
    """A third sweep without its OXTS packet: it fails, and so does sweep 1 (its neighbour); sweep 0, whose
    only neighbour is sweep 1, completes (two sources: the program of the tests above)."""
    drive, _ = drive
    copy = tmp_path / drive.parent.name / drive.name
    shutil.copytree(drive.parent, tmp_path / drive.parent.name)
    shutil.copyfile(copy / "velodyne_points" / "data" / "0000000001.bin",
                    copy / "velodyne_points" / "data" / "0000000002.bin")
    assert not (copy / "oxts" / "data" / "0000000002.txt").exists()
    scan = kitti_datasets.kitti_raw_jobs(copy, tmp_path / "out", camera=2)
    summary = kitti_sweeps_job.run_kitti_raw_sweeps(scan.jobs, sweeps=1)
    failed = sorted(name for name, _ in summary.failed)
    assert failed == [f"{drive.name}/0000000001", f"{drive.name}/0000000002"]
    assert all("0000000002.txt: OXTS packet not found" in m for _, m in summary.failed)
    assert sorted(summary.done) == [f"{drive.name}/0000000000"]
    with pytest.raises(ValueError, match="sweeps"):
        kitti_sweeps_job.run_kitti_raw_sweeps(scan.jobs, sweeps=0)


def test_analytic_wall_depth_helper_is_consistent():
    """The oracle itself: a pixel whose ray is the camera's optical axis meets the wall at the distance
    along x from the camera centre (identity rotation between camera and world, for the check)."""
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    T_cam_lidar = np.eye(4)
    T_cam_lidar[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]  # velo x forward -> camera z
    z = _wall_depth(K, T_cam_lidar, np.eye(4), 100, 100, frame=2)
    assert z[50, 50] == pytest.approx(WALL_X - 2.0, abs=1e-9)
    assert math.isclose(z[0, 50], 0.0) or z[0, 50] > z[50, 50]


@pytest.mark.xdist_group("jobs_kitti_sweeps_job")  # one worker builds the drive, runs api_run and compiles the sweep program once
@pytest.mark.slow  # 120k-point sweeps completed at KITTI camera size (API and CLI)
def test_command_line_sweeps(drive, api_run, tmp_path, capsys):
    """``jaxdepth complete DRIVE DST --sweeps 1`` runs this job (same bytes as the API); --sweeps on a folder
    that is no KITTI raw drive is a data error; --sweeps 0 is the single-sweep path."""
    from jaxdepth import cli
    drive, _ = drive
    _, _, api = api_run  # the API's run of test_sweeps_job_completes_the_wall_and_resumes
    dst = tmp_path / "cli"
    assert cli.main(["complete", str(drive), str(dst), "--sweeps", "1", "--camera", "2", "-q"]) == 0
    outs = sorted(p.relative_to(dst) for p in dst.rglob("*.png"))
    assert len(outs) == 2
    assert all((dst / p).read_bytes() == (api / p).read_bytes() for p in outs)
    assert cli.main(["complete", str(drive), str(tmp_path / "x"), "--sweeps", "1", "--guidance-weight", "2", "-q"]) == 2
    assert cli.main(["complete", str(drive), str(tmp_path / "x"), "--cameras", "image_02", "-q"]) == 2
    flat = tmp_path / "flat"
    flat.mkdir()
    (flat / "a.png").write_bytes(b"")
    assert cli.main(["complete", str(flat), str(tmp_path / "y"), "--sweeps", "2", "-q"]) == 1
    assert "--sweeps applies to KITTI raw drives" in capsys.readouterr().err


def test_sweeps_job_refuses_an_inverted_velo_to_cam_calibration(drive, tmp_path):
    """calib_velo_to_cam.txt holding camera -> LiDAR: every sweep FAILED naming the file and the cause, before
    any compile (the job used to complete them: issue 39 item 2); the drive as written passes the check."""
    from jaxdepth.batch.runner import RunSummary
    from tests.test_far_points_and_calibration import invert_velo_to_cam
    drive, _ = drive
    copy = tmp_path / drive.parent.name / drive.name
    shutil.copytree(drive.parent, tmp_path / drive.parent.name)
    scan = kitti_datasets.kitti_raw_jobs(copy, tmp_path / "out", camera=2)
    todo = kitti_sweeps_job.plan(scan.jobs, overwrite=False, summary=RunSummary(), notify=lambda *a: None)
    cloud, rig = kitti_sweeps_job._load(todo[0], sweeps=1, force=False)  # as written: plausible
    assert cloud.num_sources == 2 and rig.cameras[0].name == "image_02"
    invert_velo_to_cam(copy.parent / "calib_velo_to_cam.txt")
    scan = kitti_datasets.kitti_raw_jobs(copy, tmp_path / "out", camera=2)
    summary = kitti_sweeps_job.run_kitti_raw_sweeps(scan.jobs, sweeps=1)
    assert not summary.done and len(summary.failed) == 2
    for _, message in summary.failed:
        assert (f"{copy.parent / 'calib_velo_to_cam.txt'}: camera 'image_02' field 'T_cam_lidar': T_cam_lidar "
                "looks inverted" in message and "--force" in message), message
    assert not list((tmp_path / "out").rglob("*.png"))
