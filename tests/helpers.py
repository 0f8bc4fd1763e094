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


def fitting(items):
    """``items`` ((depth, K) pairs) with the depth kept on every 4th row and column only (the synthetic
    street's 71 % of the pixels with depth -> 4.4 %, under H W / 16): frames the KITTI job's listed program
    (``jaxdepth.batch.listed``) completes alone, no full program built (the whole frames overflow it)."""
    out = []
    for depth, K in items:
        kept = np.zeros_like(depth)
        kept[::4, ::4] = depth[::4, ::4]
        out.append((kept, K))
    return out


def write_kitti_folder(root: pathlib.Path, frames, *, names=None) -> pathlib.Path:
    from jaxdepth.io import write_depth_png
    (root / "velodyne_raw").mkdir(parents=True, exist_ok=True)
    (root / "intrinsics").mkdir(parents=True, exist_ok=True)
    names = names or [f"frame_{i:03d}" for i in range(len(frames))]
    for name, (depth, K) in zip(names, frames):
        write_depth_png(root / "velodyne_raw" / f"{name}.png", depth)
        (root / "intrinsics" / f"{name}.txt").write_text(" ".join(f"{x:.6f}" for x in K.reshape(-1)) + "\n")
    return root


def numpy_column_hypotheses(depth_raw, kept, window, *, seed_distance=None, normals=None, K=None, blend=False,
                            min_abs_denom=0.01, max_residual_ratio=0.5):
    """Column bracket (and blend) of jaxdepth._src.hypotheses in float64 NumPy, vectorised with
    running max / min of row indices (an algorithm unlike the library's scan); tests/test_hypotheses.py
    checks it against a per-pixel walk."""
    depth_raw = np.asarray(depth_raw, np.float64)
    kept = np.asarray(kept, np.float64)
    h, w = kept.shape
    rows = np.arange(h)[:, None]
    cols = np.arange(w)[None, :]
    has = kept > 0
    up = np.maximum.accumulate(np.where(has, rows, -1), axis=0)
    dn = np.minimum.accumulate(np.where(has, rows, h)[::-1], axis=0)[::-1]
    gap_up = np.where(up >= 0, rows - up, -1)
    gap_dn = np.where(dn < h, dn - rows, -1)
    up_c, dn_c = np.clip(up, 0, h - 1), np.clip(dn, 0, h - 1)
    z_up = np.where(up >= 0, kept[up_c, cols], 0.0)
    z_dn = np.where(dn < h, kept[dn_c, cols], 0.0)
    ok = (gap_up >= 0) & (gap_up <= window) & (gap_dn >= 0) & (gap_dn <= window) & (depth_raw > 0)
    lo, hi = np.minimum(z_up, z_dn), np.maximum(z_up, z_dn)
    out = np.where(ok, np.clip(depth_raw, lo, hi), depth_raw)
    if not blend:
        return out
    K = np.asarray(K, np.float64)
    normals = np.asarray(normals, np.float64)
    v, u = np.broadcast_to(rows, (h, w)), np.broadcast_to(cols, (h, w))
    denom_base = lambda n: (u - K[0, 2]) / K[0, 0] * n[0] + (v - K[1, 2]) / K[1, 1] * n[1] + n[2]

    def hypothesis(z, row, dv):
        n = normals[:, row, cols]
        denom = denom_base(n)
        good = (np.abs(denom) > min_abs_denom) & (z > 0)
        dz = np.where(good, z * dv * n[1] / K[1, 1] / np.where(good, denom, 1.0), 0.0)
        return z + np.clip(dz, -max_residual_ratio * z, max_residual_ratio * z)

    h_up = hypothesis(z_up, up_c, -gap_up)
    h_dn = hypothesis(z_dn, dn_c, gap_dn)
    w_up = np.where(ok & (h_up >= lo) & (h_up <= hi), 1.0 / np.maximum(gap_up, 1), 0.0)
    w_dn = np.where(ok & (h_dn >= lo) & (h_dn <= hi), 1.0 / np.maximum(gap_dn, 1), 0.0)
    dist = np.asarray(seed_distance, np.float64)
    at_seed = dist <= 0
    w_0 = 1.0 / np.where(at_seed, 1.0, dist)
    blended = (w_0 * out + w_up * h_up + w_dn * h_dn) / (w_0 + w_up + w_dn)
    return np.where(at_seed, out, blended)


