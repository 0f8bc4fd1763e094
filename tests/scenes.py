"""Scenes shared by the test modules: one small LiDAR, one small forward camera, two street rigs.

Modules that use the same LiDAR, camera and image size also compile the same programs, which
the session's persistent compilation cache (``tests/conftest.py``) then reads back instead of
compiling again; so a new test should take its scene from here when one fits.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from jaxdepth._src import synthetic
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.types import Camera, LidarSpec

#: A 32-beam spinning LiDAR with KITTI's HDL-64 vertical field of view and 1024 columns.
SMALL_LIDAR = LidarSpec(beams=32, fov_up_deg=2.0, fov_down_deg=-24.9, columns=1024)


def lidar_to_camera(offset=(-0.3, 0.0, 0.3)) -> np.ndarray:
    """(4, 4) float32 T_cam_lidar of a forward camera (z = LiDAR x, x = -LiDAR y, y = -LiDAR z)
    with the LiDAR at ``offset`` from it (LiDAR frame)."""
    R = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], np.float64)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = R @ np.asarray(offset)
    return T.astype(np.float32)


def turned_lidar_to_camera(offset=(-0.3, 0.0, 0.3), *, yaw_deg: float = 7.3, pitch_deg: float = 3.1,
                           roll_deg: float = -2.2) -> np.ndarray:
    """:func:`lidar_to_camera` turned by odd angles (LiDAR z, y, x axes): no rotation entry is 0 or
    +-1, so the transform's products are not exact in float32 (the axis-aligned pose's are, which
    hides any rounding difference between two ways of computing a projection)."""
    from scipy.spatial.transform import Rotation
    T = lidar_to_camera(offset).astype(np.float64)
    turn = Rotation.from_euler("zyx", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_matrix()
    T[:3, :3] = T[:3, :3] @ turn.T
    T[:3, 3] = T[:3, :3] @ np.asarray(offset, np.float64)
    return T.astype(np.float32)


def snap_to_pixel_edges(points: np.ndarray, camera: Camera, *, min_depth_m: float = 0.1) -> np.ndarray:
    """(N, 3) float32 ``points`` with every one ``camera`` sees moved (float64) so that its pixel
    coordinates are exactly ``(k + 0.5, m + 0.5)``: a rounding edge in u and v, where any float32
    difference between two projections of it picks another pixel. At most half a pixel sideways;
    points outside the image or behind the camera are kept."""
    K = np.asarray(camera.K, np.float32).astype(np.float64)
    T = np.asarray(camera.T_cam_lidar, np.float32).astype(np.float64)
    p = np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]
    z = p[:, 2]
    front = z > min_depth_m
    zs = np.where(front, z, 1.0)
    v = K[1, 1] * p[:, 1] / zs + K[1, 2]
    u = K[0, 0] * p[:, 0] / zs + K[0, 1] * p[:, 1] / zs + K[0, 2]
    seen = front & (u > -0.5) & (u < camera.width - 0.5) & (v > -0.5) & (v < camera.height - 0.5)
    u, v = np.floor(u) + 0.5, np.floor(v) + 0.5
    y = (v - K[1, 2]) / K[1, 1] * zs
    x = (u - K[0, 2] - K[0, 1] * y / zs) / K[0, 0] * zs
    moved = (np.stack([x, y, z], 1) - T[:3, 3]) @ T[:3, :3]      # R^T (p - t)
    return np.where(seen[:, None], moved, points).astype(np.float32)


def small_camera(T_cam_lidar=None, h: int = 96, w: int = 160, f: float = 120.0) -> Camera:
    """An (h, w) pinhole camera of focal length ``f`` px, principal point 10 rows above the centre
    (the horizon in the upper half); ``T_cam_lidar`` defaults to :func:`lidar_to_camera`."""
    T = lidar_to_camera() if T_cam_lidar is None else T_cam_lidar
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2 - 10], [0, 0, 1]], np.float32)
    return Camera(K=jnp.asarray(K), T_cam_lidar=jnp.asarray(T, jnp.float32), height=h, width=w)


def stereo_street(seed: int = 1):
    """(frame, cameras): the synthetic street seen by :data:`SMALL_LIDAR` and the stereo rig at 1/4 scale."""
    cams = stereo_cameras()
    return synthetic.make_street_scene(seed, lidar=SMALL_LIDAR, cameras=cams), cams


def mixed_size_rig():
    """(points, valid, cameras): the street of :data:`SMALL_LIDAR` (seed 3) and three cameras of two sizes,
    24 x 40, 40 x 24 (portrait) and 24 x 40 (a 40 x 40 canvas): the padded-canvas rig of
    tests/test_rig_sizes.py and tests/test_rig.py (one compiled rig program for both)."""
    cams = [small_camera(h=24, w=40, f=30.0),
            small_camera(lidar_to_camera((0.2, 0.0, 0.5)), h=40, w=24, f=30.0),
            small_camera(lidar_to_camera((-0.5, 0.1, 0.2)), h=24, w=40, f=34.0)]
    frame = synthetic.make_street_scene(3, lidar=SMALL_LIDAR, cameras=cams)
    return np.asarray(frame.points), np.asarray(frame.valid), cams


def edge_size_rig():
    """(points, valid, cameras): :func:`mixed_size_rig`'s points seen by three 24 x 40 cameras turned by odd
    angles (one vmapped group), every point the middle camera sees moved onto a rounding edge of its pixel
    grid (:func:`snap_to_pixel_edges`): ``edge_rig`` of tests/test_rig_sizes.py. A batched product of three
    or more cameras' rotations rounds apart from the unbatched one, so a projection computed with plain
    float32 products puts points into other pixels here (issue 37; tests/test_projection_rounding.py).
    Its one-source rig and ``complete_sources`` programs also serve tests/test_sources.py."""
    points, valid, _ = mixed_size_rig()
    cams = [small_camera(turned_lidar_to_camera((-0.3, 0.2, 0.3), yaw_deg=14.1), h=24, w=40, f=30.0),
            small_camera(turned_lidar_to_camera(), h=24, w=40, f=30.0),
            small_camera(turned_lidar_to_camera((-0.5, 0.1, 0.2), yaw_deg=-11.9, pitch_deg=1.7), h=24, w=40,
                         f=34.0)]
    return snap_to_pixel_edges(points, cams[1]), valid, cams


def kitti_street(seed: int = 0):
    """(frame, camera): the synthetic street seen by :data:`SMALL_LIDAR` and the KITTI-like camera at 1/4 scale."""
    cams = synthetic.rig_cameras("kitti", image_scale=0.25)
    return synthetic.make_street_scene(seed, lidar=SMALL_LIDAR, cameras=cams), cams[0]


@functools.lru_cache(maxsize=None)
def tiny_street_frames(seeds: tuple, h: int = 32, w: int = 48):
    """[(points, valid, camera)] per seed: synthetic street sweeps of :data:`SMALL_LIDAR` for an
    (h, w) camera (eager runs stay short), focal length 40 + 4 * index px (per-frame intrinsics)."""
    frames = []
    for i, seed in enumerate(seeds):
        frame, camera = _small_street(seed, h=h, w=w, f=40.0 + 4 * i)
        frames.append((np.asarray(frame.points), np.asarray(frame.valid), camera))
    return frames


def _small_street(seed: int, *, h: int, w: int, f: float, images: bool = False):
    """(frame, camera): the synthetic street seen by :data:`SMALL_LIDAR` and an (h, w) :func:`small_camera`
    of focal length ``f`` px (the scene of :func:`tiny_street_frames` and :func:`tiny_frame`)."""
    camera = small_camera(lidar_to_camera(), h=h, w=w, f=f)
    return synthetic.make_street_scene(seed, lidar=SMALL_LIDAR, cameras=[camera], images=images), camera


def thinned_for_listed_normals(sparse: np.ndarray, *, seed: int = 0, keep: float = 1 / 8,
                               min_points: int = 400) -> np.ndarray:
    """(H, W) float32: ``sparse`` with about a share ``keep`` of its pixels kept, so that it holds
    fewer points than the image-plane normals' listed-path capacity (``ceil(H W / 16)``,
    ``pixel_normals``' default ``max_points``) while ``sparse`` holds more: the thinned image takes
    the listed branch (the one a KITTI frame takes), ``sparse`` the dense one. Both facts, and at
    least ``min_points`` points left, are asserted."""
    thin = np.where(np.random.default_rng(seed).random(sparse.shape) < keep, sparse, 0).astype(np.float32)
    assert (sparse > 0).sum() > -(-sparse.size // 16) > (thin > 0).sum() > min_points
    return thin


# ---------------------------------------------------------------- jobs (batch runner, CLI, Ray engine)


def nuscenes_front_dataroot(root, tmp):
    """The fake v1.0-mini dataroot of ``tests/test_nuscenes_job.py`` with CAM_FRONT only and no JPEGs
    (s1, s2 complete; s3's LiDAR file is missing), built at ``root`` from a one-camera copy of the
    shared sample's calibration in ``tmp``. The extras runs of test_extras_cli and test_ray use it:
    one camera, one compiled rig completion with validity for both."""
    import json
    import os
    import pathlib

    from conftest import require_shared
    from test_nuscenes_job import LIDAR_FILE, build_dataroot

    sample_dir = require_shared("nuscenes", "sample")
    calib = json.loads((sample_dir / "calibration.json").read_text())
    calib["cameras"] = {"CAM_FRONT": calib["cameras"]["CAM_FRONT"]}
    one = pathlib.Path(tmp) / "sample_one_camera"
    one.mkdir()
    (one / "calibration.json").write_text(json.dumps(calib))
    os.symlink(sample_dir / LIDAR_FILE, one / LIDAR_FILE)
    build_dataroot(root, one)
    return root, calib


# ----------------------------------------------------------------------------- image group
# Frames and options of the image-pipeline modules (test_speed_equivalence, test_xla_tuning,
# test_pipeline, test_geodesic): 32 x 48 frames with SMALL_LIDAR and the default configuration are
# the programs of the stage table's pipeline rows; the point-cloud pipeline's stages run on the
# 96 x 160 small_camera.

#: test_pipeline's complete_points_stages configuration where the output clip matters (one program):
#: the default one with the clip at 60 m, which the street scenes' farthest returns (~100 m) exceed.
POINTS_CONFIG = SGMConfig(max_depth_m=60.0)

#: The pipeline's non-default code paths in one configuration (one compiled program per function and
#: shape): no outlier removal, l2 seeds, blended column hypotheses, no smoothing, measured depths not kept,
#: the farthest seed above the top scan line.
NON_DEFAULT = SGMConfig(outlier_removal=False, distance_metric="l2", blend_hypotheses=True, smoothing_sigma_px=0.0,
                        keep_measured_depth=False, above_scan="background")

#: Image-guided seeds with the noise floor: the guided 32 x 48 pipeline of test_geodesic and test_xla_tuning.
GUIDED = SGMConfig(guidance_weight=30.0, guidance_sweeps=2, guidance_noise_floor=1.0)


def tiny_frame(seed: int, *, f: float = 40.0, h: int = 32, w: int = 48, images: bool = False):
    """(sparse, K, T[, image]): a synthetic street sweep of SMALL_LIDAR projected into an (h, w) camera
    of focal length ``f`` px (float32; the image, with ``images``, is the (h, w, 3) uint8 rendering)."""
    from jaxdepth._src.geometry import project_to_image
    frame, camera = _small_street(seed, h=h, w=w, f=f, images=images)
    sparse, _ = project_to_image(frame.points, frame.valid, camera.K, camera.T_cam_lidar, height=h, width=w)
    out = (np.asarray(sparse), np.asarray(camera.K), np.asarray(camera.T_cam_lidar))
    return out + (np.asarray(frame.images[0]),) if images else out


# ---------------------------------------------------------------- sweeps group (rigs, sources, jobs)

def stereo_cameras():
    """The two 1/4-scale stereo cameras of :func:`stereo_street` alone (no street ray-cast): with any
    :data:`SMALL_LIDAR` sweep of 32 x 1024 points, ``complete_rig`` runs tests/test_rig.py's program."""
    return synthetic.rig_cameras("stereo", image_scale=0.25)
