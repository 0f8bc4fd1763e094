"""How the XLA:CPU compile uses the cores, and what compiling stage programs concurrently gives (issue 38 item 5).

One process, persistent compile cache off, ``jax.clear_caches()`` before every variant (nothing reused).
The process's CPU seconds are read per thread from ``/proc/self/task`` (every thread's user + system time),
so what the calling Python thread does (JAX's lowering, XLA's HLO passes and kernel emission) is told
apart from what XLA:CPU runs in its own per-process code generation pool (LLVM, one task per split module).

Parts (``--parts``):

``threads``: two programs (``jax.jit(complete)`` on two crops of the shared KITTI frame, 352 x 1216 and
352 x 1184: two compiles of the same size) compiled one after the other (``serial``) or each
``Lowered.compile()`` in a Python thread of its own, started together (``threads``); the two variants
alternate. Per variant: wall, process CPU, the calling threads' CPU and the other threads'.

``stages``: the Argoverse 2 sweep's multi-source pipeline (``av2``) or the nuScenes rig (``nuscenes``),
as :mod:`benchmarks.bench_stage_programs` builds them, three ways: ``one`` (the one program: lower, then
compile), ``stages`` (the three stage programs lowered from each other's output shapes and compiled one
after another) and ``pool`` (the same, each stage's compile handed to a thread pool of
``os.cpu_count()`` as soon as it is lowered, so that the next stage's trace and lowering, and the stages'
compiles, overlap). The variants rotate in order round by round.

``first``: the cold path to the first and second sweep of the same cases, with the demand's idle estimate at
each: ``one`` (the one program compiled, two sweeps through it), ``keep`` (the stage programs compiled in the
pool, both sweeps through them) and ``switch`` (the same, while the one program is lowered and compiled in a
background thread; the second sweep through it, once compiled). Outputs compared byte for byte.

    python -m benchmarks.bench_compile_threads [--parts threads stages] [--cases av2] [--rounds 3]
        [--json benchmarks/results/compile_threads.json]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import functools
import os
import statistics
import threading
import time

from benchmarks._common import RESULTS, write_results

WIDTHS = (1216, 1184)
_TCK = os.sysconf("SC_CLK_TCK")


def thread_cpu() -> dict:
    """``{tid: CPU seconds}`` of every thread of this process (user + system, from ``/proc``)."""
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        out[int(tid)] = (int(fields[11]) + int(fields[12])) / _TCK
    return out


class Demand:
    """Samples, every ``period`` seconds, how many of this process's threads want a core (state R: running
    or waiting for one) and the process CPU seconds; :meth:`stop` returns the *idle estimate*: each
    interval's CPU seconds divided by min(cores, threads wanting one), summed, i.e. the wall time the same
    work would take on an idle machine of ``os.cpu_count()`` cores if the threads' demand stayed as
    sampled (on a loaded machine the wall time stretches, the demand does not), and the CPU seconds spent
    while at most one thread wanted a core (what another thread could overlap at best)."""

    def __init__(self, period: float = 0.05):
        self.period, self.cores = period, os.cpu_count() or 1
        self.idle_s = self.single_cpu_s = self.cpu_s = 0.0
        self.t0 = time.perf_counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @staticmethod
    def _wanting(own: int) -> int:
        n = 0
        for tid in os.listdir("/proc/self/task"):
            if int(tid) == own:
                continue
            try:
                with open(f"/proc/self/task/{tid}/stat") as f:
                    n += f.read().rsplit(")", 1)[1].split()[0] == "R"
            except OSError:
                continue
        return n

    def _run(self) -> None:
        own = threading.get_native_id()
        cpu, wanting = time.process_time(), self._wanting(own)
        while not self._stop.wait(self.period):
            now, want = time.process_time(), self._wanting(own)
            used, n = now - cpu, (wanting + want) / 2
            self.cpu_s += used
            self.idle_s += used / min(self.cores, max(1.0, n))
            self.single_cpu_s += used if n <= 1 else 0.0
            cpu, wanting = now, want

    def mark(self) -> dict:
        """The estimate so far (up to the last sample), wall seconds since the start beside it."""
        return {"idle_estimate_s": self.idle_s, "sampled_cpu_s": self.cpu_s, "wall_s": time.perf_counter() - self.t0}

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join()
        return {"idle_estimate_s": self.idle_s, "sampled_cpu_s": self.cpu_s, "cpu_one_thread_wanting_s": self.single_cpu_s}


class Clock:
    """Wall, process CPU and per-thread CPU from construction to :meth:`stop`; ``callers``: the native ids
    of the threads that called into JAX (the rest is XLA's own pool)."""

    def __init__(self):
        self.callers = {threading.get_native_id()}
        self.t0, self.before = (time.perf_counter(), time.process_time()), thread_cpu()
        self.demand = Demand()

    def stop(self) -> dict:
        wall, cpu = time.perf_counter() - self.t0[0], time.process_time() - self.t0[1]
        demand = self.demand.stop()
        after = thread_cpu()
        per = {tid: after[tid] - self.before.get(tid, 0.0) for tid in after}
        caller = sum(v for tid, v in per.items() if tid in self.callers)
        return {"wall_s": wall, "cpu_s": cpu, "caller_threads_cpu_s": caller, "other_threads_cpu_s": cpu - caller,
                "busy_threads_cpu_s": sorted((round(v, 2) for v in per.values() if v > 0.2), reverse=True),
                "cpu_per_wall": cpu / wall,
                "load_1min": os.getloadavg()[0], **demand}


def _short(doc: dict) -> dict:
    return {k: round(v, 2) if isinstance(v, float) else v for k, v in doc.items()}


def _kitti_lowered(width: int):
    import jax

    import jaxdepth
    from benchmarks._common import load_frame
    sparse, K, T, _ = load_frame()
    return jax.jit(jaxdepth.complete).lower(sparse[:, :width], K, T)


def _compile_in(pool, lowered, clock: Clock | None):
    def task():
        if clock is not None:
            clock.callers.add(threading.get_native_id())
        return lowered.compile()
    return pool.submit(task)


def part_threads(rounds: int) -> dict:
    import jax
    out = []
    for r in range(rounds):
        row = {}
        for variant in (("serial", "threads") if r % 2 == 0 else ("threads", "serial")):
            jax.clear_caches()
            lowered = [_kitti_lowered(w) for w in WIDTHS]
            clock = Clock()
            if variant == "threads":
                with concurrent.futures.ThreadPoolExecutor(len(lowered)) as pool:
                    exes = [f.result() for f in [_compile_in(pool, low, clock) for low in lowered]]
            else:
                exes = [low.compile() for low in lowered]
            row[variant] = clock.stop()
            del exes
            print("threads", r, variant, _short(row[variant]), flush=True)
        row["wall_ratio_threads_serial"] = row["threads"]["wall_s"] / row["serial"]["wall_s"]
        out.append(row)
    return {"programs": [f"jit(complete) 352x{w}" for w in WIDTHS], "rounds": out,
            "median_wall_ratio_threads_serial": statistics.median(r["wall_ratio_threads_serial"] for r in out)}


def _digest(tree) -> str:
    """SHA-256 of every leaf's bytes, in order."""
    import hashlib

    import jax
    import numpy as np
    h = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(tree):
        h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    return h.hexdigest()


def _shape_of(tree):
    import jax
    return jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), tree)


