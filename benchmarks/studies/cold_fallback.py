"""Study (issue 38): the cold first KITTI frame with ``pixel_normals``' never-run dense fallback (main)
against a probe without it, each a fresh ``jaxdepth complete`` process with empty caches.

Each round runs ``jaxdepth complete SRC OUT -q`` on a one-frame KITTI depth-completion folder of the
shared frame (``bench_offline_job.build_folder``) twice, once per variant, order alternating, each in a
fresh child process with its own empty ``XDG_CACHE_HOME`` (so JAX's persistent compile cache and the
CLI's program cache are both empty; ``JAX_COMPILATION_CACHE*`` / ``JAXDEPTH_COMPILE*`` variables are
dropped). ``probe`` (measurement only, not a library change) replaces ``pixel_normals``' module-level
``cond_all`` by a call of its true branch, at trace time: the listed path alone, exact whenever a frame
fits (the shared frame does). Recorded per run: wall seconds of the whole process, its CPU seconds
(``RUSAGE_CHILDREN``), the child's *idle estimate* (:class:`benchmarks.bench_compile_threads.Demand`
from before its imports to the end: the wall time the same work would take on an idle 2-core machine, as
``bench_coldstart_profile``'s), its trace / lower / compile CPU seconds (``jax.monitoring``, CPU since the
previous event), the SHA-256 of the output PNGs and the load average. ``--fingerprint``: ``output_fingerprint
--check`` (every output on the shared data, the CLI's KITTI jobs included) made by the probe, against main's
committed hashes.

    python -m benchmarks.studies.cold_fallback [--rounds 3] [--json PATH]
    python -m benchmarks.studies.cold_fallback --fingerprint   # output_fingerprint --check with the probe
    python -m benchmarks.studies.cold_fallback --run [ROUNDS]  # run time of jit(complete), main and probe
    python -m benchmarks.studies.cold_fallback --job [--rounds 3]  # main's job against the listed job (coldjob)

``--job`` (branch coldjob, after the jobs got their listed program, :mod:`jaxdepth.batch.listed`): variants
``main`` (the job made to run the full program, as main did: ``listed_only=None`` forced into the runner's
``_group_call``) and ``job`` (the job as it is), results in ``results/cold_job.json``. Without ``--job``,
``main`` is the job as it is (since coldjob: listed) and ``probe`` patches what the job no longer runs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pathlib
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from benchmarks._common import RESULTS, write_results

VARIANTS = ("main", "probe")
KEYS = ("wall_s", "cpu_s", "idle_estimate_s")


def _probe() -> None:
    """The listed branch only, at trace time (no dense fallback: exact whenever a frame fits)."""
    from jaxdepth._src import pixel_normals
    pixel_normals.cond_all = lambda pred, true_fn, false_fn, *ops: true_fn(*ops)


def _full_program_job() -> None:
    """The job with main's full program (dense fallback inside), as before branch coldjob."""
    from jaxdepth.batch import runner
    real = runner._group_call
    runner._group_call = lambda key, items, **kw: real(key, items, **{**kw, "listed_only": None})


