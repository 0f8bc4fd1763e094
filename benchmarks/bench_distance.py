"""Run time of step 3 (nearest_seed) against OpenCV and SciPy, in one process.

Mask: the real KITTI sparse input (``velodyne_raw_image_02.png``, cropped the
benchmark way to the bottom 352 rows and columns 13..1228); a random ~4 % mask
of the same size when the shared data is missing.

    PYTHONPATH=. python benchmarks/bench_distance.py [--runs 50] [--json benchmarks/results/distance.json]

Compared (all return distances and the nearest seed):
- jaxdepth nearest_seed, metric "l1" and "l2" (distance, du, dv);
- cv2.distanceTransformWithLabels(~mask, cv2.DIST_L1, 3, labelType=cv2.DIST_LABEL_PIXEL);
- scipy.ndimage.distance_transform_edt(~mask, return_indices=True).
Times are medians after a warm-up call; compile time (lower + compile) is
reported separately.  The machine may be shared: only the ratios measured in
the same run mean much.  The script also checks that the distances agree.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import time

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import scipy
import scipy.ndimage as ndi

from jaxdepth._src.distance import nearest_seed

ROOT = pathlib.Path(__file__).resolve().parents[1]
PNG = ROOT.parent / "shared" / "data" / "kitti" / "drive_0001_frame05" / "velodyne_raw_image_02.png"


def load_mask() -> tuple[np.ndarray, str]:
    if PNG.exists():
        depth = cv2.imread(str(PNG), cv2.IMREAD_UNCHANGED)
        return depth[-352:, 13:1229] > 0, f"KITTI {PNG.name} (bottom 352 rows, cols 13..1228)"
    rng = np.random.default_rng(0)
    return rng.random((352, 1216)) < 0.04, "random 4 % mask (shared data missing)"


def median_ms(fn, runs: int) -> tuple[float, float]:
    fn()  # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3), float(np.min(times) * 1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--json", type=pathlib.Path, default=ROOT / "benchmarks" / "results" / "distance.json")
    args = parser.parse_args()

    mask, source = load_mask()
    src = (~mask).astype(np.uint8)  # OpenCV / SciPy measure the distance to zero pixels
    mask_j = jnp.asarray(mask)

    rows = {}
    compiled = {}
    for metric in ("l1", "l2"):
        t0 = time.perf_counter()
        exe = jax.jit(nearest_seed, static_argnames="metric").lower(mask_j, metric=metric).compile()
        compile_s = time.perf_counter() - t0
        compiled[metric] = exe
        rows[f"jax_{metric}"] = {"compile_s": compile_s}

    def run_jax(metric):
        return lambda: jax.block_until_ready(compiled[metric](mask_j))

    def run_cv():
        return cv2.distanceTransformWithLabels(src, cv2.DIST_L1, 3, labelType=cv2.DIST_LABEL_PIXEL)

    def run_scipy():
        return ndi.distance_transform_edt(src, return_indices=True)

    # Agreement check (distances, not labels: ties may pick different seeds).
    l1 = compiled["l1"](mask_j)
    l2 = compiled["l2"](mask_j)
    assert np.array_equal(np.asarray(l1.distance), run_cv()[0]), "L1 distances differ from OpenCV"
    assert np.allclose(np.asarray(l2.distance), run_scipy()[0], rtol=1e-6, atol=0), "L2 differs from SciPy"

    # Interleave the pairs so that load changes hit both sides of each ratio.
    for name, fn, runs in (("jax_l1", run_jax("l1"), args.runs), ("opencv_l1", run_cv, args.runs),
                           ("jax_l2", run_jax("l2"), max(args.runs // 3, 5)),
                           ("scipy_edt", run_scipy, max(args.runs // 3, 5))):
        med, best = median_ms(fn, runs)
        rows.setdefault(name, {}).update({"median_ms": med, "min_ms": best, "runs": runs})

    ratios = {
        "jax_l1 / opencv_l1": rows["jax_l1"]["median_ms"] / rows["opencv_l1"]["median_ms"],
        "jax_l2 / scipy_edt": rows["jax_l2"]["median_ms"] / rows["scipy_edt"]["median_ms"],
        "jax_l2 / opencv_l1": rows["jax_l2"]["median_ms"] / rows["opencv_l1"]["median_ms"],
    }

    print(f"mask: {source}, shape {mask.shape}, {mask.mean() * 100:.2f} % seeds")
    print(f"{'method':<12} {'median ms':>10} {'min ms':>9} {'compile s':>10}")
    for name, r in rows.items():
        comp = f"{r['compile_s']:10.2f}" if "compile_s" in r else f"{'':>10}"
        print(f"{name:<12} {r['median_ms']:10.2f} {r['min_ms']:9.2f} {comp}")
    for k, v in ratios.items():
        print(f"{k:<22} {v:6.2f}")

    result = {
        "mask": source,
        "shape": list(mask.shape),
        "seed_fraction": float(mask.mean()),
        "timings": rows,
        "ratios": ratios,
        "environment": {
            "jax": jax.__version__, "opencv": cv2.__version__, "scipy": scipy.__version__,
            "numpy": np.__version__, "python": platform.python_version(),
            "cpu_count": os.cpu_count(), "load_avg_1min": os.getloadavg()[0],
        },
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.json.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(tmp, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
