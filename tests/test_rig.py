"""One sweep, several cameras: vmapped rig completion equals per-camera completion."""

from __future__ import annotations


import jax.numpy as jnp
import numpy as np
import pytest

import jaxdepth
from jaxdepth import Camera, complete_points_stages, complete_rig_stages, project_to_image, stack_cameras

from scenes import SMALL_LIDAR, stereo_street

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


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_cameras_of_different_sizes_share_a_padded_canvas(stereo):
    frame, cams = stereo
    big = cams[0]
    small = Camera(K=cams[1].K, T_cam_lidar=cams[1].T_cam_lidar, height=big.height - 16, width=big.width - 40)
    rig = stack_cameras([big, small])
    assert (rig.height, rig.width) == (big.height, big.width)
    np.testing.assert_array_equal(np.asarray(rig.image_size), [[big.height, big.width], [small.height, small.width]])
    out = complete_rig_stages(frame.points, frame.valid, rig, lidar=LIDAR)  # the program of the test above
    # the small camera's own z-buffer (the public projection: no completion compiled at its size)
    own, _ = project_to_image(frame.points, frame.valid, small.K, small.T_cam_lidar, height=small.height,
                              width=small.width)
    sparse = np.asarray(out.sparse_depth[1])
    np.testing.assert_array_equal(sparse[:small.height, :small.width], np.asarray(own))
    assert not sparse[small.height:].any() and not sparse[:, small.width:].any()
    depth = np.asarray(out.depth[1])
    assert not depth[small.height:].any() and not depth[:, small.width:].any()
    assert np.all(depth[:small.height, :small.width] > 0)


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
