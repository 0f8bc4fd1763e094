"""XLA:CPU compile options against compile time, run time and output bytes, each in a fresh process.

For every option set (``XLA_FLAGS`` of the child process; ``default`` = none) and every program, a
fresh child process with JAX's persistent cache off:

* traces, lowers and compiles the program once, timed through ``jax.monitoring`` (wall seconds of
  the trace, the lowering and XLA's backend compile, and the process CPU seconds during the compile);
* runs it ``--runs`` times more (medians, ``block_until_ready`` before the clock is read);
* hashes the output (SHA-256 of the float32 depth bytes): equal hashes = the option changes no byte;
* with ``--hlo``, counts the optimised HLO of the program (``compiled.as_text()``: instructions,
  fusions, while loops, conditionals, computations).

Programs: ``kitti`` (``jax.jit(complete)`` on camera 2 of the shared KITTI frame, 352 x 1216: what
``jaxdepth complete`` compiles per frame size, without the runner's batch axis) and ``av2``
(``jaxdepth.batch.sources_job.complete_cloud`` on the shared Argoverse 2 log's first sweep at LiDAR
time: two VLP-32C, 7 ring cameras, the program ``jaxdepth complete LOG OUT --lidar-time`` compiles) and
``tiny`` (``jax.jit(complete)`` on a 32 x 48 crop of the KITTI frame: the test suite's size).
Ratios are against the ``default`` row of the same run (the machine is shared: compare only within one
run, read the CPU column).

    python -m benchmarks.bench_compile_flags [--programs kitti av2] [--sets default o1 ...] [--runs 3]
        [--hlo] [--json benchmarks/results/compile_flags.json]
    python -m benchmarks.bench_compile_flags --anatomy 3 [--programs kitti av2]
        --json benchmarks/results/compile_anatomy.json
    python -m benchmarks.bench_compile_flags --trees this=. main=/work/main [--rounds 3] [--programs kitti]
        --json benchmarks/results/compile_trees.json

``--anatomy DEPTH`` instead dumps the default compile (``--xla_dump_to``) and groups the program's
kernels (XLA:CPU compiles each fusion as an LLVM module of its own) by the first DEPTH parts of their
HLO ``op_name``: where the code that LLVM compiles comes from. ``--trees NAME=PATH ...`` instead compiles
each program with the default options against each checkout's ``jaxdepth`` (linked, with these benchmarks,
into a folder first on the child's path), checkouts interleaved over ``--rounds``: a code change's compile
cost against a baseline.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from benchmarks._common import DATA, RESULTS, write_results

#: Option sets measured (name -> XLA_FLAGS). Flags that exist in jax 0.10.2's jaxlib (names read from
#: the library's strings; an unknown flag aborts the process).
SETS = {
    "default": "",
    "o0": "--xla_backend_optimization_level=0",
    "o1": "--xla_backend_optimization_level=1",
    "o2": "--xla_backend_optimization_level=2",
    "no_expensive_llvm": "--xla_llvm_disable_expensive_passes=true",
    "split1": "--xla_cpu_parallel_codegen_split_count=1",
    "split2": "--xla_cpu_parallel_codegen_split_count=2",
    "split64": "--xla_cpu_parallel_codegen_split_count=64",
    "no_fusion_emitters": "--xla_cpu_use_fusion_emitters=false",
    "no_region_copy": "--xla_cpu_copy_insertion_use_region_analysis=false",
    "concurrency_sched": "--xla_cpu_enable_concurrency_optimized_scheduler=true",
    "no_xnn": "--xla_cpu_use_xnnpack=false",
    "vec128": "--xla_cpu_prefer_vector_width=128",
    # XLA:CPU's own backend options (not flags of their own in this jaxlib) and LLVM options: keys of
    # --xla_backend_extra_options; keys not starting with xla_ are passed to LLVM's command line.
    "no_unroll": "--xla_backend_extra_options=xla_cpu_disable_loop_unrolling",
    "no_slp": "--xla_backend_extra_options=xla_cpu_disable_slp_vectorizer",
    "size": "--xla_backend_extra_options=xla_cpu_optimize_for_size",
    "fast_isel": "--xla_backend_extra_options=-fast-isel",
    "no_misched": "--xla_backend_extra_options=-enable-misched=false,-enable-post-misched=false",
    "no_unroll_slp": "--xla_backend_extra_options=xla_cpu_disable_loop_unrolling,xla_cpu_disable_slp_vectorizer",
}
PROGRAMS = ("kitti", "av2", "tiny")
AV2_LOG = DATA / "av2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"


def _cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime


def _kitti():
    """(call, jitted, args): the single-frame program on the shared frame's camera 2."""
    import jax

    import jaxdepth
    from benchmarks._common import load_frame
    sparse, K, T, _ = load_frame()
    fn = jax.jit(jaxdepth.complete)
    return (lambda: fn(sparse, K, T)), fn, (sparse, K, T)


