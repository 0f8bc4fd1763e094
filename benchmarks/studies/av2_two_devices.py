"""Study (issue 38, branch devices2): two executions of the Argoverse 2 job's SGM program at once.

One process, the CPU split into 2 host devices before JAX starts
(:func:`jaxdepth.batch.devices.split_cpu_into_devices`), the host allocator as the CLI sets it
(:func:`jaxdepth.batch.devices.keep_freed_memory`). The shared log's first sweep (7 ring cameras, LiDAR
time: the log has no images) is read and prepared as the job does (:func:`jaxdepth.batch.av2_job._load`,
:func:`jaxdepth.batch.cloud_runner.cloud_preparation`); its program's call ``call()`` is then timed in
interleaved rounds, each form blocked on all its results before the clock stops:

- ``one_call``: one call on device 0 (the job as it is: one sweep in flight);
- ``two_dispatched_one_device``: two calls dispatched back to back on device 0, then both read;
- ``two_devices``: one call under ``jax.default_device`` of each device, then both read (two sweeps in
  flight, one per device: each device compiles its own copy).

Recorded: median wall and process-CPU seconds per form and the ratios to two ``one_call`` (``< 1``: two
sweeps at once finish sooner than two in a row), the process's peak resident memory after each form's
first (compiling) call (``ru_maxrss``: the peak is kept, so each figure includes the forms before) and the
first calls' wall (the second device's compile). Needs ``free -g`` >= 10 GB (two programs' buffers).

    python -m benchmarks.studies.av2_two_devices [--rounds 5] [--json PATH]
    python -m benchmarks.studies.av2_two_devices --cold R [--json PATH]

``--cold R``: the cold first sweep with two devices. R rounds of fresh ``jaxdepth complete LOG OUT -q``
processes on the shared 2-sweep log (LiDAR time), one device and ``--cpu-devices 2`` alternating, each with an
empty cache folder of its own: seconds from the process's start until the first sweep's 7 PNGs exist (polled
every 50 ms) and the process's wall (the second sweep on the second device compiles a copy of its own).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import resource
import statistics
import sys
import tempfile
import time

from benchmarks._common import RESULTS, write_results
from benchmarks.bench_av2_coldstart import LOG


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def cold(rounds: int) -> dict:
    """``{variant: [{"first_sweep_s", "wall_s"}, ...]}`` of ``--cold`` (module docstring)."""
    import subprocess

    from jaxdepth.io import av2
    first_ts = min(int(p.stem) for p in (LOG / "sensors" / "lidar").glob("*.feather"))
    out = {"one_device": [], "devices_2": []}
    for r in range(rounds):
        for name, flags in (("one_device", []), ("devices_2", ["--cpu-devices", "2"])):
            with tempfile.TemporaryDirectory(prefix="jaxdepth-av2cold2-") as tmp:
                dst = pathlib.Path(tmp) / "out"
                env = {k: v for k, v in os.environ.items()
                       if not k.startswith(("JAX_COMPILATION_CACHE", "JAXDEPTH_COMPILE"))}
                env["XDG_CACHE_HOME"] = str(pathlib.Path(tmp) / "cache")
                firsts = [dst / LOG.name / c / f"{first_ts}.png" for c in av2.RING_CAMERAS]
                start = time.perf_counter()
                proc = subprocess.Popen([sys.executable, "-m", "jaxdepth.cli", "complete", str(LOG), str(dst), "-q",
                                         "--lidar-time", *flags], env=env, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.PIPE, text=True)
                first = None
                while proc.poll() is None:
                    if first is None and all(f.exists() for f in firsts):
                        first = time.perf_counter() - start
                    time.sleep(0.05)
                wall = time.perf_counter() - start
                if proc.returncode != 0:
                    raise SystemExit(proc.stderr.read()[-2000:])
                first = wall if first is None else first
                out[name].append({"first_sweep_s": first, "wall_s": wall})
                print(f"round {r} {name}: first sweep {first:.1f} s, process {wall:.1f} s", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--json", type=pathlib.Path, default=RESULTS / "av2_two_devices_devices2.json")
    ap.add_argument("--cold", type=int, default=0, metavar="R", help="instead: R rounds of cold processes")
    args = ap.parse_args(argv)
    if not LOG.exists():
        print(f"shared Argoverse 2 log missing: {LOG}", file=sys.stderr)
        return 1
    if args.cold:
        t0 = time.time()
        rec = cold(args.cold)
        med = {k: {m: statistics.median(r[m] for r in v) for m in ("first_sweep_s", "wall_s")} for k, v in rec.items()}
        print(f"medians {med}")
        return _save(args, argv, t0, None, log=str(LOG), runs=rec, medians=med)
    from jaxdepth.batch import devices
    devices.quiet_jax_start()
    devices.keep_freed_memory()
    devices.split_cpu_into_devices(2)
    t0 = time.time()
    import jax

    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch.av2_job import _load, plan
    from jaxdepth.batch.cloud_runner import cloud_preparation
    from jaxdepth.batch.runner import RunSummary
    from jaxdepth.io import av2

    targets = jax.local_devices()[:2]
    config = SGMConfig()
    with tempfile.TemporaryDirectory(prefix="jaxdepth-av2two-") as tmp:
        tables, todo = plan([LOG], pathlib.Path(tmp), cameras=av2.RING_CAMERAS, overwrite=True, summary=RunSummary(),
                            notify=lambda *a: None, time="lidar")
    cloud, rig = _load(todo[0], tables=tables, cameras=av2.RING_CAMERAS, force=False)
    call = cloud_preparation("sgm", config=config)(cloud, rig)

    def on(device):
        with jax.default_device(device):
            return call()[0]

    forms = {"one_call": lambda: [on(targets[0])],
             "two_dispatched_one_device": lambda: [on(targets[0]), on(targets[0])],
             "two_devices": lambda: [on(targets[0]), on(targets[-1])]}
    first, peaks = {}, {}
    for name, form in forms.items():
        start = time.perf_counter()
        jax.block_until_ready(form())
        first[name] = time.perf_counter() - start
        peaks[name] = _peak_gb()
        print(f"first {name}: {first[name]:.1f} s, peak RSS {peaks[name]:.2f} GB", flush=True)
    walls, cpus = {k: [] for k in forms}, {k: [] for k in forms}
    for r in range(args.rounds):
        for name, form in forms.items():
            cpu, start = time.process_time(), time.perf_counter()
            jax.block_until_ready(form())
            walls[name].append(time.perf_counter() - start)
            cpus[name].append(time.process_time() - cpu)
        print(f"round {r}: " + ", ".join(f"{k} {v[-1]:.3f} s" for k, v in walls.items()), flush=True)
    wall = {k: statistics.median(v) for k, v in walls.items()}
    cpu = {k: statistics.median(v) for k, v in cpus.items()}
    ratios = {f"{k}_over_two_calls": wall[k] / (2 * wall["one_call"]) for k in forms if k != "one_call"}
    print(f"median wall {wall}; ratios {ratios}")
    return _save(args, argv, t0, config, devices=len(targets), rounds=args.rounds, median_wall_s=wall,
                 median_cpu_s=cpu, ratios=ratios, first_call_wall_s=first, peak_rss_gb_after_first=peaks,
                 data={"log": str(LOG), "sweep": int(todo[0].source[1]), "cameras": len(rig.cameras), "time": "lidar"})


def _save(args, argv, t0: float, config, **rec) -> int:
    """Writes the study's JSON (``rec`` with the command and the load average); exit code 0."""
    command = "python -m benchmarks.studies.av2_two_devices " + " ".join(sys.argv[1:] if argv is None else argv)
    write_results(args.json, {"command": command, **rec, "load_average": os.getloadavg()}, config, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
