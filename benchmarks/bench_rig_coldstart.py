"""``complete-rig`` start-up: the first sweep with an empty compile cache, after ``jaxdepth warmup``, warm;
and several sweeps in one process against one process per sweep.

Every run is a fresh ``jaxdepth`` process (what a cluster job or a shell loop pays), with its own
compile cache folder (``XDG_CACHE_HOME`` in a temporary folder; the user's cache is never touched).
Wall seconds of each process and its CPU seconds (user + system, from ``getrusage`` of the children)
are recorded; rounds are interleaved and medians reported, as the 2-core machine is shared and noisy.
Data: the shared nuScenes sample (one HDL-32E sweep, 6 cameras of 1600 x 900, its rig JSON written
from ``calibration.json`` into the temporary folder); the several-sweeps runs use symbolic links to
that one sweep under distinct names. The outputs of every variant are checked byte-identical.

Per round:

* ``cold``: ``complete-rig SWEEP RIG OUT`` with an empty cache;
* ``warmup``: ``jaxdepth warmup RIG --points <the sweep's point count>`` with an empty cache, then
  ``after warmup``: ``complete-rig`` in that cache;
* ``warm``: ``complete-rig`` again in the same cache (everything it needs is stored);
* ``N singles``: N ``complete-rig`` processes, one sweep each (warm cache), against ``one call``:
  ``complete-rig`` on the folder of the N sweeps (warm cache).

Writes benchmarks/results/rig_coldstart.json.

    python -m benchmarks.bench_rig_coldstart [--rounds 2] [--sweeps 5]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pathlib
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from benchmarks._common import DATA, RESULTS, write_results

NUSCENES = DATA / "nuscenes" / "sample"


def _cpu_children() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run(args, cache: pathlib.Path, extra_env: dict | None = None) -> tuple[float, float]:
    """(wall s, CPU s) of one ``jaxdepth`` process with its compile cache under ``cache`` (``extra_env``: more
    environment variables)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAXDEPTH_COMPILE"))}
    env.update(extra_env or {}, XDG_CACHE_HOME=str(cache))
    cpu, start = _cpu_children(), time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "jaxdepth.cli", *map(str, args)], env=env,
                            capture_output=True, text=True)
    wall = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f"jaxdepth {' '.join(map(str, args))} failed:\n{result.stderr}")
    return wall, _cpu_children() - cpu


def _digest(folder: pathlib.Path) -> str:
    h = hashlib.sha256()
    for path in sorted(folder.glob("*.png")):
        h.update(path.name.encode() + path.read_bytes())
    return h.hexdigest()


def medians(rounds: list) -> dict:
    """``{variant: {"wall_s", "cpu_s"}}``: the median over rounds of each variant's (wall, CPU) seconds."""
    return {k: {"wall_s": statistics.median(t[k][0] for t in rounds),
                "cpu_s": statistics.median(t[k][1] for t in rounds)} for k in rounds[0]}


def print_medians(median: dict, rounds: int) -> None:
    for k, v in median.items():
        print(f"{k}: {v['wall_s']:.1f} s wall, {v['cpu_s']:.1f} s CPU (median of {rounds})")


def one_round(tmp: pathlib.Path, sweep: pathlib.Path, rig: pathlib.Path, points: int, sweeps: int) -> tuple:
    times, digests = {}, {}
    times["cold"] = _run(["complete-rig", sweep, rig, tmp / "cold", "-q"], tmp / "cache_cold")
    times["warmup"] = _run(["warmup", rig, "--points", points, "-q"], tmp / "cache_warm")
    times["after warmup"] = _run(["complete-rig", sweep, rig, tmp / "after", "-q"], tmp / "cache_warm")
    times["warm"] = _run(["complete-rig", sweep, rig, tmp / "warm", "-q"], tmp / "cache_warm")
    for key in ("cold", "after", "warm"):
        digests[key] = _digest(tmp / key)
    log = tmp / "log"
    log.mkdir()
    for i in range(sweeps):
        (log / f"{i:06d}.pcd.bin").symlink_to(sweep)
    wall = cpu = 0.0
    for i in range(sweeps):
        w, c = _run(["complete-rig", log / f"{i:06d}.pcd.bin", rig, tmp / f"single{i}", "-q"], tmp / "cache_warm")
        wall, cpu = wall + w, cpu + c
        digests[f"single{i}"] = _digest(tmp / f"single{i}")
    times[f"{sweeps} singles"] = (wall, cpu)
    times["one call"] = _run(["complete-rig", log, rig, tmp / "many", "-q"], tmp / "cache_warm")
    for i in range(sweeps):
        digests[f"many/{i}"] = _digest(tmp / "many" / f"{i:06d}")
    return times, digests


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--sweeps", type=int, default=5, help="sweeps of the one-process / one-per-sweep comparison")
    parser.add_argument("--json", default=str(RESULTS / "rig_coldstart.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    found = sorted(NUSCENES.glob("*LIDAR_TOP*.pcd.bin")) if NUSCENES.is_dir() else []
    if not found:
        sys.exit(f"no nuScenes LIDAR_TOP sweep in {NUSCENES} (the shared sample)")
    from jaxdepth.io import read_points, rig_from_nuscenes_calibration, write_rig_json
    sweep = found[0]
    points = len(read_points(sweep, columns=5)[0])
    rounds = []
    with tempfile.TemporaryDirectory(prefix="jaxdepth-coldstart-") as tmp:
        rig = pathlib.Path(tmp) / "rig.json"
        write_rig_json(rig, rig_from_nuscenes_calibration(NUSCENES / "calibration.json"))
        for r in range(args.rounds):
            folder = pathlib.Path(tmp) / f"round{r}"
            folder.mkdir()
            times, digests = one_round(folder, sweep, rig, points, args.sweeps)
            if len(set(digests.values())) != 1:
                raise SystemExit(f"outputs differ between variants: {digests}")
            rounds.append(times)
            print(f"round {r}: " + ", ".join(f"{k} {w:.1f} s wall / {c:.1f} s CPU" for k, (w, c) in times.items()),
                  flush=True)
    median = medians(rounds)
    singles = f"{args.sweeps} singles"
    doc = {"what": "complete-rig start-up in fresh processes (nuScenes sample, 6 cameras): empty cache, after "
                   "jaxdepth warmup, warm; N sweeps in one process vs one process per sweep",
           "points": points, "rounds": rounds, "median": median,
           "ratio_after_warmup_to_cold": {u: median["after warmup"][u] / median["cold"][u] for u in ("wall_s", "cpu_s")},
           "ratio_one_call_to_singles": {u: median["one call"][u] / median[singles][u] for u in ("wall_s", "cpu_s")},
           "per_sweep_s": {"singles_wall": median[singles]["wall_s"] / args.sweeps,
                           "one_call_wall": median["one call"]["wall_s"] / args.sweeps},
           "outputs_identical": True}
    write_results(args.json, doc, None, t0)
    print_medians(median, len(rounds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