def _tiny():
    """(call, jitted, args): ``jax.jit(complete)`` on a 32 x 48 crop of the shared frame (the test suite's size)."""
    import jax

    import jaxdepth
    from benchmarks._common import load_frame
    sparse, K, T, _ = load_frame()
    K = K.copy()
    K[0, 2] -= 584
    K[1, 2] -= 300
    sparse = sparse[300:332, 584:632].copy()
    fn = jax.jit(jaxdepth.complete)
    return (lambda: fn(sparse, K, T)), fn, (sparse, K, T)


def _av2():
    """(call, None, None): the Argoverse 2 job's program on the shared log's first sweep, LiDAR time."""
    from jaxdepth.batch.sources_job import complete_cloud
    from jaxdepth.io import av2
    log_ = av2.read_log(AV2_LOG)
    rig = av2.read_rig(log_, av2.RING_CAMERAS)
    cloud = av2.read_cloud(log_, None, sweeps=0)
    return (lambda: complete_cloud(cloud, rig, free_space=True)), None, None


def _hlo_counts(text: str) -> dict:
    lines = text.splitlines()
    body = [ln for ln in lines if " = " in ln and not ln.lstrip().startswith(("HloModule", "//"))]
    return {"instructions": len(body),
            "fusion_instructions": sum(" fusion(" in ln for ln in body),
            "computations": sum(ln.rstrip().endswith("{") for ln in lines),
            "while": sum(" while(" in ln for ln in body),
            "conditional": sum(" conditional(" in ln for ln in body),
            "bytes": len(text)}


def child(program: str, runs: int, hlo: bool) -> dict:
    import jax
    import numpy as np

    from benchmarks.bench_coldstart_profile import record_compile_steps

    jax.config.update("jax_enable_compilation_cache", False)
    events, last = record_compile_steps(time.perf_counter())
    call, fn, args = {"kitti": _kitti, "av2": _av2, "tiny": _tiny}[program]()
    last["cpu"] = _cpu()
    t0, c0 = time.perf_counter(), _cpu()
    out = jax.block_until_ready(call())
    first = {"wall_s": time.perf_counter() - t0, "cpu_s": _cpu() - c0}
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        again = jax.block_until_ready(call())
        times.append(time.perf_counter() - t)
    digest = hashlib.sha256(np.ascontiguousarray(np.asarray(out, np.float32)).tobytes()).hexdigest()
    same = all(np.array_equal(np.asarray(again), np.asarray(out)) for _ in [0])
    big = max((e for e in events if e["step"] == "compile"), key=lambda e: e["wall_s"])
    doc = {"first_call": first, "run_s": times, "run_median_s": statistics.median(times), "sha256": digest,
           "repeat_identical": bool(same), "main_program": big["program"],
           "compile_wall_s": big["wall_s"], "compile_cpu_s": big["cpu_s_since_previous_event"],
           "trace_wall_s": sum(e["wall_s"] for e in events if e["step"] == "trace"),
           "lower_wall_s": sum(e["wall_s"] for e in events if e["step"] == "lower"),
           "all_compiles_wall_s": sum(e["wall_s"] for e in events if e["step"] == "compile"),
           "programs_compiled": len([e for e in events if e["step"] == "compile"])}
    if hlo and fn is not None:
        doc["hlo"] = _hlo_counts(fn.lower(*args).compile().as_text())
    return doc


def _seconds(text: str) -> float:
    value, unit = text.split()[:2]
    return float(value) * {"us": 1e-6, "ms": 1e-3, "s": 1.0, "min": 60.0}[unit]


def _module_name(fun_name: str) -> str:
    """XLA's module name of a jitted program: ``jit(f)`` (JAX's ``fun_name``) -> ``jit_f``."""
    inner = re.fullmatch(r"jit\((.*)\)", fun_name)
    return f"jit_{inner.group(1)}" if inner else fun_name


