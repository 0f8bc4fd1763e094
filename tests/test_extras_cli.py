"""Extra outputs of `jaxdepth complete` / `complete-rig`: --preview, --validity, --seed-distance, --zero-invalid.

Oracles: the library (complete_stages + validity_and_distance) for the CLI's masks; the run
without --zero-invalid times the written mask for --zero-invalid; a vectorised NumPy ray
elevation for the rig and nuScenes cameras; file modification times for resume.
"""

from __future__ import annotations

import math
import os
import pathlib

import cv2
import numpy as np
import pytest

from jaxdepth import cli
from jaxdepth.batch import extras, runner
from jaxdepth.research import evaluation
from jaxdepth._src import presets
from jaxdepth.io import encode_depth_uint16, read_depth_png

from helpers import WALL_CAMERAS, WALL_DOWN_DEG, WALL_UP_DEG, fitting, small_frames, wall_sweep, write_kitti_folder, \
    write_wall_rig

ALL = ["--preview", "--validity", "--seed-distance"]
B2 = ["--batch-size", "2"]  # one batch bucket (2 frames) for every run here: compiled once per process


@pytest.fixture(scope="module")
def src(tmp_path_factory):
    # frames the job's listed program fits (helpers.fitting): its full program, which the whole frames would
    # need too, is not what these tests check (tests/test_listed_job.py checks the overflow)
    items = fitting(small_frames(3, seed=21)[0])
    return write_kitti_folder(tmp_path_factory.mktemp("src"), items), items


def _u16(path):
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)


def _stamps(folder):
    return {p.name: p.stat().st_mtime_ns for p in sorted(pathlib.Path(folder).iterdir())}


