"""Argoverse 2 job start-up: the first sweep with an empty compile cache, after ``jaxdepth warmup --av2``,
warm; and whether the log's second sweep compiles a program of its own.

Every run is a fresh ``jaxdepth complete LOG OUT`` process with its own compile cache folder
(:func:`benchmarks.bench_rig_coldstart._run`: wall seconds and CPU seconds of the child; the user's
cache is never touched). Data: the shared Argoverse 2 log (two sweeps, 7 ring cameras, LiDAR time: the
log has no images), as two logs of symbolic links in a temporary folder: ``one`` holds the first sweep
only (the process's time is start-up + first sweep), ``two`` both (the second sweep's extra cost: a
program of its own, or the warm per-sweep cost).

Per round: ``cold one`` and ``cold two`` (each an empty cache); ``warmup`` (``warmup --av2`` on the ``two``
log, empty cache), then ``after warmup one`` and ``after warmup two`` in that cache, and ``warm two``
again. ``--no-warmup`` runs the cold variants only (e.g. against an older checkout: the code is the
one ``PYTHONPATH`` names). Outputs of every variant are checked byte-identical per log.

    python -m benchmarks.bench_av2_coldstart [--rounds 1] [--no-warmup] [--json results/av2_coldstart.json]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile
import time

from benchmarks._common import DATA, RESULTS, write_results
from benchmarks.bench_rig_coldstart import _run, medians, print_medians

LOG = DATA / "av2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"


def _log_of(folder: pathlib.Path, sweeps: list, names: list | None = None) -> pathlib.Path:
    """A log folder of symbolic links: LOG's calibration and poses, the given lidar sweeps (under
    ``names``, default their own file names)."""
    log = folder / LOG.name
    (log / "sensors" / "lidar").mkdir(parents=True)
    for entry in LOG.iterdir():
        if entry.name != "sensors":
            os.symlink(entry, log / entry.name)
    for sweep, name in zip(sweeps, names or [s.name for s in sweeps]):
        os.symlink(sweep, log / "sensors" / "lidar" / name)
    return log


def _digest(folder: pathlib.Path) -> str:
    import hashlib
    h = hashlib.sha256()
    for path in sorted(folder.rglob("*.png")):
        h.update(str(path.relative_to(folder)).encode() + path.read_bytes())
    return h.hexdigest()


def one_round(tmp: pathlib.Path, logs: dict, warmup: bool) -> tuple:
    times, digests = {}, {}

    def complete(key, log, cache):
        times[key] = _run(["complete", log, tmp / key, "--lidar-time", "-q"], cache)
        digests.setdefault(log.parent.name, set()).add(_digest(tmp / key))

    for name, log in logs.items():
        complete(f"cold {name}", log, tmp / f"cache_cold_{name}")
    if warmup:
        times["warmup"] = _run(["warmup", "--av2", logs["two"], "--lidar-time", "-q"], tmp / "cache_warm")
        for name, log in logs.items():
            complete(f"after warmup {name}", log, tmp / "cache_warm")
        complete("warm two", logs["two"], tmp / "cache_warm")
    return times, digests


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--no-warmup", action="store_true", help="cold variants only (code without warmup --av2)")
    parser.add_argument("--json", default=str(RESULTS / "av2_coldstart.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    sweeps = sorted((LOG / "sensors" / "lidar").glob("*.feather"))
    if len(sweeps) < 2:
        sys.exit(f"expected the shared Argoverse 2 log (two sweeps) at {LOG}")
    rounds = []
    with tempfile.TemporaryDirectory(prefix="jaxdepth-av2-coldstart-") as tmp:
        tmp = pathlib.Path(tmp)
        logs = {"one": _log_of(tmp / "one", sweeps[:1]), "two": _log_of(tmp / "two", sweeps[:2])}
        for r in range(args.rounds):
            folder = tmp / f"round{r}"
            folder.mkdir()
            times, digests = one_round(folder, logs, not args.no_warmup)
            if any(len(d) != 1 for d in digests.values()):
                raise SystemExit(f"outputs differ between variants: {digests}")
            rounds.append(times)
            print(f"round {r}: " + ", ".join(f"{k} {w:.1f} s wall / {c:.1f} s CPU" for k, (w, c) in times.items()),
                  flush=True)
    median = medians(rounds)
    second = {v: {u: median[f"{v} two"][u] - median[f"{v} one"][u] for u in ("wall_s", "cpu_s")}
              for v in ("cold", "after warmup") if f"{v} two" in median}
    doc = {"what": "jaxdepth complete on the shared Argoverse 2 log (7 ring cameras, --lidar-time) in fresh "
                   "processes: one-sweep and two-sweep logs, empty cache, after jaxdepth warmup --av2, warm",
           "code": os.environ.get("PYTHONPATH", ""), "rounds": rounds, "median": median,
           "second_sweep_extra": second, "outputs_identical": True}
    write_results(args.json, doc, None, t0)
    print_medians(median, len(rounds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
