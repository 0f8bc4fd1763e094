"""The KITTI job's batch program with and without the entry points' compile options, in one process.

`jaxdepth complete SRC DST` runs :func:`jaxdepth.batch.runner.batched_completion` (SGM, "map", batch 4 over the
two CPU devices the CLI splits the cores into). That program is an :func:`jaxdepth._src.xla_tuning.entry_jit`
function: it compiles with region-analysis copy insertion (``xla_tuning.COMPILER_OPTIONS``). This times it
against a plain ``jax.jit`` of the same function, on the shared KITTI frame's two cameras (352 x 1216, twice),
in interleaved rounds (the order alternating), process CPU per frame, and checks the outputs are the same bytes.

    python -m benchmarks.bench_batch_program [--rounds 20] [--calls 3] [--json benchmarks/results/batch_program.json]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--calls", type=int, default=3, help="calls per program per round")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    t0 = time.time()
    import jax
    jax.config.update("jax_num_cpu_devices", 2)      # as `jaxdepth complete` on this 2-core machine
    import numpy as np

    from benchmarks._common import FRAME, RESULTS, load_frames, write_results
    from jaxdepth import SGMConfig
    from jaxdepth._src import presets
    from jaxdepth.batch import runner
    if not FRAME.exists():
        print(f"shared data not found: {FRAME}", file=sys.stderr)
        return 1
    frames = load_frames()
    cams = ("image_02", "image_03") * 2
    depth, K, T = (np.stack([frames[c][i] for c in cams]).astype(np.float32) for i in (0, 2, 3))
    fn = runner.batched_completion(4, 352, 1216, method="sgm", config=SGMConfig(), lidar=presets.KITTI_HDL64,
                                   strategy="map", devices=2)
    programs = {"entry_jit": fn.jitted, "plain_jit": jax.jit(fn.jitted.__wrapped__)}
    outs = {name: np.asarray(f(depth, K, T)) for name, f in programs.items()}      # compiles, untimed
    identical = outs["entry_jit"].tobytes() == outs["plain_jit"].tobytes()
    cpu = {name: [] for name in programs}
    for r in range(args.rounds):
        for name in (tuple(programs) if r % 2 == 0 else tuple(reversed(programs))):
            start = time.process_time()
            for _ in range(args.calls):
                jax.block_until_ready(programs[name](depth, K, T))
            cpu[name].append((time.process_time() - start) / args.calls / 4 * 1e3)
    ratios = [a / b for a, b in zip(cpu["entry_jit"], cpu["plain_jit"])]
    doc = {"what": __doc__.splitlines()[0], "identical": identical, "cpu_ms_per_frame": cpu,
           "median_cpu_ms_per_frame": {k: statistics.median(v) for k, v in cpu.items()},
           "ratio_entry_over_plain_per_round": ratios, "ratio_entry_over_plain_median": statistics.median(ratios),
           "load_average": os.getloadavg()}
    print({k: doc[k] for k in ("identical", "median_cpu_ms_per_frame", "ratio_entry_over_plain_median", "load_average")})
    write_results(args.json or RESULTS / "batch_program.json", doc, None, t0)
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())
