"""One KITTI frame (``complete_with(method="sgm")``) of this library and of another checkout's, and IP_Basic, in one process.

Issue 38's first bar (one frame at most 0.8x IP_Basic) before and after a change, measured without the
machine's drift between two runs: the other checkout's ``jaxdepth`` is copied as the package
``jaxdepth_base`` (``bench_rig_against_checkout``'s copy), both SGM programs are compiled and their depth
compared byte for byte, then ``--rounds`` rounds each call the three once: this SGM, the checkout's SGM,
IP_Basic's fast mode in OpenCV (``ip_basic_opencv``, Gaussian blur, as ``bench_end_to_end``). The order of
each round (``--order balanced``, the default): every block of 6 rounds runs the 6 permutations, shuffled
with ``--seed`` (``_common.balanced_orders``), so each arm is in each place and after each other arm
equally often; ``--order rotate``: the former rotation (this, checkout, IP_Basic, rotated by one a round),
in which the SGM called first in the rotation follows IP_Basic in 2 rounds of 3 and the other follows it.
Process CPU (user + system of every thread) and wall of each call; reported: the medians, the ratio of
CPU sums SGM / IP_Basic and the ratio of wall medians SGM / IP_Basic for each library, the median of the
per-round ratios this / checkout, and each arm's medians by place and by the arm called before it
(``_common.order_effects``: how much the order moves the same code), and both frame programs' buffer sizes
(``_common.program_memory``: the temporary and its room below the 32 MiB mmap cliff; branch kitti14). ``--stage outliers``: Step 2 alone (``outlier_keep_mask`` with the default options)
instead of the whole frame, against IP_Basic all the same; ``--stage normals``: Step 1 alone (``pixel_normals``,
the frame's range image and normals, the default options). ``--above-scan background``: both libraries'
frames with ``SGMConfig(above_scan="background")`` (Step 4c) instead of the default.

    python -m benchmarks.bench_frame_against_checkout --checkout PATH [--rounds 60] [--stage frame|outliers|normals]
        [--above-scan plane|background] [--order balanced|rotate] [--seed 0] [--json benchmarks/results/frame_against_checkout.json]
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

from benchmarks._common import (RESULTS, balanced_orders, load_frame, order_effects, program_memory,
                                rotated_orders, write_results)
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


def _frame_memory(package: str, d, k, t, *, above_scan: str = "plane") -> dict:
    """:func:`~benchmarks._common.program_memory` of ``package``'s compiled frame program (the one ``_program`` calls)."""
    lib = importlib.import_module(package)
    presets = importlib.import_module(f"{package}._src.presets")
    methods = importlib.import_module(f"{package}._src.methods")
    return program_memory(methods.complete_with.lower(d, k, t, method="sgm", config=lib.SGMConfig(above_scan=above_scan),
                                                      lidar=presets.KITTI_HDL64).compile())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", required=True, help="another checkout (a folder holding its jaxdepth/)")
    parser.add_argument("--rounds", type=int, default=60)
    parser.add_argument("--stage", choices=("frame", "outliers", "normals"), default="frame")
    parser.add_argument("--above-scan", choices=("plane", "background"), default="plane",
                        help="SGMConfig.above_scan of both libraries' frames")
    parser.add_argument("--order", choices=("balanced", "rotate"), default="balanced",
                        help="each round's call order: all permutations in seeded blocks, or the former rotation")
    parser.add_argument("--seed", type=int, default=0, help="the shuffle of --order balanced")
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
    memory = {n: _frame_memory(p, d, k, t, above_scan=args.above_scan) for n, p in (("this", "jaxdepth"), ("checkout", BASE))}
    for n, m in memory.items():
        print(f"{n:9s} frame program: temp {m['temp_mb']:.2f} MB ({m['room_below_mmap_cliff_mb']:+.2f} MB below the "
              f"32 MiB mmap cliff{'; OVER IT: every call page-faults its temporary' if m['over_mmap_cliff'] else ''})",
              flush=True)
    for fn in calls.values():
        fn()
    names = list(calls)
    if args.order == "rotate":
        orders = rotated_orders(names, args.rounds)
    else:
        orders = balanced_orders(names, args.rounds, seed=args.seed)
    wall, cpu = {n: [] for n in names}, {n: [] for n in names}
    timed = []                                        # (name, place, wall s, CPU s) in run order
    for order in orders:
        for place, n in enumerate(order):
            w, c = (ms / 1e3 for ms in wall_and_cpu_ms(calls[n]))
            wall[n].append(w)
            cpu[n].append(c)
            timed.append((n, place, w, c))
    med = lambda v: statistics.median(v) * 1e3
    doc = {"what": f"{args.stage} (above_scan={args.above_scan}): this library, the checkout's and IP_Basic (OpenCV, Gaussian) in turn, one process",
           "frame": label, "checkout": str(args.checkout), "rounds": args.rounds, "order": args.order,
           "seed": args.seed if args.order == "balanced" else None,
           "cpu_ms_median": {n: med(cpu[n]) for n in names}, "wall_ms_median": {n: med(wall[n]) for n in names},
           "cpu_ratio_to_ip_basic": {n: sum(cpu[n]) / sum(cpu["ip_basic"]) for n in ("this", "checkout")},
           "wall_ratio_to_ip_basic": {n: med(wall[n]) / med(wall["ip_basic"]) for n in ("this", "checkout")},
           "cpu_ratio_this_to_checkout_median": statistics.median(a / b for a, b in zip(cpu["this"], cpu["checkout"])),
           "wall_ratio_this_to_checkout_median": statistics.median(a / b for a, b in zip(wall["this"], wall["checkout"])),
           "wall_by_order": order_effects([(n, p, w) for n, p, w, _ in timed], names),
           "cpu_by_order": order_effects([(n, p, c) for n, p, _, c in timed], names),
           "frame_program_memory": memory, "load_average": os.getloadavg(), "runs_cpu_s": cpu, "runs_wall_s": wall,
           "run_order": [n for n, *_ in timed]}
    for n in names:
        print(f"{n:9s} CPU {doc['cpu_ms_median'][n]:6.2f} ms  wall {doc['wall_ms_median'][n]:6.2f} ms (medians)")
    print(f"CPU / IP_Basic's (ratio of sums): this {doc['cpu_ratio_to_ip_basic']['this']:.2f}, checkout "
          f"{doc['cpu_ratio_to_ip_basic']['checkout']:.2f}; this / checkout per round (median): CPU "
          f"{doc['cpu_ratio_this_to_checkout_median']:.3f}, wall {doc['wall_ratio_this_to_checkout_median']:.3f}; "
          f"wall / IP_Basic's (ratio of medians): this {doc['wall_ratio_to_ip_basic']['this']:.3f}, checkout "
          f"{doc['wall_ratio_to_ip_basic']['checkout']:.3f}; order {args.order}; load {doc['load_average']}")
    for n in names:
        print(f"  {n} wall median by the call before it: " + ", ".join(
            f"{k} {v['median_ms']:.2f} ms ({v['calls']})" for k, v in doc["wall_by_order"]["after"][n].items()))
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
