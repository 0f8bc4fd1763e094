"""One KITTI frame (``complete_with(method="sgm")``) of this library and of another checkout's, and IP_Basic, in one process.

Issue 38's first bar (one frame at most 0.8x IP_Basic) before and after a change, measured without the
machine's drift between two runs: the other checkout's ``jaxdepth`` is copied as the package
``jaxdepth_base`` (``bench_rig_against_checkout``'s copy), both SGM programs are compiled and their depth
compared byte for byte, then ``--rounds`` rounds each call the three in turn (the order rotating): this
SGM, the checkout's SGM, IP_Basic's fast mode in OpenCV (``ip_basic_opencv``, Gaussian blur, as
``bench_end_to_end``). Process CPU (user + system of every thread) and wall of each call; reported: the
medians, the ratio of CPU sums SGM / IP_Basic for each library, and the median of the per-round ratios
this / checkout. ``--stage outliers``: Step 2 alone (``outlier_keep_mask`` with the default options)
instead of the whole frame, against IP_Basic all the same; ``--stage normals``: Step 1 alone (``pixel_normals``,
the frame's range image and normals, the default options). ``--above-scan background``: both libraries'
frames with ``SGMConfig(above_scan="background")`` (Step 4c) instead of the default.

    python -m benchmarks.bench_frame_against_checkout --checkout PATH [--rounds 60] [--stage frame|outliers|normals]
        [--above-scan plane|background] [--json benchmarks/results/frame_against_checkout.json]
"""

from __future__ import annotations

import argparse
import importlib
import os
import pathlib
import statistics
import sys
import tempfile
import time

import numpy as np

from benchmarks._common import RESULTS, load_frame, write_results
from benchmarks.bench_end_to_end import wall_and_cpu_ms
from benchmarks.bench_rig_against_checkout import BASE, _copy_as_base


def _program(package: str, stage: str, d, k, t, *, above_scan: str = "plane"):
    """A no-argument call of ``package``'s SGM frame (or Step 2 alone) on the frame, blocking."""
    import jax

    lib = importlib.import_module(package)
    presets = importlib.import_module(f"{package}._src.presets")
    config = lib.SGMConfig(above_scan=above_scan)
    if stage == "normals":
        normals = importlib.import_module(f"{package}._src.pixel_normals")
        fn = jax.jit(lambda d, k, t: normals.pixel_normals(d, k, t, lidar=presets.KITTI_HDL64,
                                                          smoothing=config.normal_smoothing,
                                                          fill_max_gap=config.range_fill_max_gap))
        return lambda: fn(d, k, t).block_until_ready()
    if stage == "outliers":
        outliers = importlib.import_module(f"{package}._src.outliers")
        fn = jax.jit(lambda d, k, t: outliers.keep_mask_for_config(d, k, t, beams=presets.KITTI_HDL64.beams,
                                                                   config=config))
        return lambda: fn(d, k, t).block_until_ready()
    methods = importlib.import_module(f"{package}._src.methods")
    return lambda: methods.complete_with(d, k, t, method="sgm", config=config,
                                         lidar=presets.KITTI_HDL64).block_until_ready()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", required=True, help="another checkout (a folder holding its jaxdepth/)")
    parser.add_argument("--rounds", type=int, default=60)
    parser.add_argument("--stage", choices=("frame", "outliers", "normals"), default="frame")
    parser.add_argument("--above-scan", choices=("plane", "background"), default="plane",
                        help="SGMConfig.above_scan of both libraries' frames")
    parser.add_argument("--json", default=str(RESULTS / "frame_against_checkout.json"))
    args, t0 = parser.parse_args(argv), time.time()
    import jax.numpy as jnp

    from jaxdepth.research.baselines import ip_basic_opencv
    folder = tempfile.TemporaryDirectory(prefix="bench_frame_")      # removed when main returns
    _copy_as_base(pathlib.Path(args.checkout), pathlib.Path(folder.name))
    sparse, K, T, label = load_frame()
    d, k, t = jnp.asarray(sparse), jnp.asarray(K), jnp.asarray(T)
    calls = {"this": _program("jaxdepth", args.stage, d, k, t, above_scan=args.above_scan),
             "checkout": _program(BASE, args.stage, d, k, t, above_scan=args.above_scan),
             "ip_basic": lambda: ip_basic_opencv(sparse, blur_type="gaussian")}
    outs = {name: np.asarray(fn()) for name, fn in calls.items() if name != "ip_basic"}
    same = bool(np.array_equal(outs["this"].view(np.uint8), outs["checkout"].view(np.uint8)))
    print(f"{label}: {args.stage} output byte-identical to the checkout's: {same}", flush=True)
    if not same:
        print("bench_frame_against_checkout: the outputs differ", file=sys.stderr)
        return 1
    for fn in calls.values():
        fn()
    names = list(calls)
    wall, cpu = {n: [] for n in names}, {n: [] for n in names}
    for r in range(args.rounds):
        for n in names[r % 3:] + names[:r % 3]:       # the order rotating
            w, c = (ms / 1e3 for ms in wall_and_cpu_ms(calls[n]))
            wall[n].append(w)
            cpu[n].append(c)
    med = lambda v: statistics.median(v) * 1e3
    doc = {"what": f"{args.stage} (above_scan={args.above_scan}): this library, the checkout's and IP_Basic (OpenCV, Gaussian) in turn, one process",
           "frame": label, "checkout": str(args.checkout), "rounds": args.rounds,
           "cpu_ms_median": {n: med(cpu[n]) for n in names}, "wall_ms_median": {n: med(wall[n]) for n in names},
           "cpu_ratio_to_ip_basic": {n: sum(cpu[n]) / sum(cpu["ip_basic"]) for n in ("this", "checkout")},
           "cpu_ratio_this_to_checkout_median": statistics.median(a / b for a, b in zip(cpu["this"], cpu["checkout"])),
           "wall_ratio_this_to_checkout_median": statistics.median(a / b for a, b in zip(wall["this"], wall["checkout"])),
           "load_average": os.getloadavg(), "runs_cpu_s": cpu, "runs_wall_s": wall}
    for n in names:
        print(f"{n:9s} CPU {doc['cpu_ms_median'][n]:6.2f} ms  wall {doc['wall_ms_median'][n]:6.2f} ms (medians)")
    print(f"CPU / IP_Basic's (ratio of sums): this {doc['cpu_ratio_to_ip_basic']['this']:.2f}, checkout "
          f"{doc['cpu_ratio_to_ip_basic']['checkout']:.2f}; this / checkout per round (median): CPU "
          f"{doc['cpu_ratio_this_to_checkout_median']:.3f}, wall {doc['wall_ratio_this_to_checkout_median']:.3f}; "
          f"load {doc['load_average']}")
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
