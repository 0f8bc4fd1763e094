"""Study (issue 38, branch cold6): the cold KITTI job as the program runs it, this tree against another
checkout, to the first PNG written and to the process's end.

Each round runs the ``jaxdepth`` program (``jaxdepth.cli.main()`` as the console script calls it: no
``argv``, so its process settings and its end are the program's) on a one-frame KITTI depth-completion
folder of the shared frame (``bench_offline_job.build_folder``), once with this tree's library and once
with ``--checkout``'s (its folder first on ``PYTHONPATH`` and the working directory, so ``import
jaxdepth`` finds it: docs/speed.md's trap), order alternating, each a fresh child process with its own
empty ``XDG_CACHE_HOME`` (JAX's persistent cache and the program cache empty). The child is this file,
run by path, so both libraries are measured by the same code. Per run: the process's wall and CPU
seconds (``RUSAGE_CHILDREN``: interpreter start and shutdown included); the wall seconds from the
parent's spawn to the end of the first ``write_outputs`` (the first PNG on disk: ``time.perf_counter`` is
the system's monotonic clock, shared by both processes) and the child's CPU seconds then (its whole
process: interpreter start included); the idle estimate (:class:`benchmarks.bench_compile_threads.Demand`,
from the child's first line to the first PNG: add the interpreter start, ~0.6 s); the SHA-256 of the PNGs
and the load average. JAX is not imported before ``main`` (as in the program: its start-up settings apply).

    python -m benchmarks.studies.cold_first_png --checkout /work/base-cold6 [--rounds 3] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

KEYS = ("wall_s", "cpu_s", "first_png_wall_s", "first_png_cpu_s", "idle_estimate_to_png_s")


def _child(report: str, argv: list) -> None:
    """Runs the program on ``argv``; writes the report at the first PNG and again before the process ends."""
    from benchmarks.bench_compile_threads import Demand
    demand = Demand()
    from jaxdepth import interrupts
    from jaxdepth.batch import extras
    doc = {"jaxdepth": None}
    write = extras.write_outputs

    def first_write(*args, **kwargs):
        out = write(*args, **kwargs)
        if "first_png_at" not in doc:
            doc.update(first_png_at=time.perf_counter(), first_png_cpu_s=time.process_time(), **{
                f"{k}_to_png": v for k, v in demand.stop().items()})
        return out

    def dump() -> None:
        import jaxdepth
        doc["jaxdepth"] = jaxdepth.__file__
        pathlib.Path(report).write_text(json.dumps(doc))

    exit_now = interrupts.exit_now
    interrupts.exit_now = lambda code: (dump(), exit_now(code))
    extras.write_outputs = first_write
    sys.argv = ["jaxdepth"] + argv
    from jaxdepth.cli import main
    code = main()
    dump()
    sys.exit(code)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        _child(argv[1], argv[3:])
        return 0
    from benchmarks._common import RESULTS, write_results
    from benchmarks.studies.cold_fallback import _children_cpu, _digest
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", required=True, help="the baseline checkout (a folder holding its jaxdepth/)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", default=str(RESULTS / "cold_first_png.json"))
    args, t0 = parser.parse_args(argv), time.time()
    this = pathlib.Path(__file__).resolve().parents[2]
    trees = {"this": this, "checkout": pathlib.Path(args.checkout).resolve()}
    from benchmarks.bench_offline_job import build_folder
    rows = {v: [] for v in trees}
    with tempfile.TemporaryDirectory(prefix="cold_first_png_") as tmp:
        tmp = pathlib.Path(tmp)
        src = build_folder(tmp / "build", 1)
        env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAXDEPTH_COMPILE"))}
        for r in range(args.rounds):
            for variant in (tuple(trees) if r % 2 == 0 else tuple(trees)[::-1]):
                cache, out, report = tmp / f"cache_{r}_{variant}", tmp / f"out_{r}_{variant}", tmp / f"report_{r}_{variant}.json"
                cache.mkdir()
                path = os.pathsep.join([str(trees[variant]), str(this)])   # its jaxdepth; benchmarks from this tree
                run_env = {**env, "XDG_CACHE_HOME": str(cache), "PYTHONPATH": path}
                load = os.getloadavg()[0]
                c0, w0 = _children_cpu(), time.perf_counter()
                subprocess.run([sys.executable, str(pathlib.Path(__file__).resolve()), "--child", str(report), "--",
                                "complete", str(src), str(out), "-q"],
                               env=run_env, cwd=trees[variant], check=True, capture_output=True)
                wall, cpu = time.perf_counter() - w0, _children_cpu() - c0
                child = json.loads(report.read_text())
                assert pathlib.Path(child["jaxdepth"]).resolve().is_relative_to(trees[variant]), child["jaxdepth"]
                row = {"wall_s": wall, "cpu_s": cpu, "first_png_wall_s": child["first_png_at"] - w0,
                       "first_png_cpu_s": child["first_png_cpu_s"],
                       "idle_estimate_to_png_s": child["idle_estimate_s_to_png"], "child": child,
                       "sha256": _digest(out), "load_before": load, "load_after": os.getloadavg()[0]}
                rows[variant].append(row)
                print(f"round {r} {variant:8s} " + ", ".join(f"{k} {row[k]:.2f}" for k in KEYS)
                      + f", load {load:.1f}, sha256 {row['sha256'][:12]}", flush=True)
    doc = {"what": "cold `jaxdepth complete` (the program, main()) on a one-frame KITTI folder (shared frame), fresh "
                   "process, empty caches: this tree against the checkout, alternating; to the first PNG and to the end",
           "checkout": str(trees["checkout"]), "rounds": args.rounds,
           "medians": {v: {k: statistics.median(x[k] for x in rs) for k in KEYS} for v, rs in rows.items()},
           "this_to_checkout_per_round": {k: [a[k] / b[k] for a, b in zip(rows["this"], rows["checkout"])] for k in KEYS},
           "same_bytes": len({x["sha256"] for rs in rows.values() for x in rs}) == 1,
           "runs": rows, "load_average": os.getloadavg()}
    write_results(args.json, doc, None, t0)
    return print(json.dumps({k: doc[k] for k in ("medians", "this_to_checkout_per_round", "same_bytes")}, indent=1)) or 0


if __name__ == "__main__":
    sys.exit(main())
