"""One-command accelerator check: frames/s and peak memory of jaxdepth on this machine's GPU and CPU.

Installs nothing; run from the repository root (or anywhere jaxdepth is importable)::

    python benchmarks/gpu_check.py [--size tiny|small|full] [--cpu-size tiny|small|full] [--json [PATH]]

Cases, all on synthetic inputs (the procedural street of ``jaxdepth.make_street_scene``):

- ``jaxdepth.complete`` vmapped over a batch of sparse depth images, 352 x 1216, batches
  1, 8 and 64 (``full``; ``small``: 1 and 8; ``tiny``: 64 x 128, batches 1 and 2);
- ``jaxdepth.complete_rig`` on one 32-beam sweep and a surround rig of 6 cameras, 900 x 1600
  (``full``; ``small``: 450 x 800; ``tiny``: 2 cameras, 72 x 128).

Each case is jitted, compiled once (reported apart as ``compile_s``), then timed ``--repeats``
times with ``block_until_ready`` before the clock is read; the median is reported as ms per
call and frames (camera images) per second. Peak memory: ``device.memory_stats()
["peak_bytes_in_use"]`` where the backend reports it (GPU, TPU; the process's peak so far,
read after each case, cases run smallest first), else ``null`` (CPU), plus the process's
max RSS. The accelerator (the default backend when it is not the CPU) runs ``--size``
(default ``full``); the CPU backend of the same process runs ``--cpu-size`` (default
``small``: fewer repeats, no batch of 64; ``--cpu-size full`` for the accelerator's sizes).
``--json`` writes everything to ``benchmarks/results/gpu_check.json`` (or PATH).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import resource
import statistics
import sys
import time

import numpy as np

RESULTS = pathlib.Path(__file__).resolve().parent / "results" / "gpu_check.json"

# (frame height, width, batches), (rig cameras, image scale of the 900 x 1600 surround cameras)
SIZES = {
    "tiny": {"frame": (64, 128, (1, 2)), "rig": (2, 0.08)},
    "small": {"frame": (352, 1216, (1, 8)), "rig": (6, 0.5)},
    "full": {"frame": (352, 1216, (1, 8, 64)), "rig": (6, 1.0)},
}


def frame_inputs(height: int, width: int, batch: int):
    """(B, H, W) float32 sparse depths, (B, 3, 3) K, (B, 4, 4) T_cam_lidar: a 64-beam sweep of the
    synthetic street projected into a KITTI-like camera of this size (two scenes, alternating)."""
    import jaxdepth
    cam = jaxdepth.make_street_scene(0, image_scale=0.25).cameras[0]
    T = np.asarray(cam.T_cam_lidar, np.float32)
    f = 721.5 * width / 1216
    K = np.array([[f, 0, width / 2], [0, f, height * 0.3], [0, 0, 1]], np.float32)
    sparse = []
    for seed in range(min(batch, 2)):
        scene = jaxdepth.make_street_scene(seed, image_scale=0.25)
        depth, _ = jaxdepth.project_to_image(scene.points, scene.valid, K, T, height=height, width=width)
        sparse.append(np.asarray(depth, np.float32))
    stack = np.stack([sparse[i % len(sparse)] for i in range(batch)])
    return stack, np.broadcast_to(K, (batch, 3, 3)).copy(), np.broadcast_to(T, (batch, 4, 4)).copy()


def rig_inputs(cameras: int, scale: float):
    """(points (N, 3), valid (N,), RigCameras) of one 32-beam sweep of the street and its surround rig."""
    import jaxdepth
    scene = jaxdepth.make_street_scene(0, lidar=jaxdepth.NUSCENES_HDL32, cameras="surround", image_scale=scale)
    cams = scene.cameras[:cameras]
    return (np.asarray(scene.points, np.float32), np.asarray(scene.valid), jaxdepth.stack_cameras(cams),
            [(int(c.height), int(c.width)) for c in cams])


def _peak_bytes(device):
    try:
        stats = device.memory_stats()
    except Exception:  # noqa: BLE001 - backends without memory statistics raise or return None
        return None
    return None if not stats or "peak_bytes_in_use" not in stats else int(stats["peak_bytes_in_use"])


def _max_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def time_case(fn, args, device, *, repeats: int, images: int) -> dict:
    """Compile + first run apart, then the median of ``repeats`` calls (``block_until_ready``)."""
    import jax
    args = jax.device_put(args, device)
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    median = statistics.median(times)
    peak = _peak_bytes(device)
    return {"compile_s": round(compile_s, 3), "median_ms": round(median * 1e3, 3),
            "frames_per_s": round(images / median, 2), "repeats": repeats,
            "peak_bytes_in_use": peak, "peak_mb": None if peak is None else round(peak / 2**20, 1),
            "process_max_rss_mb": round(_max_rss_mb(), 1)}


def run_backend(device, size: str, repeats: int, log) -> dict:
    """Every case of ``size`` on ``device``."""
    import jax
    import jaxdepth
    spec = SIZES[size]
    height, width, batches = spec["frame"]
    batched = jax.jit(jax.vmap(lambda s, K, T: jaxdepth.complete(s, K, T)))
    out = {"device": str(device), "platform": device.platform, "size": size, "complete": {}, "rig": None}
    for batch in batches:
        args = frame_inputs(height, width, batch)
        row = time_case(batched, args, device, repeats=repeats, images=batch)
        row.update(batch=batch, height=height, width=width)
        out["complete"][f"batch_{batch}"] = row
        log(f"{device.platform}: complete {height}x{width} batch {batch:3d}: {row['frames_per_s']:9.1f} frames/s "
            f"({row['median_ms']:.1f} ms per call, compile {row['compile_s']:.1f} s), peak "
            f"{'n/a' if row['peak_mb'] is None else str(row['peak_mb']) + ' MB'}, max RSS {row['process_max_rss_mb']:.0f} MB")
    cameras, scale = spec["rig"]
    points, valid, rig, sizes = rig_inputs(cameras, scale)
    lidar = jaxdepth.NUSCENES_HDL32
    rig_fn = jax.jit(lambda p, v, r: jaxdepth.complete_rig(p, v, r, lidar=lidar))
    row = time_case(rig_fn, (points, valid, rig), device, repeats=repeats, images=cameras)
    row.update(cameras=cameras, camera_sizes=sizes, points=int(points.shape[0]))
    row["sweeps_per_s"] = round(row["frames_per_s"] / cameras, 2)
    out["rig"] = row
    log(f"{device.platform}: complete_rig {cameras} x {sizes[0][0]}x{sizes[0][1]}: {row['sweeps_per_s']:.2f} sweeps/s "
        f"({row['frames_per_s']:.1f} images/s, compile {row['compile_s']:.1f} s), peak "
        f"{'n/a' if row['peak_mb'] is None else str(row['peak_mb']) + ' MB'}, max RSS {row['process_max_rss_mb']:.0f} MB")
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=tuple(SIZES), default="full", help="accelerator sizes (default full)")
    parser.add_argument("--cpu-size", choices=tuple(SIZES), default=None,
                        help="CPU sizes (default small; tiny when --size tiny)")
    parser.add_argument("--repeats", type=int, default=10, help="timed calls per case on the accelerator")
    parser.add_argument("--cpu-repeats", type=int, default=3, help="timed calls per case on the CPU")
    parser.add_argument("--no-cpu", action="store_true", help="skip the CPU figures")
    parser.add_argument("--json", nargs="?", const=str(RESULTS), default=None, metavar="PATH",
                        help=f"write the results as JSON (default path {RESULTS.relative_to(RESULTS.parents[2])})")
    args = parser.parse_args(argv)
    cpu_size = args.cpu_size or ("tiny" if args.size == "tiny" else "small")

    import jax

    def log(line):
        print(line, flush=True)

    backend = jax.default_backend()
    doc = {"jax": jax.__version__, "python": platform.python_version(), "cpu_count": os.cpu_count(),
           "load_average_at_start": list(os.getloadavg()), "default_backend": backend,
           "accelerator": None, "cpu": None}
    log(f"jax {jax.__version__}, default backend {backend}, devices {jax.devices()}")
    if backend != "cpu":
        doc["accelerator"] = run_backend(jax.devices()[0], args.size, args.repeats, log)
    else:
        log("no accelerator: JAX's default backend is the CPU (install JAX for your GPU, e.g. "
            "pip install -U \"jax[cuda12]\")")
    if not args.no_cpu:
        doc["cpu"] = run_backend(jax.devices("cpu")[0], cpu_size, args.cpu_repeats, log)
    doc["process_max_rss_mb"] = round(_max_rss_mb(), 1)
    if args.json:
        out = pathlib.Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(json.dumps(doc, indent=2) + "\n")
        os.replace(tmp, out)
        log(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
