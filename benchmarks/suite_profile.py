"""Where the test suite's time goes: a pytest plugin that records JAX's compile work per test, and its summary.

Record (from the repository root; one JSON line per test, one file per xdist worker)::

    JAXDEPTH_SUITE_PROFILE=/tmp/profile python -m pytest -q -p benchmarks.suite_profile

Summarise (prints the tables; ``--json`` writes them, default ``results/suite_profile.json``;
``--compile-cost`` also times one compile of the 32 x 48 pipeline in this process)::

    python -m benchmarks.suite_profile /tmp/profile [--compile-cost] [--cores N] [--json [PATH]]

Per test: wall seconds; whether it is marked ``slow`` (the summary adds up the quick subset,
``-m "not slow"``, and the rest); CPU seconds of the test's process (``cpu_s``: user + system, every thread,
XLA's compile threads included) and of the subprocesses it waited for (``child_cpu_s``: CLI runs,
notebook kernels; not Ray's workers, which outlive the test), which other processes' load on a
shared machine inflates far less than wall time; and the seconds JAX reports through ``jax.monitoring`` in that test's
process: XLA compiling (``backend_compile``), tracing, lowering to MLIR, reading the persistent
compilation cache; and every single compile of at least 0.25 s (``JAXDEPTH_SUITE_PROFILE_MIN_S``)
with its function's name, argument shapes (from JAX's ``jax_log_compiles`` messages, which the
plugin turns on) and persistent-cache key (from JAX's cache-miss message). The controller (or the only
process) samples the machine every second into ``machine.jsonl``: ``/proc/stat``, the load average,
its ``cpuacct`` control group, and the runnable threads of every process of the run (the environment
holds the run's ``JAXDEPTH_SUITE_PROFILE``; Ray's daemons included). Work in subprocesses (CLI runs, notebook kernels, Ray workers) shows as wall time
only. The summary gives the totals, each worker's span, the modules and tests that take longest, the
functions whose compiles cost most, and the function names compiled more than once with the same
argument shapes (other static options, another function of that name, or one program compiled twice:
the first place to look for a compile to share), the programs (cache keys) compiled more than once, and
the run's idle cores: the core-seconds its runnable threads left unused (``--cores``), charged to the
tests running then, the tail, and an idle-machine wall estimate. The plugin does nothing unless
``JAXDEPTH_SUITE_PROFILE`` names a folder.
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import logging
import os
import pathlib
import re
import resource
import sys
import threading
import time

import pytest

ENV = "JAXDEPTH_SUITE_PROFILE"
#: jax.monitoring duration events -> short field names.
EVENTS = {
    "/jax/core/compile/backend_compile_duration": "compile_s",
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/compilation_cache/cache_retrieval_time_sec": "cache_read_s",
}
#: Compiles at least this long are listed one by one (``JAXDEPTH_SUITE_PROFILE_MIN_S`` overrides it).
BIG_COMPILE_S = 0.25
_LISTED = f">= {BIG_COMPILE_S} s, or {ENV}_MIN_S when the run set it"

_state = {"out": None, "sums": collections.Counter(), "big": [], "signature": ""}

_DTYPES = {"float32": "f32", "float64": "f64", "int32": "s32", "int64": "s64", "uint8": "u8", "bool": "pred"}


def signature(message: str) -> str:
    """``f32[32,48] f32[3,3] ~f32[]``: the argument shapes of JAX's "Compiling <fun> with global shapes and
    types (ShapedArray(float32[32,48]), ...)" message (static options are not in it); ``~`` marks a weakly
    typed argument (a Python scalar: a program apart from the same call with a typed array)."""
    shapes = re.findall(r"ShapedArray\((\w+)(\[[^\]]*\])([^)]*)\)", message)
    return " ".join(("~" if "weak_type=True" in rest else "") + _DTYPES.get(dtype, dtype) + dims
                    for dtype, dims, rest in shapes)


class _CompilingMessages(logging.Handler):
    """Keeps the argument shapes of the program JAX lowered last (``jax_log_compiles``) and the
    persistent-cache key of the program it is about to compile (its cache-miss message)."""

    def emit(self, record):
        message = record.getMessage()
        if message.startswith("Compiling "):
            _state["signature"] = signature(message)
        elif message.startswith("PERSISTENT COMPILATION CACHE MISS"):
            _state["key"] = record.args[1] if len(record.args or ()) > 1 else ""


def _listener(event, duration, **kwargs):
    field = EVENTS.get(event)
    if field is None:
        return
    _state["sums"][field] += duration
    _state["sums"][field.replace("_s", "_n")] += 1
    if field == "compile_s":
        # the shapes belong to this compile only: a later one without a message of its own gets ""
        shapes, _state["signature"] = _state["signature"], ""
        key, _state["key"] = _state.get("key", ""), ""
        if duration >= _state.get("min_s", BIG_COMPILE_S):
            _state["big"].append([str(kwargs.get("fun_name", "?")), round(duration, 2), shapes, key])


def pytest_configure(config):
    folder = os.environ.get(ENV)
    if not folder:
        return
    import jax
    import jax.monitoring
    _state["min_s"] = float(os.environ.get(ENV + "_MIN_S", BIG_COMPILE_S))
    jax.monitoring.register_event_duration_secs_listener(_listener)
    # The argument shapes of each compile: JAX logs them (at WARNING) with jax_log_compiles on.
    jax.config.update("jax_log_compiles", True)
    handler = _CompilingMessages()
    logging.getLogger("jax._src.interpreters.pxla").addHandler(handler)
    # The persistent-cache key of each compiled program: JAX logs each cache miss at DEBUG. The logger is
    # opened to DEBUG for this handler only: a filter hands it the records below the level that passed
    # before and drops them, so no other handler sees more than it did.
    compiler = logging.getLogger("jax._src.compiler")
    passed = compiler.getEffectiveLevel()

    def cache_misses_only(record):
        if record.levelno >= passed:
            return True
        handler.emit(record)
        return False

    compiler.addFilter(cache_misses_only)
    compiler.setLevel(min(passed, logging.DEBUG))
    os.makedirs(folder, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    _state["worker"] = worker
    _state["out"] = open(os.path.join(folder, f"{worker}.jsonl"), "a", encoding="utf-8")
    if worker == "main":  # the xdist controller, or the only process: sample the machine while the run lasts
        _start_machine_sampler(folder)


def _machine_sample() -> dict:
    """The machine's CPU counters now: seconds per state summed over cores (``/proc/stat``), the load
    average, and the CPU seconds of this process's control group (cgroup v1 ``cpuacct``; every process the
    run starts, Ray's daemons included), when readable."""
    ticks = os.sysconf("SC_CLK_TCK")
    with open("/proc/stat", encoding="ascii") as f:
        fields = f.readline().split()[1:]
    names = ("user", "nice", "system", "idle", "iowait", "irq", "softirq", "steal")
    sample = {"t": round(time.time(), 3), **{n: int(v) / ticks for n, v in zip(names, fields)}}
    with open("/proc/loadavg", encoding="ascii") as f:
        sample["load1"] = float(f.read().split()[0])
    try:
        with open("/proc/self/cgroup", encoding="ascii") as f:
            path = next(line.split(":")[2].strip() for line in f if "cpuacct" in line.split(":")[1].split(","))
        if path != "/":  # the root group is the whole machine
            with open(f"/sys/fs/cgroup/cpuacct{path}/cpuacct.usage", encoding="ascii") as f:
                sample["group_cpu_s"] = int(f.read()) / 1e9
    except (OSError, StopIteration, IndexError):
        pass
    return sample


