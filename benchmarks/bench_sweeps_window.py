"""Multi-sweep jobs at a scene's start: programs compiled with and without the job's sweep window.

A nuScenes ``--sweeps 3`` run meets samples holding 1, 2 and 3 sweeps (a scene's first, second and
later samples). Without a window each count is a program of its own (the one-sweep sample takes
the single-source rig program); with the window (``complete_cloud(..., window=(0, -1, -2))``, what the
job now passes) the two-sweep sample is spread over three sources with empty ones
(:func:`jaxdepth.batch.sources_job.fit_to_window`) and runs the three-sweep program; the one-sweep sample
runs the rig program there too (branch onesource: ``complete_rig``'s program for one source at the origin). Data: the shared
nuScenes sample (6 cameras of 1600 x 900); its one sweep stands in for the earlier sweeps too, moved
1.5 m back per sweep (a stand-in: only the program count and bytes are measured, not accuracy).

Per variant, in this one process: each frame's first call (trace + compile or cache-free load + run),
wall and CPU seconds, the compiles counted through ``jax.monitoring``; the depths of the two variants
are checked bit-identical. No persistent compile cache (every compile is paid).

    python -m benchmarks.bench_sweeps_window [--json benchmarks/results/sweeps_window.json]
"""

from __future__ import annotations

import argparse
import resource
import sys
import time

import numpy as np

from benchmarks._common import DATA, RESULTS, write_results


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def clouds(sweep_path, counts=(1, 2, 3)):
    """SourceClouds of the sample's sweep as sweeps 0, -1, ... (each earlier copy 1.5 m back)."""
    from jaxdepth._src.presets import NUSCENES_HDL32
    from jaxdepth.io import read_points
    from jaxdepth.io.sources import SourceCloud
    xyz = np.asarray(read_points(sweep_path, columns=5)[0][:, :3], np.float32)
    out = []
    for n in counts:
        T = np.tile(np.eye(4), (n, 1, 1))
        T[:, 0, 3] = -1.5 * np.arange(n)
        pts = np.concatenate([xyz + T[k, :3, 3].astype(np.float32) for k in range(n)])
        out.append(SourceCloud(points=pts, source=np.repeat(np.arange(n, dtype=np.int32), len(xyz)), T_ref_source=T,
                               lidars=(NUSCENES_HDL32,) * n, sweep=-np.arange(n, dtype=np.int32),
                               names=tuple(f"LIDAR_TOP@{-k}" for k in range(n))))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(RESULTS / "sweeps_window.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    import jax
    import jax.monitoring

    from jaxdepth.batch.sources_job import complete_cloud
    from jaxdepth.io import rig_from_nuscenes_calibration

    sample = DATA / "nuscenes" / "sample"
    found = sorted(sample.glob("*LIDAR_TOP*.pcd.bin")) if sample.is_dir() else []
    if not found:
        sys.exit(f"no nuScenes LIDAR_TOP sweep in {sample} (the shared sample)")
    jax.config.update("jax_enable_compilation_cache", False)
    rig = rig_from_nuscenes_calibration(sample / "calibration.json")
    frames = clouds(found[0])
    compiles = []

    def on_duration(event, secs, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration" and "_program" in str(kwargs.get("fun_name")):
            compiles.append((kwargs.get("fun_name"), secs))

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    results, depths = {}, {}
    for variant, window in (("window", (0, -1, -2)), ("own programs", None)):
        rows = []
        jax.clear_caches()          # each variant compiles what it needs
        for cloud in frames:
            compiles.clear()
            w, c = time.perf_counter(), _cpu()
            depth = complete_cloud(cloud, rig, window=window)
            rows.append({"sweeps": cloud.num_sources, "first_call_wall_s": time.perf_counter() - w,
                         "first_call_cpu_s": _cpu() - c, "compiles": [name for name, _ in compiles],
                         "compile_wall_s": sum(s for _, s in compiles)})
            depths.setdefault(cloud.num_sources, []).append(depth)
            print(variant, rows[-1], flush=True)
        results[variant] = {"frames": rows, "compiles": sum(len(r["compiles"]) for r in rows),
                            "wall_s": sum(r["first_call_wall_s"] for r in rows),
                            "cpu_s": sum(r["first_call_cpu_s"] for r in rows)}
    identical = all(np.array_equal(a, b) for a, b in depths.values())
    if not identical:
        raise SystemExit("depth differs between the window and the frames' own programs")
    doc = {"what": "nuScenes sample (6 cameras) as 1-, 2- and 3-sweep frames: first calls with the job's sweep "
                   "window (one program) against each frame's own program; no persistent cache",
           "variants": results, "outputs_identical": identical,
           "ratio_cpu_window_over_own": results["window"]["cpu_s"] / results["own programs"]["cpu_s"]}
    try:
        import os
        doc["load_average"] = os.getloadavg()
    except OSError:
        pass
    write_results(args.json, doc, None, t0)
    print({k: (v["compiles"], round(v["wall_s"], 1), round(v["cpu_s"], 1)) for k, v in results.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