def _child(variant: str, report: str, argv: list) -> int:
    from benchmarks.bench_compile_threads import Demand
    demand = Demand()      # from before the imports, as bench_coldstart_profile's child
    from benchmarks.bench_coldstart_profile import record_compile_steps
    from jaxdepth.cli import main
    events, _ = record_compile_steps(time.perf_counter())
    if variant == "probe":
        _probe()
    elif variant == "main" and os.environ.get("COLD_FALLBACK_JOB"):
        _full_program_job()
    code = main(argv)
    steps = {}
    for e in events:
        steps[e["step"]] = steps.get(e["step"], 0.0) + e["cpu_s_since_previous_event"]
    pathlib.Path(report).write_text(json.dumps({"demand": demand.stop(), "steps_cpu_s": steps}))
    return code


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _digest(folder: pathlib.Path) -> str:
    h = hashlib.sha256()
    for f in sorted(folder.rglob("*.png")):  # (jaxdepth_run.json holds timings)
        h.update(str(f.relative_to(folder)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def _run_time(rounds: int) -> int:
    """Run time of ``jit(complete)`` on the shared frame, main's program against the probe's (both compiled
    in this process), interleaved rounds of 5 calls each: medians of process CPU ms per call, bytes compared."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import jaxdepth
    from benchmarks._common import load_frame
    from jaxdepth._src import pixel_normals
    sparse, K, T, label = load_frame()
    frame = (jnp.asarray(sparse), jnp.asarray(K), jnp.asarray(T))
    main_cond = pixel_normals.cond_all
    fns = {"main": jax.jit(jaxdepth.complete).lower(*frame).compile()}
    _probe()
    fns["probe"] = jax.jit(jaxdepth.complete).lower(*frame).compile()
    pixel_normals.cond_all = main_cond
    outs = {v: np.asarray(f(*frame)).tobytes() for v, f in fns.items()}
    ms = {v: [] for v in fns}
    for r in range(rounds):
        for v in (VARIANTS if r % 2 == 0 else VARIANTS[::-1]):
            c0 = time.process_time()
            for _ in range(5):
                fns[v](*frame).block_until_ready()
            ms[v].append((time.process_time() - c0) / 5 * 1e3)
    med = {v: statistics.median(x) for v, x in ms.items()}
    ratio = statistics.median(p / m for p, m in zip(ms["probe"], ms["main"]))
    print(f"{label}: jit(complete) CPU ms per call, medians of {rounds} rounds: {med}, probe / main "
          f"{med['probe'] / med['main']:.3f} (median of the rounds' ratios {ratio:.3f}); same bytes {outs['main'] == outs['probe']}; load {os.getloadavg()}")
    return 0


def _summary(rows: dict) -> dict:
    """Medians per variant, the other / main ratio of each round, and whether every run wrote the same PNGs."""
    other = [v for v in rows if v != "main"][0]
    return {"medians": {v: {k: statistics.median(x[k] for x in rs) for k in KEYS} for v, rs in rows.items()},
            f"{other}_to_main_per_round": {k: [p[k] / m[k] for p, m in zip(rows[other], rows["main"])] for k in KEYS},
            "same_bytes": len({x["sha256"] for rs in rows.values() for x in rs}) == 1}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        return _child(argv[1], argv[2], argv[4:])
    if argv[:1] == ["--run"]:
        return _run_time(int(argv[1]) if len(argv) > 1 else 20)
    if argv[:1] == ["--fingerprint"]:   # every output of output_fingerprint made by the probe, checked against main's
        _probe()
        from benchmarks.output_fingerprint import main as fingerprint
        return fingerprint(["--check", str(RESULTS / "output_fingerprint.json")])
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", default=None)
    parser.add_argument("--job", action="store_true", help="main's job (full program) against the listed job")
    args, t0 = parser.parse_args(argv), time.time()
    variants = ("main", "job") if args.job else VARIANTS
    args.json = args.json or str(RESULTS / ("cold_job.json" if args.job else "cold_fallback.json"))
    from benchmarks.bench_offline_job import build_folder
    rows = {v: [] for v in variants}
    with tempfile.TemporaryDirectory(prefix="cold_fallback_") as tmp:
        tmp = pathlib.Path(tmp)
        src = build_folder(tmp / "build", 1)
        env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAXDEPTH_COMPILE"))}
        env.update({"COLD_FALLBACK_JOB": "1"} if args.job else {})
        for r in range(args.rounds):
            for variant in (variants if r % 2 == 0 else variants[::-1]):
                cache, out = tmp / f"cache_{r}_{variant}", tmp / f"out_{r}_{variant}"
                cache.mkdir()
                run_env = {**env, "XDG_CACHE_HOME": str(cache)}
                load = os.getloadavg()[0]
                c0, w0 = _children_cpu(), time.perf_counter()
                report = tmp / f"report_{r}_{variant}.json"
                subprocess.run([sys.executable, "-m", "benchmarks.studies.cold_fallback", "--child", variant,
                                str(report), "--", "complete", str(src), str(out), "-q"],
                               env=run_env, check=True, capture_output=True)
                child = json.loads(report.read_text())
                row = {"wall_s": time.perf_counter() - w0, "cpu_s": _children_cpu() - c0,
                       "idle_estimate_s": child["demand"]["idle_estimate_s"], **child,
                       "sha256": _digest(out), "load_before": load, "load_after": os.getloadavg()[0]}
                rows[variant].append(row)
                print(f"round {r} {variant:5s} wall {row['wall_s']:.2f} s, CPU {row['cpu_s']:.2f} s, idle estimate "
                      f"{row['idle_estimate_s']:.2f} s, steps {child['steps_cpu_s']}, load {load:.1f}, "
                      f"sha256 {row['sha256'][:12]}", flush=True)
    doc = {"what": "cold `jaxdepth complete` on a one-frame KITTI folder (shared frame), fresh process, empty caches; "
                   + ("main's job (full program) against the job's listed program (branch coldjob), alternating"
                      if args.job else "main against a probe without pixel_normals' dense fallback, alternating"),
           "rounds": args.rounds, **_summary(rows), "runs": rows, "load_average": os.getloadavg()}
    ratio_key = [k for k in doc if k.endswith("_to_main_per_round")][0]
    print(f"medians {doc['medians']}; {ratio_key} {doc[ratio_key]}; "
          f"same bytes {doc['same_bytes']}")
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