class _RunProcesses:
    """The processes of this run (the controller, the workers and everything they started, Ray's daemons
    included: every process whose environment holds this run's ``JAXDEPTH_SUITE_PROFILE``) and how many
    of their threads are runnable (state ``R``: running or waiting for a core) right now."""

    def __init__(self, folder: str):
        self._mark = f"{ENV}={folder}".encode() + b"\0"
        self._ours = {}  # pid -> bool

    def _is_ours(self, pid: str) -> bool:
        if pid not in self._ours:
            try:
                with open(f"/proc/{pid}/environ", "rb") as f:
                    self._ours[pid] = self._mark in f.read() + b"\0"
            except OSError:
                return False
        return self._ours[pid]

    def runnable(self) -> dict:
        """``{pid: runnable threads}`` of the run's processes that have one."""
        counts, me = {}, str(threading.get_native_id())
        pids = set(filter(str.isdigit, os.listdir("/proc")))
        for gone in set(self._ours) - pids:  # a process id can be reused once its process is gone
            del self._ours[gone]
        for pid in pids:
            if not self._is_ours(pid):
                continue
            try:
                tids = os.listdir(f"/proc/{pid}/task")
            except OSError:
                continue
            for tid in tids:
                try:
                    with open(f"/proc/{pid}/task/{tid}/stat", "rb") as f:
                        state = f.read().rsplit(b")", 1)[1].split()[0]
                except (OSError, IndexError):
                    continue
                if state == b"R" and tid != me:  # not the sampling thread itself
                    counts[pid] = counts.get(pid, 0) + 1
        return counts


