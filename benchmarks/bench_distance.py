"""Run time of step 3 (nearest_seed) against its previous version, OpenCV and SciPy, in one process.

Mask: the real KITTI sparse input of the end-to-end benchmark
(``benchmarks._common.load_frame()``: drive_0001 frame 5, camera 2, cropped to
352 x 1216), ``sparse > 0``; a random ~4 % mask of that size when the shared
data is missing.

    PYTHONPATH=. python -m benchmarks.bench_distance [--runs 40] [--json benchmarks/results/distance.json]

Compared (all return distances and the nearest seed):
- jaxdepth nearest_seed, metric "l1" and "l2" (distance, du, dv);
- the same function as of commit ``REFERENCE_COMMIT`` (before the speed work,
  loaded from git into a private module): "ref_l1", "ref_l2".  Its outputs
  must be bit-identical to the current ones (checked before timing);
- cv2.distanceTransformWithLabels(~mask, cv2.DIST_L1, 3, labelType=cv2.DIST_LABEL_PIXEL);
- scipy.ndimage.distance_transform_edt(~mask, return_indices=True).
All methods run interleaved (one call of each per round in a shuffled order,
many rounds) so that load changes on a shared machine hit every method alike; medians and minima
after a warm-up call, compile time (lower + compile) separately.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import pathlib
import platform
import subprocess
import tempfile
import time

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import scipy
import scipy.ndimage as ndi

from jaxdepth._src.distance import nearest_seed

ROOT = pathlib.Path(__file__).resolve().parents[1]
REFERENCE_COMMIT = "070cbc9"  # nearest_seed before the l2 speed work (Meijster with an (H + 1) * W buffer)


def load_mask() -> tuple[np.ndarray, str]:
    from benchmarks._common import load_frame

    sparse, _, _, source = load_frame()
    return np.asarray(sparse) > 0, source + ", sparse > 0"


def reference_nearest_seed():
    """nearest_seed as of REFERENCE_COMMIT (git show into a temporary module), or None."""
    try:
        src = subprocess.run(["git", "show", f"{REFERENCE_COMMIT}:jaxdepth/_src/distance.py"], cwd=ROOT,
                             check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
        f.write(src)
    spec = importlib.util.spec_from_file_location("_distance_reference", f.name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    os.unlink(f.name)
    return module.nearest_seed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=40)
    parser.add_argument("--json", type=pathlib.Path, default=ROOT / "benchmarks" / "results" / "distance.json")
    args = parser.parse_args()

    mask, source = load_mask()
    src = (~mask).astype(np.uint8)  # OpenCV / SciPy measure the distance to zero pixels
    mask_j = jnp.asarray(mask)
    reference = reference_nearest_seed()

    rows = {}
    methods = {}
    for prefix, fn in (("jax", nearest_seed), ("ref", reference)):
        if fn is None:
            continue
        for metric in ("l1", "l2"):
            t0 = time.perf_counter()
            exe = jax.jit(fn, static_argnames="metric").lower(mask_j, metric=metric).compile()
            rows[f"{prefix}_{metric}"] = {"compile_s": time.perf_counter() - t0}
            methods[f"{prefix}_{metric}"] = lambda exe=exe: jax.block_until_ready(exe(mask_j))
    methods["opencv_l1"] = lambda: cv2.distanceTransformWithLabels(src, cv2.DIST_L1, 3,
                                                                   labelType=cv2.DIST_LABEL_PIXEL)
    methods["scipy_edt"] = lambda: ndi.distance_transform_edt(src, return_indices=True)

    # Agreement: distances with OpenCV / SciPy (their labels may name another equally near
    # seed), every output bit-identical with the reference version.
    outs = {name: methods[name]() for name in methods}
    assert np.array_equal(np.asarray(outs["jax_l1"].distance), outs["opencv_l1"][0]), "L1 differs from OpenCV"
    assert np.allclose(np.asarray(outs["jax_l2"].distance), outs["scipy_edt"][0], rtol=1e-6, atol=0), \
        "L2 differs from SciPy"
    identical = {}
    for metric in ("l1", "l2"):
        if f"ref_{metric}" in outs:
            identical[metric] = all(np.array_equal(np.asarray(a), np.asarray(b))
                                    for a, b in zip(outs[f"jax_{metric}"], outs[f"ref_{metric}"]))
            assert identical[metric], f"{metric}: outputs differ from the reference version"

    times = {name: [] for name in methods}
    order = list(methods)
    rng = np.random.default_rng(0)
    for _ in range(args.runs):
        rng.shuffle(order)  # no method always runs right after SciPy's cache-thrashing call
        for name in order:
            fn = methods[name]
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    for name, ts in times.items():
        rows.setdefault(name, {}).update({"median_ms": float(np.median(ts) * 1e3),
                                          "min_ms": float(np.min(ts) * 1e3), "runs": args.runs})

    def ratio(a, b):
        return rows[a]["median_ms"] / rows[b]["median_ms"] if a in rows and b in rows else None

    ratios = {
        "jax_l2 / ref_l2": ratio("jax_l2", "ref_l2"),
        "jax_l1 / ref_l1": ratio("jax_l1", "ref_l1"),
        "jax_l2 / jax_l1": ratio("jax_l2", "jax_l1"),
        "jax_l1 / opencv_l1": ratio("jax_l1", "opencv_l1"),
        "jax_l2 / opencv_l1": ratio("jax_l2", "opencv_l1"),
        "jax_l2 / scipy_edt": ratio("jax_l2", "scipy_edt"),
    }

    print(f"mask: {source}, shape {mask.shape}, {mask.mean() * 100:.2f} % seeds")
    print(f"{'method':<12} {'median ms':>10} {'min ms':>9} {'compile s':>10}")
    for name, r in rows.items():
        comp = f"{r['compile_s']:10.2f}" if "compile_s" in r else f"{'':>10}"
        print(f"{name:<12} {r['median_ms']:10.2f} {r['min_ms']:9.2f} {comp}")
    for k, v in ratios.items():
        if v is not None:
            print(f"{k:<22} {v:6.2f}")
    print("bit-identical to the reference:", identical or "reference unavailable")

    result = {
        "mask": source,
        "shape": list(mask.shape),
        "seed_fraction": float(mask.mean()),
        "reference_commit": REFERENCE_COMMIT if reference is not None else None,
        "bit_identical_to_reference": identical,
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