def compile_stages(stages, args, statics, *, pool=None, clock: Clock | None = None) -> list:
    """The stage programs lowered in turn from each other's output shapes (``args[k]`` builds stage k's
    arguments from the earlier outputs, as in :mod:`benchmarks.bench_stage_programs`) and compiled; with a
    ``pool``, each compile submitted as soon as its stage is lowered. Returns the executables in order."""
    import jax
    done, inputs = [], None
    for k, (stage, extra) in enumerate(zip(stages, statics)):
        call_args = args[0] if k == 0 else args[k](inputs)
        lowered = jax.jit(functools.partial(stage, **extra)).lower(*call_args)
        done.append(_compile_in(pool, lowered, clock) if pool is not None else lowered.compile())
        shapes = _shape_of(lowered.out_info)
        inputs = shapes if k == 0 else (inputs, shapes)
    return [d.result() for d in done] if pool is not None else done


def _run_stages(exes: list, args: tuple):
    """The three compiled stage programs called in turn (``args`` as in :func:`compile_stages`)."""
    views = exes[0](*args[0])
    keeps = exes[1](*args[1](views))
    return exes[2](*args[2]((views, keeps)))


def _pool_compiled(stages, args, statics, clock: Clock | None = None) -> list:
    with concurrent.futures.ThreadPoolExecutor(os.cpu_count()) as pool:
        return compile_stages(stages, args, statics, pool=pool, clock=clock)