def _start_machine_sampler(folder: str, *, every_s: float = 1.0) -> None:
    """Appends a ``_machine_sample`` and the run's runnable threads (``runnable``: per process id, and
    ``names``: each process's command line once) to ``folder/machine.jsonl`` every ``every_s`` seconds
    (a daemon thread of the controller)."""
    processes, named = _RunProcesses(folder), set()

    def run():
        with open(os.path.join(folder, "machine.jsonl"), "a", encoding="utf-8") as out:
            while True:
                sample = _machine_sample()
                sample["runnable"] = processes.runnable()
                for pid in set(sample["runnable"]) - named:
                    named.add(pid)
                    try:
                        with open(f"/proc/{pid}/cmdline", "rb") as f:
                            sample.setdefault("names", {})[pid] = f.read().replace(b"\0", b" ").decode()[:120]
                    except OSError:
                        pass
                out.write(json.dumps(sample) + "\n")
                out.flush()
                time.sleep(every_s)

    threading.Thread(target=run, name="suite_profile_machine", daemon=True).start()


def _child_cpu_s() -> float:
    """User + system seconds of this process's finished (waited-for) subprocesses so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Runs in the process that runs the test (an xdist worker, or the only process)."""
    out = _state["out"]
    if out is None:
        yield
        return
    _state["sums"].clear()
    _state["big"].clear()
    start, cpu, child = time.time(), time.process_time(), _child_cpu_s()
    yield
    record = {"id": item.nodeid, "worker": _state["worker"], "pid": os.getpid(), "start": round(start, 3),
              "wall_s": round(time.time() - start, 3), "cpu_s": round(time.process_time() - cpu, 3),
              "child_cpu_s": round(_child_cpu_s() - child, 3), "slow": item.get_closest_marker("slow") is not None}
    record.update({k: round(v, 3) for k, v in sorted(_state["sums"].items())})
    record["big_compiles"] = list(_state["big"])
    out.write(json.dumps(record) + "\n")
    out.flush()


# ---------------------------------------------------------------------------------------- summary
def load(folder) -> list:
    """Every test record written under ``folder``."""
    records = []
    for path in sorted(glob.glob(os.path.join(folder, "*.jsonl"))):
        if os.path.basename(path) == "machine.jsonl":  # the controller's samples (load_machine)
            continue
        with open(path, encoding="utf-8") as f:
            records += [json.loads(line) for line in f if line.strip()]
    return records


def _module(nodeid: str) -> str:
    return nodeid.split("::")[0]


