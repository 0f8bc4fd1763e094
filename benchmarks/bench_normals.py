"""Benchmark Step 1: range image + per-point normals of one KITTI HDL-64 sweep.

Reads ../shared/data/kitti/drive_0001_frame05/lidar_data.bin (float32 x, y, z,
reflectance), pads it to 131072 points with a validity mask, and times
``range_image`` and ``point_normals`` with the KITTI_HDL64 preset (compile time
reported separately; median of repeated runs after warm-up). Also times the
dense case: every pixel of the 352x1216-cropped KITTI ground truth back-projected
to the LiDAR frame (~430k points padded to 524288). Then ``pixel_normals`` on
the KITTI benchmark frame (``benchmarks._common.load_frame()``, ~18.9k LiDAR
pixels of 352x1216, SGMConfig defaults smoothing=1, fill_max_gap=2) against the
frozen pre-speed-up version (``normals.py`` at commit ``REFERENCE_COMMIT``,
loaded with ``git show``) and the listed-pixels version (``LISTED_COMMIT``),
timed interleaved in the same process, with the largest output differences.
``point_normals`` on the sweep cases is timed interleaved against
``LISTED_COMMIT`` too. Prints a table and writes benchmarks/results/normals.json.

Usage: python -m benchmarks.bench_normals [--repeats 50]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import pathlib
import platform
import statistics
import subprocess
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.normals import point_normals
from jaxdepth._src.range_image import range_image
from jaxdepth._src.presets import KITTI_HDL64, KITTI_K_CAM2, KITTI_T_CAM2_LIDAR

ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = pathlib.Path(os.environ.get("JAXDEPTH_SHARED_DATA", ROOT.parent / "shared" / "data"))
FRAME = DATA / "kitti" / "drive_0001_frame05"
#: The last commit before pixel_normals listed the pixels with depth (its normals.py is the reference).
REFERENCE_COMMIT = "070cbc9"
#: pixel_normals lists the pixels with depth; before the fit / smoothing fusions were merged.
LISTED_COMMIT = "58cfbac"


def _current_imports(src: str) -> str:
    """Old source with its imports of renamed modules pointed at today's (the XLA:CPU helpers moved
    from ``staging`` to ``xla_tuning`` with the same names)."""
    return src.replace("jaxdepth._src.staging import", "jaxdepth._src.xla_tuning import")


def _reference_module(commit: str = REFERENCE_COMMIT):
    """normals.py at ``commit`` as a module, or None when git or the commit is unavailable."""
    try:
        src = subprocess.run(["git", "show", f"{commit}:jaxdepth/_src/normals.py"], cwd=ROOT,
                             check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    path = pathlib.Path(tempfile.mkdtemp()) / f"normals_{commit}.py"
    path.write_text(_current_imports(src))
    spec = importlib.util.spec_from_file_location(f"normals_{commit}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _interleaved(fns: dict, repeats: int):
    """{name: (compile_plus_first_s, median_ms, min_ms)}, the functions timed round-robin."""
    first = {}
    for name, fn in fns.items():
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        first[name] = time.perf_counter() - t0
    for _ in range(3):
        for fn in fns.values():
            jax.block_until_ready(fn())
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            times[name].append((time.perf_counter() - t0) * 1e3)
    return {name: (first[name], statistics.median(t), min(t)) for name, t in times.items()}


def pixel_case(repeats: int):
    """pixel_normals on the KITTI benchmark frame: new vs the reference version, same process."""
    from benchmarks._common import load_frame

    from jaxdepth._src.pixel_normals import pixel_normals

    sparse, K, T, name = load_frame()
    d, K, T = (jnp.asarray(a, jnp.float32) for a in (sparse, K, T))
    lidar = KITTI_HDL64
    fns = {"pixel_normals": jax.jit(lambda d, K, T: pixel_normals(d, K, T, lidar=lidar))}
    refs = {"reference": (REFERENCE_COMMIT, _reference_module(REFERENCE_COMMIT)),
            "listed": (LISTED_COMMIT, _reference_module(LISTED_COMMIT))}
    for tag, (_, ref) in refs.items():
        if ref is not None:
            fns[f"pixel_normals_{tag}"] = jax.jit(lambda d, K, T, ref=ref: ref.pixel_normals(d, K, T, lidar=lidar))
    timed = _interleaved({k: (lambda f=f: f(d, K, T)) for k, f in fns.items()}, repeats)
    row = {"frame": name, "lidar_pixels": int(np.sum(np.asarray(sparse) > 0))}
    for fname, (first, med, best) in timed.items():
        row[fname] = {"compile_plus_first_s": round(first, 4), "median_ms": round(med, 3), "min_ms": round(best, 3)}
        print(f"{'kitti_frame_352x1216':22s} {fname:28s} median={med:8.3f} ms  min={best:8.3f} ms  "
              f"compile+first={first:6.2f} s")
    new = np.asarray(fns["pixel_normals"](d, K, T))
    for tag, (commit, ref) in refs.items():
        if ref is not None:
            diff = float(np.max(np.abs(new - np.asarray(fns[f"pixel_normals_{tag}"](d, K, T)))))
            row[f"max_abs_diff_vs_{tag}"] = diff
            row[f"{tag}_commit"] = commit
            print(f"max |new - {tag} ({commit})| = {diff:.3g}")
    return row


def _pad(points: np.ndarray, size: int):
    out = np.zeros((size, 3), np.float32)
    out[: len(points)] = points
    valid = np.zeros(size, bool)
    valid[: len(points)] = True
    return jnp.asarray(out), jnp.asarray(valid)


def _dense_points() -> np.ndarray:
    """Back-projects the cropped ground-truth depth image (352x1216) to LiDAR-frame points."""
    import cv2

    depth = cv2.imread(str(FRAME / "groundtruth_image_02.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) / 256.0
    depth = depth[23:375, 13:1229]
    h, w = depth.shape
    K = KITTI_K_CAM2.astype(np.float64).copy()
    K[0, 2] -= 13
    K[1, 2] -= 23
    v, u = np.mgrid[0:h, 0:w]
    # Fill every pixel (the dense case): empty pixels take a 20 m plane so the
    # point count matches a completed image; only the count matters for timing.
    z = np.where(depth > 0, depth, 20.0)
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    cam = np.stack([x, y, z], -1).reshape(-1, 3)
    T = np.linalg.inv(KITTI_T_CAM2_LIDAR.astype(np.float64))
    return (cam @ T[:3, :3].T + T[:3, 3]).astype(np.float32)




def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args()

    raw = np.fromfile(FRAME / "lidar_data.bin", np.float32).reshape(-1, 4)[:, :3]
    listed = _reference_module(LISTED_COMMIT)
    cases = {"kitti_sweep": (raw, 131072), "kitti_dense_352x1216": (_dense_points(), 524288)}
    lidar = KITTI_HDL64
    results = {"device": str(jax.devices()[0]), "jax": jax.__version__, "platform": platform.platform(),
               "lidar": {"beams": lidar.beams, "columns": lidar.columns}, "cases": {}}
    for name, (pts, size) in cases.items():
        points, valid = _pad(pts, size)
        fns = {
            "range_image": jax.jit(lambda p, m: range_image(p, m, lidar=lidar)),
            "point_normals": jax.jit(lambda p, m: point_normals(p, m, lidar=lidar)),
        }
        if listed is not None:
            fns["point_normals_listed"] = jax.jit(lambda p, m: listed.point_normals(p, m, lidar=lidar))
        row = {"points": int(len(pts)), "padded": size}
        timed = _interleaved({k: (lambda f=f: f(points, valid)) for k, f in fns.items()}, args.repeats)
        for fname, (first, med, best) in timed.items():
            row[fname] = {"compile_plus_first_s": round(first, 4), "median_ms": round(med, 3), "min_ms": round(best, 3)}
            print(f"{name:22s} {fname:20s} points={len(pts):7d} pad={size:7d} "
                  f"median={med:8.3f} ms  min={best:8.3f} ms  compile+first={first:6.2f} s")
        if listed is not None:
            diff = float(np.max(np.abs(np.asarray(fns["point_normals"](points, valid))
                                       - np.asarray(fns["point_normals_listed"](points, valid)))))
            row["point_normals_max_abs_diff_vs_listed"] = diff
            row["listed_commit"] = LISTED_COMMIT
            print(f"max |point_normals - listed ({LISTED_COMMIT})| = {diff:.3g}")
        results["cases"][name] = row
    results["cases"]["kitti_frame_pixel_normals"] = pixel_case(args.repeats)
    out = ROOT / "benchmarks" / "results" / "normals.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(results, indent=2) + "\n")
    os.replace(tmp, out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
