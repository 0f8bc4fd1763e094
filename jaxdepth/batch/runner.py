"""Batched offline completion of many frames: I/O overlapped with compute.

One compiled function per (image size, batch size, method, config): frames are
grouped by size and run in fixed-size batches; the last batch is padded with
empty frames, never recompiled. Background threads read/decode inputs and
encode/write outputs while the device computes. Finished outputs are skipped
on a re-run, writes are atomic, a bad frame is reported and skipped.

On CPU a batch runs as ``lax.map`` over the frames (XLA already uses both
cores on one frame; lax.map and a Python loop of single-frame calls both run
at about the single-frame rate, ``vmap`` slower, with its batched gathers and
scatters; benchmarks/bench_batching.py); on GPU/TPU it runs as ``vmap``. With
several local devices (e.g. one host device per core,
``jaxdepth.batch.devices.split_cpu_into_devices``) the batch is sharded over them with ``shard_map``. Strategy "loop"
(single-frame calls dispatched asynchronously, frame i on device i mod n) gives
exactly the bytes of single-frame calls; "map" and "vmap" may differ from them
by float32 rounding.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import functools
import logging
import pathlib
import collections
import itertools
import threading
import time
from typing import Callable, Iterable, Sequence

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxdepth._src import presets
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.types import LidarSpec
from jaxdepth._src.xla_tuning import entry_jit
from jaxdepth.batch.devices import first_devices
from jaxdepth.io import errors as io_errors
from jaxdepth.io.calib import read_intrinsics_txt
from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION, read_depth_png
from jaxdepth.io.kitti_datasets import FrameFiles

log = logging.getLogger("jaxdepth")


@dataclasses.dataclass(frozen=True)
class FrameJob(FrameFiles):
    """One frame to complete: a :class:`~jaxdepth.io.kitti_datasets.FrameFiles` (input PNG or
    sweep, output PNG, ``K``, the frame's own ``T_cam_lidar`` or None for the run's default,
    camera image) and, for selection folders, the intrinsics file ``intrinsics_path`` read
    when ``K`` is None.

    A *sweep job* (``image_size`` set) reads a LiDAR sweep from ``sparse_path`` instead
    (``.bin`` float32 records of ``point_columns`` values, x, y, z first, metres; None:
    :func:`jaxdepth.io.points.infer_point_columns`) and completes it with
    :func:`jaxdepth.complete_points` (SGM only) into an image of ``image_size`` =
    (height, width) pixels with ``K`` and ``T_cam_lidar``. Sweeps are padded to the
    power-of-two buckets of :func:`jaxdepth.io.points.bucket_size`.

    ``image_path``: the frame's camera image, read only by guided runs
    (``SGMConfig.guidance_weight > 0``, image-guided seeds) with
    :func:`jaxdepth.io.guidance_images.read_guidance_image`; it must have the
    depth's size, or, with ``image_crop_from`` = (H, W), be the full H x W frame
    whose 352 x 1216 benchmark crop the job completes (cut the same way).

    ``force``: use an input that fails the plausibility checks of
    :mod:`jaxdepth.io.plausibility` (a warning is logged instead).
    """

    intrinsics_path: pathlib.Path | None = None
    force: bool = False

    @classmethod
    def from_files(cls, files: FrameFiles) -> "FrameJob":
        """The job of one frame a dataset discovery function listed."""
        return cls(**{field.name: getattr(files, field.name) for field in dataclasses.fields(FrameFiles)})


@dataclasses.dataclass
class RunSummary:
    done: list = dataclasses.field(default_factory=list)
    skipped: list = dataclasses.field(default_factory=list)
    failed: list = dataclasses.field(default_factory=list)  # (name, message)
    started_at: float | None = None  # time.perf_counter() when run_jobs started
    first_output_at: float | None = None  # time.perf_counter() when the first output was in place

    @property
    def ok(self) -> bool:
        return not self.failed


STRATEGIES = ("loop", "map", "vmap")


def batch_strategy(backend: str | None = None) -> str:
    """"map" on CPU (measured fastest there), "vmap" on accelerators."""
    backend = backend or jax.default_backend()
    return "map" if backend == "cpu" else "vmap"


@functools.lru_cache(maxsize=32)
def batched_completion(batch_size: int, height: int, width: int, *, method: str, config: SGMConfig,
                       lidar: LidarSpec, strategy: str, devices: int = 1,
                       max_seed_distance_px: float | None = None, listed_only: bool = False) -> Callable:
    """(B, H, W), (B, 3, 3), (B, 4, 4) -> (B, H, W) completion for one bucket (one compiled function).

    Every frame carries its own intrinsics and extrinsic (traced: a new calibration never recompiles).

    With ``max_seed_distance_px`` (extra outputs, method "sgm" only; pixels, or ``"sensor"``: each
    camera's :func:`jaxdepth._src.validity.sensor_max_seed_distance_px`) the function returns
    ``(depth, valid, seed_distance)``, each (B, H, W), from
    :func:`jaxdepth._src.validity.validity_and_distance` of the frame's Stages (another
    compiled function; without it nothing changes).

    Guided (``config.guidance_weight > 0``, method "sgm" only): the function takes a fourth
    argument, the (B, H, W) grey or (B, H, W, 3) colour uint8 camera images, and frame i is
    :func:`jaxdepth.complete` of it with ``image=images[i]``. Unguided functions take no image.

    ``listed_only`` (method "sgm"): the program without Step 1's dense fallback
    (:mod:`jaxdepth.batch.listed`); it returns one more output, the (B,) bool ``fits``; where it
    is False that frame's outputs are not meaningful. Both programs map one frame function,
    :func:`jaxdepth.batch.frame_program.frame_function`.
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"batched_completion: field 'strategy' expected one of {STRATEGIES}, got {strategy!r}")
    if max_seed_distance_px is not None and method != "sgm":
        raise ValueError(f"batched_completion: extra outputs (validity, seed distance) need method 'sgm', "
                         f"got {method!r}")
    guided = is_guided(config)
    if guided and method != "sgm":
        raise ValueError(f"batched_completion: image-guided seeds (config.guidance_weight > 0) need method "
                         f"'sgm', got {method!r}")
    if listed_only and method != "sgm":
        raise ValueError(f"batched_completion: listed_only needs method 'sgm', got {method!r}")
    from jaxdepth.batch.frame_program import frame_function
    one = frame_function(method=method, config=config, lidar=lidar, max_seed_distance_px=max_seed_distance_px,
                         listed_only=listed_only)
    statics = ("listed_only",) if listed_only else ()  # main's stored programs keep their key
    return _batched(one, arity=4 if guided else 3, batch_size=batch_size, strategy=strategy, devices=devices,
                    out_specs=_out_specs(max_seed_distance_px, fits=listed_only), first_shape=(batch_size, height, width),
                    program=("batched_completion", (batch_size, height, width, method, config, lidar, strategy,
                                                    devices, max_seed_distance_px) + statics))


