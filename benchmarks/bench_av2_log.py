"""The Argoverse 2 job over a log of many sweeps, default options against ``--method nearest``, warm cache.

Issue 38's first "Done when" figure: per sweep, ``jaxdepth complete LOG OUT`` (default options) at most
2x the same job with ``--method nearest``. The shared log holds two real sweeps, so the benchmark builds,
in a temporary folder, logs the job reads exactly as a real one: the shared calibration and
``city_SE3_egovehicle.feather`` (symbolic links), and ``sensors/lidar/<ts>.feather`` links to the two
real sweep files, alternately, under timestamps taken from the pose table's rows (the row nearest each
multiple of 0.1 s from the first real sweep on, the LiDAR's 10 Hz). ``--camera-images`` (default on) also
lays out ``sensors/cameras/<camera>/<ts>.jpg`` for the 7 ring cameras at the pose rows nearest every
0.05 s (the cameras' 20 Hz) as empty files: the job reads only their names (the image timestamps,
for camera-time depth, its default), never their pixels (no guidance by default); the shared log has no
images. Nothing is written under /work/shared.

Two logs: ``long`` with ``--sweeps`` sweeps (default 10) and ``short`` with the first 2 of them. Each
run is a fresh process (:func:`benchmarks.bench_rig_coldstart._run`: wall and CPU seconds of the child)
with one compile cache folder for the whole benchmark (the user's cache is never touched). A warm-up
run of each method on the short log fills the cache (every run's 7 PNGs per sweep are counted); then ``--rounds`` interleaved rounds, each
running default-long, default-short, nearest-long, nearest-short (a fresh output folder each). Per
sweep = (long - short) / (sweeps - 2): start-up, cache load and the first sweep cancel. The ratio
default / nearest is taken within each round, then the median. Writes benchmarks/results/av2_log.json.

``--checkout PATH`` adds the default job with another checkout's code (``PYTHONPATH`` on it; e.g. main's, a
``git worktree add --detach``) to every round, ``default-base``, and the ratios this / that per round: the two
codes' jobs interleaved, not in two runs minutes apart at another load.

``--release-memory`` adds both jobs with ``JAXDEPTH_KEEP_MEMORY=0`` (glibc's default malloc: the process
before :func:`jaxdepth.batch.devices.keep_freed_memory`) to every round, with their ratios.

``--devices N`` adds ``default-devices``, the default job with ``--cpu-devices N`` (whole sweeps dealt to N host
devices), to every round, with its ratios to nearest and to the one-device job.

    python -m benchmarks.bench_av2_log [--sweeps 10] [--rounds 2] [--no-camera-images] [--release-memory]
                                       [--checkout PATH] [--devices N] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import statistics
import sys
import tempfile
import time

import numpy as np

from benchmarks._common import DATA, RESULTS, write_results
from benchmarks.bench_av2_coldstart import LOG, _log_of
from benchmarks.bench_rig_coldstart import _run

METHODS = {"default": [], "nearest": ["--method", "nearest"]}
#: ``--release-memory``: the same two jobs with glibc's default malloc (``JAXDEPTH_KEEP_MEMORY=0``, no
#: :func:`jaxdepth.batch.devices.keep_freed_memory`), in the same rounds: the before of that change.
RELEASE = {"JAXDEPTH_KEEP_MEMORY": "0"}


def variants(release: bool, checkout: pathlib.Path | None = None, devices: int = 1) -> dict:
    """``{name: (flags, environment)}`` of the runs of one round (``checkout``: also ``default-base``, the
    default job with that checkout's code first on ``PYTHONPATH``; ``devices`` > 1: also ``default-devices``,
    the default job with ``--cpu-devices devices``)."""
    out = {name: (flags, {}) for name, flags in METHODS.items()}
    if devices > 1:
        out["default-devices"] = (["--cpu-devices", str(devices)], {})
    if release:
        out.update({f"{name}-release": (flags, RELEASE) for name, flags in METHODS.items()})
    if checkout is not None:
        out["default-base"] = ([], {"PYTHONPATH": str(checkout.resolve())})
    return out


def pose_times(step_ns: int, count: int) -> np.ndarray:
    """(count,) int64 timestamps of the pose table's rows nearest ``t0 + k step_ns``, ``t0`` the first real
    sweep; distinct and increasing (asserted)."""
    from jaxdepth.io.av2 import read_log
    log = read_log(LOG)
    t0 = log.sweeps[0]
    rows = log.city_times
    picked = np.array([rows[np.argmin(np.abs(rows - (t0 + k * step_ns)))] for k in range(count)], np.int64)
    assert np.all(np.diff(picked) > 0), "pose table too sparse for the requested spacing"
    return picked


def build_log(folder: pathlib.Path, sweep_times: np.ndarray, image_times) -> pathlib.Path:
    """A log folder under ``folder``: LOG's calibration and poses linked, sweep ``k`` a link to real sweep
    ``k mod 2`` named ``<sweep_times[k]>.feather``; empty ``<ts>.jpg`` per ring camera for ``image_times``."""
    from jaxdepth.io.av2 import RING_CAMERAS
    real = sorted((LOG / "sensors" / "lidar").glob("*.feather"))
    log = _log_of(folder, [real[k % len(real)] for k in range(len(sweep_times))],
                  [f"{int(t)}.feather" for t in sweep_times])
    for cam in RING_CAMERAS if image_times is not None else ():
        (log / "sensors" / "cameras" / cam).mkdir(parents=True)
        for t in image_times:
            (log / "sensors" / "cameras" / cam / f"{int(t)}.jpg").touch()
    return log


def one_round(tmp: pathlib.Path, logs: dict, cache: pathlib.Path, tag: str, runs: dict) -> dict:
    """``{"<variant>-<log>": (wall s, CPU s)}`` for every variant of ``runs`` (:func:`variants`) and log,
    interleaved."""
    times = {}
    for method, (flags, env) in runs.items():
        for name, log in logs.items():
            out = tmp / f"{tag}-{method}-{name}"
            times[f"{method}-{name}"] = _run(["complete", log, out, "-q", *flags], cache, env)
            written = len(list(out.rglob("*.png")))
            expected = 7 * len(list((log / "sensors" / "lidar").glob("*.feather")))
            if written != expected:
                raise SystemExit(f"{out}: {written} depth PNGs written, expected {expected} (7 cameras x sweeps)")
            print(f"  {tag} {method} {name}: {times[f'{method}-{name}'][0]:.1f} s wall", flush=True)
    return times


def per_sweep(times: dict, sweeps: int, runs=METHODS) -> dict:
    """Per-sweep wall and CPU seconds of each variant from one round's long and short runs, and the ratios
    (default / nearest; with the release variants also default-release / nearest-release and each
    method kept / released)."""
    out = {}
    for method in runs:
        long, short = times[f"{method}-long"], times[f"{method}-short"]
        out[method] = {"wall_s": (long[0] - short[0]) / (sweeps - 2), "cpu_s": (long[1] - short[1]) / (sweeps - 2)}
    out["ratio_wall"] = out["default"]["wall_s"] / out["nearest"]["wall_s"]
    out["ratio_cpu"] = out["default"]["cpu_s"] / out["nearest"]["cpu_s"]
    out["ratio_total_long"] = times["default-long"][0] / times["nearest-long"][0]
    if "default-base" in runs:
        out["default_over_base_cpu"] = out["default"]["cpu_s"] / out["default-base"]["cpu_s"]
        out["default_over_base_wall"] = out["default"]["wall_s"] / out["default-base"]["wall_s"]
        out["base_ratio_cpu"] = out["default-base"]["cpu_s"] / out["nearest"]["cpu_s"]
    if "default-devices" in runs:
        out["devices_ratio_wall"] = out["default-devices"]["wall_s"] / out["nearest"]["wall_s"]
        out["devices_ratio_cpu"] = out["default-devices"]["cpu_s"] / out["nearest"]["cpu_s"]
        out["devices_over_one_wall"] = out["default-devices"]["wall_s"] / out["default"]["wall_s"]
        out["devices_over_one_cpu"] = out["default-devices"]["cpu_s"] / out["default"]["cpu_s"]
    if "default-release" in runs:
        out["release_ratio_wall"] = out["default-release"]["wall_s"] / out["nearest-release"]["wall_s"]
        out["release_ratio_cpu"] = out["default-release"]["cpu_s"] / out["nearest-release"]["cpu_s"]
        for method in METHODS:
            out[f"{method}_kept_over_release_wall"] = out[method]["wall_s"] / out[f"{method}-release"]["wall_s"]
            out[f"{method}_kept_over_release_cpu"] = out[method]["cpu_s"] / out[f"{method}-release"]["cpu_s"]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweeps", type=int, default=10, help="sweeps in the long log (>= 3)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--no-camera-images", action="store_true", help="no image names: depth at LiDAR time")
    ap.add_argument("--release-memory", action="store_true",
                    help="also both jobs with JAXDEPTH_KEEP_MEMORY=0 (glibc's default malloc), same rounds")
    ap.add_argument("--checkout", type=pathlib.Path, default=None,
                    help="also the default job with this checkout's code (PYTHONPATH), same rounds")
    ap.add_argument("--devices", type=int, default=1, metavar="N",
                    help="also the default job with --cpu-devices N (sweeps dealt to N host devices), same rounds")
    ap.add_argument("--json", type=pathlib.Path, default=RESULTS / "av2_log.json")
    args = ap.parse_args(argv)
    args.json = args.json.resolve()
    if args.checkout is not None:
        args.checkout = args.checkout.resolve()
    if not LOG.exists():
        print(f"shared Argoverse 2 log missing: {LOG}", file=sys.stderr)
        return 1
    if args.sweeps < 3:
        ap.error("--sweeps must be at least 3")
    t0 = time.time()
    sweep_times = pose_times(100_000_000, args.sweeps)
    image_times = None if args.no_camera_images else pose_times(50_000_000, 2 * args.sweeps)
    with tempfile.TemporaryDirectory(prefix="jaxdepth-av2log-") as tmp_name:
        tmp = pathlib.Path(tmp_name)
        logs = {"long": build_log(tmp / "long", sweep_times, image_times),
                "short": build_log(tmp / "short", sweep_times[:2],
                                   None if image_times is None else image_times[:4])}
        cache = tmp / "cache"
        # The jobs run in `tmp`: `python -m` puts the working directory first on sys.path, ahead of
        # PYTHONPATH, so from a checkout's folder `default-base` would import that checkout's jaxdepth.
        here = os.getcwd()
        os.chdir(tmp)
        runs = variants(args.release_memory, args.checkout, args.devices)
        for method, (flags, env) in {**{m: (f, {}) for m, f in METHODS.items()},
                                     **{k: v for k, v in runs.items() if k in ("default-base", "default-devices")}
                                     }.items():
            wall, cpu = _run(["complete", logs["short"], tmp / f"warmup-{method}", "-q", *flags], cache, env)
            print(f"warm-up {method} short: {wall:.1f} s wall, {cpu:.1f} s CPU", flush=True)
        rounds = []
        for r in range(args.rounds):
            times = one_round(tmp, logs, cache, f"round{r}", runs)
            rounds.append({"runs": {k: {"wall_s": w, "cpu_s": c} for k, (w, c) in times.items()},
                           "per_sweep": per_sweep(times, args.sweeps, runs)})
            print(f"round {r}: " + ", ".join(f"{m} {rounds[-1]['per_sweep'][m]['wall_s']:.2f} s/sweep"
                                             for m in runs)
                  + f", ratio {rounds[-1]['per_sweep']['ratio_wall']:.2f}", flush=True)
        os.chdir(here)
    median = {m: {"wall_s": statistics.median(r["per_sweep"][m]["wall_s"] for r in rounds),
                  "cpu_s": statistics.median(r["per_sweep"][m]["cpu_s"] for r in rounds)} for m in runs}
    ratios = {k: statistics.median(r["per_sweep"][k] for r in rounds)
              for k, v in rounds[0]["per_sweep"].items() if k not in runs}
    print(f"median per sweep: default {median['default']['wall_s']:.2f} s, nearest {median['nearest']['wall_s']:.2f} s;"
          f" ratio {ratios['ratio_wall']:.2f} (per round "
          + ", ".join(f"{r['per_sweep']['ratio_wall']:.2f}" for r in rounds) + ")")
    doc = {"command": "python -m benchmarks.bench_av2_log " + " ".join(sys.argv[1:] if argv is None else argv),
           "log": {"source": str(LOG.relative_to(DATA)), "sweeps": args.sweeps, "short_sweeps": 2,
                   "sweep_timestamps_ns": sweep_times.tolist(), "camera_images": image_times is not None,
                   "cameras": 7},
           "method": "per sweep = (long log - 2-sweep log) / (sweeps - 2), fresh processes, shared warm cache;"
                     " ratio default / nearest within each round, median",
           "rounds": rounds, "median_per_sweep": median, "median_ratios": ratios,
           "load_average": os.getloadavg()}
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
