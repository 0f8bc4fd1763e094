"""The worked examples of docs/rig_json.md (rig JSON ``lidars`` / ``columns``, the sweeps JSON) parse and mean
what the page says: each example is read from the page, written next to synthetic point files, and read back."""

from __future__ import annotations

import json
import pathlib
import re

import numpy as np
import pytest

from jaxdepth.io import read_rig_json
from jaxdepth.io.errors import InputError
from jaxdepth.io.sweeps import read_point_file_cloud, read_sweeps_cloud, read_sweeps_json

DOC = pathlib.Path(__file__).resolve().parents[1] / "docs" / "rig_json.md"


def _example(title: str) -> dict:
    """The JSON block that follows ``<!-- example: title -->`` in docs/rig_json.md."""
    found = re.search(r"<!-- example: " + re.escape(title) + r" -->\s*```json\n(.*?)```", DOC.read_text(), re.S)
    assert found, f"docs/rig_json.md has no example {title!r}"
    return json.loads(found.group(1))


def _sweep_file(path: pathlib.Path, rig_doc: dict, names, *, seed: int) -> np.ndarray:
    """A plausible merged sweep of the rig's LiDARs: 32 rings each, about each LiDAR's own origin and axes,
    written with the named float32 columns; returns the (N, columns) array written."""
    rng = np.random.default_rng(seed)
    rows = []
    for j, lidar in enumerate(rig_doc["lidars"]):
        T = np.asarray(lidar["T_points_lidar"], np.float64)
        for ring, el in enumerate(np.radians(np.linspace(-25.0, 15.0, 32))):
            az, r = rng.uniform(-np.pi, np.pi, 20), rng.uniform(25.0, 35.0, 20)
            local = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el) * np.ones(20)], 1)
            xyz = local @ T[:3, :3].T + T[:3, 3]
            values = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": rng.uniform(0, 1, 20),
                      "lidar": np.full(20, j), "ring": np.full(20, ring)}
            rows.append(np.stack([values[n] for n in names], axis=1))
    out = np.concatenate(rows).astype(np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    out.tofile(path)
    return out


def test_rig_example_lidars_and_columns(tmp_path):
    doc = _example("rig with lidars")
    (tmp_path / "rig.json").write_text(json.dumps(doc))
    rig = read_rig_json(tmp_path / "rig.json")
    assert [x.name for x in rig.lidars] == ["up_lidar", "down_lidar"]
    assert rig.columns == ("x", "y", "z", "intensity", "lidar", "ring")
    assert (rig.lidars[0].spec.beams, rig.lidars[0].spec.fov_up_deg, rig.lidars[0].spec.fov_down_deg) == (32, 15, -25)
    assert rig.lidars[1].spec is None                                   # left out: estimated from its own points
    values = _sweep_file(tmp_path / "a.bin", doc, rig.columns, seed=0)
    cloud = read_point_file_cloud(tmp_path / "a.bin", rig)              # no --point-columns needed
    np.testing.assert_array_equal(cloud.source, values[:, 4].astype(np.int32))
    np.testing.assert_array_equal(cloud.ring, values[:, 5].astype(np.int32))
    np.testing.assert_allclose(cloud.T_ref_source[1], doc["lidars"][1]["T_points_lidar"])
    # The upside-down LiDAR's points, back in its own frame, lie on its 32 rings' elevations.
    T = np.linalg.inv(cloud.T_ref_source[1])
    local = cloud.points[cloud.source == 1] @ T[:3, :3].T + T[:3, 3]
    el = np.degrees(np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1])))
    np.testing.assert_allclose(el, np.linspace(-25.0, 15.0, 32)[cloud.ring[cloud.source == 1]], atol=1e-3)
    values[7, 4] = 2                                                    # a lidar index the rig does not have
    values.tofile(tmp_path / "bad.bin")
    with pytest.raises(InputError, match=r"bad\.bin: field 'lidar' expected an index into the rig's 2 lidars"):
        read_point_file_cloud(tmp_path / "bad.bin", rig)


def test_sweeps_example(tmp_path):
    rig_doc, doc = _example("rig with lidars"), _example("sweeps json")
    (tmp_path / "rig.json").write_text(json.dumps(rig_doc))
    rig = read_rig_json(tmp_path / "rig.json")
    path = tmp_path / "sweeps.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"sweeps\.json: field 'sweeps\[0\]\.file' expected an existing point file"):
        read_sweeps_json(path)                                          # files missing
    written = [_sweep_file(tmp_path / e["file"], rig_doc, e.get("columns", rig.columns), seed=k)
               for k, e in enumerate(doc["sweeps"])]
    cloud = read_sweeps_cloud(path, rig)
    # listed in time order, the reference last: sweeps -2, -1, 0; the cloud puts the reference first
    assert cloud.names == ("up_lidar@0", "down_lidar@0", "up_lidar@-2", "down_lidar@-2", "up_lidar@-1",
                           "down_lidar@-1")
    assert list(cloud.sweep) == [0, 0, -2, -2, -1, -1]
    order = [2, 0, 1]
    start = 0
    for k, (entry, values) in enumerate((doc["sweeps"][i], written[i]) for i in order):
        T_ref_sweep = np.asarray(entry["T_ref_sweep"])
        got = cloud.points[start:start + len(values)]
        np.testing.assert_allclose(got, values[:, :3] @ T_ref_sweep[:3, :3].T + T_ref_sweep[:3, 3], atol=1e-4)
        for j, lidar in enumerate(rig_doc["lidars"]):                   # each (sweep, LiDAR) posed at T_ref_sweep @ T
            np.testing.assert_allclose(cloud.T_ref_source[2 * k + j], T_ref_sweep @ np.asarray(lidar["T_points_lidar"]),
                                       atol=1e-6)
        start += len(values)
    own = slice(len(written[2]), len(written[2]) + len(written[0]))   # 000008: its own columns, no ring
    assert cloud.ring is not None and np.all(cloud.ring[own] == -1) and np.all(cloud.ring[:len(written[2])] >= 0)
