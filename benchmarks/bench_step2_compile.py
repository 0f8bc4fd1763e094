"""Step 2's compile cost alone: trace, lowering and XLA compile CPU seconds of ``outliers._keep_mask``.

Cases (synthetic inputs: the compile depends on shapes and options, not on values): ``kitti`` (352 x 1216,
image input, 64 beams: window 5 x 12), ``tiny`` (32 x 48, image input, 32 beams: the suite's size),
``av2`` (1550 x 2048, points and each pixel's own LiDAR origin, 64 beams: window 24 x 12, the rig path's
call); random depths at KITTI's / an Argoverse 2 camera's share of pixels (4.4 %, 0.5 %). ``--baseline FILE``: another version of ``jaxdepth/_src/outliers.py`` (e.g. ``git show
main:jaxdepth/_src/outliers.py > /tmp/outliers_main.py``), loaded beside this one; each case compiles
both versions ``--rounds`` times in interleaved order, every compile a fresh ``jax.jit`` (no in-memory
cache; the persistent cache is off), and its masks must equal this one's. ``--suite-flags``: compile
under the test suite's ``XLA_FLAGS`` (``xla_tuning.SUITE_XLA_FLAGS``, set before JAX starts). Also
reports the lowered module's StableHLO lines and the warm run's median seconds.

    python -m benchmarks.bench_step2_compile [--cases kitti tiny av2] [--rounds 2] [--baseline FILE]
        [--suite-flags] [--out benchmarks/results/step2_compile.json]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import time

import numpy as np

from benchmarks._common import RESULTS, write_results

CASES = {"kitti": (352, 1216, 64, False, 0.044), "tiny": (32, 48, 32, False, 0.04), "av2": (1550, 2048, 64, True, 0.005)}


def _inputs(height, width, beams, raw, density, seed=0):
    """(depth, K, T, points, origins) of a synthetic sparse frame (``density``: share of pixels with depth)."""
    rng = np.random.default_rng(seed)
    depth = np.where(rng.random((height, width)) < density, rng.uniform(2, 80, (height, width)), 0).astype(np.float32)
    K = np.array([[0.9 * width, 0, width / 2], [0, 0.9 * width, height / 2], [0, 0, 1]], np.float32)
    T = np.eye(4, dtype=np.float32)
    T[:3, 3] = (0.0, -0.08, -0.27)
    if not raw:
        return depth, K, T, None, None
    v, u = np.mgrid[:height, :width].astype(np.float32)
    points = np.stack([(u - K[0, 2]) * depth / K[0, 0], (v - K[1, 2]) * depth / K[1, 1], depth]).astype(np.float32)
    origins = np.broadcast_to(T[:3, 3, None, None], (3, height, width)).astype(np.float32).copy()
    origins[2, :, : width // 2] += 0.3
    return depth, K, T, points, origins


def _cpu():
    return time.process_time()


def _compile_once(module, args, beams):
    """A fresh jit of ``module._keep_mask``: (trace, lower, compile) CPU seconds, StableHLO lines, executable."""
    import jax
    import jax.numpy as jnp

    depth, K, T, points, origins = args
    h, w = depth.shape
    hw, hh = module.window_half_sizes(h, w, beams=beams, max_half_width_px=12, max_half_height_px=24)
    opts = dict(beams=beams, half_width=hw, half_height=hh)
    if origins is None:
        fn = jax.jit(lambda s, K, T: module._keep_mask.__wrapped__(s, K, T, None, jnp.float32(1.0), **opts))
        call = (depth, K, T)
    else:
        fn = jax.jit(lambda s, K, T, p, o: module._keep_mask.__wrapped__(s, K, T, p, jnp.float32(1.0), origins=o,
                                                                        **opts))
        call = (depth, K, T, points, origins)
    c0 = _cpu()
    traced = fn.trace(*call)
    c1 = _cpu()
    lowered = traced.lower()
    c2 = _cpu()
    compiled = lowered.compile()
    c3 = _cpu()
    lines = lowered.as_text().count("\n")
    return dict(trace_s=c1 - c0, lower_s=c2 - c1, compile_s=c3 - c2, stablehlo_lines=lines), compiled, call


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--baseline", default=None, help="another outliers.py to compile against (masks must agree)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--runs", type=int, default=5, help="warm runs per compiled program (median)")
    parser.add_argument("--suite-flags", action="store_true", help="compile under the test suite's XLA_FLAGS")
    parser.add_argument("--no-mask-check", action="store_true",
                        help="a baseline that is a throw-away cut (e.g. without the exact test): skip the mask check")
    parser.add_argument("--out", default=str(RESULTS / "step2_compile.json"))
    args, t0 = parser.parse_args(argv), time.time()
    if args.suite_flags:
        from jaxdepth._src.xla_tuning import SUITE_XLA_FLAGS
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + SUITE_XLA_FLAGS).strip()
    import jax
    jax.config.update("jax_enable_compilation_cache", False)

    from jaxdepth._src import outliers
    versions = {"this": outliers}
    if args.baseline:
        spec = importlib.util.spec_from_file_location("outliers_baseline", args.baseline)
        versions["baseline"] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(versions["baseline"])
    rows = {}
    for case in args.cases:
        h, w, beams, raw, density = CASES[case]
        inputs = _inputs(h, w, beams, raw, density)
        for r in range(args.rounds):
            order = list(versions.items()) if r % 2 == 0 else list(versions.items())[::-1]
            masks = {}
            for name, module in order:
                timing, compiled, call = _compile_once(module, inputs, beams)
                masks[name] = np.asarray(compiled(*call))
                runs = []
                for _ in range(args.runs):
                    s = time.perf_counter()
                    jax.block_until_ready(compiled(*call))
                    runs.append(time.perf_counter() - s)
                timing["run_s"] = statistics.median(runs)
                rows.setdefault(f"{case} | {name}", []).append(timing)
                print(case, name, {k: round(v, 3) for k, v in timing.items()}, flush=True)
            if not args.no_mask_check and any((m != masks["this"]).any() for m in masks.values()):
                print(f"bench_step2_compile: {case}: the masks differ from the baseline's", file=sys.stderr)
                return 1
    medians = {key: {k: statistics.median(t[k] for t in v) for k in v[0]} for key, v in rows.items()}
    for key, m in medians.items():
        print(f"{key:20s} trace {m['trace_s']:.2f} lower {m['lower_s']:.2f} compile {m['compile_s']:.2f} s CPU, "
              f"{m['stablehlo_lines']:.0f} lines, run {m['run_s'] * 1e3:.2f} ms")
    doc = {"what": "Step 2 alone (outliers._keep_mask): trace / lower / XLA compile CPU seconds, fresh jit per "
                   "compile, persistent cache off, medians over rounds (versions interleaved in one process)",
           "baseline": args.baseline, "suite_flags": args.suite_flags, "xla_flags": os.environ.get("XLA_FLAGS", ""),
           "rounds": args.rounds, "medians": medians, "rounds_raw": rows}
    write_results(args.out, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
