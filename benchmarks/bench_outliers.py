"""Run time and effect of step 2 (outlier_keep_mask) on the real KITTI frame.

Input: the official sparse depth ``velodyne_raw_image_02.png`` of
../shared/data/kitti/drive_0001_frame05, cropped the benchmark way (rows 23..374,
columns 13..1228, K shifted by (13, 23)), KITTI camera-2 calibration from
jaxdepth presets, 64 beams, epsilon 1 m, default caps (12, 24) px.

    PYTHONPATH=. python -m benchmarks.bench_outliers [--runs 50] [--json benchmarks/results/outliers.json]

Rows:
- jax_*: the paper's axis-aligned condition 1 (``test="paper"``);
- footprint_*: the default footprint form of condition 1, same paths;
- jax_image: the image-only path (angles back-projected from pixel centres);
- jax_raw: the raw-sweep path (points_cam given; here the same back-projected
  points, so only the time differs);
- jax_vmap2_per_image: cameras 2 and 3 under one vmap, time per image (under
  vmap the run-time skips become selects, see the docstring);
- frozen_*: the same three for the frozen pre-rewrite dense sweep
  (``frozen_keep_mask`` from tests/oracles/outliers_dense_sweep.py, the implementation before the prefilter), timed
  interleaved with the new rows in one process; its masks must equal the new
  ones bit for bit (also checked by tests/test_outliers.py);
- numpy_offsets: a vectorised NumPy version (one pass per window offset), also
  used to check the mask.
Times are median and minimum wall time after a warm-up, plus the median process
CPU time (both cores count); compile time is separate. The jax rows run
interleaved (one call of each per round), so load from other jobs hits them
alike: compare rows of one run, not runs.

Effect (the paper's Table 1 on one frame): RMSE / MAE of the sparse input
against ``groundtruth_image_02.png`` on pixels valid in both, before and after
removal, and the share of sparse pixels kept. Also for the raw HDL-64E sweep
(``lidar_data.bin``) projected with the same calibration, image-only vs raw path.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import pathlib
import platform
import sys
import time

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src import presets
from jaxdepth._src.geometry import project_to_image, transform_points
from jaxdepth._src.outliers import outlier_keep_mask, window_half_sizes

# The frozen dense sweep (the pre-rewrite implementation) lives in tests/oracles/.
from tests.oracles.outliers_dense_sweep import frozen_keep_mask


# ----------------------------------------------------------------------------- benchmark
ROOT = pathlib.Path(__file__).resolve().parents[1]
FRAME = ROOT.parent / "shared" / "data" / "kitti" / "drive_0001_frame05"
ROWS, COLS = slice(23, 375), slice(13, 1229)
BEAMS, EPS = 64, 1.0


def read_crop(name: str) -> np.ndarray:
    raw = cv2.imread(str(FRAME / name), cv2.IMREAD_UNCHANGED)
    return raw[ROWS, COLS].astype(np.float32) / 256.0


def cropped_K() -> np.ndarray:
    K = presets.KITTI_K_CAM2.copy()
    K[0, 2] -= COLS.start
    K[1, 2] -= ROWS.start
    return K


def numpy_offsets(depth, K, T, *, beams, eps, max_hw=12, max_hh=24):
    """Vectorised NumPy reference: one boolean pass per offset of the window."""
    H, W = depth.shape
    valid = depth > 0
    n = int(valid.sum())
    if n == 0:
        return valid
    hw, hh = window_half_sizes(H, W, beams=beams, max_half_width_px=max_hw, max_half_height_px=max_hh)
    hw = min(hw, (W * beams - 1) // n)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    Ki = np.linalg.inv(K.astype(np.float64))
    p = np.einsum("ij,jhw->ihw", Ki, np.stack([u, v, np.ones_like(u)])) * depth
    q = p - T[:3, 3].astype(np.float64)[:, None, None]
    theta, phi = np.arctan2(q[0], q[2]), np.arctan2(q[1], q[2])
    z = np.where(valid, depth, np.inf)
    pad = ((hh, hh), (hw, hw))
    tp, pp, zp = np.pad(theta, pad), np.pad(phi, pad), np.pad(z, pad, constant_values=np.inf)
    removed = np.zeros_like(valid)
    for du in range(-hw, hw + 1):
        for dv in range(-hh, hh + 1):
            if du == 0 and dv == 0:
                continue
            s = np.s_[hh + dv:hh + dv + H, hw + du:hw + du + W]
            flip = (du * (theta - tp[s]) > 0) | (dv * (phi - pp[s]) > 0)
            removed |= flip & (z > zp[s] + eps)
    return valid & ~removed


def timed(fn, runs: int):
    fn()
    wall, cpu = [], []
    for _ in range(runs):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return summary(wall, cpu)


def summary(wall, cpu):
    return {"median_ms": float(np.median(wall) * 1e3), "min_ms": float(np.min(wall) * 1e3),
            "cpu_median_ms": float(np.median(cpu) * 1e3), "runs": len(wall)}


def timed_interleaved(fns: dict, runs: int) -> dict:
    """Each callable once per round, ``runs`` rounds (after one warm-up round)."""
    for fn in fns.values():
        fn()
    wall = {name: [] for name in fns}
    cpu = {name: [] for name in fns}
    for _ in range(runs):
        for name, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    return {name: summary(wall[name], cpu[name]) for name in fns}


def errors(sparse, truth, keep):
    both = (sparse > 0) & (truth > 0)
    e = (sparse - truth)[both & keep]
    return {"rmse_mm": float(np.sqrt(np.mean(e ** 2)) * 1e3), "mae_mm": float(np.mean(np.abs(e)) * 1e3),
            "pixels": int(e.size), "keep_ratio": float(keep[sparse > 0].mean())}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--json", type=pathlib.Path, default=ROOT / "benchmarks" / "results" / "outliers.json")
    args = parser.parse_args(argv)
    if not FRAME.exists():
        print(f"shared data not found: {FRAME}", file=sys.stderr)
        return 1

    sparse = read_crop("velodyne_raw_image_02.png")
    sparse3 = read_crop("velodyne_raw_image_03.png")
    truth = read_crop("groundtruth_image_02.png")
    K, T = cropped_K(), presets.KITTI_T_CAM2_LIDAR
    H, W = sparse.shape
    n = int((sparse > 0).sum())
    hw_cap, hh = window_half_sizes(H, W, beams=BEAMS, max_half_width_px=12, max_half_height_px=24)
    hw = min(hw_cap, (W * BEAMS - 1) // n)

    d_j, K_j, T_j = jnp.asarray(sparse), jnp.asarray(K), jnp.asarray(T)
    v, u = np.mgrid[0:H, 0:W].astype(np.float32)
    pts = np.stack([(u - K[0, 2]) / K[0, 0] * sparse, (v - K[1, 2]) / K[1, 1] * sparse, sparse])
    p_j = jnp.asarray(pts)
    batch = (jnp.asarray(np.stack([sparse, sparse3])), jnp.stack([K_j, K_j]), jnp.stack([T_j, T_j]))

    paper = dict(beams=BEAMS, epsilon_m=EPS, test="paper")
    image_fn = jax.jit(lambda d, k, t: outlier_keep_mask(d, k, t, **paper))
    raw_fn = jax.jit(lambda d, k, t, p: outlier_keep_mask(d, k, t, points_cam=p, **paper))
    vmap_fn = jax.jit(jax.vmap(lambda d, k, t: outlier_keep_mask(d, k, t, **paper)))
    foot = dict(beams=BEAMS, epsilon_m=EPS, test="footprint")
    foot_image = jax.jit(lambda d, k, t: outlier_keep_mask(d, k, t, **foot))
    foot_raw = jax.jit(lambda d, k, t, p: outlier_keep_mask(d, k, t, points_cam=p, **foot))
    foot_vmap = jax.jit(jax.vmap(lambda d, k, t: outlier_keep_mask(d, k, t, **foot)))
    frozen_image = jax.jit(lambda d, k, t: frozen_keep_mask(d, k, t, beams=BEAMS, epsilon_m=EPS))
    frozen_raw = jax.jit(lambda d, k, t, p: frozen_keep_mask(d, k, t, beams=BEAMS, epsilon_m=EPS, points_cam=p))
    frozen_vmap = jax.jit(jax.vmap(lambda d, k, t: frozen_keep_mask(d, k, t, beams=BEAMS, epsilon_m=EPS)))

    rows = {}
    compiled = {}
    for name, fn, fargs in (("jax_image", image_fn, (d_j, K_j, T_j)), ("jax_raw", raw_fn, (d_j, K_j, T_j, p_j)),
                            ("jax_vmap2_per_image", vmap_fn, batch),
                            ("frozen_image", frozen_image, (d_j, K_j, T_j)),
                            ("frozen_raw", frozen_raw, (d_j, K_j, T_j, p_j)),
                            ("frozen_vmap2_per_image", frozen_vmap, batch),
                            ("footprint_image", foot_image, (d_j, K_j, T_j)),
                            ("footprint_raw", foot_raw, (d_j, K_j, T_j, p_j)),
                            ("footprint_vmap2_per_image", foot_vmap, batch)):
        t0 = time.perf_counter()
        exe = fn.lower(*fargs).compile()
        rows[name] = {"compile_s": time.perf_counter() - t0}
        compiled[name] = (exe, fargs)

    run = lambda name: np.asarray(compiled[name][0](*compiled[name][1]))
    keep = run("jax_image")
    keep_np = numpy_offsets(sparse, K, T, beams=BEAMS, eps=EPS)
    mismatch = int((keep != keep_np).sum())
    keep_raw_same = bool(np.array_equal(run("jax_raw"), keep))
    frozen_equal = {"image": bool(np.array_equal(run("frozen_image"), keep)),
                    "raw": bool(np.array_equal(run("frozen_raw"), run("jax_raw"))),
                    "vmap2": bool(np.array_equal(run("frozen_vmap2_per_image"), run("jax_vmap2_per_image")))}

    timings = timed_interleaved({name: functools.partial(lambda exe, fargs: jax.block_until_ready(exe(*fargs)),
                                                         exe, fargs)
                                 for name, (exe, fargs) in compiled.items()}, args.runs)
    for name in compiled:
        rows[name].update(timings[name])
    for name in ("jax_vmap2_per_image", "frozen_vmap2_per_image", "footprint_vmap2_per_image"):
        rows[name].update({k: rows[name][k] / 2 for k in ("median_ms", "min_ms", "cpu_median_ms")})
    rows["numpy_offsets"] = timed(lambda: numpy_offsets(sparse, K, T, beams=BEAMS, eps=EPS),
                                  max(args.runs // 10, 3))

    # Effect on the official input, and on the raw sweep (image-only vs raw path).
    effect = {"input": errors(sparse, truth, sparse > 0), "after": errors(sparse, truth, keep),
              "after_footprint": errors(sparse, truth, run("footprint_image"))}
    scan = np.fromfile(FRAME / "lidar_data.bin", np.float32).reshape(-1, 4)[:, :3]
    depth_s, index = project_to_image(jnp.asarray(scan), jnp.ones(len(scan), bool), K_j, T_j, height=H, width=W)
    depth_s, index = np.asarray(depth_s), np.asarray(index)
    p_cam = np.asarray(transform_points(T_j, jnp.asarray(scan)))
    pts_s = np.moveaxis(np.where((index >= 0)[..., None], p_cam[np.maximum(index, 0)], 0.0), -1, 0)
    keep_s_img = np.asarray(image_fn(jnp.asarray(depth_s), K_j, T_j))
    keep_s_raw = np.asarray(raw_fn(jnp.asarray(depth_s), K_j, T_j, jnp.asarray(pts_s, jnp.float32)))
    effect["sweep_input"] = errors(depth_s, truth, depth_s > 0)
    effect["sweep_after_image_path"] = errors(depth_s, truth, keep_s_img)
    effect["sweep_after_raw_path"] = errors(depth_s, truth, keep_s_raw)
    effect["sweep_paths_disagree_px"] = int((keep_s_img != keep_s_raw).sum())
    frozen_equal["sweep_image"] = bool(np.array_equal(
        np.asarray(frozen_image(jnp.asarray(depth_s), K_j, T_j)), keep_s_img))
    frozen_equal["sweep_raw"] = bool(np.array_equal(
        np.asarray(frozen_raw(jnp.asarray(depth_s), K_j, T_j, jnp.asarray(pts_s, jnp.float32))), keep_s_raw))

    print(f"input: {FRAME.name}/velodyne_raw_image_02.png cropped {H}x{W}, N = {n} points, "
          f"W L / N = {W * BEAMS / n:.2f} -> |du| <= {hw}, H / L = {H / BEAMS:.2f} -> |dv| <= {hh}, "
          f"{(2 * hw + 1) * (2 * hh + 1) - 1} offsets")
    print(f"{'method':<22} {'median ms':>10} {'min ms':>8} {'cpu ms':>8} {'compile s':>10}")
    for name, r in rows.items():
        comp = f"{r['compile_s']:10.2f}" if "compile_s" in r else f"{'':>10}"
        print(f"{name:<22} {r['median_ms']:10.2f} {r['min_ms']:8.2f} {r['cpu_median_ms']:8.2f} {comp}")
    print(f"mask vs numpy_offsets: {mismatch} pixels differ; raw path == image path on these points: "
          f"{keep_raw_same}")
    print(f"new mask == frozen dense sweep: {frozen_equal}")
    for path in ("image", "raw", "vmap2_per_image"):
        new, old = rows[f"jax_{path}"], rows[f"frozen_{path}"]
        print(f"speed-up {path:<16} median {old['median_ms'] / new['median_ms']:5.2f}x, "
              f"min {old['min_ms'] / new['min_ms']:5.2f}x")
        foot_row = rows[f"footprint_{path}"]
        print(f"footprint {path:<15} median {old['median_ms'] / foot_row['median_ms']:5.2f}x the frozen sweep")
    print(f"{'effect':<24} {'RMSE mm':>8} {'MAE mm':>8} {'pixels':>7} {'keep %':>7}")
    for name in ("input", "after", "after_footprint", "sweep_input", "sweep_after_image_path",
                 "sweep_after_raw_path"):
        e = effect[name]
        print(f"{name:<24} {e['rmse_mm']:8.0f} {e['mae_mm']:8.0f} {e['pixels']:7d} {100 * e['keep_ratio']:7.1f}")
    print("paper (KITTI val, 1000 frames): RMSE 1595 -> 663 mm, MAE 202 -> 82 mm, keep 94.0 %")

    result = {
        "input": {"file": str(FRAME.name + "/velodyne_raw_image_02.png"), "shape": [H, W], "points": n,
                  "beams": BEAMS, "epsilon_m": EPS, "half_width": hw, "half_height": hh},
        "timings": rows,
        "check": {"pixels_differing_from_numpy": mismatch, "raw_path_equals_image_path": keep_raw_same,
                  "equals_frozen_dense_sweep": frozen_equal},
        "effect": effect,
        "paper_table1": {"rmse_mm": [1595.24, 662.87], "mae_mm": [202.16, 81.68], "keep_ratio": 0.94},
        "environment": {"jax": jax.__version__, "python": platform.python_version(),
                        "cpu_count": os.cpu_count(), "machine": platform.machine(),
                        "load_average": list(os.getloadavg())},
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.json.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(tmp, args.json)
    return 0 if mismatch == 0 and all(frozen_equal.values()) else 2


if __name__ == "__main__":
    sys.exit(main())
