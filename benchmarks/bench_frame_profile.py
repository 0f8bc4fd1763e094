"""One KITTI frame's program (``complete_with(method="sgm")``) kernel by kernel, summed by stage and thread.

The compiled frame runs ``--runs`` times under ``jax.profiler`` (a Perfetto trace). Every XLA:CPU kernel
event (loops and conditionals left out: their kernels are counted) is attributed to a stage by the
``op_name`` of its HLO instruction in the compiled program (the named jits and scopes: ``pixel_normals`` or
``pixel_normals_slots`` Step 1,
``_keep_mask`` Step 2, ``nearest_seed`` Step 3, the rest of ``_complete_stages`` Step 4's tail: seed
gathers, residual, column bracket, blur, clip; no op_name (copies XLA inserted): "input and output").
Per stage: the kernels' exclusive time per frame (loop bodies' kernels summed over their steps), the
length of the union of their intervals (the wall while any of them runs; equal to the sum when no two
kernels overlap), the kernel count and launches per frame, and the time split by the trace's threads (XLA's two Eigen workers,
the PjRt client's). The profiler adds a cost to every kernel, so the sums exceed the unprofiled frame,
most where kernels are many and small (loops); ``--rounds`` unprofiled calls give the frame's wall and
process CPU beside them. ``--stage-rounds N`` (branch kitti12): the stages unprofiled, each jitted alone on the
frame and called in shuffled order N rounds in one process beside the frame and IP_Basic (Step 1 ``pixel_normals_slots``
as the frame runs it, the listed form (kitti14; ``pixel_normals`` before),
Step 2 ``keep_mask_for_config``, Step 3 ``nearest_seed`` of Step 2's kept pixels; the tail is the frame
minus the three): the loops' kernels are not inflated there, the profiler's per-kernel cost is.

    python -m benchmarks.bench_frame_profile [--runs 20] [--rounds 40] [--top 25] [--stage-rounds 0]
        [--json benchmarks/results/frame_profile.json]
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import re
import statistics
import sys
import tempfile
import time

from benchmarks._common import RESULTS, load_frame, program_memory, write_results
from benchmarks.bench_end_to_end import wall_and_cpu_ms

#: (keyword in the HLO op_name, stage), the first match wins: the named jits of each step's functions.
STAGES = (("jit(pixel_normals)", "1 normals"), ("pixel_normals_slots", "1 normals"), ("jit(_keep_mask)", "2 outliers"),
          ("jit(nearest_seed)", "3 distance transform"), ("jit(_complete_stages)", "4 tail (gathers, residual, bracket, blur)"),
          ("", "0 input and output"))
CONTAINERS = ("while", "cond", "conditional", "call")


def _stage(op_name: str) -> str:
    return next(s for key, s in STAGES if key in op_name)


def _union_us(intervals) -> float:
    """Length of the union of (start, end) intervals."""
    total, end = 0.0, -1e30
    for a, b in sorted(intervals):
        if b > end:
            total += b - max(a, end)
            end = b
    return total


def _origins(hlo_text: str) -> dict:
    """``{instruction name: op_name}`` from the compiled HLO's metadata (no source files there)."""
    out = {}
    for line in hlo_text.splitlines():
        m = re.match(r"\s*(?:ROOT )?%([\w.\-]+) = ", line)
        if not m:
            continue
        op = re.search(r'op_name="([^"]*)"', line)
        out.setdefault(m.group(1), op.group(1) if op else "")
    return out