def _elevation_level(K, height, width, R_tilt=np.eye(3)):
    """NumPy: elevation of R^T K^-1 [u, v, 1] for a camera with rotation R_tilt @ level (vectorised, float64)."""
    level = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], np.float64)
    R = R_tilt @ level
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(np.asarray(K, np.float64)).T
    d = rays @ R  # (R^T ray) as a row vector
    return np.arctan2(d[..., 2], np.hypot(d[..., 0], d[..., 1]))


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 SGM batches once
def test_folder_extras_match_the_library_zero_invalid_and_default_bytes(tmp_path, src, capsys, monkeypatch):
    root, items = src
    plain, full, zeroed = tmp_path / "plain", tmp_path / "full", tmp_path / "zeroed"
    # The runner's batch programs (a job's listed and full ones, one frame function: jaxdepth.batch.frame_program):
    # frame_function runs once per program built, validity once per trace of the extras body (both looked up when used).
    from jaxdepth.batch import frame_program
    runner.batched_completion.cache_clear()
    plain_traces, extra_traces = [], []
    real_frame_function, real_validity = frame_program.frame_function, frame_program.validity
    monkeypatch.setattr(frame_program, "frame_function", lambda **k: plain_traces.append(
        (k["max_seed_distance_px"], k["listed_only"])) or real_frame_function(**k))
    monkeypatch.setattr(frame_program, "validity", lambda *a, **k: extra_traces.append(1) or real_validity(*a, **k))
    assert cli.main(["complete", str(root), str(plain), "--batch-size", "2", "-q"]) == 0
    # no flag: no extra compiled function (the listed program alone: these frames fit it, no full one built)
    assert plain_traces == [(None, True)] and not extra_traces
    assert cli.main(["complete", str(root), str(full), "--batch-size", "2", "-q", *ALL]) == 0
    assert cli.main(["complete", str(root), str(zeroed), "--batch-size", "2", "-q", "--validity",
                     "--zero-invalid"]) == 0
    assert len(extra_traces) == 1  # one compile (the listed program) for 3 frames (2 batches) and 2 runs
    assert sorted(p.name for p in full.glob("*.png")) == sorted(
        f"frame_00{i}{s}.png" for i in range(3) for s in ("", "_preview", "_validity", "_seed_distance"))
    assert sorted(p.name for p in plain.glob("*.png")) == [f"frame_00{i}.png" for i in range(3)]

    import jaxdepth
    from jaxdepth._src.validity import validity_and_distance
    T = np.asarray(presets.KITTI_T_CAM2_LIDAR)  # the folder's default extrinsic (camera 2)
    for i, (depth, K) in enumerate(items):
        name = f"frame_00{i}"
        # preview / validity / seed distance leave the depth PNG's bytes as they are without flags
        assert (full / f"{name}.png").read_bytes() == (plain / f"{name}.png").read_bytes()
        stages = jaxdepth.complete_stages(read_depth_png(root / "velodyne_raw" / f"{name}.png"), K, T)
        valid, dist = (np.asarray(a) for a in validity_and_distance(stages, K, T, lidar=presets.KITTI_HDL64,
                                                                    metric="l1"))  # the sensor's limit
        mask = _u16(full / f"{name}_validity.png")
        assert mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
        np.testing.assert_array_equal(mask == 255, valid)
        assert valid.any() and not valid.all()
        np.testing.assert_array_equal(_u16(full / f"{name}_seed_distance.png"), extras.encode_seed_distance(dist))
        preview = cv2.imread(str(full / f"{name}_preview.png"), cv2.IMREAD_COLOR)
        assert preview.shape[:2] == (depth.shape[0] + 36, depth.shape[1])
        # --zero-invalid: the depth PNG is the plain one times the mask
        np.testing.assert_array_equal(_u16(zeroed / f"{name}.png"),
                                      np.where(_u16(zeroed / f"{name}_validity.png") == 255,
                                               _u16(plain / f"{name}.png"), 0))
    # jaxdepth eval reads the depth PNGs only, never the extras
    frames, skipped = evaluation.collect_frames(full, side="prediction")
    assert sorted(frames) == [f"frame_00{i}.png" for i in range(3)] and len(skipped) == 9


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 SGM batches once
def test_resume_with_extras_and_a_flag_added_later(tmp_path, src, capsys):
    root, _ = src
    out = tmp_path / "out"
    assert cli.main(["complete", str(root), str(out), *B2, "-q", "--preview"]) == 0
    first = _stamps(out)
    assert cli.main(["complete", str(root), str(out), *B2, "--preview"]) == 0
    assert "0 completed, 3 skipped" in capsys.readouterr().err
    assert _stamps(out) == first
    # a new flag: the frames run again, only the missing files are written
    assert cli.main(["complete", str(root), str(out), *B2, "--preview", "--seed-distance"]) == 0
    assert "3 completed, 0 skipped" in capsys.readouterr().err
    after = _stamps(out)
    assert {k: v for k, v in after.items() if k in first} == first
    assert sorted(set(after) - set(first)) == [f"frame_00{i}_seed_distance.png" for i in range(3)]
    # files removed by hand are filled in (two frames: the runs' batch of 2 again, no new compile)
    os.unlink(out / "frame_001_preview.png")
    os.unlink(out / "frame_002_seed_distance.png")
    assert cli.main(["complete", str(root), str(out), *B2, "--preview", "--seed-distance"]) == 0
    assert "2 completed, 1 skipped" in capsys.readouterr().err
    refilled = _stamps(out)
    assert (out / "frame_001_preview.png").exists() and (out / "frame_002_seed_distance.png").exists()
    assert {k: refilled[k] for k in after if k not in ("frame_001_preview.png", "frame_002_seed_distance.png")} == \
        {k: after[k] for k in after if k not in ("frame_001_preview.png", "frame_002_seed_distance.png")}
    assert all(p.suffix == ".png" or p.name == "jaxdepth_run.json" for p in out.iterdir())  # no temp files left


@pytest.mark.parametrize("extra,pattern", [
    (["--method", "nearest", "--validity"], "need --method sgm"),
    (["--zero-invalid", "--max-seed-distance-px", "-3"], "max_seed_distance_px"),
])
def test_extras_usage_errors_before_any_work(tmp_path, src, capsys, extra, pattern):
    root, _ = src
    assert cli.main(["complete", str(root), str(tmp_path / "out"), *extra]) == 2
    assert pattern in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_complete_rig_extras_cameras_of_two_sizes(tmp_path, capsys):
    up, down, cams = WALL_UP_DEG, WALL_DOWN_DEG, WALL_CAMERAS
    sweep = tmp_path / "sweep.npy"
    wall_sweep(sweep)
    rig = tmp_path / "rig.json"
    write_wall_rig(rig)
    plain, full, zeroed = tmp_path / "plain", tmp_path / "full", tmp_path / "zeroed"
    assert cli.main(["complete-rig", str(sweep), str(rig), str(plain), "--no-estimate", "-q"]) == 0
    assert cli.main(["complete-rig", str(sweep), str(rig), str(full), "--no-estimate", "-q", *ALL,
                     "--max-seed-distance-px", "4"]) == 0
    assert cli.main(["complete-rig", str(sweep), str(rig), str(zeroed), "--no-estimate", "-q", "--validity",
                     "--zero-invalid", "--max-seed-distance-px", "4"]) == 0
    for name, (w, h, K) in cams.items():
        assert (full / f"{name}.png").read_bytes() == (plain / f"{name}.png").read_bytes()
        mask = _u16(full / f"{name}_validity.png") == 255
        assert mask.shape == (h, w)
        dist = extras.decode_seed_distance(_u16(full / f"{name}_seed_distance.png"))
        elev = _elevation_level(K, h, w)
        inside = (elev >= math.radians(down)) & (elev <= math.radians(up))
        edge = np.minimum(np.abs(elev - math.radians(down)), np.abs(elev - math.radians(up))) < 1e-5
        spacing = K[1][1] * math.radians(up - down) / (16 - 1)  # one scan-line spacing: valid beyond the FOV too
        np.testing.assert_array_equal(mask[~edge], ((inside & (dist <= 4)) | (dist <= min(spacing, 4)))[~edge])
        assert mask.any() and not inside.all()  # the field of view cuts the image: rows above the top beam
        np.testing.assert_array_equal(_u16(zeroed / f"{name}.png"), np.where(mask, _u16(plain / f"{name}.png"), 0))
    assert cli.main(["complete-rig", str(sweep), str(rig), str(full), "--no-estimate", *ALL,
                     "--max-seed-distance-px", "4"]) == 0
    assert capsys.readouterr().err.count("exists, skipped") == 2