def is_guided(config: SGMConfig) -> bool:
    """Whether a run with ``config`` reads camera images (image-guided seeds, ``guidance_weight > 0``)."""
    return config.guidance_weight > 0


def check_sgm_only(method: str, *, where: str, extras=None, guided: bool = False) -> None:
    """ValueError naming ``where`` when a baseline ``method`` (not "sgm") comes with options that need the SGM's
    seeds (``extras``: validity, seed distance, zero-invalid) or with image-guided seeds (``guided``).
    The one wording of every job's check (the KITTI runners, the multi-source jobs, ``complete-rig``)."""
    if method != "sgm" and ((extras is not None and extras.needs_seeds) or guided):
        raise ValueError(f"{where}: validity, seed distance, zero-invalid and image guidance need method 'sgm', "
                         f"got {method!r}")


def _stack_outputs(outs: list):
    """Per-frame results (arrays or tuples of arrays) -> one stacked array or tuple."""
    if isinstance(outs[0], tuple):
        return tuple(np.stack([np.asarray(out[j]) for out in outs]) for j in range(len(outs[0])))
    return np.stack([np.asarray(out) for out in outs])


def _out_specs(max_seed_distance_px, *, fits: bool = False):
    """The outputs' specs: the depth[, validity, seed distance][, fits], each split over the batch."""
    count = (1 if max_seed_distance_px is None else 3) + fits
    return PartitionSpec("batch") if count == 1 else (PartitionSpec("batch"),) * count


