"""The rig pipelines' Steps 3-4 (the ``tail`` stage program) kernel by kernel, and its blur's window form.

For each case (the Argoverse 2 sweep through :func:`jaxdepth._src.sources.sources_stage_tail`, the nuScenes
sample through :func:`jaxdepth._src.rig.rig_stage_tail`, inputs as ``bench_stage_programs`` builds them):

1. **Kernels**: one run of the compiled tail under ``jax.profiler`` (a Perfetto trace), as the library has
   it (``library``) and with the former form below (``blur_gather``); each XLA:CPU kernel's time, summed
   over its calls (loop bodies run once a step), with the JAX operation it comes from (the HLO's
   ``op_name``), the largest first, in ms and ns per real pixel.
2. **Blur window forms** (``--rounds`` interleaved rounds after a first call each): ``library`` (the
   window's reflect-101 padding a select among the 2 r + 1 static shifts, elementwise,
   :func:`jaxdepth._src.smoothing._reflect101_pad_window`) against ``blur_gather`` (that padding a row /
   column gather, the form before; defined here, swapped in, JAX's caches cleared) and ``blur_static``
   (the blur's static canvas padding, ``image_size`` not passed to the blur: right only because every size
   group's canvas is its cameras' size). Medians in ns per real pixel, per-round ratios to ``library``, and
   how many ``depth`` values differ from ``library`` (count, largest difference in float32 ulps): the
   padding moves the same values, but the gather's kernel holds the vertical taps, and XLA:CPU rounds them
   there unlike in a loop kernel, and unlike from machine to machine (docs/speed.md, "The rig's tail").
   ``results/rig_tail_profile.json`` was written before the select form was the library's: there
   ``library`` is the gather and ``blur_select`` the select form.

    python -m benchmarks.bench_rig_tail_profile [--cases av2 nuscenes] [--rounds 3] [--top 25]
        [--json benchmarks/results/rig_tail_profile.json]
"""

from __future__ import annotations

import argparse
import collections
import functools
import glob
import gzip
import json
import os
import re
import statistics
import tempfile
import time

import numpy as np

from benchmarks._common import RESULTS, write_results


def _gather_pad_window(image, radius: int, axis: int, n):
    """The window's reflect-101 padding as one row / column gather: the library's form before the select
    among static shifts (main before ad6b88c), kept here as the baseline."""
    import jax.numpy as jnp
    idx = jnp.arange(-radius, image.shape[axis] + radius, dtype=jnp.int32)
    period = jnp.maximum(2 * n - 2, 1)
    idx = jnp.abs(idx) % period
    idx = jnp.where(idx >= n, period - idx, idx)
    return jnp.take(image, idx, axis=axis, mode="clip")      # idx is in [0, n), n <= the length


def _tail(case: str):
    """``(jitted tail, args, real pixels)`` of a case."""
    import jax

    from benchmarks.bench_stage_programs import _case_inputs
    stages, args, statics, _, one_args = _case_inputs(case)
    jitted = [jax.jit(functools.partial(stage, **extra)) for stage, extra in zip(stages, statics)]
    views = jitted[0](*args[0])
    keeps = jitted[1](*args[1](views))
    cameras = one_args[-1]
    pixels = float(sum(int(h) * int(w) for h, w in np.asarray(cameras.image_size)))
    return jitted[2], args[2]((views, keeps)), pixels


def _compiled_variant(fn, args, variant: str):
    """``fn`` compiled with the blur's window form ``variant`` swapped in (caches cleared around)."""
    import jax

    from jaxdepth._src import smoothing
    kept_pad, kept_blur = smoothing._reflect101_pad_window, smoothing.gaussian_blur
    jax.clear_caches()
    if variant == "blur_gather":
        smoothing._reflect101_pad_window = _gather_pad_window
    elif variant == "blur_static":
        smoothing.gaussian_blur = lambda image, *, image_size=None, **kw: kept_blur(image, **kw)
    try:
        from jaxdepth._src import pipeline
        pipeline.gaussian_blur = smoothing.gaussian_blur
        return fn.lower(*args).compile()
    finally:
        smoothing._reflect101_pad_window, smoothing.gaussian_blur = kept_pad, kept_blur
        from jaxdepth._src import pipeline
        pipeline.gaussian_blur = kept_blur
        jax.clear_caches()


