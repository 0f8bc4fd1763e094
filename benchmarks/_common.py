"""What several benchmark tools share: paths, the shared KITTI frame, JSON results.

Import as ``from benchmarks._common import ...`` (run tools from the repository root with
``python -m benchmarks.<tool>``). The KITTI frame comes from :func:`jaxdepth.io.load_kitti_frame`.
"""

from __future__ import annotations

import json
import os
import pathlib
import platform
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
FRAME = DATA / "kitti" / "drive_0001_frame05"
RESULTS = ROOT / "benchmarks" / "results"


def load_frames(frame_dir: pathlib.Path = FRAME) -> dict:
    """``{"image_02": (sparse, truth, K, T_cam_lidar), "image_03": ...}``: cameras 2 and 3 of the
    frame folder, cropped to 352 x 1216 (float32 metres; K of the crop)."""
    from jaxdepth.io import load_kitti_frame
    out = {}
    for cam in (2, 3):
        f = load_kitti_frame(frame_dir, camera=cam, image=False)
        out[f"image_0{cam}"] = (f.sparse, f.truth, f.K, f.T_cam_lidar)
    return out


def load_images(frame_dir: pathlib.Path = FRAME) -> dict:
    """``{"image_02": (352, 1216, 3) uint8 RGB, "image_03": ...}``, cropped like :func:`load_frames`."""
    from jaxdepth.io.guidance_images import decode_camera_image
    from jaxdepth.io import crop_to_benchmark
    return {f"image_0{cam}": crop_to_benchmark(decode_camera_image(frame_dir / f"image_0{cam}.png"), np.eye(3))[0]
            for cam in (2, 3)}


def load_frame():
    """(sparse, K, T_cam_lidar, label) of camera 2 of the shared frame (352 x 1216 crop), or, when the
    shared data is absent, a random 4 % sparse image of the same size with KITTI's calibration."""
    if FRAME.exists():
        sparse, _, K, T = load_frames()["image_02"]
        return sparse, K, T, "KITTI drive_0001 frame 5, camera 2, 352x1216"
    from jaxdepth._src import presets
    rng = np.random.default_rng(0)
    sparse = np.where(rng.random((352, 1216)) < 0.04, rng.uniform(2, 80, (352, 1216)), 0).astype(np.float32)
    K = presets.KITTI_K_CAM2.copy()
    K[0, 2] -= 13
    K[1, 2] -= 23
    return sparse, K, presets.KITTI_T_CAM2_LIDAR, "random 4 % sparse 352x1216 (shared data missing)"


#: glibc's largest dynamic mmap threshold (``DEFAULT_MMAP_THRESHOLD_MAX`` on 64-bit, 32 MiB): XLA:CPU takes a
#: program's temporary from ``malloc``; past this size it is a fresh ``mmap`` page-faulted in on every call
#: (1.8-2.5x slower frames, docs/speed.md, "Step 1's normals kept listed").
MMAP_CLIFF_BYTES = 32 * 2**20


def program_memory(compiled) -> dict:
    """A compiled program's buffers (``memory_analysis``) in MB (10^6 bytes): temp, arguments, output; the
    temporary's room below :data:`MMAP_CLIFF_BYTES` (33.55 MB; negative: over it) and whether it is over."""
    m = compiled.memory_analysis()
    temp = m.temp_size_in_bytes
    return {"temp_mb": temp / 1e6, "argument_mb": m.argument_size_in_bytes / 1e6,
            "output_mb": m.output_size_in_bytes / 1e6, "room_below_mmap_cliff_mb": (MMAP_CLIFF_BYTES - temp) / 1e6,
            "over_mmap_cliff": temp >= MMAP_CLIFF_BYTES}


def write_results(path, doc: dict, config, t0: float, *, indent: int | None = 2) -> None:
    """``doc`` plus the config (none for a tool that runs no configuration), run time and environment,
    atomically as JSON at ``path`` (``indent=None``: one line, for results of many per-target records)."""
    import jax

    from jaxdepth.io.atomic import atomic_write_bytes
    if config is not None:
        doc = {"config": {"distance_metric": config.distance_metric, "outlier_test": config.outlier_test}, **doc}
    doc = {**doc, "seconds": time.time() - t0,
           "environment": {"jax": jax.__version__, "python": platform.python_version(), "cpu_count": os.cpu_count()}}
    out = pathlib.Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, (json.dumps(doc, indent=indent) + "\n").encode())


def balanced_orders(names, rounds: int, *, seed: int = 0) -> list[tuple]:
    """``rounds`` call orders of ``names``, balanced so that no arm's place in the round decides it.

    Every block of ``len(names)!`` rounds holds each permutation of ``names`` once (shuffled within
    the block by a NumPy generator seeded with ``seed``: the same orders on every run), so over whole
    blocks each arm is first, second, ... equally often and, within a round, follows each other arm
    equally often (for two arms: AB / BA, ABBA-like). A rotation (``names[r % k:] + names[:r % k]``)
    balances the place but not the predecessor: every arm follows the same arm in most rounds.
    """
    import itertools
    perms = list(itertools.permutations(names))
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < rounds:
        out.extend(perms[i] for i in rng.permutation(len(perms)))
    return out[:rounds]


def rotated_orders(names, rounds: int) -> list[tuple]:
    """The frame bench's former orders: ``names`` rotated by one place a round (``--order rotate``)."""
    names = list(names)
    return [tuple(names[r % len(names):] + names[:r % len(names)]) for r in range(rounds)]


def order_effects(calls: list[tuple], names) -> dict:
    """Per arm, the median ms of its calls by place in the round and by the arm called just before.

    ``calls`` is every timed call in run order as ``(name, place, seconds)``; the first call's
    predecessor is ``"none"``. Shows how much the order moves an arm (the same code in two places).
    """
    import statistics
    by_place = {n: {} for n in names}
    by_prev = {n: {} for n in names}
    prev = "none"
    for name, place, seconds in calls:
        by_place[name].setdefault(str(place), []).append(seconds)
        by_prev[name].setdefault(prev, []).append(seconds)
        prev = name
    med = lambda groups: {k: {"median_ms": statistics.median(v) * 1e3, "calls": len(v)} for k, v in sorted(groups.items())}
    return {"by_place": {n: med(by_place[n]) for n in names}, "after": {n: med(by_prev[n]) for n in names}}
