"""Rig JSON ``lidars`` / ``columns`` and the sweeps JSON: parsing, frames, errors naming file and field."""

from __future__ import annotations

import json
import pathlib
import re

import numpy as np
import pytest

from jaxdepth.io import read_rig_json
from jaxdepth.io.errors import InputError
from jaxdepth.io.rig import write_rig_json
from jaxdepth.io.sweeps import read_point_file_cloud, read_sweeps_cloud, read_sweeps_json

K = [[100.0, 0.0, 63.5], [0.0, 100.0, 31.5], [0.0, 0.0, 1.0]]
T_CAM = [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


def _pose(t, yaw_deg=0.0):
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = t
    return T


def _rig(tmp_path, **extra) -> pathlib.Path:
    doc = {"cameras": [{"name": "cam", "width": 128, "height": 64, "K": K, "T_cam_lidar": T_CAM}]}
    doc.update(extra)
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(doc))
    return path


LIDARS = [{"name": "up", "T_points_lidar": _pose((1.3, 0.0, 1.6)).tolist(), "beams": 32, "fov_up_deg": 15,
           "fov_down_deg": -25},
          {"name": "down", "T_points_lidar": _pose((1.3, 0.0, 1.5), 180.0).tolist()}]
COLUMNS = ["x", "y", "z", "intensity", "lidar"]


def _points(n=200, seed=0, lidar=None):
    rng = np.random.default_rng(seed)
    pts = np.zeros((n, 5), np.float32)
    rho, az = rng.uniform(5, 30, n), rng.uniform(-np.pi, np.pi, n)     # a plausible sweep: near the horizon
    pts[:, :3] = np.stack([rho * np.cos(az), rho * np.sin(az), rng.uniform(-1.7, 1.0, n)], axis=1)
    pts[:, 3] = rng.uniform(0, 1, n)
    pts[:, 4] = np.arange(n) % 2 if lidar is None else lidar
    return pts


def test_rig_json_lidars_and_columns(tmp_path):
    rig = read_rig_json(_rig(tmp_path, lidars=LIDARS, columns=COLUMNS))
    assert [x.name for x in rig.lidars] == ["up", "down"]
    assert rig.lidars[0].spec.beams == 32 and rig.lidars[0].spec.fov_up_deg == 15 and rig.lidars[1].spec is None
    np.testing.assert_allclose(rig.lidars[1].T_points_lidar, _pose((1.3, 0.0, 1.5), 180.0), atol=1e-6)
    assert rig.columns == tuple(COLUMNS)
    again = read_rig_json(write_rig_json(tmp_path / "again.json", rig))
    assert again == rig


@pytest.mark.parametrize("extra, field", [
    (dict(lidars=[{"name": "a", "T_points_lidar": (2 * np.eye(4)).tolist()}]), "lidars[0].T_points_lidar"),
    (dict(lidars=LIDARS, columns=["x", "y", "z", "intensity"]), "columns"),
    (dict(lidar={"beams": 32}, columns=["x", "y", "z", "lidar"]), "columns"),
    (dict(lidars=[{"name": "a"}]), "lidars[0].T_points_lidar"),
    (dict(lidars=[LIDARS[0], {"name": "b", "T_points_lidar": np.diag([1.0, 1.0, -1.0, 1.0]).tolist()}]),
     "lidars[1].T_points_lidar"),                                   # a mirror, not an upside-down LiDAR
    (dict(lidars=LIDARS, columns=["x", "y", "intensity", "lidar"]), "columns"),
])
def test_rig_json_errors_name_the_field(tmp_path, extra, field):
    with pytest.raises(InputError, match=r"rig\.json: field '" + re.escape(field) + "'"):
        read_rig_json(_rig(tmp_path, **extra))


def test_point_file_sources_and_lidar_index_error(tmp_path):
    rig = read_rig_json(_rig(tmp_path, lidars=LIDARS, columns=COLUMNS))
    pts = _points()
    pts.tofile(tmp_path / "a.bin")
    cloud = read_point_file_cloud(tmp_path / "a.bin", rig)
    assert cloud.num_sources == 2 and list(cloud.sweep) == [0, 0]
    np.testing.assert_array_equal(cloud.source, pts[:, 4].astype(np.int32))
    np.testing.assert_allclose(cloud.points, pts[:, :3])
    np.testing.assert_allclose(cloud.T_ref_source[1], _pose((1.3, 0.0, 1.5), 180.0), atol=1e-6)
    bad = _points(lidar=np.where(np.arange(200) == 7, 2, 0))
    bad.tofile(tmp_path / "bad.bin")
    with pytest.raises(InputError, match=r"bad\.bin: field 'lidar' expected an index into the rig's 2 lidars.*got 2"):
        read_point_file_cloud(tmp_path / "bad.bin", rig)