def square_before_plane(*, seed: int, far_points: int, near_points: int, near_half_m: float):
    """A near square (z = 4 m, half width ``near_half_m``) in front of a far plane (z = 20 m),
    seen by one 64 x 48 camera at the points' origin: (stacked cameras, K, T, (N, 3) float32 points,
    far points first)."""
    import jax.numpy as jnp

    from jaxdepth._src.rig import stack_cameras
    K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]], np.float32)
    T = np.eye(4, dtype=np.float32)
    cams = stack_cameras([Camera(K=jnp.asarray(K), T_cam_lidar=jnp.asarray(T), height=48, width=64)])
    rng = np.random.default_rng(seed)
    far = np.stack([rng.uniform(-8, 8, far_points), rng.uniform(-6, 6, far_points), np.full(far_points, 20.0)], 1)
    near = np.stack([rng.uniform(-near_half_m, near_half_m, near_points),
                     rng.uniform(-near_half_m, near_half_m, near_points), np.full(near_points, 4.0)], 1)
    return cams, K, T, np.concatenate([far, near]).astype(np.float32)


def block_images(sizes, *, seed: int, block_px: int = 8, noise_dn: int = 8) -> list[np.ndarray]:
    """One uint8 (h, w, 3) image per (h, w) in ``sizes``: blocks of ``block_px`` pixels in random colours
    (real edges for the geodesic cost) plus uniform noise of +-``noise_dn``."""
    rng = np.random.default_rng(seed)
    out = []
    for h, w in sizes:
        blocks = rng.integers(0, 256, size=(h // block_px + 1, w // block_px + 1, 3))
        image = np.repeat(np.repeat(blocks, block_px, axis=0), block_px, axis=1)[:h, :w]
        out.append(np.clip(image + rng.integers(-noise_dn, noise_dn + 1, size=image.shape), 0, 255).astype(np.uint8))
    return out


#: The small two-camera rig of the ``complete-rig`` tests (test_extras_cli, test_camera_and_format):
#: name -> (width, height, K). Both cameras look along the LiDAR's +x (:data:`LEVEL`), and a
#: 16-beam LiDAR from +5 to -10 degrees (:data:`WALL_LIDAR`) scans the wall of :func:`wall_sweep`.
#: Tests that run the same rig with the same options share one compiled completion.
WALL_UP_DEG, WALL_DOWN_DEG = 5.0, -10.0
WALL_LIDAR = {"beams": 16, "fov_up_deg": WALL_UP_DEG, "fov_down_deg": WALL_DOWN_DEG, "columns": 720}
LEVEL = [[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]]
WALL_CAMERAS = {"CAM_A": (64, 48, [[40, 0, 31.5], [0, 40, 20.2], [0, 0, 1]]),
                "CAM_B": (40, 30, [[30, 0, 19.5], [0, 30, 9.7], [0, 0, 1]])}


def wall_sweep(path, *, up_deg=WALL_UP_DEG, down_deg=WALL_DOWN_DEG, beams=16):
    """A spinning-LiDAR pattern on the wall x = 20 m, saved as (N, 4) float32 ``.npy``: ``beams``
    elevations, 0.5 degree azimuth steps from -40 to +40 degrees."""
    el = np.radians(np.linspace(down_deg, up_deg, beams))[:, None]
    az = np.radians(np.arange(-40.0, 40.0, 0.5))[None, :]
    r = 20.0 / (np.cos(el) * np.cos(az))
    pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], -1).reshape(-1, 3)
    np.save(path, np.concatenate([pts, np.zeros((len(pts), 1))], 1).astype(np.float32))


def write_wall_rig(path, *, T_cam_lidar=None) -> None:
    """The rig JSON of :data:`WALL_CAMERAS`; ``T_cam_lidar``: camera name -> (4, 4) list (default :data:`LEVEL`)."""
    import json
    T = T_cam_lidar or {}
    pathlib.Path(path).write_text(json.dumps({"lidar": WALL_LIDAR, "cameras": [
        {"name": n, "width": w, "height": h, "K": K, "T_cam_lidar": T.get(n, LEVEL)}
        for n, (w, h, K) in WALL_CAMERAS.items()]}))


def warm_then_run(cache: pathlib.Path, warmup_args, run_args, *, program: str) -> tuple[set, set, object]:
    """``jaxdepth warmup`` and then a job, each in a fresh process with ``cache`` as its own persistent
    compile cache (a folder of this test's only: under xdist the session's cache also gets the other
    worker's programs, so a listing of it cannot say which run stored what).

    Returns (the ``program*`` entries the warm-up stored, those the job then added, the warm-up's
    ``subprocess.CompletedProcess``).
    """
    import os
    import subprocess
    import sys

    cache.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(cache)}

    def programs():
        return {entry for entry in os.listdir(cache) if entry.startswith(program)}

    def run(args):
        result = subprocess.run([sys.executable, "-m", "jaxdepth.cli", *map(str, args)], capture_output=True,
                                text=True, timeout=900, env=env)
        assert result.returncode == 0, result.stderr
        return result

    warm = run(["warmup", *warmup_args])
    warmed = programs()
    run(run_args)
    return warmed, programs() - warmed, warm