@functools.lru_cache(maxsize=32)
def batched_sweep_completion(batch_size: int, points: int, height: int, width: int, *, config: SGMConfig,
                             lidar: LidarSpec, strategy: str, devices: int = 1,
                             max_seed_distance_px: float | None = None) -> Callable:
    """(B, P, 3), (B, P), (B, 3, 3), (B, 4, 4) -> (B, H, W) SGM completion of padded sweeps (one bucket).

    Frame i is :func:`jaxdepth.complete_points` of ``points[i]``, ``valid[i]`` for the
    camera (``K[i]``, ``T[i]``, ``height`` x ``width``); K and T are traced. Strategies
    and devices as in :func:`batched_completion`, and so is ``max_seed_distance_px``
    (then ``(depth, valid, seed_distance)``). Guided (``config.guidance_weight > 0``): a fifth
    argument, the (B, H, W) or (B, H, W, 3) uint8 camera images (``image=`` of
    :func:`jaxdepth.complete_points`).
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"batched_sweep_completion: field 'strategy' expected one of {STRATEGIES}, got {strategy!r}")
    from jaxdepth._src.pipeline import complete_points, complete_points_stages
    from jaxdepth._src.types import Camera
    from jaxdepth.batch.frame_program import validity
    guided = is_guided(config)

    def one(pts, valid, K, T, image=None):
        camera = Camera(K=K, T_cam_lidar=T, height=height, width=width)
        more = {"image": image} if guided else {}
        if max_seed_distance_px is None:
            return complete_points(pts, valid, camera, config=config, lidar=lidar, **more)
        stages = complete_points_stages(pts, valid, camera, config=config, lidar=lidar, **more)
        return (stages.depth,) + validity(stages, K, T, config=config, lidar=lidar,
                                          max_seed_distance_px=max_seed_distance_px)

    return _batched(one, arity=5 if guided else 4, batch_size=batch_size, strategy=strategy, devices=devices,
                    out_specs=_out_specs(max_seed_distance_px),
                    program=("batched_sweep_completion", (batch_size, points, height, width, config, lidar, strategy,
                                                          devices, max_seed_distance_px)))


def _batched(one: Callable, *, arity: int, batch_size: int, strategy: str, devices: int, out_specs,
             first_shape: tuple | None = None, program: tuple | None = None) -> Callable:
    """``one`` (a single frame's arrays -> output) over a leading batch axis of every argument.

    "loop": one jitted frame at a time, dispatched round-robin to ``devices`` local devices
    (the bytes of per-frame calls); "map" / "vmap": ``lax.map`` / ``vmap`` inside one jit, the
    batch sharded over the devices with ``shard_map`` when ``devices > 1``. ``first_shape``:
    the shape the loop strategy requires of the first argument (clear error otherwise).
    ``program``: ``(name, statics)`` of the "map" / "vmap" program, which then runs through the
    on-disk program cache (:class:`jaxdepth.batch.program_cache.Program`: a warm start skips tracing;
    the same bytes). Every strategy's ``jit`` is :func:`~jaxdepth._src.xla_tuning.entry_jit`'s (region-analysis
    copy insertion, as the single-frame entry points; the same bytes as a plain ``jit``).
    """
    if strategy == "loop":
        single = entry_jit(one)
        targets = first_devices(devices)

        def run(*args):
            if first_shape is not None and args[0].shape != first_shape:
                raise ValueError(f"batched completion: field 'depths' expected shape {first_shape}, "
                                 f"got {args[0].shape}")
            # Dispatch every frame first (asynchronous), then collect.
            outs = [single(*jax.device_put(tuple(a[i] for a in args), targets[i % len(targets)]))
                    for i in range(batch_size)]
            return _stack_outputs(outs)

        return run

    def per_device(*args):
        if strategy == "vmap":
            return jax.vmap(one)(*args)
        return jax.lax.map(lambda a: one(*a), args)

    def sharded(*args):
        if devices > 1:
            mesh = Mesh(np.array(first_devices(devices)), ("batch",))
            fn = jax.shard_map(per_device, mesh=mesh, in_specs=(PartitionSpec("batch"),) * arity,
                               out_specs=out_specs, check_vma=False)
            return fn(*args)
        return per_device(*args)

    if program is None:
        return entry_jit(sharded)
    from jaxdepth.batch.program_cache import Program

    def in_shardings(exported):      # the batch axis over the devices, as shard_map splits it
        mesh = Mesh(np.array(first_devices(exported.nr_devices)), ("batch",))
        return (NamedSharding(mesh, PartitionSpec("batch")),) * len(exported.in_avals)

    return Program(entry_jit(sharded), name=program[0], statics=program[1], in_shardings=in_shardings)


def complete_batch(depths: np.ndarray, Ks: np.ndarray, T_cam_lidar: np.ndarray | None = None, *,
                   method: str = "sgm", config: SGMConfig = SGMConfig(),
                   lidar: LidarSpec = presets.KITTI_HDL64, batch_size: int | None = None,
                   strategy: str | None = None, devices: int | None = None,
                   images: np.ndarray | None = None) -> np.ndarray:
    """Completes a stack of same-size frames in fixed-size (padded) batches.

    Args:
      depths: (F, H, W) float32 sparse depths, metres. Ks: (F, 3, 3).
      T_cam_lidar: (4, 4) for every frame or (F, 4, 4) per frame (default: KITTI camera 2's).
      images: (F, H, W) grey or (F, H, W, 3) colour camera images (uint8, or float in [0, 1]);
        required when ``config.guidance_weight > 0`` (image-guided seeds), else not allowed.
      batch_size: frames per compiled call (default: F rounded up to the device count).
      strategy: "loop", "map" or "vmap" (default: :func:`batch_strategy`).
      devices: local devices to shard the batch over (default: all).

    Returns:
      (F, H, W) float32 dense depths: with "loop" the bytes of per-frame calls;
      "map" / "vmap" may differ from them by float32 rounding.
    """
    depths = np.asarray(depths, np.float32)
    Ks = np.asarray(Ks, np.float32)
    if depths.ndim != 3 or Ks.shape != (depths.shape[0], 3, 3):
        raise ValueError(f"complete_batch: expected depths (F, H, W) and Ks (F, 3, 3), got {depths.shape}, {Ks.shape}")
    T = np.asarray(presets.KITTI_T_CAM2_LIDAR if T_cam_lidar is None else T_cam_lidar, np.float32)
    if T.shape not in ((4, 4), (depths.shape[0], 4, 4)):
        raise ValueError(f"complete_batch: field 'T_cam_lidar' expected shape (4, 4) or {(depths.shape[0], 4, 4)}, "
                         f"got {T.shape}")
    Ts = np.ascontiguousarray(np.broadcast_to(T, (depths.shape[0], 4, 4)))
    if is_guided(config) != (images is not None):
        raise ValueError("complete_batch: field 'images' expected " + (
            "(F, H, W) or (F, H, W, 3) camera images because config.guidance_weight > 0, got None"
            if images is None else "None because config.guidance_weight is 0 (no image guidance), got images"))
    if images is not None:
        images = np.asarray(images)
        if images.shape[:3] != depths.shape or images.ndim not in (3, 4):
            raise ValueError(f"complete_batch: field 'images' expected shape {depths.shape} or "
                             f"{depths.shape + (3,)}, got {images.shape}")
    devices = devices or len(jax.local_devices())
    batch_size = batch_size or depths.shape[0]
    batch_size = -(-batch_size // devices) * devices
    fn = batched_completion(batch_size, depths.shape[1], depths.shape[2], method=method, config=config,
                            lidar=lidar, strategy=strategy or batch_strategy(), devices=devices)
    out = []
    for start in range(0, depths.shape[0], batch_size):
        d, k, t, n = _pad_batch(depths[start:start + batch_size], Ks[start:start + batch_size],
                                Ts[start:start + batch_size], batch_size)
        more = () if images is None else (_pad_zeros(images[start:start + batch_size], batch_size),)
        out.append(np.asarray(fn(d, k, t, *more))[:n])
    return np.concatenate(out, axis=0)


def _pad_zeros(stack: np.ndarray, batch_size: int) -> np.ndarray:
    """``stack`` (n, ...) padded with zero entries to (batch_size, ...)."""
    pad = batch_size - stack.shape[0]
    return stack if pad == 0 else np.concatenate([stack, np.zeros((pad,) + stack.shape[1:], stack.dtype)])


def _pad_batch(depths: np.ndarray, Ks: np.ndarray, Ts: np.ndarray, batch_size: int):
    n = depths.shape[0]
    if n == batch_size:
        return depths, Ks, Ts, n
    pad = batch_size - n
    depths = np.concatenate([depths, np.zeros((pad,) + depths.shape[1:], np.float32)])
    Ks = np.concatenate([Ks, np.repeat(Ks[-1:], pad, axis=0)])
    Ts = np.concatenate([Ts, np.repeat(Ts[-1:], pad, axis=0)])
    return depths, Ks, Ts, n


def _load_sweep(job: FrameJob):
    """A sweep job's input: ((padded (P, 3), valid (P,)), K), K checked against ``image_size``."""
    from jaxdepth.io.points import infer_point_columns, pad_points, read_points

    points, _ = read_points(job.sparse_path, columns=infer_point_columns(job.sparse_path, job.point_columns),
                            force=job.force, columns_option=None)      # `complete`: the layout fixes the columns
    if job.K is None:
        raise io_errors.InputError(f"{job.sparse_path}: no intrinsics given for this sweep (field 'K' of the job)")
    K = np.asarray(job.K, np.float32)
    h, w = (int(s) for s in job.image_size)
    cx, cy = float(K[0, 2]), float(K[1, 2])
    if not (0 <= cx <= w and 0 <= cy <= h):
        raise io_errors.InputError(f"{job.sparse_path}: field 'K' principal point ({cx:.1f}, {cy:.1f}) expected "
                                   f"inside the {w}x{h} image")
    if job.T_cam_lidar is not None:  # the frame's own calibration: does it fit the sweep?
        from types import SimpleNamespace

        from jaxdepth.io.plausibility import check_rig_geometry
        camera = SimpleNamespace(name=job.name, K=K, T_cam_lidar=job.T_cam_lidar, width=w, height=h)
        check_rig_geometry(points, [camera], path=job.sparse_path, force=job.force)
    return pad_points(points), K


def _group_key(job: FrameJob, data, image: np.ndarray | None = None) -> tuple:
    """Frames with equal keys share one compiled batch: (H, W) for a depth image,
    ("sweep", P, H, W) for a sweep padded to P points; a guided frame appends
    ("image", C) with C = 1 (grey) or 3 (colour) channels of its camera image."""
    key = data.shape if job.image_size is None else (
        ("sweep", data[0].shape[0]) + tuple(int(s) for s in job.image_size))
    if image is None:
        return key
    return tuple(key) + ("image", 1 if image.ndim == 2 else int(image.shape[2]))


def batch_item(job: FrameJob, loaded: tuple, T_default: np.ndarray) -> tuple:
    """``(group key, item)`` of a loaded frame (:func:`try_load`'s value): the item is
    ``(job, data, K, T)``, plus the camera image for a guided frame."""
    data, K, *image = loaded
    T = T_default if job.T_cam_lidar is None else np.asarray(job.T_cam_lidar, np.float32)
    return _group_key(job, data, *image), (job, data, K, T, *image)


def _group_call(key: tuple, items: list, *, batch_size: int, method: str, config: SGMConfig, lidar: LidarSpec,
                strategy: str, devices: int, max_seed_distance_px: float | None = None, listed_only=None):
    """(compiled function, padded argument arrays, real frame count) of one group's batch.

    ``listed_only``: a set, the run's groups that had a frame beyond the listed path (filled by ``listed.settle``):
    an SGM depth-image batch of a group not in it runs a :class:`jaxdepth.batch.listed.ListedBatch`.

    ``items``: up to ``batch_size`` tuples (job, data, K, T[, image]) of one :func:`_group_key`
    (:func:`batch_item`); guided items carry the camera image, padded with zero images.
    """
    # The extras keyword only when set: lru_cache keys on the keywords passed, and a run
    # without extras must reuse the very function (and compilation) it always did.
    more = {} if max_seed_distance_px is None else {"max_seed_distance_px": max_seed_distance_px}
    images = () if len(items[0]) < 5 else (_pad_zeros(np.stack([it[4] for it in items]), batch_size),)
    if key[0] != "sweep":
        h, w = key[:2]
        build = functools.partial(batched_completion, batch_size, h, w, method=method, config=config,
                                  lidar=lidar, strategy=strategy, devices=devices, **more)
        if listed_only is not None and method == "sgm" and key not in listed_only:  # full program on first need
            from jaxdepth.batch.listed import ListedBatch
            fn = ListedBatch(build(listed_only=True), full=build, overflowed=functools.partial(listed_only.add, key))
        else:
            fn = build()
        d, k, t, n = _pad_batch(np.stack([it[1] for it in items]), np.stack([it[2] for it in items]),
                                np.stack([it[3] for it in items]), batch_size)
        return fn, (d, k, t, *images), n
    if method != "sgm":
        raise ValueError(f"sweeps complete with method 'sgm' only, got {method!r}")
    _, points, h, w = key[:4]
    fn = batched_sweep_completion(batch_size, points, h, w, config=config, lidar=lidar, strategy=strategy,
                                  devices=devices, **more)
    pts = np.stack([it[1][0] for it in items])
    valid = np.stack([it[1][1] for it in items])
    d, k, t, n = _pad_batch(pts, np.stack([it[2] for it in items]), np.stack([it[3] for it in items]), batch_size)
    valid = np.concatenate([valid, np.zeros((batch_size - n,) + valid.shape[1:], bool)])
    return fn, (d, valid, k, t, *images), n


def _load(job: FrameJob, *, guided: bool = False):
    """(data, K) of a job, plus its camera image (:func:`_load_image`) when ``guided``."""
    data, K = _load_sparse(job)
    if not guided:
        return data, K
    size = tuple(int(s) for s in job.image_size) if job.image_size is not None else data.shape
    return data, K, _load_image(job, size)


def _load_image(job: FrameJob, size: tuple[int, int]) -> np.ndarray:
    """The job's camera image, (H, W) or (H, W, 3) uint8 of the depth's ``size`` (InputError naming
    the file otherwise, or naming the frame when it has no image)."""
    from jaxdepth.io.guidance_images import read_guidance_image
    if job.image_path is None:
        raise io_errors.InputError(f"{job.sparse_path}: no camera image for this frame (image-guided seeds, "
                                   "--guidance-weight > 0, need one: see --image-dir)")
    return read_guidance_image(job.image_path, size=size, crop_from=job.image_crop_from)


def _load_sparse(job: FrameJob):
    if job.image_size is not None:
        return _load_sweep(job)
    depth = read_depth_png(job.sparse_path)
    from jaxdepth.io.plausibility import check_depth_scale
    check_depth_scale(depth, path=job.sparse_path, role="LiDAR input", force=job.force)
    if job.K is not None:
        K = np.asarray(job.K, np.float32)
    elif job.intrinsics_path is not None:
        K = read_intrinsics_txt(job.intrinsics_path)
    else:
        raise io_errors.InputError(f"{job.sparse_path}: no intrinsics given (expected intrinsics/<name>.txt or --intrinsics)")
    h, w = depth.shape
    cx, cy = float(K[0, 2]), float(K[1, 2])
    if not (0 <= cx <= w and 0 <= cy <= h):
        src = job.intrinsics_path or "intrinsics"
        raise io_errors.InputError(
            f"{src}: field 'K' principal point ({cx:.1f}, {cy:.1f}) expected inside the {w}x{h} image "
            f"{job.sparse_path.name}")
    return depth, K


def job_identity(job: FrameJob, *, guided: bool = False) -> dict:
    """What a frame job's output is made from (:func:`jaxdepth.batch.run_record.input_identity`):
    its sparse input, its intrinsics file when ``K`` is not given, its camera image when ``guided``;
    ``K``, ``T_cam_lidar``, image size, point columns and crop as values."""
    from jaxdepth.batch.run_record import input_identity
    files = (job.sparse_path, job.intrinsics_path if job.K is None else None, job.image_path if guided else None)
    return input_identity(files, values=(job.K, job.T_cam_lidar, job.image_size, job.point_columns,
                                         job.image_crop_from))


def pending_jobs(jobs: Iterable[FrameJob], *, overwrite: bool, summary: RunSummary,
                 notify: Callable[[str, str], None], extras=None) -> list:
    """The jobs still to run: a finished output is recorded as skipped (resume) unless ``overwrite``.

    With ``extras`` (:class:`jaxdepth.batch.extras.ExtraOutputs`) an output is finished when the
    depth PNG and every requested extra file exist.
    """
    from jaxdepth.batch.extras import NONE, is_done
    extras = NONE if extras is None else extras
    todo = []
    for job in jobs:
        if not overwrite and is_done(job.out_path, extras):
            summary.skipped.append(job.name)
            notify(job.name, "skipped")
        else:
            todo.append(job)
    return todo


def run_jobs(jobs: Sequence[FrameJob], *, method: str = "sgm", config: SGMConfig = SGMConfig(),
             lidar: LidarSpec = presets.KITTI_HDL64, T_cam_lidar: np.ndarray | None = None,
             batch_size: int = 4, overwrite: bool = False, strategy: str | None = None,
             devices: int | None = None, io_threads: int = 2,
             png_compression: int = DEFAULT_PNG_COMPRESSION,
             on_progress: Callable[[str, str], None] | None = None, extras=None) -> RunSummary:
    """Completes every job; never raises for a bad frame (it is recorded in ``failed``).

    ``on_progress(name, status)`` is called once per frame with status "done",
    "skipped" or "failed: <message>". ``png_compression``: zlib level 0-9 of the
    outputs (:func:`jaxdepth.io.depth_png.encode_depth_png`; same values at every level).

    The main thread only batches and dispatches: batch k+1 is handed to the devices
    (asynchronously) before batch k's result is collected, while ``io_threads``
    threads decode inputs and ``2 * io_threads`` threads encode + write outputs (OpenCV,
    NumPy, zlib and fsync release the GIL; a writer waits in fsync part of the time).

    Sweep jobs (``FrameJob.image_size`` set) are batched per (power-of-two point
    bucket, image size): one compiled function each, like depth images per size.

    ``extras`` (:class:`jaxdepth.batch.extras.ExtraOutputs`, default none): preview, validity
    mask, seed distance, zero outside the valid region, written beside each output
    (:mod:`jaxdepth.batch.extras`). Validity, seed distance and zero-invalid need method "sgm"
    and use their own compiled functions; with none of them the run compiles and
    writes exactly what it does without ``extras``.

    Guided runs (``config.guidance_weight > 0``, image-guided seeds, method "sgm") read each
    frame's camera image (``FrameJob.image_path``) on the reader threads with its input and
    pass it into the compiled batch (frames grouped also by grey / colour); a missing or bad
    image fails that frame only, with a message naming the image file. Each output equals
    :func:`jaxdepth.complete` / :func:`jaxdepth.complete_points` with ``image=``. Unguided runs
    never open the images.

    Raises:
      ValueError: sweep jobs, validity / seed-distance / zero-invalid extras, or a guided
        config, with a ``method`` other than "sgm".
    """
    from jaxdepth.batch import extras as extra_outputs
    extras = extra_outputs.NONE if extras is None else extras
    if method != "sgm" and any(job.image_size is not None for job in jobs):
        raise ValueError(f"run_jobs: sweep jobs (image_size set) complete with method 'sgm' only, got {method!r}")
    check_sgm_only(method, where="run_jobs", extras=extras, guided=is_guided(config))
    summary = RunSummary(started_at=time.perf_counter())
    notify = on_progress or (lambda name, status: None)
    todo = pending_jobs(jobs, overwrite=overwrite, summary=summary, notify=notify, extras=extras)
    if not todo:
        return summary
    T = np.asarray(presets.KITTI_T_CAM2_LIDAR if T_cam_lidar is None else T_cam_lidar, np.float32)
    devices = devices or len(jax.local_devices())
    # A short run (e.g. one image) is not padded up to a full default batch.
    batch_size = min(max(1, batch_size), len(todo))
    batch_size = -(-batch_size // devices) * devices
    group_call = functools.partial(
        _group_call, batch_size=batch_size, method=method, config=config, lidar=lidar,
        strategy=strategy or batch_strategy(), devices=devices, listed_only=set(),
        max_seed_distance_px=extras.seed_limit if extras.needs_seeds else None)
    pending: dict = {}  # _group_key -> list of (job, depth or (points, valid), K, T[, image])
    # Twice as many writers: each spends a good part of a frame waiting in fsync (atomic writes),
    # which costs no CPU (48 PNGs written with 4 threads instead of 2: 0.75x the wall time).
    with cf.ThreadPoolExecutor(io_threads) as readers, cf.ThreadPoolExecutor(2 * io_threads) as writers:
        run = _BatchRun(summary, notify, writers, group_call=group_call, extras=extras, overwrite=overwrite,
                        png_compression=png_compression)
        for job, (loaded, message) in read_ahead(todo, readers, window=max(2 * batch_size, 4),
                                                 load=loader(config)):
            if message is not None:
                run.record_failure(job.name, message)
                continue
            key, item = batch_item(job, loaded, T)
            items = pending.setdefault(key, [])
            items.append(item)
            if len(items) == batch_size:
                run.flush(key, pending.pop(key))
        for key, items in list(pending.items()):
            run.flush(key, items)
        run.finish()
    return summary


def loader(config: SGMConfig) -> Callable:
    """The job loader of a run with ``config``: (data, K), plus the camera image when guided."""
    return functools.partial(_load, guided=True) if is_guided(config) else _load


def _sparse_path_error(job, err: OSError) -> str:
    return f"{job.sparse_path}: {err}"


def try_load(job, load: Callable | None = None, os_error: Callable = _sparse_path_error):
    """``(load(job), None)``, or ``(None, message)`` for an input that cannot be read (a
    :class:`~jaxdepth.io.errors.JaxdepthError`, or an ``OSError`` worded by ``os_error``).
    ``load`` defaults to reading a :class:`FrameJob`'s sparse input (depth, K)."""
    try:
        return (_load if load is None else load)(job), None
    except io_errors.JaxdepthError as err:
        return None, str(err)
    except OSError as err:
        return None, os_error(job, err)


def write_failure(path, write: Callable[[], object]) -> str | None:
    """Runs ``write()``; None when it succeeded, else the failure message (an ``OSError`` says
    that ``path`` cannot be written)."""
    try:
        write()
    except io_errors.JaxdepthError as err:
        return str(err)
    except OSError as err:
        return f"{path}: cannot write ({err.strerror or err})"
    return None


def read_ahead(todo: Sequence, readers: cf.Executor, *, window: int, load: Callable | None = None,
               os_error: Callable = _sparse_path_error):
    """Yields :func:`try_load`'s ``(job, (value, message))`` in job order; at most ``window``
    inputs are loaded ahead on ``readers``, so memory stays bounded."""
    futures = collections.deque()
    jobs_iter = iter(todo)
    for job in itertools.islice(jobs_iter, window):
        futures.append((job, readers.submit(try_load, job, load, os_error)))
    while futures:
        job, fut = futures.popleft()
        nxt = next(jobs_iter, None)
        if nxt is not None:
            futures.append((nxt, readers.submit(try_load, nxt, load, os_error)))
        yield job, fut.result()


class Ledger:
    """Thread-safe record of a run's frames in its :class:`RunSummary`, with the progress callback."""

    def __init__(self, summary: RunSummary, notify: Callable[[str, str], None]):
        self.summary, self.notify = summary, notify
        self.lock = threading.Lock()

    def fail(self, name: str, message: str) -> None:
        with self.lock:
            self.summary.failed.append((name, message))
        self.notify(name, f"failed: {message}")

    def done(self, name: str) -> None:
        """Records ``name`` as done; the first output's time is kept."""
        with self.lock:
            self.summary.done.append(name)
            if self.summary.first_output_at is None:
                self.summary.first_output_at = time.perf_counter()
        self.notify(name, "done")


class _BatchRun:
    """The dispatch side of :func:`run_jobs`: batch k+1 is handed to the devices before batch
    k's result is collected; results are encoded and written on the ``writers`` threads."""

    def __init__(self, summary: RunSummary, notify, writers: cf.Executor, *, group_call, extras, overwrite: bool,
                 png_compression: int):
        self.ledger, self.writers, self.group_call = Ledger(summary, notify), writers, group_call
        self.extras, self.overwrite, self.png_compression = extras, overwrite, png_compression
        self.write_futures = []
        self.in_flight = []  # at most one dispatched batch whose result is not collected yet

    def record_failure(self, name, message):
        self.ledger.fail(name, message)

    def write(self, job, depth, valid=None, distance=None):
        from jaxdepth.batch import extras as extra_outputs
        message = write_failure(job.out_path, lambda: extra_outputs.write_outputs(
            job.out_path, depth, extras=self.extras, valid=valid, distance=distance, overwrite=self.overwrite,
            compression=self.png_compression))
        if message is None:
            self.ledger.done(job.name)
        else:
            self.ledger.fail(job.name, message)

    def collect(self):
        from jaxdepth.batch.listed import settle
        items, out = self.in_flight.pop()
        try:
            result = settle(out)  # (a listed batch with a frame that does not fit: recomputed here)
        except Exception as err:  # a compute failure costs this batch, not the run
            for job, *_ in items:
                self.record_failure(job.name, f"completion failed: {err}")
            return
        for i, (job, *_) in enumerate(items):
            self.write_futures.append(self.writers.submit(self.write, job, *(r[i] for r in result)))

    def flush(self, key, items):
        fn, args, _ = self.group_call(key, items)
        try:
            out = fn(*args)  # dispatched; runs while the previous batch is collected
        except Exception as err:
            for job, *_ in items:
                self.record_failure(job.name, f"completion failed: {err}")
            out = None
        if self.in_flight:
            self.collect()
        if out is not None:
            self.in_flight.append((items, out))

    def finish(self):
        if self.in_flight:
            self.collect()
        for f in self.write_futures:
            f.result()