def _sweeps(tmp_path, entries) -> pathlib.Path:
    path = tmp_path / "sweeps.json"
    path.write_text(json.dumps({"sweeps": entries}))
    return path


def test_sweeps_json_frames(tmp_path):
    rig = read_rig_json(_rig(tmp_path, lidars=LIDARS, columns=COLUMNS))
    a, b = _points(seed=1), _points(seed=2)
    a.tofile(tmp_path / "now.bin")
    (tmp_path / "old").mkdir()
    b.tofile(tmp_path / "old" / "before.bin")
    T_old = _pose((-1.5, 0.2, 0.0), 4.0)
    path = _sweeps(tmp_path, [{"file": "old/before.bin", "T_ref_sweep": T_old.tolist()},
                              {"file": "now.bin", "T_ref_sweep": np.eye(4).tolist()}])
    entries = read_sweeps_json(path)
    assert entries[0].file.name == "now.bin"                         # the reference sweep comes first
    cloud = read_sweeps_cloud(path, rig)
    assert cloud.num_sources == 4 and list(cloud.sweep) == [0, 0, -1, -1]   # listed before the reference: earlier
    assert cloud.names == ("up@0", "down@0", "up@-1", "down@-1")
    np.testing.assert_allclose(cloud.points[:200], a[:, :3])
    np.testing.assert_allclose(cloud.points[200:], b[:, :3] @ T_old[:3, :3].T + T_old[:3, 3], atol=1e-5)
    np.testing.assert_allclose(cloud.T_ref_source[3], T_old @ _pose((1.3, 0.0, 1.5), 180.0), atol=1e-6)
    np.testing.assert_array_equal(cloud.source[200:], b[:, 4].astype(np.int32) + 2)


@pytest.mark.parametrize("entries, field", [
    ([{"file": "now.bin", "T_ref_sweep": np.eye(4).tolist()}, {"file": "gone.bin", "T_ref_sweep": np.eye(4).tolist()}],
     "sweeps[1].file"),
    ([{"file": "now.bin", "T_ref_sweep": (np.eye(4) * 1.1).tolist()}], "sweeps[0].T_ref_sweep"),
    ([{"file": "now.bin", "T_ref_sweep": _pose((1, 0, 0)).tolist()}], "sweeps"),
    ([{"file": "now.bin"}], "sweeps[0].T_ref_sweep"),
    ([{"file": "now.bin", "T_ref_sweep": np.eye(4).tolist(), "colums": ["x"]}], "sweeps[0].colums"),
])
def test_sweeps_json_errors_name_file_and_field(tmp_path, entries, field):
    _points().tofile(tmp_path / "now.bin")
    path = _sweeps(tmp_path, entries)
    with pytest.raises(InputError, match=r"sweeps\.json: field '" + re.escape(field) + "'"):
        read_sweeps_json(path)


def test_sweeps_json_lidar_index_error_names_the_sweep_file(tmp_path):
    rig = read_rig_json(_rig(tmp_path, lidars=LIDARS, columns=COLUMNS))
    _points(seed=1).tofile(tmp_path / "now.bin")
    _points(seed=2, lidar=np.where(np.arange(200) == 3, 5, 1)).tofile(tmp_path / "before.bin")
    path = _sweeps(tmp_path, [{"file": "now.bin", "T_ref_sweep": np.eye(4).tolist()},
                              {"file": "before.bin", "T_ref_sweep": _pose((-1.5, 0.0, 0.0)).tolist()}])
    with pytest.raises(InputError, match=r"before\.bin: field 'lidar' expected an index into the rig's 2 lidars "
                                         r"\(0\.\.1\) \(sweep before\.bin of .*sweeps\.json\), got 5 \(point 3\)"):
        read_sweeps_cloud(path, rig)


def test_source_cloud_checks_and_take():
    from jaxdepth.io.sources import SourceCloud
    pts = np.zeros((4, 3), np.float32)
    pose = np.stack([np.eye(4), _pose((1.0, 0.0, 0.0))])
    fields = dict(points=pts, source=np.array([0, 1, 1, 0]), T_ref_source=pose, lidars=(None, None),
                  sweep=np.zeros(2, np.int32), names=("a", "b"), ring=np.arange(4), path="x.bin")
    cloud = SourceCloud(**fields)
    part = cloud.take(np.array([False, True, False, True]))
    assert list(part.source) == [1, 0] and list(part.ring) == [1, 3] and part.num_sources == 2
    with pytest.raises(ValueError, match=r"x\.bin: field 'source' expected indices in \[0, 2\), got 2"):
        SourceCloud(**(fields | dict(source=np.array([0, 2, 1, 0]))))
    sheared = pose.copy()
    sheared[1, 0, 1] = 0.3
    with pytest.raises(ValueError, match=r"x\.bin: field 'T_ref_source\[1\]' expected a rigid 4x4 pose"):
        SourceCloud(**(fields | dict(T_ref_source=sheared)))
