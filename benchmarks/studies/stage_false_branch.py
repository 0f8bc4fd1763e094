"""Study (issue 38 item 5): the KITTI frame's compile with ``stage``'s never-taken branch returning zeros
(main) against running ``fn`` too, in one process, alternating.

The variant is made at trace time without editing the library: ``xla_tuning``'s ``jax.lax.cond`` is wrapped
so that a false branch named ``zeros`` (``stage``'s) is the true one (every ``stage`` and ``fence``
conditional; XLA then also drops the conditionals of identity fences whose two branches pass their operands
through; ``cond_all``'s fallback stays. A first version replaced that fallback too: 0.67-0.72x). Each round clears JAX's
caches and lowers and compiles ``jax.jit(complete)`` on the shared frame once per variant (order
alternating), persistent cache off; process CPU seconds of the trace + lowering and of the XLA compile, the
output's hash and the compiled program's conditionals. A fresh-process comparison across two checkouts
(``bench_compile_flags --trees``) scattered by more than this difference on this machine (docs/speed.md,
"Step 1 kernel by kernel").

    python -m benchmarks.studies.stage_false_branch [--rounds 3] [--json PATH]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import sys
import time

from benchmarks._common import RESULTS, load_frame, write_results
from benchmarks.bench_compile_flags import _cpu


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", default=str(RESULTS / "stage_false_branch.json"))
    args, t0 = parser.parse_args(argv), time.time()
    import jax
    import jax.numpy as jnp
    import numpy as np

    import jaxdepth
    from jaxdepth._src import xla_tuning
    jax.config.update("jax_enable_compilation_cache", False)
    same = [False]

    class _Lax:
        def __getattr__(self, name):
            if name == "cond" and same[0]:     # stage's false branch only (cond_all's fallback stays)
                return lambda pred, true_fn, false_fn, *ops: jax.lax.cond(
                    pred, true_fn, true_fn if false_fn.__name__ == "zeros" else false_fn, *ops)
            return getattr(jax.lax, name)

    class _Jax:
        lax = _Lax()

        def __getattr__(self, name):
            return getattr(jax, name)

    xla_tuning.jax = _Jax()
    sparse, K, T, label = load_frame()
    frame = (jnp.asarray(sparse), jnp.asarray(K), jnp.asarray(T))
    rows = {"zeros": [], "fn": []}
    for r in range(args.rounds):
        for name in (("zeros", "fn") if r % 2 == 0 else ("fn", "zeros")):
            same[0] = name == "fn"
            jax.clear_caches()
            c0 = _cpu()
            lowered = jax.jit(jaxdepth.complete).lower(*frame)
            c1 = _cpu()
            compiled = lowered.compile()
            c2 = _cpu()
            out = np.asarray(compiled(*frame))
            row = {"trace_lower_cpu_s": c1 - c0, "compile_cpu_s": c2 - c1,
                   "sha256": hashlib.sha256(out.tobytes()).hexdigest(),
                   "conditionals": compiled.as_text().count(" conditional("), "load": os.getloadavg()[0]}
            rows[name].append(row)
            print(f"{name:5s} trace+lower {row['trace_lower_cpu_s']:.2f} s, compile {row['compile_cpu_s']:.2f} s CPU, "
                  f"{row['conditionals']} conditionals, sha256 {row['sha256'][:12]}", flush=True)
    med = {n: {k: statistics.median(x[k] for x in v) for k in ("trace_lower_cpu_s", "compile_cpu_s")}
           for n, v in rows.items()}
    ratios = [a["compile_cpu_s"] / b["compile_cpu_s"] for a, b in zip(rows["fn"], rows["zeros"])]
    doc = {"what": "jit(complete) on the KITTI frame, stage's false branch zeros (main) or fn, one process, alternating",
           "frame": label, "rounds": args.rounds, "medians": med, "compile_ratio_fn_to_zeros_per_round": ratios,
           "same_bytes": len({x["sha256"] for v in rows.values() for x in v}) == 1, "runs": rows,
           "load_average": os.getloadavg()}
    print(f"medians {med}; per round fn / zeros {[round(x, 3) for x in ratios]}; same bytes {doc['same_bytes']}")
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