def _each_variant(variants: tuple, rounds: int, out: list):
    """Yields ``(row, variant)``: ``rounds`` rounds (each a ``row`` dict appended to ``out``) of the variants,
    each round in another order (each variant first in turn), JAX's in-memory caches cleared before each."""
    import jax
    for r in range(rounds):
        row = {}
        out.append(row)
        for variant in variants[r % len(variants):] + variants[:r % len(variants)]:
            jax.clear_caches()
            yield row, variant


def part_stages(case: str, rounds: int) -> dict:

    from benchmarks.bench_stage_programs import _case_inputs
    stages, args, statics, one, one_args = _case_inputs(case)
    variants = ("one", "stages", "pool")
    out, reference = [], None
    for row, variant in _each_variant(variants, rounds, out):
        clock = Clock()
        if variant == "one":
            exes = [one.lower(*one_args).compile()]
        elif variant == "stages":
            exes = compile_stages(stages, args, statics)
        else:
            exes = _pool_compiled(stages, args, statics, clock)
        row[variant] = clock.stop()
        result = exes[0](*one_args) if variant == "one" else _run_stages(exes, args)
        digest = _digest(result)
        del result, exes
        reference = digest if reference is None else reference
        row[variant]["bytes_identical_to_first"] = digest == reference
        print(case, len(out) - 1, variant, _short(row[variant]), flush=True)
    med = {v: statistics.median(row[v]["wall_s"] for row in out) for v in variants}
    return {"rounds": out, "median_wall_s": med,
            "median_wall_ratio_pool_one": statistics.median(row["pool"]["wall_s"] / row["one"]["wall_s"] for row in out)}


def part_first(case: str, rounds: int) -> dict:
    """Compile and two sweeps (``block_until_ready``) three ways; the demand's idle estimate and CPU seconds
    at the first sweep's end and at the second's (see the module docs, part ``first``)."""
    import jax

    from benchmarks.bench_stage_programs import _case_inputs
    stages, args, statics, one, one_args = _case_inputs(case)

    def run_stages(exes):
        return jax.block_until_ready(_run_stages(exes, args))

    variants = ("one", "keep", "switch")
    out, reference = [], None
    for row, variant in _each_variant(variants, rounds, out):
        demand = Demand()
        background = None
        if variant == "one":
            exe = one.lower(*one_args).compile()
            first = jax.block_until_ready(exe(*one_args))
        else:
            exes = _pool_compiled(stages, args, statics)
            if variant == "switch":   # the one program, traced and compiled beside the first sweep
                background = concurrent.futures.ThreadPoolExecutor(1).submit(
                    lambda: one.lower(*one_args).compile())
            first = run_stages(exes)
        at_first = demand.mark()
        if variant == "one":
            second = jax.block_until_ready(exe(*one_args))
        elif variant == "keep":
            second = run_stages(exes)
        else:
            second = jax.block_until_ready(background.result()(*one_args))
        at_second = demand.mark()
        total = demand.stop()
        digest = _digest((first, second))
        reference = digest if reference is None else reference
        row[variant] = {"first_sweep": at_first, "second_sweep": at_second, "total": total,
                        "load_1min": os.getloadavg()[0], "bytes_identical_to_first": digest == reference}
        del first, second, background
        exe = exes = None   # free the executables before the next variant
        print(case, len(out) - 1, variant, "first", _short(at_first), "second", _short(at_second),
              "identical", digest == reference, flush=True)
    return {"rounds": out, "median_idle_first_s": {v: statistics.median(
        row[v]["first_sweep"]["idle_estimate_s"] for row in out) for v in variants},
        "median_idle_second_s": {v: statistics.median(row[v]["second_sweep"]["idle_estimate_s"] for row in out)
                                 for v in variants}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", nargs="+", default=["threads", "stages"], choices=("threads", "stages", "first"))
    parser.add_argument("--cases", nargs="+", default=["av2"], choices=("av2", "nuscenes"))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", default=str(RESULTS / "compile_threads.json"))
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    import jax
    jax.config.update("jax_enable_compilation_cache", False)
    doc = {"cpu_count": os.cpu_count(), "load_average_start": os.getloadavg()}
    if "threads" in args.parts:
        doc["threads"] = part_threads(args.rounds)
    if "stages" in args.parts:
        doc["stages"] = {case: part_stages(case, args.rounds) for case in args.cases}
    if "first" in args.parts:
        doc["first"] = {case: part_first(case, args.rounds) for case in args.cases}
    doc["load_average_end"] = os.getloadavg()
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
