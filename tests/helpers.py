"""Small synthetic inputs shared by the CLI / runner tests (fast to compile)."""

from __future__ import annotations

import pathlib

import numpy as np

from jaxdepth._src import synthetic
from jaxdepth._src.geometry import project_to_image
from jaxdepth._src.types import Camera

H, W = 64, 128


def small_frames(count: int, *, seed: int = 0):
    """``count`` (sparse depth (H, W), K (3, 3)) pairs from the synthetic street, KITTI-like camera shrunk."""
    K = np.array([[90.0, 0, (W - 1) / 2], [0, 90.0, 20.0], [0, 0, 1]], np.float32)
    cameras = synthetic.rig_cameras("kitti")
    T = np.asarray(cameras[0].T_cam_lidar)
    camera = Camera(K=K, T_cam_lidar=T, height=H, width=W)
    out = []
    for i in range(count):
        frame = synthetic.make_street_scene(seed + i, cameras=[camera])
        depth, _ = project_to_image(frame.points, frame.valid, K, T, height=H, width=W)
        out.append((np.asarray(depth), K))
    return out, T


def write_kitti_folder(root: pathlib.Path, frames, *, names=None) -> pathlib.Path:
    from jaxdepth.io import write_depth_png
    (root / "velodyne_raw").mkdir(parents=True, exist_ok=True)
    (root / "intrinsics").mkdir(parents=True, exist_ok=True)
    names = names or [f"frame_{i:03d}" for i in range(len(frames))]
    for name, (depth, K) in zip(names, frames):
        write_depth_png(root / "velodyne_raw" / f"{name}.png", depth)
        (root / "intrinsics" / f"{name}.txt").write_text(" ".join(f"{x:.6f}" for x in K.reshape(-1)) + "\n")
    return root