def _cpu(record: dict) -> float:
    """CPU seconds of a test, its waited-for subprocesses included (0 in profiles from before they were kept)."""
    return record.get("cpu_s", 0.0) + record.get("child_cpu_s", 0.0)


def summarise(records: list, *, top: int = 25) -> dict:
    """Totals, per-worker spans, and the modules, tests and compiled functions that take longest."""
    fields = ("wall_s", "cpu_s", "child_cpu_s", "compile_s", "trace_s", "lower_s", "cache_read_s")
    totals = {k: round(sum(r.get(k, 0.0) for r in records), 1) for k in fields}
    totals.update(tests=len(records), has_cpu=any("cpu_s" in r for r in records),
                  compiles=int(sum(r.get("compile_n", 0) for r in records)),
                  cache_reads=int(sum(r.get("cache_read_n", 0) for r in records)))
    # the quick subset (-m "not slow") and the rest; records of older profiles carry no marker
    if any("slow" in r for r in records):
        totals["subsets"] = {
            name: {"tests": len(part), "cpu_s": round(sum(_cpu(r) for r in part), 1),
                   "compile_s": round(sum(r.get("compile_s", 0.0) for r in part), 1)}
            for name, part in (("quick", [r for r in records if not r.get("slow")]),
                               ("slow", [r for r in records if r.get("slow")]))}
    workers = {}
    for r in records:
        w = workers.setdefault(r["worker"], {"tests": 0, "first_start": r["start"], "last_end": 0.0, "wall_s": 0.0})
        w["tests"] += 1
        w["first_start"] = min(w["first_start"], r["start"])
        w["last_end"] = max(w["last_end"], r["start"] + r["wall_s"])
        w["wall_s"] += r["wall_s"]
    workers = {k: {"tests": v["tests"], "span_s": round(v["last_end"] - v["first_start"], 1),
                   "busy_s": round(v["wall_s"], 1)} for k, v in sorted(workers.items())}
    modules = collections.defaultdict(lambda: [0.0, 0.0, 0, 0.0])
    for r in records:
        m = modules[_module(r["id"])]
        m[0] += r["wall_s"]
        m[1] += r.get("compile_s", 0.0)
        m[2] += 1
        m[3] += _cpu(r)
    by_module = [{"module": k, "wall_s": round(v[0], 1), "cpu_s": round(v[3], 1), "compile_s": round(v[1], 1),
                  "tests": v[2]} for k, v in sorted(modules.items(), key=lambda kv: -kv[1][0])[:top]]
    by_test = [{"test": r["id"], "wall_s": r["wall_s"], "cpu_s": round(_cpu(r), 1),
                "compile_s": round(r.get("compile_s", 0.0), 1), "big_compiles": r["big_compiles"]}
               for r in sorted(records, key=lambda r: -r["wall_s"])[:top]]
    funs = collections.defaultdict(lambda: [0.0, 0])
    same, again = collections.defaultdict(list), collections.defaultdict(list)
    for r in records:
        for name, seconds, *shapes in r["big_compiles"]:
            funs[name][0] += seconds
            funs[name][1] += 1
            if shapes and shapes[0]:
                same[(name, shapes[0])].append({"test": r["id"], "worker": r["worker"], "compile_s": seconds})
            if len(shapes) > 1 and shapes[1]:  # the program's persistent-cache key (profiles since suite4)
                again[shapes[1]].append({"function": name, "test": r["id"], "worker": r["worker"], "compile_s": seconds})
    by_function = [{"function": k, "compile_s": round(v[0], 1), "compiles": v[1]}
                   for k, v in sorted(funs.items(), key=lambda kv: -kv[1][0])[:top]]
    repeated = [{"function": name, "shapes": shapes, "compile_s": round(sum(c["compile_s"] for c in v), 1),
                 "compiles": v} for (name, shapes), v in same.items() if len(v) > 1]
    repeated = sorted(repeated, key=lambda d: -d["compile_s"])[:top]
    # one program (one cache key) compiled twice: by two workers at once, before either had stored it
    twice = [{"key": key, "function": v[0]["function"], "again_s": round(sum(c["compile_s"] for c in v[1:]), 1),
              "compiles": v} for key, v in again.items() if len(v) > 1]
    totals["compiled_again_s"] = round(sum(d["again_s"] for d in twice), 1)
    return {"totals": totals, "workers": workers, "by_module": by_module, "by_test": by_test,
            "by_function": by_function, "same_shapes_compiled_again": repeated,
            "same_program_compiled_again": sorted(twice, key=lambda d: -d["again_s"])[:top]}


