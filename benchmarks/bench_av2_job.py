"""The Argoverse 2 job per sweep, and the cost of completing more sweeps, on the shared log.

Measures, in one process (this VM drifts by tens of percent within minutes, so compare the
ratios, not the seconds):

1. the job's stages for one sweep of the shared log (two VLP-32C, ~99,000 points) and the
   chosen ring cameras at their calibrated sizes: reading the sweep into a SourceCloud
   (``jaxdepth.io.av2.read_cloud``), the completion (``jaxdepth.batch.cloud_runner.complete_sources``,
   i.e. ``complete_cloud`` with free space on; first call = compile + run, reported apart), and
   writing the PNGs; median of ``--repeats`` runs after the compile;
2. the completion's cost against the number of sweeps, 1, 2, 3 and 5, each sweep two sources.
   The log holds two real sweeps: sweeps 3 and 5 are stand-ins, the second real sweep again,
   moved on by further multiples of the real ego step (6.6 cm) as if the car kept driving. Only
   the cost is measured here, not accuracy; the point count grows by one sweep each time;
3. for reference, the reference sweep's points as one source at ``up_lidar`` (the old
   single-origin input) against the same points as two sources.

Medians over ``--repeats`` interleaved rounds (every variant once per round); ratios are
against 1 sweep within each round, then the median. Writes benchmarks/results/av2_job.json.

    python benchmarks/bench_av2_job.py [--repeats 3] [--cameras ring_front_center,ring_side_left]
"""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib
import platform
import statistics
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
LOG = ROOT.parent / "shared" / "data" / "av2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
RESULTS = ROOT / "benchmarks" / "results" / "av2_job.json"
SWEEPS = (1, 2, 3, 5)


def stand_in_cloud(two, count: int):
    """A SourceCloud of ``count`` sweeps from the real two-sweep cloud ``two`` (sources 0-1 reference,
    2-3 the second sweep): sweep k >= 2 is the second sweep moved on by (k - 1) more ego steps."""
    from jaxdepth.io.sources import SourceCloud
    step = two.T_ref_source[2] @ np.linalg.inv(two.T_ref_source[0])  # ego motion between the sweeps
    points, source, T, sweep, names, ring = [], [], [], [], [], []
    for k in range(count):
        extra = np.linalg.matrix_power(step, max(k - 1, 0))
        for j in (0, 1):
            s = j if k == 0 else 2 + j
            mine = two.source == s
            p = two.points[mine].astype(np.float64) @ extra[:3, :3].T + extra[:3, 3]
            points.append(p.astype(np.float32))
            source.append(np.full(int(mine.sum()), len(names), np.int32))
            ring.append(two.ring[mine])
            T.append(extra @ two.T_ref_source[s])
            sweep.append(k)
            names.append(f"{two.names[s].split('@')[0]}@{k}")
    return SourceCloud(points=np.concatenate(points), source=np.concatenate(source), T_ref_source=np.stack(T),
                       lidars=tuple(two.lidars[0] for _ in names), sweep=np.asarray(sweep, np.int32),
                       names=tuple(names), ring=np.concatenate(ring))


def one_source(cloud):
    """The reference sweep's points as one source at up_lidar's pose (the single-origin input)."""
    from jaxdepth._src.types import LidarSpec
    from jaxdepth.io.sources import SourceCloud
    ref = cloud.sweep[cloud.source] == 0
    from jaxdepth._src.presets import AV2_VLP32C
    spec = cloud.lidars[0] or AV2_VLP32C  # the job states no spec (rows from the laser numbers)
    merged = LidarSpec(beams=2 * spec.beams, fov_up_deg=spec.fov_up_deg, fov_down_deg=spec.fov_down_deg,
                       columns=spec.columns)
    return SourceCloud(points=cloud.points[ref], source=np.zeros(int(ref.sum()), np.int32),
                       T_ref_source=cloud.T_ref_source[:1], lidars=(merged,), sweep=np.zeros(1, np.int32),
                       names=("merged@0",))


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cameras", default=None, help="comma-separated (default: the 7 ring cameras)")
    args = parser.parse_args(argv)
    if not LOG.is_dir():
        print(f"shared log not found: {LOG}", file=sys.stderr)
        return 1
    import jax

    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch.cloud_runner import complete_sources
    from jaxdepth.io import av2
    from jaxdepth.io.depth_png import write_depth_png

    config = SGMConfig()
    log = av2.read_log(LOG)
    cameras = av2.RING_CAMERAS if args.cameras is None else tuple(args.cameras.split(","))
    rig = av2.read_rig(log, cameras)
    two = av2.read_cloud(log, sweeps=1)
    clouds = {k: stand_in_cloud(two, k) for k in SWEEPS}
    clouds["one source"] = one_source(clouds[1])

    def complete(cloud):
        return complete_sources(cloud, rig, config=config)

    compile_s = {}
    for key, cloud in clouds.items():  # first call of each shape: compile + one run
        _, compile_s[str(key)] = timed(lambda: complete(cloud))
        print(f"first call {key}: {compile_s[str(key)]:.1f} s ({len(cloud.points)} points, "
              f"{cloud.num_sources} sources)", flush=True)

    stage = {"read": [], "complete": [], "write": []}
    runs = {str(k): [] for k in clouds}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeats):
            cloud, t_read = timed(lambda: av2.read_cloud(log))
            depth, t_complete = timed(lambda: complete(cloud))

            def write():
                for i, cam in enumerate(rig.cameras):
                    write_depth_png(pathlib.Path(tmp) / f"{cam.name}.png", depth[i, :cam.height, :cam.width])
            _, t_write = timed(write)
            for name, t in (("read", t_read), ("complete", t_complete), ("write", t_write)):
                stage[name].append(t)
            for key, c in clouds.items():
                _, t = timed(lambda: complete(c))
                runs[str(key)].append(t)
            print(f"round {r + 1}: " + ", ".join(f"{k} {v[-1]:.2f} s" for k, v in runs.items()), flush=True)

    med = {k: statistics.median(v) for k, v in runs.items()}
    ratios = {k: statistics.median(v[i] / runs["1"][i] for i in range(args.repeats)) for k, v in runs.items()}
    per_point = {str(k): med[str(k)] / len(clouds[k].points) * 1e6 for k in SWEEPS}
    result = {
        "what": "Argoverse 2 job per sweep (shared log, two VLP-32C) and completion cost vs sweeps",
        "date": datetime.date.today().isoformat(),
        "machine": platform.platform(),
        "jax": jax.__version__,
        "cameras": list(cameras),
        "repeats": args.repeats,
        "job_stage_median_s": {k: statistics.median(v) for k, v in stage.items()},
        "first_call_s (compile + run)": compile_s,
        "completion_median_s": med,
        "completion_ratio_vs_1_sweep": ratios,
        "points": {str(k): int(len(c.points)) for k, c in clouds.items()},
        "us_per_point": per_point,
        "note": "sweeps 3 and 5 are stand-ins (the second real sweep moved on by further ego steps); "
                "'one source' is the reference sweep's points as one source at up_lidar (64 merged lasers)",
    }
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("job_stage_median_s", "completion_median_s",
                                              "completion_ratio_vs_1_sweep", "us_per_point")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
