"""The nuScenes job over many samples, default options against ``--method nearest``, one process, warm.

Issue 38's second "Done when" figure: nuScenes, 6 cameras, per sweep at most 2x the same job with
``--method nearest``. The shared sample holds one sweep, so the benchmark builds, in a temporary
folder, a v1.0-mini table set the job reads exactly as a real one: ``--samples`` samples (default 10)
0.5 s apart, each key-frame ``LIDAR_TOP`` file a symbolic link to the shared sweep, the six cameras at
their full 1600 x 900 with the shared calibration, the LiDAR and the cameras at one ego pose (the
cameras 30 ms before the LiDAR, so ego-motion compensation runs as on real data); with ``--sweeps S``
each sample also gets ``S - 1`` earlier sweeps (links to the same file) 0.4 m behind each other, the
multi-source path. Camera images are not read (no guidance). Nothing is written under /work/shared.

One process (:func:`jaxdepth.batch.nuscenes_job.run_nuscenes`, the function ``jaxdepth complete
--nusc-version`` runs): a warm-up run of each method compiles its programs; then ``--rounds``
interleaved rounds, each running default then nearest (then ``--ip-basic``) into fresh output folders.
Per sweep = the run's wall (``time.perf_counter``) and process CPU (``time.process_time``, every thread)
seconds / samples; the ratio default / nearest is taken within each round, then the median. Every run
must write 6 PNGs per sample. Writes benchmarks/results/nuscenes_job.json.

``--parts N``: instead, where one sample's time goes (``--sweeps 1``), each part timed apart with
``block_until_ready`` before the clock, N times after a warm-up call each, medians: reading
(:func:`jaxdepth.batch.nuscenes_job._load`: tables, the sweep file, ``prepare_sweep``, padding), the
projection of the six cameras alone (``project_to_image`` vmapped), the job's nearest fill
(:func:`jaxdepth.batch.cloud_runner.baseline_depth`: projection + fill, on the host), the job's SGM
program without outlier removal (projection, Step 1, Steps 3-4) and with it (the default: + Step 2),
the depth's copy to the host and the six PNG writes. Step 2 = default - without removal; Steps 1 and
3-4 = without removal - projection. Writes benchmarks/results/nuscenes_job_parts.json.

``--devices N`` (branch devices2): the CPU is split into N host devices before JAX starts, and every round
also runs ``sgm@N``, the default job dealing whole samples to the N devices (``run_nuscenes(devices=N)``,
the CLI's ``--cpu-devices N``); ``--threads`` also runs ``sgm~threads``, a probe: the job's SGM calls on two
dispatch threads of one device. ``--overlap R``: instead, the SGM program of one sample alone, one call, two
calls dispatched back to back on device 0, two threads each calling on device 0, one call on each of two
devices, R interleaved rounds, medians (wall and process CPU). ``--cold R``: instead, fresh CLI processes on
a 2-sample dataroot, one device and ``--cpu-devices N``, cold (an empty cache folder each) then warm.

    python -m benchmarks.bench_nuscenes_job [--samples 10] [--sweeps 1] [--rounds 3] [--ip-basic] [--json PATH]
    python -m benchmarks.bench_nuscenes_job --parts 5 [--json PATH]
    python -m benchmarks.bench_nuscenes_job --devices 2 [--threads] --samples 20 --rounds 5 [--json PATH]
    python -m benchmarks.bench_nuscenes_job --devices 2 --overlap 15 | --cold 2 [--json PATH]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import pathlib
import statistics
import sys
import tempfile
import time

import numpy as np

from benchmarks._common import DATA, RESULTS, write_results

SAMPLE = DATA / "nuscenes" / "sample"
VERSION = "v1.0-mini"
CAMERA_LEAD_US = 30_000   # each camera fires this long before its sample's LiDAR
SAMPLE_STEP_US = 500_000  # samples 0.5 s apart (2 Hz key frames)
SWEEP_STEP_US = 50_000    # earlier sweeps 50 ms apart (20 Hz)
SWEEP_BACK_M = 0.4        # ... each this far behind the next


def _wxyz(R) -> list:
    from scipy.spatial.transform import Rotation
    x, y, z, w = Rotation.from_matrix(np.asarray(R, np.float64)).as_quat()
    return [float(w), float(x), float(y), float(z)]


def _pose(T, forward_m: float = 0.0) -> dict:
    T = np.asarray(T, np.float64)
    return {"rotation": _wxyz(T[:3, :3]), "translation": (T[:3, 3] + T[:3, 0] * forward_m).tolist()}


def build_dataroot(root: pathlib.Path, samples: int, sweeps: int) -> None:
    """The table set of the module docstring under ``root`` (``root/v1.0-mini/*.json``, ``samples/``,
    ``sweeps/``): LiDAR files are links to the shared sweep."""
    calib = json.loads((SAMPLE / "calibration.json").read_text())
    lidar_file = SAMPLE / calib["lidar_path"]
    for sub in ("samples", "sweeps"):
        (root / sub / "LIDAR_TOP").mkdir(parents=True)
    sensor = [{"token": "sensor_lidar", "channel": "LIDAR_TOP", "modality": "lidar"}]
    cs = [{"token": "cs_lidar", "sensor_token": "sensor_lidar", "camera_intrinsic": [],
           **_pose(calib["lidar2ego"])}]
    for ch, cam in calib["cameras"].items():
        sensor.append({"token": f"sensor_{ch}", "channel": ch, "modality": "camera"})
        cs.append({"token": f"cs_{ch}", "sensor_token": f"sensor_{ch}", "camera_intrinsic": cam["cam2img"],
                   **_pose(cam["cam2ego"])})
    t0 = int(round(calib["timestamp"] * 1e6))
    ego, sample, sample_data = [], [], []

    def add(token, sample_token, ts, pose, cs_token, filename, key, w=0, h=0, prev=""):
        ego.append({"token": f"ep_{token}", "timestamp": ts, **pose})
        sample_data.append({"token": token, "sample_token": sample_token, "ego_pose_token": f"ep_{token}",
                            "calibrated_sensor_token": cs_token, "timestamp": ts, "fileformat": "",
                            "is_key_frame": key, "height": h, "width": w, "filename": filename, "prev": prev,
                            "next": ""})

    for i in range(samples):
        name, ts = f"s{i:03d}", t0 + i * SAMPLE_STEP_US
        sample.append({"token": name, "timestamp": ts, "scene_token": "scene0", "prev": "", "next": ""})
        prev = ""
        for k in range(sweeps - 1, 0, -1):            # the earliest first: each links to the one before
            token = f"lidar_{name}_prev{k}"
            (root / "sweeps" / "LIDAR_TOP" / f"{token}.pcd.bin").symlink_to(lidar_file)
            add(token, name, ts - k * SWEEP_STEP_US, _pose(calib["ego2global"], -k * SWEEP_BACK_M), "cs_lidar",
                f"sweeps/LIDAR_TOP/{token}.pcd.bin", False, prev=prev)
            prev = token
        (root / "samples" / "LIDAR_TOP" / f"{name}.pcd.bin").symlink_to(lidar_file)
        add(f"lidar_{name}", name, ts, _pose(calib["ego2global"]), "cs_lidar", f"samples/LIDAR_TOP/{name}.pcd.bin",
            True, prev=prev)
        for ch in calib["cameras"]:
            add(f"{ch}_{name}", name, ts - CAMERA_LEAD_US, _pose(calib["ego2global"]), f"cs_{ch}",
                f"samples/{ch}/{name}.jpg", True, 1600, 900)
    tables = {"sensor": sensor, "calibrated_sensor": cs, "ego_pose": ego, "sample": sample,
              "sample_data": sample_data,
              "scene": [{"token": "scene0", "log_token": "log0", "nbr_samples": samples, "first_sample_token": "s000",
                         "last_sample_token": sample[-1]["token"], "name": "scene-0001", "description": ""}],
              "log": [{"token": "log0", "logfile": "n015-2018-07-24-11-22-45+0800", "vehicle": "n015",
                       "date_captured": "2018-07-24", "location": "singapore-onenorth"}]}
    for empty in ("category", "attribute", "visibility", "instance", "sample_annotation", "map"):
        tables[empty] = []
    (root / VERSION).mkdir()
    for name, records in tables.items():
        (root / VERSION / f"{name}.json").write_text(json.dumps(records))


def run_once(root: pathlib.Path, out: pathlib.Path, *, method: str, sweeps: int, samples: int) -> tuple:
    """(wall s, process CPU s) of one :func:`run_nuscenes` over the dataroot; every camera written.
    ``method``: the job's method, or ``"sgm@N"``: the default method dealt round robin to N host devices."""
    from jaxdepth.batch import devices
    from jaxdepth.batch.nuscenes_job import run_nuscenes

    threads = method == "sgm~threads"
    method, _, count = method.partition("@")
    cpu, start = time.process_time(), time.perf_counter()
    with _dispatch_threads(threads):
        summary = run_nuscenes(root, out, version=VERSION, sweeps=sweeps, method=method.partition("~")[0],
                               io_threads=devices.io_threads(), devices=int(count or 1))
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    written = len(list(out.rglob("*.png")))
    if summary.failed or written != 6 * samples:
        raise SystemExit(f"{method}: {written} PNGs written (expected {6 * samples}), failed: {summary.failed[:2]}")
    return wall, cpu


class _Later:
    """A program call running on a dispatch thread: ``np.asarray`` waits for it (the job's read-back)."""

    def __init__(self, future):
        self.future = future

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.future.result())


@contextlib.contextmanager
def _dispatch_threads(on: bool):
    """``--threads`` (a probe, not the job's code): the job's SGM program called on one of two dispatch threads,
    not on the main thread, so the two samples the job keeps in flight on its one device can execute at once."""
    if not on:
        yield
        return
    import concurrent.futures as cf

    from jaxdepth.batch import nuscenes_job
    real = nuscenes_job._depth_fn
    with cf.ThreadPoolExecutor(2) as pool:
        def wrapped(config, lidar):
            fn = real(config, lidar)
            return lambda *args: _Later(pool.submit(fn, *args))
        nuscenes_job._depth_fn = wrapped
        try:
            yield
        finally:
            nuscenes_job._depth_fn = real


def _part(fn, repeats: int) -> dict:
    """Median wall and process-CPU seconds of ``fn()`` over ``repeats`` calls after one warm-up call, and
    the last result."""
    import jax
    out = jax.block_until_ready(fn())
    walls, cpus = [], []
    for _ in range(repeats):
        cpu, start = time.process_time(), time.perf_counter()
        out = jax.block_until_ready(fn())
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - cpu)
    return {"wall_s": statistics.median(walls), "cpu_s": statistics.median(cpus), "result": out}


def parts(root: pathlib.Path, out: pathlib.Path, repeats: int) -> dict:
    """``{part: {"wall_s", "cpu_s"}}`` of one sample of the dataroot (module docstring, ``--parts``)."""
    import functools

    import jax

    import jaxdepth
    from jaxdepth._src.config import SGMConfig
    from jaxdepth._src.geometry import project_to_image
    from jaxdepth.batch import nuscenes_job
    from jaxdepth.batch.cloud_runner import baseline_depth
    from jaxdepth.batch.extras import NONE, write_outputs
    from jaxdepth.batch.runner import RunSummary
    from jaxdepth.io import nuscenes as nusc

    tables = nusc.load_tables(root, VERSION)
    job = nuscenes_job.plan(tables, out, overwrite=True, summary=RunSummary(), notify=lambda *a: None)[0]
    rec = {"read": _part(lambda: nuscenes_job._load(tables, job, sweeps=1, ego_motion=True), repeats)}
    padded, valid, rig, _, _ = rec["read"]["result"]
    cameras = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
    project = jax.jit(jax.vmap(functools.partial(project_to_image, height=cameras.height, width=cameras.width),
                               in_axes=(None, None, 0, 0)))
    rec["projection"] = _part(lambda: project(padded, valid, cameras.K, cameras.T_cam_lidar)[0], repeats)
    config = SGMConfig()
    rec["nearest_fill"] = _part(lambda: baseline_depth(padded, valid, rig, method="nearest", config=config), repeats)
    no_removal = nuscenes_job._depth_fn(config.replace(outlier_removal=False), rig.lidar)
    rec["sgm_no_removal"] = _part(lambda: no_removal(padded, valid, cameras), repeats)
    rec["sgm"] = _part(lambda: nuscenes_job._depth_fn(config, rig.lidar)(padded, valid, cameras), repeats)
    device_depth = rec["sgm"]["result"]
    rec["to_host"] = _part(lambda: np.asarray(device_depth + 0.0), repeats)   # a fresh device array each call
    depth = rec["to_host"]["result"]

    def pngs():
        for i, c in enumerate(rig.cameras):
            write_outputs(out / f"{c.name}.png", depth[i, :c.height, :c.width], extras=NONE, overwrite=True)
    out.mkdir(parents=True, exist_ok=True)
    rec["pngs"] = _part(pngs, repeats)
    times = {k: {"wall_s": v["wall_s"], "cpu_s": v["cpu_s"]} for k, v in rec.items()}
    for key in ("wall_s", "cpu_s"):
        times.setdefault("derived", {})[key] = {
            "step2": times["sgm"][key] - times["sgm_no_removal"][key],
            "steps_1_3_4": times["sgm_no_removal"][key] - times["projection"][key],
            "fill_after_projection": times["nearest_fill"][key] - times["projection"][key],
            "default_sample": times["read"][key] + times["sgm"][key] + times["to_host"][key] + times["pngs"][key],
            "nearest_sample": times["read"][key] + times["nearest_fill"][key] + times["pngs"][key]}
    return times


def overlap(root: pathlib.Path, out: pathlib.Path, repeats: int) -> dict:
    """Whether XLA:CPU runs two executions of the job's SGM program at once (module docstring, ``--overlap``):
    median wall of one call, of two calls dispatched back to back on device 0 (the job's second sample in
    flight), of two threads each calling it on device 0, and (with 2 host devices) of one call on each device;
    every form blocked on all its results before the clock stops, in interleaved rounds."""
    import concurrent.futures as cf

    import jax

    from jaxdepth._src.config import SGMConfig
    from jaxdepth._src.rig import stack_cameras
    from jaxdepth.batch import nuscenes_job
    from jaxdepth.batch.runner import RunSummary
    from jaxdepth.io import nuscenes as nusc

    tables = nusc.load_tables(root, VERSION)
    job = nuscenes_job.plan(tables, out, overwrite=True, summary=RunSummary(), notify=lambda *a: None)[0]
    padded, valid, rig, _, _ = nuscenes_job._load(tables, job, sweeps=1, ego_motion=True)
    fn = nuscenes_job._depth_fn(SGMConfig(), rig.lidar)
    targets = jax.local_devices()[:2]
    args = [jax.device_put((padded, valid, stack_cameras(rig.cameras)), d) for d in targets]
    pool = cf.ThreadPoolExecutor(2)
    forms = {"one_call": lambda: [fn(*args[0])],
             "two_dispatched_one_device": lambda: [fn(*args[0]), fn(*args[0])],
             "two_threads_one_device": lambda: [f.result() for f in [pool.submit(fn, *args[0]) for _ in range(2)]]}
    if len(targets) > 1:
        forms["two_devices"] = lambda: [fn(*args[0]), fn(*args[1])]
    for form in forms.values():   # compiles (each device its own copy) and warms
        jax.block_until_ready(form())
    times, cpus = {k: [] for k in forms}, {k: [] for k in forms}
    for _ in range(repeats):
        for name, form in forms.items():
            cpu, start = time.process_time(), time.perf_counter()
            jax.block_until_ready(form())
            times[name].append(time.perf_counter() - start)
            cpus[name].append(time.process_time() - cpu)
    pool.shutdown()
    rec = {k: statistics.median(v) for k, v in times.items()}
    rec.update({f"{k}_over_one_call": rec[k] / rec["one_call"] for k in forms if k != "one_call"})
    return {"median_wall_s": rec, "median_cpu_s": {k: statistics.median(v) for k, v in cpus.items()},
            "devices": len(targets), "repeats": repeats}


def cold(tmp: pathlib.Path, rounds: int, count: int) -> dict:
    """``--cold R``: fresh ``jaxdepth complete DATAROOT OUT --nusc-version v1.0-mini`` processes on a 2-sample
    dataroot, one device and ``--cpu-devices count``, each first with an empty cache folder of its own (``cold``:
    every program compiled; the process's wall is start-up + both samples), then again in that folder with
    ``--overwrite`` (``warm``: do both devices' programs load from the persistent cache?); the number of files
    the run left in the XLA cache and the programs folder. Variants alternate within each round."""
    from benchmarks.bench_rig_coldstart import _run

    build_dataroot(tmp / "cold-data", 2, 1)
    variants = {"one_device": [], f"devices_{count}": ["--cpu-devices", str(count)]}
    rec = {k: {"cold": [], "warm": [], "cache_files": None} for k in variants}
    for r in range(rounds):
        for name, flags in variants.items():
            cache, out = tmp / f"cache-{name}-{r}", tmp / f"out-{name}-{r}"
            argv = ["complete", tmp / "cold-data", out, "--nusc-version", VERSION, "-q", *flags]
            rec[name]["cold"].append(_run(argv, cache))
            rec[name]["warm"].append(_run(argv + ["--overwrite"], cache))
            rec[name]["cache_files"] = {sub.name: len([f for f in sub.iterdir() if f.is_file()])
                                        for sub in [cache / "jaxdepth" / "xla", cache / "jaxdepth" / "xla" / "programs"]
                                        if sub.is_dir()}
            print(f"round {r} {name}: cold {rec[name]['cold'][-1][0]:.1f} s, warm {rec[name]['warm'][-1][0]:.1f} s "
                  f"wall; cache {rec[name]['cache_files']}", flush=True)
    for v in rec.values():
        for key in ("cold", "warm"):
            v[f"{key}_median"] = {"wall_s": statistics.median(w for w, _ in v[key]),
                                  "cpu_s": statistics.median(c for _, c in v[key])}
    return rec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=10, help="samples (one key-frame sweep each), >= 8")
    ap.add_argument("--sweeps", type=int, default=1, help="sweeps per sample (the job's --sweeps)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--ip-basic", action="store_true", help="also --method ip-basic in every round")
    ap.add_argument("--devices", type=int, default=1, metavar="N",
                    help="also the default method dealt round robin to N host devices (the CPU split into N "
                         "before JAX starts), 'sgm@N' in every round")
    ap.add_argument("--parts", type=int, default=0, metavar="N",
                    help="instead: one sample's parts, N timed calls each (module docstring)")
    ap.add_argument("--threads", action="store_true",
                    help="also 'sgm~threads' in every round: a probe, the job's SGM calls on two dispatch threads, "
                         "one device")
    ap.add_argument("--overlap", type=int, default=0, metavar="N",
                    help="instead: whether two executions of the SGM program run at once, N rounds (module docstring)")
    ap.add_argument("--cold", type=int, default=0, metavar="R",
                    help="instead: R rounds of cold and warm CLI processes, one device and --devices (module docstring)")
    ap.add_argument("--json", type=pathlib.Path, default=None,
                    help="default: results/nuscenes_job.json (--parts: results/nuscenes_job_parts.json)")
    args = ap.parse_args(argv)
    args.json = args.json or RESULTS / ("nuscenes_job_parts.json" if args.parts else "nuscenes_job.json")
    if not SAMPLE.exists():
        print(f"shared nuScenes sample missing: {SAMPLE}", file=sys.stderr)
        return 1
    if args.samples < 8:
        ap.error("--samples must be at least 8")
    from jaxdepth.batch import devices
    devices.quiet_jax_start()
    devices.keep_freed_memory()
    if args.devices > 1:
        devices.split_cpu_into_devices(args.devices)
    t0 = time.time()
    command = "python -m benchmarks.bench_nuscenes_job " + " ".join(sys.argv[1:] if argv is None else argv)

    def save(data: dict, **rec) -> int:
        write_results(args.json, {"command": command, "data": {"source": str(SAMPLE.relative_to(DATA)), **data},
                                  **rec, "load_average": os.getloadavg()}, None, t0)
        return 0

    one_sample = {"cameras": 6, "camera_size": [1600, 900]}
    if args.cold:
        with tempfile.TemporaryDirectory(prefix="jaxdepth-nusccold-") as tmp_name:
            rec = cold(pathlib.Path(tmp_name), args.cold, max(2, args.devices))
        return save({"samples": 2, "cameras": 6}, cold=rec)
    if args.overlap or args.parts:
        with tempfile.TemporaryDirectory(prefix="jaxdepth-nuscparts-") as tmp_name:
            tmp = pathlib.Path(tmp_name)
            build_dataroot(tmp / "data", 8, 1)
            if args.overlap:
                rec = overlap(tmp / "data", tmp / "out", args.overlap)
            else:
                times = parts(tmp / "data", tmp / "out", args.parts)
        if args.overlap:
            print(json.dumps(rec, indent=1))
            return save(one_sample, overlap=rec)
        for k, v in times.items():
            print(k, json.dumps(v))
        return save(one_sample, parts=times,
                    method="one process, each part after a warm-up call, median of --parts calls, block_until_ready")
    methods = (["sgm"] + ([f"sgm@{args.devices}"] if args.devices > 1 else [])
               + (["sgm~threads"] if args.threads else []) + ["nearest"]
               + (["ip-basic"] if args.ip_basic else []))
    rounds, first = [], {}
    with tempfile.TemporaryDirectory(prefix="jaxdepth-nuscjob-") as tmp_name:
        tmp = pathlib.Path(tmp_name)
        build_dataroot(tmp / "data", args.samples, args.sweeps)
        for method in methods:   # compiles each method's programs (and the first calls' set-up)
            first[method] = run_once(tmp / "data", tmp / f"warmup-{method}", method=method, sweeps=args.sweeps,
                                     samples=args.samples)
            print(f"warm-up {method}: {first[method][0]:.1f} s wall", flush=True)
        for r in range(args.rounds):
            times = {m: run_once(tmp / "data", tmp / f"r{r}-{m}", method=m, sweeps=args.sweeps, samples=args.samples)
                     for m in methods}
            per = {m: {"wall_s": w / args.samples, "cpu_s": c / args.samples} for m, (w, c) in times.items()}
            per["ratio_wall"] = per["sgm"]["wall_s"] / per["nearest"]["wall_s"]
            per["ratio_cpu"] = per["sgm"]["cpu_s"] / per["nearest"]["cpu_s"]
            if args.threads:
                per["threads_over_one_wall"] = per["sgm~threads"]["wall_s"] / per["sgm"]["wall_s"]
                per["ratio_wall_threads"] = per["sgm~threads"]["wall_s"] / per["nearest"]["wall_s"]
            if args.devices > 1:
                many = f"sgm@{args.devices}"
                per["ratio_wall_devices"] = per[many]["wall_s"] / per["nearest"]["wall_s"]
                per["ratio_cpu_devices"] = per[many]["cpu_s"] / per["nearest"]["cpu_s"]
                per["devices_over_one_wall"] = per[many]["wall_s"] / per["sgm"]["wall_s"]
            rounds.append(per)
            print(f"round {r}: " + ", ".join(f"{m} {per[m]['wall_s']:.3f} s/sweep" for m in methods)
                  + f", ratio {per['ratio_wall']:.2f} (CPU {per['ratio_cpu']:.2f})", flush=True)
    median = {m: {k: statistics.median(r[m][k] for r in rounds) for k in ("wall_s", "cpu_s")} for m in methods}
    ratios = {k: statistics.median(r[k] for r in rounds) for k in rounds[0] if k.startswith(("ratio", "devices"))}
    print(f"median per sweep: sgm {median['sgm']['wall_s']:.3f} s, nearest {median['nearest']['wall_s']:.3f} s; "
          f"ratio {ratios['ratio_wall']:.2f} wall, {ratios['ratio_cpu']:.2f} CPU" + "".join(
              f"; {k} {v:.3f}" for k, v in ratios.items() if k not in ("ratio_wall", "ratio_cpu")))
    return save({"samples": args.samples, "sweeps": args.sweeps, "devices": args.devices, **one_sample},
                method="one process, warm (a warm-up run per method first); per sweep = run wall / CPU seconds "
                       "over samples; ratio default (sgm) / nearest within each round, median",
                warmup_runs={m: {"wall_s": w, "cpu_s": c} for m, (w, c) in first.items()},
                rounds=rounds, median_per_sweep=median, median_ratios=ratios)


if __name__ == "__main__":
    raise SystemExit(main())
