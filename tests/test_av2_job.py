"""The Argoverse 2 job (jaxdepth.batch.av2_job) on the shared log: outputs, resume, a bad sweep."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from tests.conftest import require_shared

pytest.importorskip("pyarrow")

from jaxdepth.batch import av2_job  # noqa: E402
from jaxdepth.io import av2  # noqa: E402
from jaxdepth.io.depth_png import read_depth_png  # noqa: E402

LOG = ("av2", "sensor", "val", "7fab2350-7eaf-3b7e-a39d-6937a4c1bede")
CAMERA = "ring_side_left"


def _sparse_depth(cloud, cam):
    """(H, W) nearest LiDAR depth per pixel (0 = none): the brute-force projection of the sweep."""
    T = cam.T_cam_lidar.astype(np.float64)
    q = cloud.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    q = q[q[:, 2] > 0.5]
    uv = q[:, :2] / q[:, 2:] @ cam.K[:2, :2].astype(np.float64).T + cam.K[:2, 2]
    u, v = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    sparse = np.full((cam.height, cam.width), np.inf)
    np.minimum.at(sparse, (v[inside], u[inside]), q[inside, 2])
    return np.where(np.isfinite(sparse), sparse, 0.0)


@pytest.mark.xdist_group("jobs_av2")  # one worker compiles the Argoverse 2 sources program once
@pytest.mark.slow  # real Argoverse 2 sweeps completed at 1550 x 2048
def test_job_writes_resumes_and_reports_a_bad_sweep(tmp_path):
    src = tmp_path / "val"
    shutil.copytree(require_shared(*LOG), src / LOG[-1])
    log = av2.read_log(src / LOG[-1])
    bad = log.sweep_path(log.sweeps[1])
    bad.write_bytes(b"not a feather file")
    dst = tmp_path / "out"
    seen = []
    summary = av2_job.run_av2(src, dst, cameras=[CAMERA], on_progress=lambda n, s: seen.append((n, s)))
    good = f"{LOG[-1]}/{log.sweeps[0]}"
    assert summary.done == [good]
    assert len(summary.failed) == 1 and str(bad) in summary.failed[0][1]
    out = av2_job.output_path(dst, LOG[-1], CAMERA, log.sweeps[0])
    depth = read_depth_png(out)
    rig = av2.read_rig(log, (CAMERA,))
    cam = rig.cameras[0]
    assert depth.shape == (cam.height, cam.width) == (1550, 2048)
    # Where the sweep projects, the completed depth is the LiDAR's (outliers aside).
    sparse = _sparse_depth(av2.read_cloud(log), cam)
    hit = sparse > 0
    assert hit.sum() > 10_000
    err = np.abs(depth[hit] - sparse[hit])
    assert np.median(err) < 0.05 and np.mean(err < 0.5) > 0.9
    assert np.mean(depth > 0) > 0.5
    # Re-run: the done sweep is skipped, the bad one fails again; nothing is rewritten.
    before = out.stat().st_mtime_ns
    again = av2_job.run_av2(src, dst, cameras=[CAMERA])
    assert again.skipped == [good] and len(again.failed) == 1 and not again.done
    assert out.stat().st_mtime_ns == before
    # Overwrite gives the same bytes (deterministic).
    first = out.read_bytes()
    av2_job.run_av2(src, dst, cameras=[CAMERA], overwrite=True)
    assert out.read_bytes() == first


def test_layout_detection_and_errors(tmp_path):
    root = require_shared(*LOG[:-1])
    assert av2_job.is_av2_root(root) and av2_job.is_av2_root(root / LOG[-1])
    assert av2_job.find_logs(root) == [root / LOG[-1]]
    assert not av2_job.is_av2_root(tmp_path)
    with pytest.raises(Exception, match="no Argoverse 2 sensor log"):
        av2_job.find_logs(tmp_path)
    with pytest.raises(ValueError, match="sweeps"):
        av2_job.run_av2(root, tmp_path, sweeps=-1)
    summary = av2_job.run_av2(root, tmp_path, cameras=["no_such_camera"])
    assert summary.failed and "sensor_name" in summary.failed[0][1] and not summary.done


@pytest.mark.xdist_group("jobs_av2")  # one worker compiles the Argoverse 2 sources program once
@pytest.mark.slow  # real Argoverse 2 sweeps completed at 1550 x 2048
def test_command_line_detects_the_log(tmp_path, capsys):
    """``jaxdepth complete LOG DST`` finds the Argoverse 2 layout; options that do not apply are usage errors."""
    from jaxdepth import cli

    root = require_shared(*LOG)
    dst = tmp_path / "cli"
    assert cli.main(["complete", str(root), str(dst), "--cameras", CAMERA, "-q"]) == 0
    log = av2.read_log(root)
    outs = sorted(p.relative_to(dst).as_posix() for p in dst.rglob("*.png"))
    assert outs == [f"{LOG[-1]}/{CAMERA}/{ts}.png" for ts in log.sweeps]
    assert read_depth_png(dst / outs[0]).shape == (1550, 2048)
    capsys.readouterr()
    for extra in (["--camera", "2"], ["--method", "nearest", "--validity"], ["--sweeps", "-1"],
                  ["--guidance-weight", "2"], ["--engine", "ray"]):
        assert cli.main(["complete", str(root), str(dst), "-q"] + extra) == 2, extra
        assert "error" in capsys.readouterr().err


def test_job_refuses_a_log_whose_camera_pose_is_inverted(tmp_path):
    """egovehicle_SE3_sensor holding the camera's inverse pose (sensor <- ego): every sweep FAILED naming the
    calibration file and the cause, before any compile (the job used to complete them: issue 39 item 2)."""
    import os

    import pyarrow as pa
    from pyarrow import feather
    from scipy.spatial.transform import Rotation

    log_dir = tmp_path / "val" / LOG[-1]
    shutil.copytree(require_shared(*LOG), log_dir, copy_function=os.symlink)  # the inputs are never written
    path = log_dir / "calibration" / "egovehicle_SE3_sensor.feather"
    table = feather.read_table(path).to_pydict()
    path.unlink()
    i = table["sensor_name"].index("ring_front_center")
    R = Rotation.from_quat([table[k][i] for k in ("qx", "qy", "qz", "qw")]).as_matrix()
    t = np.array([table[k][i] for k in ("tx_m", "ty_m", "tz_m")])
    inverse = Rotation.from_matrix(R.T).as_quat()
    for k, value in zip(("qx", "qy", "qz", "qw", "tx_m", "ty_m", "tz_m"), [*inverse, *(-R.T @ t)]):
        table[k][i] = float(value)
    feather.write_feather(pa.table(table), path)
    summary = av2_job.run_av2(tmp_path / "val", tmp_path / "out", cameras=["ring_front_center"])
    assert not summary.done and len(summary.failed) == len(av2.read_log(log_dir).sweeps)
    for _, message in summary.failed:
        assert (f"{path}: camera 'ring_front_center' field 'T_cam_lidar': T_cam_lidar looks inverted" in message
                and "--force" in message), message
    assert not list((tmp_path / "out").rglob("*.png"))
