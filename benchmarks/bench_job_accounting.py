"""The Argoverse 2 and nuScenes jobs per sweep, accounted thread by thread: where a job's CPU goes outside its program.

One process per invocation, the jobs' own entry points (:func:`jaxdepth.batch.av2_job.run_av2` on a log of
``--sweeps`` sweeps built as :mod:`benchmarks.bench_av2_log` builds it, camera time; and
:func:`jaxdepth.batch.nuscenes_job.run_nuscenes` on a table set of ``--sweeps`` samples built as
:mod:`benchmarks.bench_nuscenes_job` builds it), the command line's process settings
(:func:`jaxdepth.batch.devices.keep_freed_memory`; the compile cache in a temporary folder), a warm-up run
per method, then ``--rounds`` rounds of default (``sgm``) and ``--method nearest``, interleaved.

The job's host functions are wrapped, by module attribute, with timers that add each call's wall and
**thread** CPU seconds (``time.thread_time``: the calling thread's CPU only) to its part: reading a sweep
(the job's ``_load``, on the reader threads), the sources pytree (``cloud_sources``, Argoverse 2: on the main
thread up to main 2b66b47, since branch av2host inside ``cloud_call``, the sweep's program inputs built on the
reader threads after ``_load``: its own part, counted with the reader threads), each camera's PNG (``write_outputs`` on the writer threads, and inside it the float -> uint16
conversion, the PNG encoding (row filter + zlib) and the atomic write); and on the main thread the calls that
hold a sweep's compute (the Argoverse 2 job's ``complete_cloud`` or nearest fill, the nuScenes job's wait for a
dispatched sample; since av2host the program's dispatch and ``read_back``, the wait for a sweep's result): their wall over the run's wall is the share of the wall the job spends on compute, the rest
being reading and writing the main thread waits for (pipelined: near 1). ``main thread`` is the thread that
runs the job (dispatch, Python per sweep and camera, waiting is not CPU); ``program and other threads`` is
the process CPU less the main, reader and writer threads' CPU: XLA's threads running the compiled program
(or the nearest fill), which no timer of the host sees. Per sweep = run / sweeps (warm: the first sweep's
set-up is a small share of ``--sweeps 10``). Wall and process CPU as ``bench_av2_log`` / ``bench_nuscenes_job``
would not be comparable (fresh processes there); the ratios of this tool are its own. Each run's PNGs are
hashed (SHA-256 of the relative paths and file bytes, ``png_sha256``): two checkouts' runs compare byte for byte.

Runs on another checkout's library too: ``cd <checkout> && PYTHONPATH=<checkout> python
<this file> ...`` (the wrapped names exist there; the JSON records which ``jaxdepth`` ran).

``--png-zlib``: ``default`` (the installation's encoder: ISA-L for levels 1-3 with the extra ``fast-png``
since branch pngisal, else zlib); ``zlib`` forces Python's zlib; ``isal`` on a checkout without
``jaxdepth.io.png_encoder`` (before pngisal) is the pngfast probe: ``encode_depth_png`` calls ISA-L's
``compress`` (package ``isal`` importable) instead of zlib's. The JSON's ``png_encoder`` says which wrote.

    python -m benchmarks.bench_job_accounting [--job av2|nuscenes|both] [--sweeps 10] [--rounds 2]
        [--png-zlib default|zlib|isal]
        [--json PATH]
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import os
import pathlib
import statistics
import sys
import tempfile
import threading
import time

from benchmarks._common import RESULTS, write_results

#: (module, attribute, part): the host functions timed. The PNG parts nest inside ``write_outputs``.
WRAPPED = (("jaxdepth.batch.av2_job", "_load", "read (reader threads)"),
           ("jaxdepth.batch.nuscenes_job", "_load", "read (reader threads)"),
           ("jaxdepth.batch.sources_job", "cloud_sources", "sources pytree (cloud_sources)"),
           ("jaxdepth.batch.sources_job", "cloud_call", "prepare: cameras, sources pytree (reader threads)"),
           ("jaxdepth.batch.sources_job", "complete_cloud", "main: the sweep's completion, sources included"),
           ("jaxdepth.batch.cloud_runner", "read_back", "main: waiting for a sweep's result"),
           ("jaxdepth.batch.cloud_runner", "baseline_depth", "main: the sweep's nearest fill"),
           ("jaxdepth.batch.nuscenes_job._SampleRun", "collect", "main: waiting for a sample's result"),
           ("jaxdepth.batch.program_cache.Program", "__call__", "main: calling a cached program (dispatch)"),
           ("jaxdepth.batch.extras", "write_outputs", "PNG writes (writer threads)"),
           ("jaxdepth.io.depth_png", "encode_depth_uint16", "  of which float -> uint16"),
           ("jaxdepth.io.depth_png", "encode_depth_png", "  of which PNG encoding (filter, zlib)"),
           ("jaxdepth.io.depth_png", "atomic_write_bytes", "  of which atomic write"))
#: The wall of the outermost ``main:`` calls (a program call inside ``complete_cloud`` counted once).
COMPUTE = "main thread in compute calls (wall)"
#: Parts run on the reader and writer threads (not nested in one another).
IO_THREAD_PARTS = ("read (reader threads)", "prepare: cameras, sources pytree (reader threads)",
                   "PNG writes (writer threads)")


class Accounts:
    """Thread-safe ``{part: [wall s, thread CPU s, calls]}``, filled by the wrapped functions."""

    def __init__(self):
        self.lock = threading.Lock()
        self.parts = collections.defaultdict(lambda: [0.0, 0.0, 0])
        self.nested = threading.local()

    def wrap(self, module, name: str, part: str) -> None:
        fn = getattr(module, name)
        compute = part.startswith("main:")

        def timed(*args, **kwargs):
            outer = compute and not getattr(self.nested, "inside", False)
            if outer:
                self.nested.inside = True
            wall, cpu = time.perf_counter(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                seconds = time.perf_counter() - wall
                with self.lock:
                    entry = self.parts[part]
                    entry[0] += seconds
                    entry[1] += time.thread_time() - cpu
                    entry[2] += 1
                    if outer:
                        self.parts[COMPUTE][0] += seconds
                        self.nested.inside = False
        setattr(module, name, timed)

    def take(self) -> dict:
        with self.lock:
            out = {k: list(v) for k, v in self.parts.items()}
            self.parts.clear()
        return out


def install(accounts: Accounts) -> None:
    import importlib
    for module, name, part in WRAPPED:
        owner, _, cls = module.rpartition(".")
        target = importlib.import_module(module) if not cls.lstrip("_")[:1].isupper() else getattr(importlib.import_module(owner), cls)
        if hasattr(target, name):           # an older checkout lacks the newer names
            accounts.wrap(target, name, part)


def av2_runner(tmp: pathlib.Path, sweeps: int):
    """``(run(method, out) -> summary, warm-up log)`` of the Argoverse 2 job on a built log of ``sweeps`` sweeps."""
    from benchmarks.bench_av2_log import build_log, pose_times
    from jaxdepth.batch import devices
    from jaxdepth.batch.av2_job import run_av2
    sweep_times, image_times = pose_times(100_000_000, sweeps), pose_times(50_000_000, 2 * sweeps)
    long = build_log(tmp / "long", sweep_times, image_times)
    short = build_log(tmp / "short", sweep_times[:2], image_times[:4])

    def run(method, out, log=long):
        return run_av2(log, out, method=method, io_threads=devices.io_threads()), 7

    return run, lambda method, out: run(method, out, short)


def nuscenes_runner(tmp: pathlib.Path, samples: int):
    """As :func:`av2_runner`, the nuScenes job over ``samples`` samples (one sweep each)."""
    from benchmarks.bench_nuscenes_job import VERSION, build_dataroot
    from jaxdepth.batch import devices
    from jaxdepth.batch.nuscenes_job import run_nuscenes
    build_dataroot(tmp / "data", samples, 1)

    def run(method, out):
        return run_nuscenes(tmp / "data", out, version=VERSION, sweeps=1, method=method,
                            io_threads=devices.io_threads()), 6

    return run, run


def one_run(run, method: str, out: pathlib.Path, sweeps: int, accounts: Accounts) -> dict:
    """Per-sweep seconds of one job run: wall, process CPU, main-thread CPU, each part, and the rest."""
    accounts.take()
    wall, cpu, main = time.perf_counter(), time.process_time(), time.thread_time()
    summary, cameras = run(method, out)
    wall, cpu, main = time.perf_counter() - wall, time.process_time() - cpu, time.thread_time() - main
    written = len(list(out.rglob("*.png")))
    if summary.failed or written != cameras * sweeps:
        raise SystemExit(f"{method}: {written} PNGs (expected {cameras * sweeps}), failed {summary.failed[:2]}")
    parts = accounts.take()
    digest = hashlib.sha256()
    for path in sorted(out.rglob("*.png")):
        digest.update(path.relative_to(out).as_posix().encode() + b"\0" + path.read_bytes())
    io_cpu = sum(parts[p][1] for p in IO_THREAD_PARTS if p in parts)
    compute_wall = parts.pop(COMPUTE, [0.0])[0]
    out = {"png_sha256": digest.hexdigest(), "wall_s": wall / sweeps, "cpu_s": cpu / sweeps, "main_thread_cpu_s": main / sweeps,
           "program_and_other_threads_cpu_s": (cpu - main - io_cpu) / sweeps, "compute_wall_share": compute_wall / wall,
           "parts": {p: {"wall_s": w / sweeps, "thread_cpu_s": c / sweeps, "calls": n} for p, (w, c, n) in parts.items()}}
    return out


def job_rounds(name: str, runner, tmp: pathlib.Path, sweeps: int, rounds: int, accounts: Accounts) -> dict:
    run, warm = runner(tmp / name, sweeps)
    for method in ("sgm", "nearest"):
        warm(method, tmp / f"{name}-warm-{method}")
    out = []
    for r in range(rounds):
        per = {m: one_run(run, m, tmp / f"{name}-r{r}-{m}", sweeps, accounts) for m in ("sgm", "nearest")}
        per["ratio_cpu"] = per["sgm"]["cpu_s"] / per["nearest"]["cpu_s"]
        per["ratio_wall"] = per["sgm"]["wall_s"] / per["nearest"]["wall_s"]
        per["load_average"] = os.getloadavg()[0]
        out.append(per)
        print(f"{name} round {r}: " + "; ".join(
            f"{m} {per[m]['cpu_s']:.3f} CPU s/sweep ({per[m]['wall_s']:.3f} wall, compute "
            f"{per[m]['compute_wall_share']:.2f} of it), program+XLA "
            f"{per[m]['program_and_other_threads_cpu_s']:.3f}, main {per[m]['main_thread_cpu_s']:.3f}, "
            + ", ".join(f"{p.strip()} {v['thread_cpu_s']:.3f}" for p, v in per[m]["parts"].items())
            for m in ("sgm", "nearest")) + f"; load {per['load_average']:.1f}", flush=True)
    return {"rounds": out, "median": median(out)}


def median(rounds: list) -> dict:
    """Medians over rounds of every per-sweep figure."""
    out = {}
    for m in ("sgm", "nearest"):
        first = rounds[0][m]
        out[m] = {k: statistics.median(r[m][k] for r in rounds) for k in first if k not in ("parts", "png_sha256")}
        out[m]["png_sha256"] = sorted({r[m]["png_sha256"] for r in rounds})
        out[m]["parts"] = {p: statistics.median(r[m]["parts"].get(p, {}).get("thread_cpu_s", 0.0) for r in rounds)
                           for p in first["parts"]}
    for k in ("ratio_cpu", "ratio_wall"):
        out[k] = statistics.median(r[k] for r in rounds)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--job", choices=("av2", "nuscenes", "both"), default="both")
    ap.add_argument("--sweeps", type=int, default=10, help="sweeps of the Argoverse 2 log / nuScenes samples (>= 8)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", type=pathlib.Path, default=RESULTS / "job_accounting.json")
    ap.add_argument("--png-zlib", choices=("default", "zlib", "isal"), default="default",
                    help="default: the installation's PNG encoder; zlib: Python's zlib forced; isal: ISA-L (before "
                         "branch pngisal a probe replacing encode_depth_png's zlib.compress): the same values")
    args = ap.parse_args(argv)
    if args.sweeps < 8:
        ap.error("--sweeps must be at least 8")
    t0 = time.time()
    import jaxdepth
    from jaxdepth.batch import devices
    devices.quiet_jax_start()
    devices.keep_freed_memory()
    import jaxdepth.io.depth_png as depth_png
    png_encoder = getattr(depth_png, "png_encoder", None)
    if args.png_zlib == "zlib" and png_encoder is not None:
        depth_png._isal_zlib = None
    elif args.png_zlib == "isal" and png_encoder is None:
        import types
        import zlib

        from isal import isal_zlib
        depth_png.zlib = types.SimpleNamespace(compress=isal_zlib.compress, crc32=zlib.crc32)
    elif args.png_zlib == "isal" and not png_encoder().startswith("isal"):
        ap.error("--png-zlib isal: the package isal is not installed (pip install -e '.[fast-png]')")
    if png_encoder is not None:
        encoder = png_encoder()
    else:
        import zlib
        encoder = "isal (probe)" if args.png_zlib == "isal" else f"zlib {zlib.ZLIB_RUNTIME_VERSION}"
    accounts = Accounts()
    install(accounts)
    jobs = {}
    with tempfile.TemporaryDirectory(prefix="jaxdepth-jobacc-") as tmp_name:
        tmp = pathlib.Path(tmp_name)
        os.environ["XDG_CACHE_HOME"] = str(tmp / "cache")
        devices.use_compile_cache()
        for name, runner in (("av2", av2_runner), ("nuscenes", nuscenes_runner)):
            if args.job in (name, "both"):
                jobs[name] = job_rounds(name, runner, tmp, args.sweeps, args.rounds, accounts)
    doc = {"command": "python -m benchmarks.bench_job_accounting " + " ".join(sys.argv[1:] if argv is None else argv),
           "jaxdepth": str(pathlib.Path(jaxdepth.__file__).parent), "sweeps": args.sweeps,
           "method": "one process, warm; per sweep = run / sweeps; parts: thread CPU of the wrapped host functions; "
                     "program_and_other_threads = process CPU - main thread - reader and writer threads",
           "png_zlib": args.png_zlib, "png_encoder": encoder, "jobs": jobs, "load_average": os.getloadavg()}
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
