"""The Argoverse 2 job's sweep taken apart: CPU seconds, system seconds and page faults of each part.

One process, the job's own functions on the shared log's sweeps in turn (LiDAR time, the 7 ring
cameras, default options), each part timed apart with ``block_until_ready`` before the clock:
reading (:func:`jaxdepth.batch.av2_job._load`: Feather, poses, the rig check), the sources
(:func:`jaxdepth.batch.sources_job.cloud_sources`), the SGM program
(:func:`jaxdepth.batch.program_cache.sources_stages`, through the program cache as the job calls it),
the device-to-host copy of the depth, the 7 PNGs (:func:`jaxdepth.batch.extras.write_outputs`, into a
temporary folder) and the job's nearest fill of the same sweep (:func:`jaxdepth.batch.av2_job.baseline_depth`).
Per part: wall, process CPU (every thread), system CPU and minor page faults (``getrusage``); the
first sweep (trace, cache load) is reported with the rest. The compile cache is a folder of its own
under ``--cache`` (default: a temporary one, so the first sweep compiles).

With the job's host-memory setting (:func:`jaxdepth.batch.devices.keep_freed_memory`) on, as the
command line runs, unless ``--release-memory`` (glibc's defaults: the process before that change).
Writes benchmarks/results/av2_sweep_parts.json.

    python -m benchmarks.bench_av2_sweep_parts [--sweeps 5] [--release-memory] [--cache DIR] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import resource
import sys
import tempfile
import time

from benchmarks._common import RESULTS, write_results
from benchmarks.bench_av2_coldstart import LOG


def _part(fn, record: dict, name: str):
    """Runs ``fn()`` and adds its wall, CPU and system seconds and minor faults to ``record[name]``."""
    import jax
    before, wall, cpu = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter(), time.process_time()
    out = jax.block_until_ready(fn())
    after = resource.getrusage(resource.RUSAGE_SELF)
    record[name] = {"wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu,
                    "system_s": after.ru_stime - before.ru_stime, "faults": after.ru_minflt - before.ru_minflt}
    return out


def one_sweep(log_, ts: int, cameras, config, out: pathlib.Path) -> dict:
    """The parts of one sweep (``{part: {wall_s, cpu_s, system_s, faults}}``)."""
    import numpy as np

    import jaxdepth
    from jaxdepth.batch import av2_job
    from jaxdepth.batch.cloud_runner import CloudJob
    from jaxdepth.batch.extras import NONE, write_outputs
    from jaxdepth.batch.program_cache import sources_stages
    from jaxdepth.batch.sources_job import cloud_sources

    rec = {}
    job = CloudJob(name=str(ts), outputs=(), source=(LOG, ts, av2_job._camera_times(log_, cameras, ts, "lidar")))
    cloud, rig = _part(lambda: av2_job._load(job, tables={LOG: (log_, 0)}, cameras=cameras, force=False), rec, "read")
    rig_cameras = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
    sources, _ = _part(lambda: cloud_sources(cloud, fallback=rig.lidar,
                                            witness_cell_spacings=config.free_space_witness_cell,
                                            min_cells=config.free_space_min_cells), rec, "sources")
    stages = _part(lambda: sources_stages(sources, rig_cameras, config=config), rec, "sgm_program")
    depth = _part(lambda: np.asarray(stages.depth), rec, "to_host")

    def pngs():
        for i, c in enumerate(rig.cameras):
            write_outputs(out / f"{c.name}.png", depth[i, :c.height, :c.width], extras=NONE, overwrite=True)
    _part(pngs, rec, "pngs")
    _part(lambda: av2_job.baseline_depth(cloud, rig, method="nearest", config=config), rec, "nearest_fill")
    rec["resident_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return rec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweeps", type=int, default=5, help="sweeps timed (the log's two, alternately)")
    ap.add_argument("--release-memory", action="store_true", help="glibc's default malloc (no keep_freed_memory)")
    ap.add_argument("--cache", type=pathlib.Path, default=None, help="compile cache root (default: a temporary one)")
    ap.add_argument("--json", type=pathlib.Path, default=RESULTS / "av2_sweep_parts.json")
    args = ap.parse_args(argv)
    if not LOG.exists():
        print(f"shared Argoverse 2 log missing: {LOG}", file=sys.stderr)
        return 1
    t0 = time.time()
    from jaxdepth.batch import devices
    kept = False if args.release_memory else devices.keep_freed_memory()
    with tempfile.TemporaryDirectory(prefix="jaxdepth-av2parts-") as tmp_name:
        tmp = pathlib.Path(tmp_name)
        os.environ["XDG_CACHE_HOME"] = str(args.cache or tmp / "cache")
        devices.use_compile_cache()
        from jaxdepth import SGMConfig
        from jaxdepth.io import av2
        log_ = av2.read_log(LOG)
        sweeps = []
        for k in range(args.sweeps):
            sweeps.append(one_sweep(log_, log_.sweeps[k % len(log_.sweeps)], av2.RING_CAMERAS, SGMConfig(), tmp))
            print(f"sweep {k}: " + ", ".join(f"{name} {v['cpu_s']:.2f} s CPU ({v['system_s']:.2f} sys, "
                                             f"{v['faults']} faults)" for name, v in sweeps[-1].items()
                                             if isinstance(v, dict)) + f"; load {os.getloadavg()[0]:.1f}", flush=True)
    doc = {"command": "python -m benchmarks.bench_av2_sweep_parts " + " ".join(sys.argv[1:] if argv is None else argv),
           "keep_freed_memory": kept, "log": str(LOG.name), "sweeps": sweeps, "load_average": os.getloadavg()}
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