def _xla_phases(stderr: str, module: str) -> dict:
    """XLA:CPU's logged timers for ``module``: HLO passes and the backend (LLVM code generation), wall s."""
    out = {}
    for key, pattern in (("hlo_passes", rf"Running HLO passes on \[{module}\] for CPU time: ([0-9.]+ \w+)"),
                         ("backend", rf"Compiling \[{module}\] for CPU using JIT time: ([0-9.]+ \w+)")):
        found = re.findall(pattern, stderr)
        if found:
            out[key] = _seconds(found[0])
    return out


def run_one(program: str, flags: str, *, runs: int, hlo: bool, tree: str | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAXDEPTH_COMPILE"))}
    env["XLA_FLAGS"] = flags
    if tree:    # that checkout's jaxdepth, this checkout's benchmarks: both linked into one folder, first on the path
        folder = tempfile.mkdtemp(prefix="jaxdepth-tree-")
        os.symlink(os.path.join(tree, "jaxdepth"), os.path.join(folder, "jaxdepth"))
        os.symlink(os.path.dirname(os.path.abspath(__file__)), os.path.join(folder, "benchmarks"))
        env["PYTHONPATH"] = tree = folder
    env["TF_CPP_MIN_LOG_LEVEL"] = "0"               # XLA's own timers of its two phases (wall seconds)
    env["TF_CPP_VMODULE"] = "cpu_compiler=1"
    u0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "benchmarks.bench_compile_flags", "--child", program, str(runs),
                           "1" if hlo else "0"], env=env, capture_output=True, text=True, cwd=tree)
    wall = time.perf_counter() - start
    u1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        return {"flags": flags, "error": done.stderr.strip().splitlines()[-1:] if done.stderr else done.returncode}
    doc = json.loads(done.stdout.strip().splitlines()[-1])
    doc["flags"] = flags
    doc["xla_phases_wall_s"] = _xla_phases(done.stderr, _module_name(doc["main_program"]))
    doc["process"] = {"wall_s": wall, "cpu_s": (u1.ru_utime + u1.ru_stime) - (u0.ru_utime + u0.ru_stime)}
    return doc


def anatomy(program: str, depth: int, *, runs: int = 1) -> dict:
    """The compiled program's kernels (one LLVM module each) grouped by the first ``depth`` parts of their
    HLO ``op_name`` (the jitted functions, vmaps, loops and branches they come from; of nested jit
    wrappers only the innermost counts): count and bytes of optimised LLVM IR per group, from an
    ``--xla_dump_to`` dump in a temporary folder (default flags)."""
    import collections
    import glob
    import tempfile
    with tempfile.TemporaryDirectory(prefix="jaxdepth-anatomy-") as tmp:
        doc = run_one(program, f"--xla_dump_to={tmp} --xla_dump_hlo_as_text", runs=runs, hlo=False)
        name = _module_name(doc["main_program"])
        hlo = open(glob.glob(f"{tmp}/*.{name}.cpu_after_optimizations.txt")[0]).read()
        op_names = dict(re.findall(r'^\s*(?:ROOT )?%([\w.\-]+) = .*?metadata=\{op_name="([^"]*)"', hlo, re.M))
        groups = collections.defaultdict(lambda: [0, 0])
        for path in glob.glob(f"{tmp}/*.{name}.*ir-with-opt.ll"):
            kernel = re.sub(r"^module_\d+\.[\w]+\.", "", os.path.basename(path))
            kernel = kernel.replace(".ir-with-opt.ll", "").replace("__compute_module_", "").replace("_kernel_module", "")
            parts = op_names.get(kernel, "(no op_name)").split("/")
            while len(parts) > 1 and parts[0].startswith("jit(") and parts[1].startswith("jit("):
                parts.pop(0)                        # nested jit wrappers: keep the innermost
            parts = parts[:depth]
            groups["/".join(parts)][0] += 1
            groups["/".join(parts)][1] += os.path.getsize(path)
    total = sum(b for _, b in groups.values())
    rows = sorted(({"group": k, "kernels": n, "ir_bytes": b, "ir_share": b / total} for k, (n, b) in groups.items()),
                  key=lambda r: -r["ir_bytes"])
    return {"program": name, "kernels": sum(r["kernels"] for r in rows), "ir_bytes": total, "groups": rows,
            "xla_phases_wall_s": doc.get("xla_phases_wall_s"), "compile_cpu_s_with_dump": doc.get("compile_cpu_s"),
            "sha256": doc.get("sha256")}


