"""Where a cold first sweep / frame goes: imports, reading, tracing, lowering, XLA compile per program, the run, writes.

Each case is a fresh ``jaxdepth`` command run inside a child process (``jaxdepth.cli.main``, so the
CLI's own start-up: device split, compile cache, progress) with a compile cache folder of its own
(``XDG_CACHE_HOME`` in a temporary folder: empty, or ``--warm``: filled by a first run of the same
command). The child registers ``jax.monitoring`` listeners before the command starts and records,
for every jitted program, its trace (``jaxpr_trace_duration``), lowering (``jaxpr_to_mlir_module``) and
backend compile / cache load (``backend_compile_duration``), each with the process CPU seconds spent
meanwhile (``getrusage``: every thread, so reader threads running beside a compile count too), the
persistent cache's hits and misses, the files in the cache folder afterwards (their bytes), and the size of each lowered module (StableHLO text written by
``jax_dump_ir_to``: lines and bytes; the dump itself costs a little of the lowering time). Reading
(the job's loader) and PNG writes (``jaxdepth.batch.extras.write_outputs``) are timed by wrapping them.
``demand``: the child's idle estimate and its CPU seconds while at most one thread wanted a core
(:class:`benchmarks.bench_compile_threads.Demand`, sampled every 50 ms from the imports to the end). The import of ``jaxdepth.cli`` and of JAX is timed apart; the interpreter's own start is the
parent's wall time minus the child's.

Cases: ``av2`` (``complete LOG OUT --lidar-time``, the shared Argoverse 2 log cut to its first sweep:
two VLP-32C, 7 ring cameras), ``av2-nearest`` (the same with ``--method nearest``), ``kitti`` (``complete SRC OUT``, a one-frame depth-completion folder of
the shared frame), ``nuscenes`` (``complete-rig SWEEP RIG OUT``, the shared sample, 6 cameras).

    python -m benchmarks.bench_coldstart_profile [--cases av2 av2-nearest kitti nuscenes] [--warm]
        [--json benchmarks/results/coldstart_profile.json]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import subprocess
import sys
import tempfile
import time

from benchmarks._common import DATA, RESULTS, write_results

CASES = ("av2", "av2-nearest", "kitti", "nuscenes")


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _command(case: str, tmp: pathlib.Path, out: pathlib.Path) -> list:
    """The ``jaxdepth`` arguments of ``case``, its inputs made in ``tmp`` (once)."""
    if case in ("av2", "av2-nearest"):
        from benchmarks.bench_av2_coldstart import LOG, _log_of
        log = tmp / "one" / LOG.name
        if not log.exists():
            _log_of(tmp / "one", sorted((LOG / "sensors" / "lidar").glob("*.feather"))[:1])
        method = ["--method", "nearest"] if case == "av2-nearest" else []
        return ["complete", str(log), str(out), "--lidar-time", *method, "-q"]
    if case == "kitti":
        from benchmarks.bench_offline_job import build_folder
        src = tmp / "kitti_src"
        if not src.exists():
            built = build_folder(tmp / "kitti_build", 1)
            built.rename(src)
        return ["complete", str(src), str(out), "-q"]
    if case == "nuscenes":
        from jaxdepth.io import rig_from_nuscenes_calibration, write_rig_json
        sample = DATA / "nuscenes" / "sample"
        rig = tmp / "rig.json"
        if not rig.exists():
            write_rig_json(rig, rig_from_nuscenes_calibration(sample / "calibration.json"))
        sweep = sorted(sample.glob("*LIDAR_TOP*.pcd.bin"))[0]
        return ["complete-rig", str(sweep), str(rig), str(out), "-q"]
    raise SystemExit(f"unknown case {case!r}; expected one of {CASES}")


def _wrap(module, name: str, bucket: list) -> None:
    """Replaces ``module.name`` by a wrapper that appends (wall s) of each call to ``bucket``."""
    fn = getattr(module, name)

    def timed(*args, **kwargs):
        start = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            bucket.append(time.perf_counter() - start)

    setattr(module, name, timed)


def record_compile_steps(t0: float) -> tuple[list, dict]:
    """Registers a ``jax.monitoring`` listener that appends every program's trace, lowering and XLA compile
    (or cache load) to the returned list: step, program (JAX's ``fun_name``), wall seconds, the process CPU
    seconds since the previous event (or since ``last["cpu"]``, the returned dict's entry, when a caller
    resets it) and the time since ``t0`` (``time.perf_counter``)."""
    import jax.monitoring
    events = []
    names = {"/jax/core/compile/jaxpr_trace_duration": "trace",
             "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
             "/jax/core/compile/backend_compile_duration": "compile"}
    last = {"cpu": _cpu()}

    def on_duration(event, secs, **kwargs):
        if event in names:
            now = _cpu()
            events.append({"step": names[event], "program": kwargs.get("fun_name", "?"), "wall_s": secs,
                           "cpu_s_since_previous_event": now - last["cpu"], "at_s": time.perf_counter() - t0})
            last["cpu"] = now

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    return events, last


def child(argv: list, ir_dir: str, report: str) -> int:
    """Runs ``jaxdepth`` ``argv`` in this process and writes the profile to ``report`` (JSON)."""
    from benchmarks.bench_compile_threads import Demand
    demand = Demand()
    t0, c0 = time.perf_counter(), _cpu()
    import jaxdepth.cli as cli
    t_cli, c_cli = time.perf_counter(), _cpu()
    import jax
    import jax.monitoring
    t_jax, c_jax = time.perf_counter(), _cpu()
    jax.config.update("jax_dump_ir_to", ir_dir)
    jax.config.update("jax_dump_ir_modes", "stablehlo")
    events, _ = record_compile_steps(t0)
    counts = {}

    def on_event(event, **kwargs):
        if event.startswith("/jax/compilation_cache/"):
            key = event.rsplit("/", 1)[1]
            counts[key] = counts.get(key, 0) + 1

    jax.monitoring.register_event_listener(on_event)
    from jaxdepth.batch import av2_job, extras, nuscenes_job, rig_job, runner
    reads, writes = [], []
    for module, name in ((av2_job, "_load"), (nuscenes_job, "_load"), (runner, "_load"), (rig_job, "prepare_rig_sweep")):
        if hasattr(module, name):
            _wrap(module, name, reads)
    _wrap(extras, "write_outputs", writes)
    t1, c1 = time.perf_counter(), _cpu()
    code = cli.main(argv)
    t2, c2 = time.perf_counter(), _cpu()
    modules = {}
    for path in sorted(pathlib.Path(ir_dir).glob("*.mlir")):
        text = path.read_text(errors="replace")
        modules[path.name] = {"lines": text.count("\n"), "bytes": len(text)}
    doc = {"exit": code, "import_cli": {"wall_s": t_cli - t0, "cpu_s": c_cli - c0},
           "import_jax": {"wall_s": t_jax - t_cli, "cpu_s": c_jax - c_cli},
           "command": {"wall_s": t2 - t1, "cpu_s": c2 - c1}, "events": events, "cache_events": counts,
           "reads_wall_s": reads, "writes_wall_s": writes, "lowered_modules": modules, "demand": demand.stop()}
    pathlib.Path(report).write_text(json.dumps(doc, indent=1))
    return 0


def _summary(doc: dict) -> dict:
    """Per step: total wall / CPU seconds; per program: trace, lower, compile wall seconds."""
    steps, programs = {}, {}
    for e in doc["events"]:
        s = steps.setdefault(e["step"], {"wall_s": 0.0, "cpu_s": 0.0, "count": 0})
        s["wall_s"] += e["wall_s"]
        s["cpu_s"] += e["cpu_s_since_previous_event"]
        s["count"] += 1
        p = programs.setdefault(e["program"], {})
        p[e["step"] + "_wall_s"] = p.get(e["step"] + "_wall_s", 0.0) + e["wall_s"]
    return {"steps": steps, "programs": programs}


def run_case(case: str, tmp: pathlib.Path, *, warm: bool) -> dict:
    cache = tmp / f"cache_{case}"
    out = tmp / f"out_{case}"
    argv = _command(case, tmp, out)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAXDEPTH_COMPILE"))}
    env["XDG_CACHE_HOME"] = str(cache)
    if warm:   # fill the cache with the same command first (its outputs apart)
        subprocess.run([sys.executable, "-m", "jaxdepth.cli", *argv[:-2], str(tmp / f"fill_{case}"), "-q"]
                       if argv[0] == "complete-rig" else
                       [sys.executable, "-m", "jaxdepth.cli", argv[0], argv[1], str(tmp / f"fill_{case}"), *argv[3:]],
                       env=env, check=True, capture_output=True)
    ir_dir = tmp / f"ir_{case}_{'warm' if warm else 'cold'}"
    ir_dir.mkdir()
    report = tmp / f"report_{case}.json"
    usage0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "benchmarks.bench_coldstart_profile", "--child", str(ir_dir),
                           str(report), "--", *argv], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    usage1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{case}: child failed:\n{done.stderr[-3000:]}")
    doc = json.loads(report.read_text())
    doc["process"] = {"wall_s": wall, "cpu_s": (usage1.ru_utime + usage1.ru_stime) - (usage0.ru_utime + usage0.ru_stime)}
    doc["interpreter_start_wall_s"] = wall - sum(doc[k]["wall_s"] for k in ("import_cli", "import_jax", "command"))
    doc["summary"] = _summary(doc)
    doc["argv"] = argv
    doc["cache_files_bytes"] = {str(f.relative_to(cache)): f.stat().st_size
                                for f in sorted(cache.rglob("*")) if f.is_file()}
    return doc


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--child":
        return child(argv[4:], argv[1], argv[2])
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["av2", "kitti", "nuscenes"], choices=CASES)
    parser.add_argument("--warm", action="store_true", help="a cache filled by the same command first")
    parser.add_argument("--json", default=str(RESULTS / "coldstart_profile.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    out = {}
    with tempfile.TemporaryDirectory(prefix="jaxdepth-coldprofile-") as tmp:
        for case in args.cases:
            doc = run_case(case, pathlib.Path(tmp), warm=args.warm)
            out[case] = doc
            s = doc["summary"]["steps"]
            print(f"{case}: process {doc['process']['wall_s']:.1f} s wall / {doc['process']['cpu_s']:.1f} s CPU; "
                  + ", ".join(f"{k} {v['wall_s']:.1f} s ({v['count']})" for k, v in s.items())
                  + f"; cache {doc['cache_events']}; demand "
                  + ", ".join(f"{k} {v:.1f}" for k, v in doc["demand"].items()), flush=True)
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    write_results(args.json, {"what": "cold (or --warm) first sweep / frame, stage by stage", "warm": args.warm,
                              "load_average": load, "cases": out}, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
