"""One sweep, several cameras: vmapped rig completion equals per-camera completion."""

from __future__ import annotations


import jax.numpy as jnp
import numpy as np
import pytest

import jaxdepth
from jaxdepth import Camera, complete_points_stages, complete_rig_stages, project_to_image, stack_cameras

from scenes import SMALL_LIDAR, mixed_size_rig, stereo_street

LIDAR = SMALL_LIDAR


@pytest.fixture(scope="module")
def stereo():
    return stereo_street()


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_rig_equals_loop_over_cameras(stereo):
    frame, cams = stereo
    rig = complete_rig_stages(frame.points, frame.valid, stack_cameras(cams), lidar=LIDAR)
    for i, cam in enumerate(cams):
        single = complete_points_stages(frame.points, frame.valid, cam, lidar=LIDAR)
        np.testing.assert_array_equal(np.asarray(rig.sparse_depth[i]), np.asarray(single.sparse_depth))
        np.testing.assert_array_equal(np.asarray(rig.inlier_mask[i]), np.asarray(single.inlier_mask))
        np.testing.assert_allclose(np.asarray(rig.depth[i]), np.asarray(single.depth), rtol=1e-5, atol=1e-4)


@pytest.mark.slow  # the mixed-size rig's program (tests/test_rig_sizes.py compiles it too: one program)
@pytest.mark.xdist_group("rig_mixed_sizes")  # one worker compiles the mixed-size rig's program for both modules
def test_cameras_of_different_sizes_share_a_padded_canvas():
    """Two landscape cameras and a portrait one on one canvas (the largest height and width): each
    camera's z-buffer is its own (the public projection at its size: no completion compiled at its
    size) in its window, and nothing is written beyond it. tests/test_rig_sizes.py checks the whole
    stages against each camera's single-camera call."""
    points, valid, cams = mixed_size_rig()
    rig = stack_cameras(cams)
    assert (rig.height, rig.width) == (max(c.height for c in cams), max(c.width for c in cams)) == (40, 40)
    np.testing.assert_array_equal(np.asarray(rig.image_size), [[c.height, c.width] for c in cams])
    out = complete_rig_stages(points, valid, rig, lidar=LIDAR)
    for i, cam in enumerate(cams):
        own, _ = project_to_image(points, valid, cam.K, cam.T_cam_lidar, height=cam.height, width=cam.width)
        sparse = np.asarray(out.sparse_depth[i])
        np.testing.assert_array_equal(sparse[:cam.height, :cam.width], np.asarray(own), err_msg=f"camera {i}")
        assert not sparse[cam.height:].any() and not sparse[:, cam.width:].any()
        depth = np.asarray(out.depth[i])
        assert not depth[cam.height:].any() and not depth[:, cam.width:].any()
        assert np.all(depth[:cam.height, :cam.width] > 0)


@pytest.mark.xdist_group("jobs_nuscenes")  # one worker: the hidden-point program is test_research_cli's too
@pytest.mark.slow  # real nuScenes sweep, six 225 x 400 cameras: programs of their own
def test_nuscenes_six_cameras_in_one_call(nuscenes_sample):
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io import pad_points, read_points, rig_from_nuscenes_calibration
    rig = rig_from_nuscenes_calibration(nuscenes_sample / "calibration.json")
    sweep = next(nuscenes_sample.glob("*LIDAR_TOP*.bin"))
    points, _ = read_points(sweep, columns=5)
    # the ego vehicle's own returns removed, as the nuScenes job's multi-sweep path does: this sweep's
    # completion is then tests/test_nuscenes_job.py's (test_multisweep_job_completes_sources: the sample
    # of one sweep, the same point bucket, cameras' canvas and LiDAR: one compiled program)
    kept = nusc.remove_close(points, nusc.MULTISWEEP_MIN_DISTANCE_M)
    padded, valid = pad_points(kept)
    scale = 0.25
    cams = []
    for cam in rig.cameras:
        c = cam.as_camera()
        K = np.asarray(c.K).copy()
        K[:2] *= scale
        cams.append(Camera(K=jnp.asarray(K), T_cam_lidar=c.T_cam_lidar, height=int(c.height * scale),
                           width=int(c.width * scale)))
    cameras = stack_cameras(cams)
    stages = complete_rig_stages(padded, valid, cameras, lidar=rig.lidar)
    assert stages.depth.shape == (6, 225, 400)
    assert np.all(np.isfinite(np.asarray(stages.depth)))
    for i in range(6):
        assert np.count_nonzero(np.asarray(stages.sparse_depth[i])) > 300
        assert np.all(np.asarray(stages.depth[i]) > 0)
    # the whole sweep, padded as tests/test_research_cli.py's hidden-eval check pads it (the same program)
    padded, valid = pad_points(points)
    hidden = jaxdepth.hidden_point_mask(valid, fraction=0.1, seed=0)
    scores = jaxdepth.hidden_point_scores(padded, valid, hidden, cameras, lidar=rig.lidar)
    assert np.all(np.asarray(scores["hidden_pixels"]) > 20)
    # at this quarter resolution SGM removes gross errors (RMSE) at the hidden points; the per-camera
    # MAE at full resolution is reported in the README
    assert np.mean(np.asarray(scores["sgm"]["rmse"])) < np.mean(np.asarray(scores["nearest"]["rmse"]))


def test_hidden_point_mask_is_seeded_and_a_subset():
    valid = np.arange(1000) % 3 != 0
    a = jaxdepth.hidden_point_mask(valid, fraction=0.2, seed=7)
    b = jaxdepth.hidden_point_mask(valid, fraction=0.2, seed=7)
    c = jaxdepth.hidden_point_mask(valid, fraction=0.2, seed=8)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert not np.any(a & ~valid) and 0.1 < a.sum() / valid.sum() < 0.3
    with pytest.raises(ValueError, match="fraction"):
        jaxdepth.hidden_point_mask(valid, fraction=1.5)