def _kernels(exe, args, pixels: float, top: int) -> list:
    """The compiled tail's kernels from one profiled run, the largest first (see the module docs)."""
    import jax
    origin = {}
    for line in exe.as_text().splitlines():
        m = re.match(r"\s*(?:ROOT )?%([\w.\-]+) = .*?op_name=\"([^\"]*)\"", line)
        if m:
            origin.setdefault(m.group(1), m.group(2))
    jax.block_until_ready(exe(*args))
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            jax.block_until_ready(exe(*args))
        events = json.load(gzip.open(glob.glob(f"{tmp}/**/perfetto_trace.json.gz", recursive=True)[0]))
    events = events["traceEvents"] if isinstance(events, dict) else events
    total, calls = collections.Counter(), collections.Counter()
    for e in events:
        name = e.get("name", "")
        if e.get("ph") == "X" and not name.startswith(("$", "ThunkExecutor", "end: ")):
            total[name] += e.get("dur", 0)
            calls[name] += 1
    return [{"kernel": name, "ms": us / 1e3, "ns_per_px": us * 1e3 / pixels, "calls": calls[name],
             "op": re.sub(r"^jit\([^)]*\)/(jit\([^)]*\)/)?", "", origin.get(name, ""))[:160]}
            for name, us in total.most_common(top)]


def _ulps(a: np.ndarray, b: np.ndarray) -> int:
    ia, ib = (np.asarray(x, np.float32).view(np.int32).astype(np.int64) for x in (a, b))
    return int(np.max(np.abs(ia - ib))) if ia.size else 0


def run_case(case: str, rounds: int, top: int) -> dict:
    import jax
    fn, args, pixels = _tail(case)
    variants = {v: _compiled_variant(fn, args, v) for v in ("library", "blur_gather", "blur_static")}
    out = {"pixels": pixels, "kernels": {}, "depth_differs": {}}
    for name in ("library", "blur_gather"):
        out["kernels"][name] = _kernels(variants[name], args, pixels, top)
        for k in out["kernels"][name][:10]:
            print(case, name, f"{k['ms']:8.1f} ms {k['calls']:5d}x {k['kernel']:34s} {k['op'][:80]}", flush=True)
    ref = np.asarray(jax.device_get(variants["library"](*args)).depth)
    for name, exe in variants.items():
        depth = np.asarray(jax.device_get(exe(*args)).depth)
        out["depth_differs"][name] = {"values": int(np.sum(depth != ref)), "max_ulps": _ulps(depth, ref)}
    runs = {name: [] for name in variants}
    for r in range(rounds):
        for name, exe in variants.items():
            t = time.perf_counter()
            jax.block_until_ready(exe(*args))
            runs[name].append(time.perf_counter() - t)
        print(case, r, {k: round(v[-1] * 1e9 / pixels, 1) for k, v in runs.items()}, os.getloadavg(), flush=True)
    out["runs_s"] = runs
    out["ns_per_px"] = {k: statistics.median(v) * 1e9 / pixels for k, v in runs.items()}
    out["over_library_per_round"] = {k: [a / b for a, b in zip(v, runs["library"])] for k, v in runs.items()}
    print(case, {k: round(v, 1) for k, v in out["ns_per_px"].items()}, out["depth_differs"], flush=True)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["av2", "nuscenes"], choices=("av2", "nuscenes"))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--json", default=str(RESULTS / "rig_tail_profile.json"))
    args = parser.parse_args(argv)
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jaxdepth command
    t0 = time.time()
    cases = {case: run_case(case, args.rounds, args.top) for case in args.cases}
    write_results(args.json, {"what": "rig tail (Steps 3-4): kernels of one profiled run, and the blur's window "
                                      "forms, ns/px, one process", "load_average": os.getloadavg(),
                              "cases": cases}, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