def compare_trees(args) -> int:
    """The default compile of each program in each checkout, a fresh process per compile, checkouts
    interleaved (order alternating by round); medians of the compile CPU seconds and run seconds."""
    t0, trees = time.time(), dict(item.split("=", 1) for item in args.trees)
    out = {}
    for program in args.programs:
        rows = out.setdefault(program, {name: [] for name in trees})
        for r in range(args.rounds):
            for name in (list(trees) if r % 2 == 0 else list(trees)[::-1]):
                doc = run_one(program, "", runs=args.runs, hlo=False, tree=os.path.abspath(trees[name]))
                rows[name].append(doc)
                print(f"{program} {name} round {r}: " + (f"failed: {doc['error']}" if "error" in doc else
                      f"compile {doc['compile_cpu_s']:.1f} s CPU, run {doc['run_median_s'] * 1e3:.0f} ms, "
                      f"sha256 {doc['sha256'][:12]}"), flush=True)
    medians = {p: {name: {k: statistics.median(d[k] for d in docs if "error" not in d)
                          for k in ("compile_cpu_s", "compile_wall_s", "trace_wall_s", "run_median_s")}
                   | {"sha256": sorted({d.get("sha256") for d in docs})}
                   for name, docs in rows.items()} for p, rows in out.items()}
    for p, m in medians.items():
        print(p, {name: {k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}
                  for name, row in m.items()})
    write_results(args.json, {"what": "default compile per checkout (fresh process each, persistent cache off), "
                                      "medians over interleaved rounds", "trees": trees, "medians": medians,
                              "rounds": out}, None, t0)
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--child":
        print(json.dumps(child(argv[1], int(argv[2]), argv[3] == "1")))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--programs", nargs="+", default=["kitti", "av2"], choices=PROGRAMS)
    parser.add_argument("--sets", nargs="+", default=list(SETS), choices=list(SETS))
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--hlo", action="store_true", help="count the optimised HLO (kitti only; one more compile)")
    parser.add_argument("--anatomy", type=int, metavar="DEPTH", default=0,
                        help="instead: the default compile's kernels by op_name prefix of DEPTH parts")
    parser.add_argument("--trees", nargs="+", metavar="NAME=PATH", default=None,
                        help="instead: the default compile of each checkout (e.g. this=. main=/work/main), "
                             "interleaved over --rounds")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", default=str(RESULTS / "compile_flags.json"))
    args = parser.parse_args(argv)
    if args.trees:
        return compare_trees(args)
    t0 = time.time()
    if args.anatomy:
        out = {p: anatomy(p, args.anatomy) for p in args.programs}
        for p, doc in out.items():
            print(f"{p}: {doc['program']} {doc['kernels']} kernels, {doc['ir_bytes'] / 1e6:.1f} MB optimised IR")
            for r in doc["groups"][:15]:
                print(f"  {r['kernels']:4d} kernels {r['ir_share']:6.1%}  {r['group']}")
        write_results(args.json, {"what": "kernels of the compiled program by op_name prefix (optimised LLVM IR)",
                                  "depth": args.anatomy, "programs": out}, None, t0)
        return 0
    out = {}
    for program in args.programs:
        rows = out.setdefault(program, {})
        for name in args.sets:
            doc = run_one(program, SETS[name], runs=args.runs, hlo=args.hlo)
            rows[name] = doc
            if "error" in doc:
                print(f"{program} {name}: failed: {doc['error']}", flush=True)
                continue
            base = rows.get("default", doc)
            print(f"{program} {name}: compile {doc['compile_wall_s']:.1f} s wall / {doc['compile_cpu_s']:.1f} s CPU "
                  f"({doc['compile_cpu_s'] / base['compile_cpu_s']:.2f}x), run {doc['run_median_s'] * 1e3:.0f} ms "
                  f"({doc['run_median_s'] / base['run_median_s']:.2f}x), trace {doc['trace_wall_s']:.1f} s, "
                  f"lower {doc['lower_wall_s']:.1f} s, bytes {'same' if doc['sha256'] == base['sha256'] else 'DIFFER'}"
                  + f", XLA phases {doc['xla_phases_wall_s']}" + (f", hlo {doc['hlo']}" if "hlo" in doc else ""),
                  flush=True)
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    write_results(args.json, {"what": "XLA:CPU options: compile time, run time, output bytes; fresh process each",
                              "sets": {k: SETS[k] for k in args.sets}, "load_average": load, "programs": out},
                  None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
