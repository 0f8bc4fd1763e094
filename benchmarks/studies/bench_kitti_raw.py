"""A KITTI raw drive as users run it: one `jaxdepth complete` vs the shell loop over `complete-rig`.

Issue 15: before `jaxdepth complete` understood raw drives, the workaround was one
`jaxdepth complete-rig SWEEP.bin RIG.json OUT/` process per sweep (each paying imports,
JAX start-up and a compile-cache load). This script builds a one-drive KITTI raw tree in a
temporary directory (outside the repository) from the two shared sweeps, repeated to
``--sweeps`` frames, and times, each as subprocesses with a warm compile cache (a temporary
XDG_CACHE_HOME, filled by one untimed run of each command):

- ``jaxdepth complete DATE/ OUT/ --crop``: every sweep x cameras 2 and 3;
- ``--loop`` sweeps of ``jaxdepth complete-rig SWEEP.bin rig.json OUT/`` (the same cameras,
  from ``rig_from_kitti_raw(crop=True)``; it also runs the sweep check of ``prepare_sweep``).

    python -m benchmarks.studies.bench_kitti_raw [--sweeps 16] [--loop 4]

Prints wall times and per-sweep costs; nothing is written into the repository.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

from benchmarks._common import ROOT as REPO
SHARED = REPO.parent / "shared" / "data" / "kitti"


def build_tree(root: pathlib.Path, sweeps: int) -> pathlib.Path:
    date = root / "2011_09_26"
    data = date / "2011_09_26_drive_0001_sync" / "velodyne_points" / "data"
    data.mkdir(parents=True)
    sources = [SHARED / "drive_0001_frame05" / "lidar_data.bin", SHARED / "raw_2011_09_26_scene2" / "lidar_data.bin"]
    for i in range(sweeps):
        shutil.copyfile(sources[i % 2], data / f"{i:010d}.bin")
    for name in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        shutil.copyfile(SHARED / "drive_0001_frame05" / name, date / name)
    return date


def run(args: list[str], env: dict) -> float:
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "jaxdepth.cli", *args], env=env, capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f"jaxdepth {' '.join(args)} failed:\n{result.stderr[-2000:]}")
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweeps", type=int, default=16)
    parser.add_argument("--loop", type=int, default=4, help="sweeps timed with the complete-rig loop")
    opts = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        date = build_tree(tmp / "raw", opts.sweeps)
        env = {**os.environ, "XDG_CACHE_HOME": str(tmp / "cache"), "JAXDEPTH_COMPILE_CACHE": "1",
               "PYTHONPATH": str(REPO)}
        from jaxdepth.io import rig_from_kitti_raw, write_rig_json
        rig = rig_from_kitti_raw(date / "calib_cam_to_cam.txt", date / "calib_velo_to_cam.txt", crop=True)
        write_rig_json(tmp / "rig.json", rig)
        sweeps = sorted((date / "2011_09_26_drive_0001_sync" / "velodyne_points" / "data").glob("*.bin"))
        # warm the compile cache of both commands (untimed)
        run(["complete", str(date), str(tmp / "warm"), "--crop", "-q"], env)
        run(["complete-rig", str(sweeps[0]), str(tmp / "rig.json"), str(tmp / "warm_rig"), "-q"], env)
        whole = run(["complete", str(date), str(tmp / "out"), "--crop", "-q"], env)
        loop = sum(run(["complete-rig", str(s), str(tmp / "rig.json"), str(tmp / "rig_out" / s.stem), "-q"], env)
                   for s in sweeps[:opts.loop])
    n = opts.sweeps
    print(f"jaxdepth complete, {n} sweeps x 2 cameras (352x1216): {whole:.1f} s, {whole / n:.2f} s per sweep "
          f"({2 * n / whole:.2f} frames/s)")
    print(f"complete-rig loop, {opts.loop} sweeps x 2 cameras: {loop:.1f} s, {loop / opts.loop:.2f} s per sweep")
    print(f"per-sweep ratio complete / loop: {(whole / n) / (loop / opts.loop):.2f}")


if __name__ == "__main__":
    main()
