"""A rig camera's depth does not depend on the rig's other cameras.

Cameras of several sizes share one padded canvas (the largest height and width). Inside its
own window each camera's result must equal the single-camera call at its own size, with the
same K and pose: Step 2's window bounds (H / L, W L / N), the column bracket's H / L, the
blur's border and the above-scan window are the camera's own, and the padding is never read.
Oracle: :func:`jaxdepth.complete_points_stages` (one LiDAR) and
:func:`jaxdepth.complete_sources` of a one-camera rig (several sources), at each camera's own
size (the mask and seeds bit for bit, depths to float32 rounding). Plus jit == eager of the
mixed-size rig.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxdepth import SGMConfig, complete_points_stages, complete_rig_stages, stack_cameras
from jaxdepth._src import synthetic
from jaxdepth._src.sources import complete_sources_stages, make_sources

from _harness import assert_close, assert_tree_close
from scenes import SMALL_LIDAR, lidar_to_camera, small_camera

LIDAR = SMALL_LIDAR
FIELDS = ("sparse_depth", "inlier_mask", "seed_depth", "du", "dv", "residual", "depth_raw", "depth")
EXACT = ("sparse_depth", "inlier_mask", "seed_depth", "du", "dv")


@pytest.fixture(scope="module")
def mixed_rig():
    """(points, valid, cameras): two landscape 24 x 40 cameras and one portrait 40 x 24 (canvas 40 x 40)."""
    cams = [small_camera(h=24, w=40, f=30.0),
            small_camera(lidar_to_camera((0.2, 0.0, 0.5)), h=40, w=24, f=30.0),
            small_camera(lidar_to_camera((-0.5, 0.1, 0.2)), h=24, w=40, f=34.0)]
    frame = synthetic.make_street_scene(3, lidar=LIDAR, cameras=cams)
    return np.asarray(frame.points), np.asarray(frame.valid), cams


def _assert_own_size(rig, i, cam, single):
    """Camera ``i`` of the rig's stages, on its window, equals ``single``; depth 0 beyond it.

    Bit for bit: the z-buffer, Step 2's mask and Step 3's seeds (depth and offsets). The float
    fields computed from them (residual, depth) within 16 eps x max(|x|, 1): the vmapped body is
    fused differently from the single call (1 ulp seen on the residual; same-size rigs too,
    tests/test_rig.py), while a camera's size read from the canvas moves depths by centimetres
    to metres (the blur's border, Step 2's window).
    """
    h, w = cam.height, cam.width
    for name in FIELDS:
        got = np.asarray(getattr(rig, name)[i])[:h, :w]
        want = np.asarray(getattr(single, name))
        msg = f"camera {i} ({h} x {w}) field {name}"
        if name in EXACT:
            np.testing.assert_array_equal(got, want, err_msg=msg)
        else:
            assert_close(got, want, ulps=16, err_msg=msg)
    depth = np.asarray(rig.depth[i])
    assert not depth[h:].any() and not depth[:, w:].any()


@pytest.mark.slow  # whole pipeline programs of their own: the 40 x 40 rig and each camera size
@pytest.mark.parametrize("config", [SGMConfig(), SGMConfig(above_scan="background", blend_hypotheses=True)],
                         ids=["default", "background_blend"])
def test_rig_camera_equals_its_own_single_camera_call(mixed_rig, config):
    points, valid, cams = mixed_rig
    rig = complete_rig_stages(points, valid, stack_cameras(cams), lidar=LIDAR, config=config)
    assert rig.depth.shape == (3, 40, 40)
    for i, cam in enumerate(cams):
        single = complete_points_stages(points, valid, cam, lidar=LIDAR, config=config)
        assert int(np.asarray(single.inlier_mask).sum()) > 20      # a real scene in every camera
        _assert_own_size(rig, i, cam, single)


@pytest.mark.slow  # whole pipeline programs of their own (several sources, each camera size)
def test_sources_rig_camera_equals_its_one_camera_rig(mixed_rig):
    points, valid, cams = mixed_rig
    # Two sources: the sweep split in two halves, the second LiDAR 0.4 m to the side (both sweep 0).
    half = points.shape[0] // 2
    T2 = np.eye(4, dtype=np.float32)
    T2[1, 3] = 0.4
    pts = np.stack([points[:half], points[half:2 * half]])
    ok = np.stack([valid[:half], valid[half:2 * half]])
    sources = make_sources(pts, ok, np.stack([np.eye(4, dtype=np.float32), T2]), lidars=(LIDAR, LIDAR))
    rig = complete_sources_stages(sources, stack_cameras(cams))
    for i, cam in enumerate(cams):
        _assert_own_size(rig, i, cam, jax.tree.map(lambda a: a[0], complete_sources_stages(
            sources, stack_cameras([cam]))))


@pytest.mark.slow  # the rig's program, and the pipeline op by op
def test_mixed_rig_jit_equals_eager(mixed_rig):
    points, valid, cams = mixed_rig
    cameras = stack_cameras(cams)
    fast = complete_rig_stages(points, valid, cameras, lidar=LIDAR)
    with jax.disable_jit():
        eager = complete_rig_stages(points, valid, cameras, lidar=LIDAR)
    np.testing.assert_array_equal(np.asarray(fast.inlier_mask), np.asarray(eager.inlier_mask))
    assert_tree_close(fast.depth, eager.depth, ulps=8, err_msg="jit != eager")
