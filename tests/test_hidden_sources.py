"""hidden-eval on several sources: each target's cover judged from its own LiDAR, and the scores of what
``complete-rig`` computes (a rig JSON with ``lidars`` / a sweeps JSON).

Oracles: the brute-force cover walk of tests/test_hidden_cover.py per source; the single-sweep
path (:func:`jaxdepth.research.cli.hidden_eval`, checked against the library in
tests/test_research_cli.py), which a one-entry sweeps JSON must reproduce; and
``complete_cloud`` itself (the job's function) scored with the devkit metrics.
"""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest

import jaxdepth
from helpers import square_before_plane
from jaxdepth.research.hidden import own_origin_targets
from test_hidden_cover import numpy_covered


def test_own_origin_targets_judge_each_target_with_its_own_source():
    """Far-plane targets of source 0 behind a near square that only source 1 measured: covered when
    every point is one source (today's single-origin test), not when judged from source 0's own sweep;
    per source, the cover equals the brute-force walk of that source's own points."""
    cams, K, T, points = square_before_plane(seed=2, far_points=1500, near_points=300, near_half_m=1.5)
    source = np.r_[np.zeros(1500, np.int32), np.ones(300, np.int32)]
    valid = np.ones(len(points), bool)
    hidden = np.zeros(len(points), bool)
    hidden[:300] = True
    h = 2

    def zbuf(mask):
        return np.asarray(jaxdepth.project_to_image(jnp.asarray(points), jnp.asarray(mask), jnp.asarray(K),
                                                    jnp.asarray(T), height=48, width=64)[0])

    target = zbuf(hidden)
    one_target, one_cover = own_origin_targets(points, valid, hidden, np.zeros_like(source), cams,
                                               half_heights={0: h})
    np.testing.assert_array_equal(np.asarray(one_target)[0], target)
    want_one = numpy_covered(target, zbuf(valid), h, h)
    np.testing.assert_array_equal(np.asarray(one_cover)[0], want_one)
    assert want_one.sum() > 10                                     # the square covers far targets
    got_target, got = own_origin_targets(points, valid, hidden, source, cams, half_heights={0: h, 1: h})
    np.testing.assert_array_equal(np.asarray(got_target)[0], target)
    want = numpy_covered(target, zbuf(valid & (source == 0)), h, h)
    np.testing.assert_array_equal(np.asarray(got)[0], want)
    assert want.sum() < want_one.sum()                            # source 0 never saw the square


def _write_sequence(tmp_path, sweeps):
    """A two-LiDAR synthetic drive (jaxdepth._src.synthetic_sequences) as point files, a sweeps JSON
    of ``sweeps`` sweeps and a rig JSON with ``lidars`` and ``columns`` (tests/test_sources.py's layout)."""
    from jaxdepth._src.synthetic_sequences import make_street_sequence

    sq = make_street_sequence(2, sweeps=sweeps, lidars=2, image_scale=0.125, noise_std_m=0.0)
    ego = [sq.T_ref_source[2 * k] for k in range(sweeps)]
    mount = np.linalg.inv(ego[0]) @ sq.T_ref_source[1]
    entries = []
    for k in range(sweeps):
        mine = sq.sweep[sq.source] == -k                              # signed: -1 the sweep before
        inv = np.linalg.inv(ego[k])
        local = sq.points[mine] @ inv[:3, :3].T + inv[:3, 3]
        np.concatenate([local, (sq.source[mine] % 2)[:, None]], axis=1).astype(np.float32).tofile(
            tmp_path / f"sweep{k}.bin")
        entries.append({"file": f"sweep{k}.bin", "T_ref_sweep": ego[k].tolist()})
    (tmp_path / "sweeps.json").write_text(json.dumps({"sweeps": entries[::-1]}))   # time order
    lidars = [{"name": "top", "T_points_lidar": np.eye(4).tolist()},
              {"name": "front_low", "T_points_lidar": mount.tolist(), "beams": 16, "fov_up_deg": 15.0,
               "fov_down_deg": -15.0}]
    cam = sq.camera
    doc = {"lidar": {"beams": 32, "fov_up_deg": 10.0, "fov_down_deg": -25.0, "columns": 1024}, "lidars": lidars,
           "columns": ["x", "y", "z", "lidar"],
           "cameras": [{"name": "cam", "width": cam.width, "height": cam.height, "K": np.asarray(cam.K).tolist(),
                        "T_cam_lidar": np.asarray(cam.T_cam_lidar).tolist()}]}
    (tmp_path / "rig.json").write_text(json.dumps(doc))
    return tmp_path / "sweeps.json", tmp_path / "rig.json"


