"""One cloud, one decision: a sweep passed as one point file or as a sweeps JSON gets the same sweep check.

The oracle is the single-file path itself (:func:`jaxdepth.io.prepare_sweep`, whose decisions
tests/test_sweep_frame.py checks against known rigs): the multi-source path
(:func:`jaxdepth.io.sweep_frame.prepare_cloud`, ``complete-rig`` with a sweeps JSON) must reach the
same points, rig and trust for the same cloud, and the same depth bytes.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxdepth._src.synthetic_sequences import RIG_LIDARS, _cast_sweep, sequence_scene
from jaxdepth.io import read_rig_json
from jaxdepth.io.sweep_frame import prepare_cloud, prepare_sweep
from jaxdepth.io.sweeps import read_point_file_cloud, read_sweeps_cloud

SPEC = RIG_LIDARS[0][4]                                   # 32 beams, +10 / -25 deg
K = [[60.0, 0.0, 63.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]]
T_CAM = [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
#: A second unit of the same kind beside the first: merged with it, the cloud is not one spinning LiDAR.
OTHER_UNIT = (1.8, 0.9, -0.5)


def _cast(t, k=0):
    scene, _ = sequence_scene(2, k)
    pts, valid = _cast_sweep(scene, np.eye(3), np.asarray(t, np.float64), lidar=SPEC, max_range_m=60.0)
    return np.asarray(pts)[np.asarray(valid)]


def _cloud(kind: str, k: int = 0) -> np.ndarray:
    """(N, 4) float32 x, y, z, intensity: one spinning unit at the origin, or two merged units."""
    pts = _cast((0.0, 0.0, 0.0), k)
    if kind == "merged":
        pts = np.concatenate([pts, _cast(OTHER_UNIT, k)])
    return np.concatenate([pts, np.full((len(pts), 1), 0.5)], axis=1).astype(np.float32)


def _rig(tmp_path, **lidar):
    doc = {"lidar": {"beams": SPEC.beams, "columns": SPEC.columns, **lidar},
           "cameras": [{"name": "cam", "width": 128, "height": 48, "K": K, "T_cam_lidar": T_CAM}]}
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(doc))
    return path


def _sweeps(tmp_path, entries):
    path = tmp_path / "sweeps.json"
    path.write_text(json.dumps({"sweeps": [{"file": f, "T_ref_sweep": np.asarray(T).tolist()} for f, T in entries]}))
    return path


@pytest.mark.parametrize("kind, trusted", [("spinning", True), ("merged", False)])
def test_one_entry_sweeps_json_gets_the_single_file_decision(tmp_path, kind, trusted):
    pts = _cloud(kind)
    pts.tofile(tmp_path / "sweep.bin")
    rig = read_rig_json(_rig(tmp_path))
    single = prepare_sweep(pts[:, :3], rig)
    assert single.outlier_removal_trusted is trusted           # the oracle's own decision, as expected
    for cloud in (read_point_file_cloud(tmp_path / "sweep.bin", rig, point_columns=4),
                  read_sweeps_cloud(_sweeps(tmp_path, [("sweep.bin", np.eye(4))]), rig, point_columns=4)):
        frame = prepare_cloud(cloud, rig)
        assert frame.outlier_removal_trusted is single.outlier_removal_trusted
        np.testing.assert_array_equal(frame.cloud.points, single.points)
        np.testing.assert_array_equal(frame.cloud.T_ref_source, np.eye(4)[None])
        assert frame.cloud.lidars == (single.rig.lidar,) and frame.rig.lidar == single.rig.lidar
        np.testing.assert_array_equal(frame.rig.cameras[0].T_cam_lidar, single.rig.cameras[0].T_cam_lidar)
        assert frame.notes == single.notes


@pytest.mark.parametrize("kind, trusted", [("spinning", True), ("merged", False)])
def test_several_sweeps_of_merged_units_back_off_removal(tmp_path, kind, trusted):
    ego = np.eye(4)
    ego[:3, 3] = (-1.5, 0.05, 0.0)
    _cloud(kind, 0).tofile(tmp_path / "now.bin")
    # sweep 1 in its own frame: the sensor rig posed at ``ego`` in the reference frame
    units = [(0.0, 0.0, 0.0)] + ([OTHER_UNIT] if kind == "merged" else [])
    before = np.concatenate([_cast_moved(ego, 1, unit) for unit in units])
    np.concatenate([before, np.full((len(before), 1), 0.5, np.float32)], axis=1).tofile(tmp_path / "before.bin")
    rig_path = _rig(tmp_path)
    path = _sweeps(tmp_path, [("now.bin", np.eye(4)), ("before.bin", ego)])
    frame = prepare_cloud(read_sweeps_cloud(path, read_rig_json(rig_path), point_columns=4), read_rig_json(rig_path))
    assert frame.outlier_removal_trusted is trusted
    np.testing.assert_allclose(frame.cloud.T_ref_source[1], ego, atol=1e-9)      # each unit sits at its points'
    stated_rig = read_rig_json(_rig(tmp_path, origin_m=[0, 0, 0]))
    stated = prepare_cloud(read_sweeps_cloud(path, stated_rig, point_columns=4), stated_rig)
    assert stated.outlier_removal_trusted                                         # a stated origin is trusted


def _cast_moved(ego, k, unit):
    """Points of the unit at ``unit`` in the sensor rig's frame posed at ``ego``, in that frame."""
    scene, _ = sequence_scene(2, k)
    t = ego[:3, :3] @ np.asarray(unit) + ego[:3, 3]
    pts, valid = _cast_sweep(scene, ego[:3, :3], t, lidar=SPEC, max_range_m=60.0)
    pts = np.asarray(pts)[np.asarray(valid)].astype(np.float64)
    inv = np.linalg.inv(ego)
    return (pts @ inv[:3, :3].T + inv[:3, 3]).astype(np.float32)


