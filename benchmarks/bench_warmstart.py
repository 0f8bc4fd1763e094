"""Warm start with and without the program cache (``jaxdepth.batch.program_cache``), fresh processes.

Cases (inputs as in ``benchmarks.bench_coldstart_profile``): ``kitti`` (``jaxdepth complete`` on a
one-frame KITTI depth-completion folder), ``av2`` (``jaxdepth complete LOG --lidar-time``, the shared
Argoverse 2 log cut to one sweep: two VLP-32C, 7 ring cameras), ``nuscenes`` (``complete-rig`` on the
shared nuScenes sweep, 6 cameras: what one ``complete-rig`` call pays). Variants: ``off``
(``JAXDEPTH_PROGRAM_CACHE=0``: the code path before the program cache, tracing on every start) and
``on`` (the default), each with a compile cache folder of its own (``XDG_CACHE_HOME`` in a temporary
folder). Each variant's cache is filled by a first run (recorded as ``cold``), then ``--rounds`` warm
runs alternate between the variants (``off`` then ``on`` in odd rounds, the other order in even
ones). Every process's wall seconds and CPU seconds (user + system of the child, ``getrusage``) are
recorded; the PNGs of every run are checked byte-identical across variants and runs. The machine is
shared: read the CPU columns and the per-round ratios.

    python -m benchmarks.bench_warmstart [--cases kitti av2 nuscenes] [--rounds 3]
        [--json benchmarks/results/warmstart.json]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pathlib
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

from benchmarks._common import RESULTS, write_results
from benchmarks.bench_coldstart_profile import _command

CASES = ("kitti", "av2", "nuscenes")
VARIANTS = ("off", "on")


def _cpu_children() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _outputs(folder: pathlib.Path) -> str:
    """SHA-256 over the relative paths and bytes of every PNG below ``folder``."""
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*.png")):
        digest.update(str(path.relative_to(folder)).encode() + path.read_bytes())
    return digest.hexdigest()


def run_once(argv: list, out: pathlib.Path, cache: pathlib.Path, variant: str) -> dict:
    """One fresh ``jaxdepth`` process writing into ``out`` (emptied first): wall, CPU, outputs' hash."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("JAX_COMPILATION_CACHE", "JAXDEPTH_COMPILE", "JAXDEPTH_PROGRAM"))}
    env["XDG_CACHE_HOME"] = str(cache)
    if variant == "off":
        env["JAXDEPTH_PROGRAM_CACHE"] = "0"
    shutil.rmtree(out, ignore_errors=True)
    args = [*argv]
    args[args.index("OUT")] = str(out)
    cpu, start = _cpu_children(), time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "jaxdepth.cli", *args], env=env, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - start, _cpu_children() - cpu
    if done.returncode != 0:
        raise SystemExit(f"jaxdepth {' '.join(args)} failed:\n{done.stderr[-3000:]}")
    return {"wall_s": wall, "cpu_s": cpu, "outputs_sha256": _outputs(out)}


def run_case(case: str, tmp: pathlib.Path, rounds: int) -> dict:
    argv = _command(case, tmp, pathlib.Path("OUT"))
    caches = {v: tmp / f"cache_{case}_{v}" for v in VARIANTS}
    doc = {"argv": argv, "cold": {}, "warm": {v: [] for v in VARIANTS}}
    for v in VARIANTS:
        doc["cold"][v] = run_once(argv, tmp / "out", caches[v], v)
        print(f"{case} cold {v}: {doc['cold'][v]['wall_s']:.1f} s wall / {doc['cold'][v]['cpu_s']:.1f} s CPU",
              flush=True)
    for r in range(rounds):
        for v in (VARIANTS if r % 2 == 0 else VARIANTS[::-1]):
            doc["warm"][v].append(run_once(argv, tmp / "out", caches[v], v))
            print(f"{case} warm {v} round {r}: {doc['warm'][v][-1]['wall_s']:.1f} s wall / "
                  f"{doc['warm'][v][-1]['cpu_s']:.1f} s CPU", flush=True)
    hashes = {run["outputs_sha256"] for runs in doc["warm"].values() for run in runs}
    hashes |= {run["outputs_sha256"] for run in doc["cold"].values()}
    doc["outputs_identical"] = len(hashes) == 1
    doc["program_files_bytes"] = {str(f.relative_to(caches["on"])): f.stat().st_size
                                  for f in sorted(caches["on"].rglob("*.jaxprog"))}
    doc["summary"] = {
        "warm_cpu_s_median": {v: statistics.median(r["cpu_s"] for r in doc["warm"][v]) for v in VARIANTS},
        "warm_wall_s_median": {v: statistics.median(r["wall_s"] for r in doc["warm"][v]) for v in VARIANTS},
        "warm_cpu_ratio_on_over_off_per_round": [on["cpu_s"] / off["cpu_s"]
                                                 for on, off in zip(doc["warm"]["on"], doc["warm"]["off"])],
        "cold_cpu_s": {v: doc["cold"][v]["cpu_s"] for v in VARIANTS},
    }
    return doc


def _report(case: str, doc: dict) -> None:
    s = doc["summary"]
    print(f"{case}: warm CPU median off {s['warm_cpu_s_median']['off']:.2f} s, on "
          f"{s['warm_cpu_s_median']['on']:.2f} s; outputs identical: {doc['outputs_identical']}", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", default=str(RESULTS / "warmstart.json"))
    args = parser.parse_args(argv)
    started, cases = time.time(), {}
    with tempfile.TemporaryDirectory(prefix="jaxdepth-warmstart-") as tmp:
        for case in args.cases:
            cases[case] = run_case(case, pathlib.Path(tmp), args.rounds)
            _report(case, cases[case])
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    write_results(args.json, {"what": "warm start, program cache off / on, fresh processes", "rounds": args.rounds,
                              "load_average": load, "cases": cases}, None, started)
    return 0 if all(doc["outputs_identical"] for doc in cases.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