def _stage_split(d, k, t, sparse, rounds: int) -> dict:
    """Medians (ms) of the frame, Steps 1-3 jitted alone and IP_Basic, in shuffled order each round; the tail
    (Step 4: gathers, residual, bracket, blur) as the frame's medians minus the three steps'."""
    import jax
    import numpy as np

    import jaxdepth
    from benchmarks.bench_frame_against_checkout import _program
    from jaxdepth._src import distance, outliers, presets
    from jaxdepth._src.pixel_normals import pixel_normals_slots
    from jaxdepth.research.baselines import ip_basic_opencv
    keep = jax.jit(lambda d, k, t: outliers.keep_mask_for_config(d, k, t, beams=presets.KITTI_HDL64.beams,
                                                                 config=jaxdepth.SGMConfig()))(d, k, t)
    seek = jax.jit(distance.nearest_seed)     # the pipeline's seeds are Step 2's kept pixels
    slots = jax.jit(lambda d, k, t: (lambda n: (n.slot, n.table, n.fits))(pixel_normals_slots(
        d, k, t, lidar=presets.KITTI_HDL64, smoothing=jaxdepth.SGMConfig().normal_smoothing,
        fill_max_gap=jaxdepth.SGMConfig().range_fill_max_gap)))
    calls = {"frame": _program("jaxdepth", "frame", d, k, t),
             "step 1 normals": lambda: jax.block_until_ready(slots(d, k, t)),
             "step 2 outliers": _program("jaxdepth", "outliers", d, k, t),
             "step 3 seed search": lambda: jax.block_until_ready(seek(keep)),
             "ip_basic": lambda: ip_basic_opencv(sparse, blur_type="gaussian")}
    for fn in calls.values():
        for _ in range(3):
            fn()
    runs, rng = {n: [] for n in calls}, np.random.default_rng(0)
    for _ in range(rounds):
        for n in rng.permutation(list(calls)):
            runs[n].append(wall_and_cpu_ms(calls[n]))
    out = {n: {"wall_ms": statistics.median(w for w, _ in v), "cpu_ms": statistics.median(c for _, c in v)}
           for n, v in runs.items()}
    steps = ("step 1 normals", "step 2 outliers", "step 3 seed search")
    out["step 4 tail (frame minus steps 1-3)"] = {m: out["frame"][m] - sum(out[s][m] for s in steps)
                                                  for m in ("wall_ms", "cpu_ms")}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--stage-rounds", type=int, default=0, help="rounds of the unprofiled stage split (0: skip)")
    parser.add_argument("--json", default=str(RESULTS / "frame_profile.json"))
    args, t0 = parser.parse_args(argv), time.time()
    import jax
    import jax.numpy as jnp

    import jaxdepth
    from jaxdepth._src import presets
    from jaxdepth._src.methods import complete_with
    sparse, K, T, label = load_frame()
    d, k, t = jnp.asarray(sparse), jnp.asarray(K), jnp.asarray(T)
    kw = {"method": "sgm", "config": jaxdepth.SGMConfig(), "lidar": presets.KITTI_HDL64}
    exe = complete_with.lower(d, k, t, **kw).compile()
    memory = program_memory(exe)
    print(f"{label}: the frame program's temp {memory['temp_mb']:.2f} MB ({memory['room_below_mmap_cliff_mb']:+.2f} MB "
          f"below the 32 MiB mmap cliff)", flush=True)
    origin = _origins(exe.as_text())
    call = lambda: exe(d, k, t).block_until_ready()
    for _ in range(3):
        call()
    walls, cpus = zip(*(wall_and_cpu_ms(call) for _ in range(args.rounds)))
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            for _ in range(args.runs):
                call()
        events = json.load(gzip.open(glob.glob(f"{tmp}/**/perfetto_trace.json.gz", recursive=True)[0]))
    events = events["traceEvents"] if isinstance(events, dict) else events
    threads = {e["tid"]: e.get("args", {}).get("name", str(e["tid"])) for e in events
               if e.get("ph") == "M" and e.get("name") == "thread_name"}
    kernel_us, calls, by_thread = collections.Counter(), collections.Counter(), collections.defaultdict(collections.Counter)
    spans, executes = collections.defaultdict(list), collections.Counter()
    for e in events:
        name = e.get("name", "")
        if e.get("ph") != "X":
            continue
        if name.startswith("PjitFunction") or "Execute" in name:
            executes[name] += e.get("dur", 0)
        if name in origin and not name.startswith(CONTAINERS):
            kernel_us[name] += e.get("dur", 0)
            calls[name] += 1
            by_thread[name][threads.get(e.get("tid"), str(e.get("tid")))] += e.get("dur", 0)
            spans[_stage(origin[name])].append((e["ts"], e["ts"] + e.get("dur", 0)))
    stage_us, stage_n, stage_thread = collections.Counter(), collections.Counter(), collections.defaultdict(collections.Counter)
    launches = collections.Counter()
    for name, us in kernel_us.items():
        stage = _stage(origin[name])
        stage_us[stage] += us
        stage_n[stage] += 1
        launches[stage] += calls[name] / args.runs
        for th, v in by_thread[name].items():
            stage_thread[stage][th] += v
    per = 1e3 * args.runs
    doc = {"what": "one KITTI frame's compiled program under jax.profiler: kernels' exclusive time per frame by stage "
                   "and thread (profiler overhead included), the union of the stage's kernel intervals (wall "
                   "while any of its kernels runs), and the unprofiled frame's wall / process CPU",
           "frame": label, "runs": args.runs, "rounds": args.rounds, "frame_program_memory": memory,
           "unprofiled_ms_median": {"wall": statistics.median(walls), "cpu": statistics.median(cpus)},
           "kernels_ms_per_frame_total": sum(kernel_us.values()) / per,
           "kernels_union_ms_per_frame": _union_us([iv for v in spans.values() for iv in v]) / per,
           "stages": {s: {"ms_per_frame": us / per, "union_ms_per_frame": _union_us(spans[s]) / per,
                          "kernels": stage_n[s], "launches_per_frame": launches[s],
                          "ms_per_frame_by_thread": {th: v / per for th, v in stage_thread[s].most_common()}}
                      for s, us in sorted(stage_us.items())},
           "top_kernels": [{"kernel": n, "ms_per_frame": us / per, "calls_per_frame": calls[n] / args.runs,
                            "stage": _stage(origin[n]), "op": origin[n][-120:],
                            "by_thread_ms": {th: v / per for th, v in by_thread[n].most_common()}}
                           for n, us in kernel_us.most_common(args.top)],
           "execute_events_ms_per_frame": {n: us / per for n, us in executes.most_common(6)},
           "load_average": os.getloadavg()}
    print(f"{label}: unprofiled median wall {doc['unprofiled_ms_median']['wall']:.2f} ms, CPU "
          f"{doc['unprofiled_ms_median']['cpu']:.2f} ms; kernels (profiled) {doc['kernels_ms_per_frame_total']:.2f} ms, "
          f"their union {doc['kernels_union_ms_per_frame']:.2f} ms")
    for s, v in doc["stages"].items():
        ths = ", ".join(f"{th} {ms:.2f}" for th, ms in v["ms_per_frame_by_thread"].items())
        print(f"  {s:44s} {v['ms_per_frame']:6.2f} ms (union {v['union_ms_per_frame']:6.2f})  {v['kernels']:4d} kernels "
              f"{v['launches_per_frame']:7.0f} launches"
              f"  [{ths}]")
    for kn in doc["top_kernels"]:
        print(f"  {kn['ms_per_frame']:6.3f} ms {kn['calls_per_frame']:6.0f}x {kn['kernel'][:28]:28s} "
              f"{kn['stage'][:2]} {kn['op'][-70:]}")
    print("execute events:", doc["execute_events_ms_per_frame"], "load", doc["load_average"])
    if args.stage_rounds:
        doc["unprofiled_stages"] = _stage_split(d, k, t, sparse, args.stage_rounds)
        print("unprofiled, one process, shuffled rounds (medians): " + ", ".join(
            f"{n} CPU {v['cpu_ms']:.2f} / wall {v['wall_ms']:.2f} ms" for n, v in doc["unprofiled_stages"].items()))
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