@pytest.mark.slow  # two whole-pipeline programs (removal on and off) of a 48 x 128 camera, through the job
@pytest.mark.parametrize("kind", ["spinning", "merged"])
def test_complete_rig_gives_the_same_bytes_for_a_file_and_a_one_entry_sweeps_json(tmp_path, kind):
    from jaxdepth.cli import main

    _cloud(kind).tofile(tmp_path / "sweep.bin")
    rig = _rig(tmp_path)
    sweeps = _sweeps(tmp_path, [("sweep.bin", np.eye(4))])
    for points, out in ((tmp_path / "sweep.bin", "a"), (sweeps, "b")):
        assert main(["complete-rig", str(points), str(rig), str(tmp_path / out), "--point-columns", "4"]) == 0
    a, b = (tmp_path / "a" / "cam.png").read_bytes(), (tmp_path / "b" / "cam.png").read_bytes()
    assert a == b
    settings = [json.loads((tmp_path / out / "jaxdepth_run.json").read_text())["settings"] for out in "ab"]
    assert settings[0] == settings[1]          # the run records too (the decision, the above-scan rule, ...)


@pytest.mark.parametrize("kind", ["spinning", "merged"])
def test_a_file_and_a_one_entry_sweeps_json_call_one_program(tmp_path, monkeypatch, kind):
    """The invariant under the same bytes: complete-rig's host work for a point file (the single path) and for a
    one-entry sweeps JSON (the multi-source path: prepare_cloud, complete_cloud's dispatch) ends in one call of one
    program: the same compile-cache key (program_cache.program_key of its name, static options (config, spec),
    input structure and shapes) and the same input values. The calls are recorded, not run (nothing compiles)."""
    import jax

    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch import program_cache, rig_job

    calls = []

    def record(stage, *args, **statics):
        leaves, treedef = jax.tree_util.tree_flatten(args)
        key = program_cache.program_key(stage.__name__, tuple(sorted(statics.items())), treedef,
                                        program_cache._signature(leaves))
        calls.append((stage.__name__, key, statics["config"], [np.asarray(x) for x in leaves]))

    monkeypatch.setattr(program_cache, "program_folder", lambda: tmp_path)      # rig_stages -> cached_stage
    monkeypatch.setattr(program_cache, "cached_stage", record)
    _cloud(kind).tofile(tmp_path / "sweep.bin")
    rig_path = _rig(tmp_path)
    rig = read_rig_json(rig_path)
    for path in (tmp_path / "sweep.bin", _sweeps(tmp_path, [("sweep.bin", np.eye(4))])):
        multi = path.suffix == ".json"
        prepared = rig_job.prepare_rig_sweep(path, rig, config=SGMConfig(), multi=multi, point_columns=4,
                                             columns=rig_job.point_columns_of(rig, path, 4, multi=multi),
                                             estimate=True, force=False, report=lambda kind, text: None)
        assert prepared.multi is multi
        rig_job._depth_call(prepared)()
    (name_a, key_a, config_a, leaves_a), (name_b, key_b, config_b, leaves_b) = calls
    assert name_a == name_b == "rig_depth_program" and key_a == key_b
    assert config_a.outlier_removal is (kind == "spinning") and config_a == config_b      # the same decision
    assert len(leaves_a) == len(leaves_b)
    for a, b in zip(leaves_a, leaves_b):
        np.testing.assert_array_equal(a, b)