@pytest.mark.slow  # the real nuScenes sample: SGM with extras on CAM_FRONT at full size
def test_nuscenes_job_writes_extras_beside_each_camera_png(tmp_path):
    """One camera (CAM_FRONT) of the fake v1.0-mini dataroot of tests/test_nuscenes_job.py."""
    from scenes import nuscenes_front_dataroot
    from tests.test_nuscenes_job import SCALE, VERSION
    from jaxdepth.batch.nuscenes_job import run_nuscenes

    root, calib = nuscenes_front_dataroot(tmp_path / "root", tmp_path)
    dst = tmp_path / "out"
    wanted = extras.ExtraOutputs(validity=True, seed_distance=True)
    summary = run_nuscenes(root, dst, version=VERSION, extras=wanted)
    assert sorted(summary.done) == ["s1", "s2"] and [t for t, _ in summary.failed] == ["s3"], summary.failed
    folder = dst / VERSION / "CAM_FRONT"
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        f"CAM_FRONT_{s}{k}.png" for s in ("s1", "s2") for k in ("", "_validity", "_seed_distance"))
    # s1: all ego poses equal, so T_cam_lidar = inverse(cam2ego) @ lidar2ego (the tables' chain)
    K = np.diag([SCALE, SCALE, 1.0]) @ np.asarray(calib["cameras"]["CAM_FRONT"]["cam2img"])
    R = (np.linalg.inv(np.asarray(calib["cameras"]["CAM_FRONT"]["cam2ego"])) @ np.asarray(calib["lidar2ego"]))[:3, :3]
    v, u = np.mgrid[0:225, 0:400].astype(np.float64)
    d = (np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T) @ R
    elev = np.arctan2(d[..., 2], np.hypot(d[..., 0], d[..., 1]))
    lidar = presets.NUSCENES_HDL32
    inside = (elev >= math.radians(lidar.fov_down_deg)) & (elev <= math.radians(lidar.fov_up_deg))
    edge = np.minimum(np.abs(elev - math.radians(lidar.fov_down_deg)),
                      np.abs(elev - math.radians(lidar.fov_up_deg))) < 1e-5
    mask = _u16(folder / "CAM_FRONT_s1_validity.png") == 255
    dist = extras.decode_seed_distance(_u16(folder / "CAM_FRONT_s1_seed_distance.png"))
    # the sensor's limit: 3 scan-line spacings of this camera, 3 * fy * beam step
    limit = 3 * K[1, 1] * math.radians(lidar.fov_up_deg - lidar.fov_down_deg) / (lidar.beams - 1)
    np.testing.assert_array_equal(mask[~edge], ((inside & (dist <= limit)) | (dist <= limit / 3))[~edge])
    assert mask.any() and not mask.all()
    # resume: the same extras skip every finished sample; a new one (preview) runs them again
    again = run_nuscenes(root, dst, version=VERSION, extras=wanted)
    assert sorted(again.skipped) == ["s1", "s2"] and not again.done
    more = run_nuscenes(root, dst, version=VERSION, extras=extras.ExtraOutputs(preview=True, validity=True))
    assert sorted(more.done) == ["s1", "s2"] and (folder / "CAM_FRONT_s2_preview.png").exists()


