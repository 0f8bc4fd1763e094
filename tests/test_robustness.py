"""Bad input end to end: defined results for conditions inside arrays, one-line errors for files."""

from __future__ import annotations

import errno
import json
import os

import numpy as np
import pytest

from jaxdepth import cli, complete_points, stack_cameras, complete_rig

from helpers import small_frames, write_kitti_folder
from scenes import SMALL_LIDAR, stereo_cameras, tiny_street_frames

LIDAR = SMALL_LIDAR


class _Frame:
    def __init__(self, points, valid):
        self.points, self.valid = points, valid


@pytest.fixture(scope="module")
def scene():
    """(frame, camera): the shared tiny street frame (32 x 48 camera): the stage table's complete_points
    program; with the stereo cameras (scenes.stereo_cameras) its sweep runs test_rig's complete_rig program."""
    points, valid, camera = tiny_street_frames((0,))[0]
    return _Frame(points, valid), camera


@pytest.mark.xdist_group("robustness_points")  # one worker compiles their shared program once
@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_nan_and_inf_points_are_ignored(scene):
    frame, camera = scene
    base = np.asarray(complete_points(frame.points, frame.valid, camera, lidar=LIDAR))
    bad = np.array([[np.nan, 1, 1], [np.inf, 0, 0], [5, -np.inf, 0], [10, 0, np.nan]], np.float32)
    # into four of the padding slots (same point count: the same compiled program), marked valid
    points, valid = np.array(frame.points), np.array(frame.valid)
    slots = np.flatnonzero(~valid)[:4]
    assert len(slots) == 4
    points[slots], valid[slots] = bad, True
    out = np.asarray(complete_points(points, valid, camera, lidar=LIDAR))
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out, base)


@pytest.mark.xdist_group("robustness_points")  # one worker compiles their shared program once
@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
@pytest.mark.parametrize("case", ["empty", "behind", "outside"])
def test_no_point_in_the_image_gives_an_empty_depth(scene, case):
    frame, camera = scene
    points = np.asarray(frame.points).copy()
    valid = np.asarray(frame.valid).copy()
    if case == "empty":
        valid[:] = False
    elif case == "behind":  # mirror every point to the back of the sensor (x forward in the LiDAR frame)
        points[:, 0] = -np.abs(points[:, 0]) - 1.0
    else:  # far to the side: in front of nothing the camera sees
        points = np.stack([np.full(len(points), 0.5), np.full(len(points), 40.0), points[:, 2]], axis=1)
    out = np.asarray(complete_points(points.astype(np.float32), valid, camera, lidar=LIDAR))
    assert np.all(out == 0)
    rig = np.asarray(complete_rig(points.astype(np.float32), valid, stack_cameras(stereo_cameras()), lidar=LIDAR))
    assert np.all(rig == 0)


def test_principal_point_outside_the_image_is_a_reported_frame_error(tmp_path, capsys):
    items, _ = small_frames(2, seed=20)
    src = write_kitti_folder(tmp_path / "src", items)
    (src / "intrinsics" / "frame_001.txt").write_text("90 0 700 0 90 20 0 0 1\n")
    code = cli.main(["complete", str(src), str(tmp_path / "out"), "--method", "nearest", "-q"])
    err = capsys.readouterr().err
    assert code == 1 and "frame_001.txt" in err and "principal point" in err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["frame_000.png", "jaxdepth_run.json"]


def test_full_disk_during_a_write_fails_that_frame_without_partial_file(tmp_path, monkeypatch, capsys):
    items, _ = small_frames(2, seed=30)
    src = write_kitti_folder(tmp_path / "src", items)
    from jaxdepth.io import atomic
    real_write = os.write
    state = {"calls": 0}

    def full_disk(fd, data):  # the disk fills up at the first PNG (the run record is written before any)
        if bytes(data[:4]) == b"\x89PNG":
            state["calls"] += 1
            if state["calls"] == 1:
                raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(atomic.os, "write", full_disk)
    # both frames in one batch (the principal-point test's compiled program); their writes are separate
    code = cli.main(["complete", str(src), str(tmp_path / "out"), "--method", "nearest", "--batch-size", "2", "-q"])
    monkeypatch.undo()
    err = capsys.readouterr().err
    if state["calls"] == 0:
        pytest.skip("atomic writes do not go through os.write on this platform")
    assert code == 1 and ("ENOSPC" in err or "space" in err)
    outputs = sorted(p.name for p in (tmp_path / "out").iterdir() if p.name != "jaxdepth_run.json")
    assert len(outputs) == 1 and outputs[0].endswith(".png")  # the other frame is complete, no temp file


def _rig_json(tmp_path, **override):
    rig = {"lidar": {"beams": 32},
           "cameras": [{"name": "CAM", "width": 64, "height": 48,
                        "K": [[50, 0, 32], [0, 50, 24], [0, 0, 1]],
                        "T_cam_lidar": [[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]]}]}
    for key, value in override.items():
        if key == "units":
            rig["lidar"]["units"] = value
        elif key == "drop":
            del rig["cameras"][0][value]
        elif key == "T":
            rig["cameras"][0]["T_cam_lidar"] = value
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(rig))
    return path


@pytest.mark.parametrize("override,field", [
    ({"units": "mm"}, "units"),
    ({"drop": "K"}, "K"),
    ({"T": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]}, "T_cam_lidar"),
])
def test_bad_rig_json_is_a_one_line_error(tmp_path, capsys, override, field):
    points = tmp_path / "sweep.bin"
    np.zeros((10, 4), np.float32).tofile(points)
    code = cli.main(["complete-rig", str(points), str(_rig_json(tmp_path, **override)), str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 1 and "rig.json" in err and field in err and "Traceback" not in err


def test_bin_with_partial_record_is_a_one_line_error(tmp_path, capsys):
    points = tmp_path / "sweep.bin"
    points.write_bytes(np.zeros(10, np.float32).tobytes() + b"\x00\x00")
    code = cli.main(["complete-rig", str(points), str(_rig_json(tmp_path)), str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 1 and "sweep.bin" in err and "Traceback" not in err
