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
  each round; the frame's wall and process CPU medians per predecessor. Branch kitti12 adds: IP_Basic then a
  1 ms sleep (its threads' wake-up and spin over), a 1 ms sleep alone, a 5.6 ms NumPy memset (``fill``) on the
  calling thread; and ``--idle-cpu`` the process CPU burnt during a 2 ms sleep right after each predecessor
  (threads left spinning: OpenCV's pthreads pool, XLA's Eigen workers), measured apart from the frame.
  ``--fill-mb 1 4 16 64``: instead, a frame, IP_Basic, IP_Basic on a 64 x 256 crop (the same OpenCV calls,
  little memory), a sleep and one NumPy fill of each size (how much of the caches' refill the order costs). ``--cv2-threads N``: ``cv2.setNumThreads(N)`` for the whole probe process (a diagnosis of the cause, never
  the bench's IP_Basic setting); OpenCV's own ``OPENCV_THREAD_POOL_*`` variables may be set on the command line.

    python -m benchmarks.studies.frame_order [--reanalyse FILE ...] [--rounds 300] [--cv2-threads N]
        [--idle-cpu] [--fill-mb MB ...] [--json benchmarks/results/frame_order.json]
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import pathlib
import resource
import statistics
import sys
import threading
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


def _worker_threads() -> dict:
    """``{thread name: (run ns, timeslices)}`` summed over the process's threads but the calling one
    (``/proc/self/task/*/schedstat``; XLA's are ``tf_XLAEigen``, OpenCV's and JAX's others ``python``)."""
    out, me = collections.defaultdict(lambda: [0, 0]), threading.get_native_id()
    for tid in os.listdir("/proc/self/task"):
        if int(tid) == me:
            continue
        try:
            name = pathlib.Path(f"/proc/self/task/{tid}/comm").read_text().strip()
            run, _, slices = map(int, pathlib.Path(f"/proc/self/task/{tid}/schedstat").read_text().split())
        except (OSError, ValueError):
            continue
        out[name][0] += run
        out[name][1] += slices
    return out


def _timed(call) -> dict:
    """One frame: wall and process CPU (ms), minor page faults, the calling thread's CPU in the dispatch and
    in the wait, and the other threads' run time (ms) and timeslices by name."""
    faults, threads = resource.getrusage(resource.RUSAGE_SELF).ru_minflt, _worker_threads()
    wall, cpu, own = time.perf_counter(), time.process_time(), time.thread_time()
    out = call()
    dispatched = time.thread_time()
    out.block_until_ready()
    wall, cpu, end = (time.perf_counter() - wall) * 1e3, (time.process_time() - cpu) * 1e3, time.thread_time()
    after = _worker_threads()
    row = {"wall_ms": wall, "cpu_ms": cpu, "minor_faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults,
           "caller_dispatch_cpu_ms": (dispatched - own) * 1e3, "caller_wait_cpu_ms": (end - dispatched) * 1e3}
    for name, (run, slices) in after.items():
        row[f"{name}_run_ms"] = (run - threads.get(name, (0, 0))[0]) / 1e6
        row[f"{name}_slices"] = slices - threads.get(name, (0, 0))[1]
    return row


def predecessors(rounds: int, *, idle_cpu: bool = False, sizes: tuple = ()) -> dict:
    """The frame's wall and CPU medians (ms) after each predecessor, drawn at random each round; with
    ``idle_cpu`` the process CPU during a 2 ms sleep after each predecessor (the frame not run in those rounds);
    with ``sizes`` (MB) the predecessors are a frame, IP_Basic, a 5.6 ms sleep and one NumPy fill of each size."""
    import jax.numpy as jnp

    from jaxdepth._src import presets
    from jaxdepth._src.methods import complete_with
    from jaxdepth.research.baselines import ip_basic_opencv
    sparse, K, T, _ = load_frame()
    d, k, t = jnp.asarray(sparse), jnp.asarray(K), jnp.asarray(T)
    call = lambda: complete_with(d, k, t, method="sgm", lidar=presets.KITTI_HDL64)
    frame = lambda: call().block_until_ready()
    big = np.ones(max((16, *sizes)) << 18, np.float32)

    def busy(seconds=0.0056):
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            pass

    before = {"frame": frame, "ip_basic": lambda: ip_basic_opencv(sparse, blur_type="gaussian"),
              "sleep_5.6ms": lambda: time.sleep(0.0056), "busy_5.6ms_one_thread": busy,
              "numpy_16MB_sums": lambda: [big.sum() for _ in range(3)],
              "ip_basic_then_sleep_1ms": lambda: (ip_basic_opencv(sparse, blur_type="gaussian"), time.sleep(0.001)),
              "sleep_1ms": lambda: time.sleep(0.001), "numpy_fill_5.6ms": lambda: busy_fill(0.0056)}
    if sizes:
        small = np.ascontiguousarray(sparse[-64:, 512:768])
        before = {"frame": frame, "ip_basic": before["ip_basic"], "sleep_5.6ms": before["sleep_5.6ms"],
                  "ip_basic_64x256_crop": lambda: ip_basic_opencv(small, blur_type="gaussian")}
        for mb in sizes:
            before[f"numpy_fill_{mb}MB"] = lambda mb=mb: big[:mb << 18].fill(1.0)

    def busy_fill(seconds):
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            big.fill(1.0)

    for fn in before.values():
        fn()
    frame()
    rng = np.random.default_rng(0)
    runs = {name: [] for name in before}
    spin = {name: [] for name in before}
    for _ in range(rounds):
        name = list(before)[rng.integers(len(before))]
        before[name]()
        runs[name].append(_timed(call))
        if idle_cpu:
            before[name]()
            spin[name].append(wall_and_cpu_ms(lambda: time.sleep(0.002))[1])
    out = {}
    for name, v in runs.items():
        if v:
            out[name] = {key: statistics.median(r[key] for r in v) for key in v[0]}
            out[name] = {"calls": len(v), **{f"{key}_median": m for key, m in out[name].items()},
                         "minor_faults_mean": statistics.fmean(r["minor_faults"] for r in v)}
    for name, v in spin.items():
        if v:
            out[name]["cpu_ms_in_2ms_sleep_after_median"] = statistics.median(v)
            out[name]["cpu_ms_in_2ms_sleep_after_mean"] = statistics.fmean(v)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reanalyse", nargs="*", default=[], help="rotate-order bench_frame_against_checkout JSONs")
    parser.add_argument("--rounds", type=int, default=300, help="rounds of the predecessor probe (0: skip)")
    parser.add_argument("--cv2-threads", type=int, default=None, help="cv2.setNumThreads for the probe process")
    parser.add_argument("--idle-cpu", action="store_true", help="also the CPU burnt in a 2 ms sleep after each")
    parser.add_argument("--fill-mb", type=int, nargs="*", default=[],
                        help="predecessors: a frame, IP_Basic, a sleep and one NumPy fill of each size (MB)")
    parser.add_argument("--json", default=str(RESULTS / "frame_order.json"))
    args, t0 = parser.parse_args(argv), time.time()
    if args.cv2_threads is not None:
        import cv2

        cv2.setNumThreads(args.cv2_threads)
    import cv2

    doc = {"what": "one KITTI frame's time by the call before it", "load_average_start": os.getloadavg(),
           "cv2_threads": cv2.getNumThreads(),
           "opencv_env": {k: v for k, v in os.environ.items() if k.startswith("OPENCV_")},
           "reanalysed": [reanalyse(pathlib.Path(p)) for p in args.reanalyse]}
    for r in doc["reanalysed"]:
        print(f"{r['file']} (load {r['load_average']}):")
        for n in ("this", "checkout"):
            print(f"  {n:8s} wall by the call before it: " + ", ".join(
                f"{a} {v['median_ms']:.2f} ms ({v['calls']})" for a, v in r["wall"]["after"][n].items()))
    if args.rounds:
        doc["frame_after"] = predecessors(args.rounds, idle_cpu=args.idle_cpu, sizes=tuple(args.fill_mb))
        for name, v in doc["frame_after"].items():
            spun = v.get("cpu_ms_in_2ms_sleep_after_median")
            print(f"frame after {name:24s} wall {v['wall_ms_median']:6.2f} ms  CPU {v['cpu_ms_median']:6.2f} ms ({v['calls']})"
                  f"  faults {v['minor_faults_median']:.0f} (mean {v['minor_faults_mean']:.0f})  caller CPU "
                  f"{v['caller_dispatch_cpu_ms_median']:.2f} + {v['caller_wait_cpu_ms_median']:.2f} ms  XLA workers "
                  f"{v.get('tf_XLAEigen_run_ms_median', 0):.2f} ms, {v.get('tf_XLAEigen_slices_median', 0):.0f} slices, "
                  f"other threads {v.get('python_run_ms_median', 0):.2f} ms"
                  + ("" if spun is None else f"  CPU in a 2 ms sleep after it {spun:.2f} ms"))
    doc["load_average"] = os.getloadavg()
    print(f"load {doc['load_average']}")
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