@pytest.mark.slow  # the real KITTI sweep: SGM with extras at 352 x 1216
def test_kitti_raw_sweep_jobs_write_extras_into_the_proj_depth_tree(tmp_path):
    """One raw drive (the shared frame's sweep), camera 2, benchmark crop: the sweep path's masks are
    the library's complete_points_stages + validity_and_distance with that camera."""
    import shutil

    import jaxdepth
    from jaxdepth.io import pad_points, read_points, rig_from_kitti_raw
    from tests.conftest import require_shared

    frame = require_shared("kitti", "drive_0001_frame05")
    date, drive = "2011_09_26", "2011_09_26_drive_0001_sync"
    data = tmp_path / "raw" / date / drive / "velodyne_points" / "data"
    data.mkdir(parents=True)
    os.symlink(frame / "lidar_data.bin", data / "0000000005.bin")
    for name in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        shutil.copyfile(frame / name, tmp_path / "raw" / date / name)
    dst = tmp_path / "out"
    args = ["complete", str(tmp_path / "raw" / date / drive), str(dst), "--camera", "2", "--crop", "-q"]
    assert cli.main(args + ["--validity", "--seed-distance", "--zero-invalid"]) == 0
    folder = dst / drive / "proj_depth" / "sgm" / "image_02"
    assert sorted(p.name for p in folder.iterdir()) == [
        "0000000005.png", "0000000005_seed_distance.png", "0000000005_validity.png"]
    camera = rig_from_kitti_raw(frame / "calib_cam_to_cam.txt", frame / "calib_velo_to_cam.txt",
                                crop=True).cameras[0].as_camera()
    points, _ = read_points(frame / "lidar_data.bin", columns=4)
    stages = jaxdepth.complete_points_stages(*pad_points(points), camera)
    valid, dist = (np.asarray(a) for a in jaxdepth.validity_and_distance(
        stages, camera.K, camera.T_cam_lidar, lidar=presets.KITTI_HDL64, max_seed_distance_px=16.0))
    np.testing.assert_array_equal(_u16(folder / "0000000005_validity.png") == 255, valid)
    np.testing.assert_array_equal(_u16(folder / "0000000005_seed_distance.png"), extras.encode_seed_distance(dist))
    got = _u16(folder / "0000000005.png").astype(np.int64)
    want = np.where(valid, encode_depth_uint16(np.asarray(stages.depth)), 0).astype(np.int64)
    np.testing.assert_array_equal(got > 0, want > 0)
    # At the suite's level-0 flags the job's batched program and the API may round one pixel's depth
    # apart by one 1/256 m step (docs/testing.md); test_kitti_datasets checks the bytes at the production flags.
    assert np.abs(got - want).max() <= 1 and (got != want).sum() <= 10
    assert 0.3 < valid.mean() < 0.95  # the crop still has rows above the top beam
    stamps = _stamps(folder)
    assert cli.main(args + ["--validity", "--seed-distance", "--zero-invalid"]) == 0  # resume: nothing to do
    assert _stamps(folder) == stamps


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 SGM batches once
def test_ray_actor_writes_the_local_runners_extras(tmp_path, src):
    """The Ray engine's actor (called directly, no cluster) writes the local runner's files, extras included."""
    from jaxdepth.batch import scale

    root, _ = src
    wanted = extras.ExtraOutputs(preview=True, validity=True, seed_distance=True, zero_invalid=True)

    def jobs(dst):
        dst.mkdir()
        return [runner.FrameJob(name=f"frame_00{i}", sparse_path=root / "velodyne_raw" / f"frame_00{i}.png",
                                out_path=dst / f"frame_00{i}.png",
                                intrinsics_path=root / "intrinsics" / f"frame_00{i}.txt") for i in range(3)]

    local = runner.run_jobs(jobs(tmp_path / "local"), batch_size=2, extras=wanted)
    assert local.ok and len(local.done) == 3
    records = [scale._record(job) for job in jobs(tmp_path / "ray")]
    batch = {key: np.array([r[key] for r in records], dtype=object) for key in records[0]}
    actor = scale._CompleteFrames(method="sgm", config=runner.SGMConfig(), lidar=presets.KITTI_HDL64,
                                  T_cam_lidar=presets.KITTI_T_CAM2_LIDAR, batch_size=2, extras=wanted)
    rows = actor(batch)
    assert list(rows["status"]) == ["done"] * 3, rows["message"]
    names = sorted(p.name for p in (tmp_path / "local").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "ray").iterdir()) and len(names) == 12
    for name in names:
        np.testing.assert_array_equal(_u16(tmp_path / "ray" / name), _u16(tmp_path / "local" / name), err_msg=name)
