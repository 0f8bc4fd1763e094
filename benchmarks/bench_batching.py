"""Throughput of batched offline processing and of multi-camera rigs.

* frames/s against batch size for 352x1216 KITTI-size frames: a loop of single-frame calls, lax.map and vmap;
* frames/s of rig completion (one sweep, C cameras vmapped) for 1, 2 and 6 cameras;
* one device against two simulated host devices (XLA_FLAGS=--xla_force_host_platform_device_count=2,
  run in a subprocess), batch sharded with shard_map;
* peak resident memory.

Medians after warm-up, compile time apart, block_until_ready before every clock read.

    python -m benchmarks.bench_batching [--json benchmarks/results/batching.json]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import statistics
import subprocess
import sys
import time

import jax
import numpy as np

from benchmarks._common import ROOT, load_frame


def timed(call, repeats):
    start = time.perf_counter()
    call()
    compile_s = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return compile_s, statistics.median(times)


def frames_section(batch_sizes, strategies, devices, repeats):
    from jaxdepth import SGMConfig
    from jaxdepth.batch import runner
    from jaxdepth._src import presets
    sparse, K, T, label = load_frame()
    out = {"frame": label}
    for strategy in strategies:
        for b in batch_sizes:
            if b % devices:
                continue
            fn = runner.batched_completion(b, sparse.shape[0], sparse.shape[1], method="sgm", config=SGMConfig(),
                                           lidar=presets.KITTI_HDL64, strategy=strategy, devices=devices)
            depths = np.repeat(sparse[None], b, axis=0)
            Ks = np.repeat(np.asarray(K, np.float32)[None], b, axis=0)
            Tf = np.ascontiguousarray(np.broadcast_to(np.asarray(T, np.float32), (depths.shape[0], 4, 4)))
            compile_s, med = timed(lambda: jax.block_until_ready(fn(depths, Ks, Tf)), repeats)
            out[f"{strategy}_b{b}_d{devices}"] = {"compile_s": compile_s, "median_s": med, "frames_per_s": b / med}
    return out


def rig_section(repeats):
    import jaxdepth
    from jaxdepth._src import synthetic
    out = {}
    cams = synthetic.rig_cameras("surround", image_scale=0.5)
    frame = synthetic.make_street_scene(0, cameras=cams)
    for count in (1, 2, 6):
        rig = jaxdepth.stack_cameras(cams[:count])
        call = lambda: jaxdepth.complete_rig(frame.points, frame.valid, rig, lidar=frame.lidar).block_until_ready()
        compile_s, med = timed(call, repeats)
        out[f"cameras_{count}"] = {"image": f"{rig.width}x{rig.height}", "compile_s": compile_s, "median_s": med,
                                   "sweeps_per_s": 1 / med, "camera_images_per_s": count / med}
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "batching.json"))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:  # two simulated devices
        print(json.dumps(frames_section([2, 4, 8], ["loop", "map", "vmap"], len(jax.local_devices()), args.repeats)))
        return 0
    results = {"backend": jax.default_backend(), "load_average": os.getloadavg(), "jax": jax.__version__}
    results["frames_one_device"] = frames_section(args.batch_sizes, ["loop", "map", "vmap"], 1, args.repeats)
    results["rig"] = rig_section(args.repeats)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    child = subprocess.run([sys.executable, __file__, "--child", "--repeats", str(args.repeats)], env=env,
                           capture_output=True, text=True)
    results["frames_two_simulated_devices"] = (json.loads(child.stdout.strip().splitlines()[-1])
                                               if child.returncode == 0 else {"error": child.stderr[-2000:]})
    results["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"backend {results['backend']}, load average {results['load_average'][0]:.2f}")
    for section in ("frames_one_device", "frames_two_simulated_devices"):
        for key, row in results[section].items():
            if isinstance(row, dict) and "frames_per_s" in row:
                print(f"{section:30s} {key:14s} {row['frames_per_s']:7.2f} frames/s (compile {row['compile_s']:.1f} s)")
    for key, row in results["rig"].items():
        print(f"rig {key:12s} {row['image']:>10s} {row['sweeps_per_s']:6.2f} sweeps/s "
              f"{row['camera_images_per_s']:6.2f} images/s (compile {row['compile_s']:.1f} s)")
    print(f"peak RSS {results['peak_rss_mb']:.0f} MB")
    out = pathlib.Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