def load_machine(folder) -> list:
    """The controller's machine samples (``machine.jsonl``), oldest first; [] for older profiles."""
    path = os.path.join(folder, "machine.jsonl")
    if not os.path.exists(path):
        return []
    with open(path, encoding="utf-8") as f:
        return sorted((json.loads(line) for line in f if line.strip()), key=lambda s: s["t"])


def _running(records: list, t: float) -> list:
    """Ids of the tests running at time ``t`` (one per worker at most)."""
    return [r["id"] for r in records if r["start"] <= t < r["start"] + r["wall_s"]]


def idle(records: list, samples: list, *, cores: int = 2, top: int = 15) -> dict:
    """Where the run leaves cores without work, from the samples' runnable threads of the run's processes
    (its own demand for CPU, which other processes' load does not lower; a waiting or sleeping thread is
    not runnable): the core-seconds below ``cores`` (``idle_core_s``), charged in equal parts to the tests
    running then, ``(between tests)`` for a worker that ran none (collection, start-up, the tail after its
    last test); the spread of the workers' last ends (``tail_s``); the machine's own idle core-seconds and
    load average while it ran; and ``estimated_idle_wall_s``, the run's wall time on ``cores`` otherwise
    idle cores: its CPU seconds over the cores its demand kept busy, ``cpu / (cores - idle_core_s / wall)``."""
    wall = samples[-1]["t"] - samples[0]["t"]
    charged, demand_s, deficit = collections.Counter(), collections.Counter(), 0.0
    n_workers = len({r["worker"] for r in records})
    for a, b in zip(samples, samples[1:]):
        dt, runnable = b["t"] - a["t"], sum(a.get("runnable", {}).values())
        demand_s[min(runnable, cores)] += dt
        short = max(0, cores - runnable) * dt
        deficit += short
        if short:
            running = _running(records, a["t"])
            holders = (running + ["(between tests)"] * (n_workers - len(running))) or ["(between tests)"]
            for test in holders:
                charged[test] += short / len(holders)
    ends = {}
    for r in records:
        ends[r["worker"]] = max(ends.get(r["worker"], 0.0), r["start"] + r["wall_s"])
    first, last = samples[0], samples[-1]
    if "group_cpu_s" in first and "group_cpu_s" in last:
        cpu, source = last["group_cpu_s"] - first["group_cpu_s"], "control group"
    else:
        cpu, source = sum(_cpu(r) for r in records), "tests"
    modules = collections.Counter()
    for test, v in charged.items():
        modules[_module(test)] += v
    return {
        "cores": cores, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "cpu_source": source,
        "first_test_after_s": round(min(r["start"] for r in records) - first["t"], 1) if records else None,
        "idle_core_s": round(deficit, 1),
        "demand_s": {(f"{k} runnable" if k < cores else f">= {cores} runnable"): round(v, 1)
                     for k, v in sorted(demand_s.items())},
        "estimated_idle_wall_s": round(cpu / max(cores - deficit / max(wall, 1e-9), 1e-9), 1),
        "tail_s": round(max(ends.values()) - min(ends.values()), 1) if ends else 0.0,
        "worker_ends_s": {k: round(v - first["t"], 1) for k, v in sorted(ends.items())},
        "machine_idle_core_s": round(last["idle"] + last["iowait"] - first["idle"] - first["iowait"], 1),
        "machine_load1": {"min": min(s["load1"] for s in samples), "max": max(s["load1"] for s in samples),
                          "mean": round(sum(s["load1"] for s in samples) / len(samples), 1)},
        "idle_by_test": [{"test": k, "idle_core_s": round(v, 1)} for k, v in charged.most_common(top)],
        "idle_by_module": [{"module": k, "idle_core_s": round(v, 1)} for k, v in modules.most_common(top)],
    }


