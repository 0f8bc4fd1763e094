"""How much the call before it moves one KITTI frame's time (why the frame bench's order decided issue 38's bar).

Two parts, one JSON:

- ``--reanalyse FILE ...``: result JSONs of ``bench_frame_against_checkout`` written before its rounds were
  balanced (``--order rotate``, no ``run_order`` in the file): each round's order is rebuilt from the rotation
  (``this, checkout, ip_basic`` rotated by one a round) and every arm's wall and CPU medians are split by the
  call just before it and by its place (``_common.order_effects``). The same code appears as ``this`` in one
  file and as ``checkout`` in its swapped twin, so the split shows the order's effect on identical code.
- ``--rounds N`` (0: skip): this library's frame, each call preceded by one of: another frame, IP_Basic's
  fast mode (OpenCV, Gaussian), a 5.6 ms sleep (IP_Basic's time, the cores idle), a 5.6 ms busy loop on one
  thread, three sums over a 16 MB NumPy array (the caches refilled); the predecessor drawn at random (seed 0)
  each round; the frame's wall and process CPU medians per predecessor.

    python -m benchmarks.studies.frame_order [--reanalyse FILE ...] [--rounds 300]
        [--json benchmarks/results/frame_order.json]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import statistics
import sys
import time

import numpy as np

from benchmarks._common import RESULTS, load_frame, order_effects, rotated_orders, write_results
from benchmarks.bench_end_to_end import wall_and_cpu_ms

NAMES = ("this", "checkout", "ip_basic")


def reanalyse(path: pathlib.Path) -> dict:
    """``order_effects`` of wall and CPU for a rotate-order ``bench_frame_against_checkout`` result."""
    doc = json.loads(path.read_text())
    if doc.get("order", "rotate") != "rotate":
        raise ValueError(f"{path}: order {doc['order']!r}, not the rotation")
    names = list(NAMES)
    timed = {"wall": [], "cpu": []}
    seen = dict.fromkeys(names, 0)
    for order in rotated_orders(names, doc["rounds"]):
        for place, n in enumerate(order):
            timed["wall"].append((n, place, doc["runs_wall_s"][n][seen[n]]))
            timed["cpu"].append((n, place, doc["runs_cpu_s"][n][seen[n]]))
            seen[n] += 1
    return {"file": path.name, "checkout": doc.get("checkout"), "rounds": doc["rounds"],
            "load_average": doc.get("load_average"),
            "wall": order_effects(timed["wall"], names), "cpu": order_effects(timed["cpu"], names)}


def predecessors(rounds: int) -> dict:
    """The frame's wall and CPU medians (ms) after each predecessor, drawn at random each round."""
    import jax.numpy as jnp

    from jaxdepth._src import presets
    from jaxdepth._src.methods import complete_with
    from jaxdepth.research.baselines import ip_basic_opencv
    sparse, K, T, _ = load_frame()
    d, k, t = jnp.asarray(sparse), jnp.asarray(K), jnp.asarray(T)
    frame = lambda: complete_with(d, k, t, method="sgm", lidar=presets.KITTI_HDL64).block_until_ready()
    big = np.ones(4 << 20, np.float32)

    def busy(seconds=0.0056):
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            pass

    before = {"frame": frame, "ip_basic": lambda: ip_basic_opencv(sparse, blur_type="gaussian"),
              "sleep_5.6ms": lambda: time.sleep(0.0056), "busy_5.6ms_one_thread": busy,
              "numpy_16MB_sums": lambda: [big.sum() for _ in range(3)]}
    for fn in before.values():
        fn()
    frame()
    rng = np.random.default_rng(0)
    runs = {name: [] for name in before}
    for _ in range(rounds):
        name = list(before)[rng.integers(len(before))]
        before[name]()
        runs[name].append(wall_and_cpu_ms(frame))
    return {name: {"wall_ms_median": statistics.median(w for w, _ in v), "cpu_ms_median": statistics.median(c for _, c in v),
                   "calls": len(v)} for name, v in runs.items() if v}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reanalyse", nargs="*", default=[], help="rotate-order bench_frame_against_checkout JSONs")
    parser.add_argument("--rounds", type=int, default=300, help="rounds of the predecessor probe (0: skip)")
    parser.add_argument("--json", default=str(RESULTS / "frame_order.json"))
    args, t0 = parser.parse_args(argv), time.time()
    doc = {"what": "one KITTI frame's time by the call before it", "load_average_start": os.getloadavg(),
           "reanalysed": [reanalyse(pathlib.Path(p)) for p in args.reanalyse]}
    for r in doc["reanalysed"]:
        print(f"{r['file']} (load {r['load_average']}):")
        for n in ("this", "checkout"):
            print(f"  {n:8s} wall by the call before it: " + ", ".join(
                f"{a} {v['median_ms']:.2f} ms ({v['calls']})" for a, v in r["wall"]["after"][n].items()))
    if args.rounds:
        doc["frame_after"] = predecessors(args.rounds)
        for name, v in doc["frame_after"].items():
            print(f"frame after {name:24s} wall {v['wall_ms_median']:6.2f} ms  CPU {v['cpu_ms_median']:6.2f} ms ({v['calls']})")
    doc["load_average"] = os.getloadavg()
    print(f"load {doc['load_average']}")
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