def _check_against_complete_cloud(doc, points_path, rig_path, *, seed, scale=1.0):
    """hidden-eval's SGM scores of every camera equal complete_cloud (the job's function) on the cloud
    without the held-out reference-sweep points, scored at their z-buffer with the devkit metrics.
    complete_cloud's ``Stages`` program (``stages=True``), the one hidden-eval compiled, not the job's
    depth-only program of its own: that one's depth equals the ``Stages`` depth bit for bit at the production
    flags (tests/test_rig_sizes.py), and at the suite's level 0 a depth-only program may round 1 ulp apart."""
    from jaxdepth.batch.sources_job import complete_cloud
    from jaxdepth.io import read_rig_json
    from jaxdepth.io.sweep_frame import prepare_cloud
    from jaxdepth.io.sweeps import is_sweeps_json, read_point_file_cloud, read_sweeps_cloud
    from jaxdepth.research.cli import scaled_rig
    from jaxdepth.research.hidden import hidden_point_mask

    rig = read_rig_json(rig_path)
    read = read_sweeps_cloud if is_sweeps_json(points_path) else read_point_file_cloud
    cloud = prepare_cloud(read(points_path, rig), rig).cloud
    rig = scaled_rig(rig, scale)
    near = np.linalg.norm(cloud.points - cloud.T_ref_source[cloud.source, :3, 3], axis=1) < 1.0
    cloud = cloud.take(~near)
    hidden = hidden_point_mask(cloud.sweep[cloud.source] == 0, fraction=0.2, seed=seed)
    assert hidden.any() and not hidden[cloud.sweep[cloud.source] != 0].any()
    depth = np.asarray(complete_cloud(cloud.take(~hidden), rig, stages=True).depth)
    for i, camera in enumerate(rig.cameras):
        cam = camera.as_camera()
        target = jaxdepth.project_to_image(jnp.asarray(cloud.points), jnp.asarray(hidden), cam.K, cam.T_cam_lidar,
                                           height=cam.height, width=cam.width)[0]
        want = jaxdepth.depth_metrics(jnp.asarray(depth[i, :cam.height, :cam.width]), target)
        assert doc["cameras"][camera.name]["hidden_pixels"] == int((np.asarray(target) > 0).sum()) > 20
        for key in ("rmse", "mae"):
            np.testing.assert_allclose(doc["cameras"][camera.name]["sgm"][key], float(want[key]), rtol=1e-5)
    for method in doc["methods"]:                        # every method on both target sets
        assert doc["mean_uncovered"][method]["mae"] > 0 and doc["mean"][method]["mae"] > 0
    assert 0 < doc["covered_share"] < 0.5


@pytest.mark.slow  # the job's multi-source programs (SGM, no removal, l2) of a 44 x 152 camera, two sweeps
def test_hidden_eval_scores_what_complete_rig_computes(tmp_path, capsys):
    from jaxdepth.cli import main

    sweeps, rig_path = _write_sequence(tmp_path, 2)
    out = tmp_path / "hidden.json"
    assert main(["hidden-eval", str(sweeps), str(rig_path), "--seeds", "4", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["sources"] == ["top@0", "front_low@0", "top@-1", "front_low@-1"] and doc["outlier_removal"]
    assert "all targets RMSE / MAE" in text and "uncovered RMSE / MAE" in text
    _check_against_complete_cloud(doc, sweeps, rig_path, seed=4)


@pytest.mark.slow  # the job's multi-source programs on the shared Argoverse 2 sweep, two cameras at 1/16 size
def test_hidden_eval_on_argoverse2_lidars(tmp_path):
    """The shared Argoverse 2 sweep as a rig JSON with both LiDARs (``lidars``, named ``ring`` and
    ``lidar`` columns, specs left to each LiDAR's own rings), as complete-rig reads it."""
    from jaxdepth.cli import main
    from jaxdepth.io import av2
    from tests.conftest import require_shared

    log = av2.read_log(require_shared("av2", "sensor", "val", "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"))
    rig = av2.read_rig(log, cameras=("ring_front_left", "ring_side_right"))
    xyz, laser = av2.read_sweep(log.sweep_path(log.sweeps[0]))
    np.concatenate([xyz, (laser % 32)[:, None], (laser // 32)[:, None]], axis=1).astype(np.float32).tofile(
        tmp_path / "sweep.bin")
    doc = {"lidars": [{"name": name, "T_points_lidar": log.sensor_pose(name).tolist()} for name, _ in av2.LIDARS],
           "columns": ["x", "y", "z", "ring", "lidar"],
           "cameras": [{"name": c.name, "width": c.width, "height": c.height, "K": np.asarray(c.K).tolist(),
                        "T_cam_lidar": np.asarray(c.T_cam_lidar).tolist()} for c in rig.cameras]}
    (tmp_path / "rig.json").write_text(json.dumps(doc))
    out = tmp_path / "hidden.json"
    argv = [str(tmp_path / "sweep.bin"), str(tmp_path / "rig.json"), "--seeds", "1", "--scale", "0.0625"]
    assert main(["hidden-eval", *argv, "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["sources"] == ["up_lidar@0", "down_lidar@0"] and result["outlier_removal"]
    _check_against_complete_cloud(result, tmp_path / "sweep.bin", tmp_path / "rig.json", seed=1, scale=0.0625)