def _print_idle(d: dict) -> None:
    print(f"\nthe run's own demand for CPU ({d['cores']} cores, sampled by the controller): {d['wall_s']:.0f} s of wall "
          f"time, {d['cpu_s']:.0f} s of CPU ({d['cpu_source']}); first test after {d['first_test_after_s']} s; "
          f"fewer than {d['cores']} runnable threads for {d['idle_core_s']:.0f} core-seconds "
          f"({', '.join(f'{k}: {v:.0f} s' for k, v in d['demand_s'].items())}); workers end at "
          f"{', '.join(f'{k} {v:.0f} s' for k, v in d['worker_ends_s'].items())} (tail {d['tail_s']:.0f} s); "
          f"on {d['cores']} idle cores about {d['estimated_idle_wall_s']:.0f} s. The machine meanwhile: "
          f"{d['machine_idle_core_s']:.0f} idle core-seconds, load average {d['machine_load1']}")
    print("idle core-seconds while these ran (shared by the tests running then)")
    for r in d["idle_by_test"]:
        print(f"  {r['idle_core_s']:7.1f}  {r['test']}")


def compile_cost(*, repeats: int = 3) -> dict:
    """Wall and CPU seconds (medians) to compile ``jaxdepth.complete`` on a 32 x 48 frame, the
    persistent compilation cache off: what one whole-pipeline program costs the suite."""
    import jax
    import numpy as np

    import jaxdepth
    jax.config.update("jax_enable_compilation_cache", False)
    rng = np.random.default_rng(0)
    sparse = np.where(rng.random((32, 48)) < 0.05, rng.uniform(5.0, 50.0, (32, 48)), 0.0).astype(np.float32)
    K = np.array([[48.0, 0.0, 24.0], [0.0, 48.0, 16.0], [0.0, 0.0, 1.0]], np.float32)
    walls, cpus = [], []
    for _ in range(repeats):
        jax.clear_caches()
        lowered = jax.jit(lambda s, k: jaxdepth.complete(s, k)).lower(sparse, K)
        cpu0, wall0 = time.process_time(), time.perf_counter()
        lowered.compile()
        walls.append(time.perf_counter() - wall0)
        cpus.append(time.process_time() - cpu0)
    return {"program": "jaxdepth.complete, 32 x 48, default configuration", "repeats": repeats,
            "compile_wall_s": round(float(np.median(walls)), 2), "compile_cpu_s": round(float(np.median(cpus)), 2)}


def _print(summary: dict) -> None:
    t = summary["totals"]
    cpu = (f" ({t['cpu_s'] + t['child_cpu_s']:.0f} s of CPU, {t['child_cpu_s']:.0f} s of it in subprocesses)"
           if t.get("has_cpu") else " (no CPU times: a profile from before they were recorded)")
    print(f"{t['tests']} tests, {t['wall_s']:.0f} s of test time over all workers{cpu}: XLA compiling {t['compile_s']:.0f} s "
          f"({t['compiles']} compiles), tracing {t['trace_s']:.0f} s, lowering {t['lower_s']:.0f} s, "
          f"cache reads {t['cache_read_s']:.0f} s ({t['cache_reads']} programs read back)")
    for name, part in t.get("subsets", {}).items():
        print(f"  {name} tests: {part['tests']}, {part['cpu_s']:.0f} s of CPU, XLA compiling {part['compile_s']:.0f} s")
    for name, w in summary["workers"].items():
        print(f"  {name}: {w['tests']} tests, busy {w['busy_s']:.0f} s over a span of {w['span_s']:.0f} s")
    print("\nmodules (wall s, CPU s, compile s, tests)")
    for m in summary["by_module"]:
        print(f"  {m['wall_s']:7.1f} {m['cpu_s']:7.1f} {m['compile_s']:7.1f} {m['tests']:5d}  {m['module']}")
    print(f"\ntests (wall s, CPU s, compile s, listed compiles: {_LISTED})")
    for r in summary["by_test"]:
        big = " ".join(f"{n}:{s}" for n, s, *_ in r["big_compiles"][:4])
        print(f"  {r['wall_s']:7.1f} {r['cpu_s']:7.1f} {r['compile_s']:7.1f}  {r['test']}  {big}")
    print(f"\ncompiled functions (compile s, listed compiles: {_LISTED})")
    for f in summary["by_function"]:
        print(f"  {f['compile_s']:7.1f} {f['compiles']:5d}  {f['function']}")
    print("\none function name compiled more than once with the same argument shapes (compile s): other\n"
          "static options (a property of their own), another function of that name (a frozen oracle), or one\n"
          "program compiled twice (by two workers at once, or after the compiled programs were dropped)")
    for f in summary["same_shapes_compiled_again"]:
        print(f"  {f['compile_s']:7.1f}  {f['function']} {f['shapes']}")
        for c in f["compiles"]:
            print(f"  {c['compile_s']:13.1f}  {c['worker']}  {c['test']}")
    print(f"\none program (one persistent-cache key) compiled more than once: {t.get('compiled_again_s', 0):.0f} s "
          "of compiling after the first (seconds after the first; then each compile)")
    for f in summary.get("same_program_compiled_again", []):
        print(f"  {f['again_s']:7.1f}  {f['function']} {f['key']}")
        for c in f["compiles"]:
            print(f"  {c['compile_s']:13.1f}  {c['worker']}  {c['test']}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Summarise a suite profile recorded with -p benchmarks.suite_profile.")
    parser.add_argument("folder", help=f"the folder {ENV} named while the suite ran")
    parser.add_argument("--compile-cost", action="store_true",
                        help="also time one compile of the 32 x 48 pipeline here (wall and CPU seconds)")
    parser.add_argument("--top", type=int, default=25, help="rows per table (default 25)")
    parser.add_argument("--cores", type=int, default=os.cpu_count(),
                        help="cores the idle estimate assumes (default: this machine's)")
    parser.add_argument("--json", nargs="?", const=str(pathlib.Path(__file__).parent / "results" / "suite_profile.json"),
                        default=None, metavar="PATH", help="also write the summary (default results/suite_profile.json)")
    args = parser.parse_args(argv)
    t0 = time.time()
    records = load(args.folder)
    if not records:
        print(f"suite_profile: no test records in {args.folder} (run pytest with {ENV} set and "
              "-p benchmarks.suite_profile)", file=sys.stderr)
        return 1
    summary = summarise(records, top=args.top)
    _print(summary)
    samples = [sample for sample in load_machine(args.folder) if "runnable" in sample]
    if len(samples) > 1:  # profiles from before the controller sampled the run's threads have none
        summary["idle"] = idle(records, samples, cores=args.cores, top=args.top)
        _print_idle(summary["idle"])
    if args.compile_cost:
        summary["pipeline_compile"] = cost = compile_cost()
        print(f"\none pipeline program ({cost['program']}): compiled in {cost['compile_wall_s']} s of wall time, "
              f"{cost['compile_cpu_s']} s of CPU time (medians of {cost['repeats']})")
    if args.json:
        from benchmarks._common import write_results
        write_results(args.json, {"command": "JAXDEPTH_SUITE_PROFILE=DIR python -m pytest -q -p benchmarks.suite_profile; "
                                             "python -m benchmarks.suite_profile DIR --compile-cost --json",
                                  **summary}, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
