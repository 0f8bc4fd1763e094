"""Optional Ray backend: complete datasets larger than one machine (``pip install 'jaxdepth[ray]'``).

The work is a Ray Data pipeline over *job records* (frame name, input/output
paths, K or intrinsics path), never over images: every actor reads its own
inputs and writes its own outputs, so only small status rows travel back to the
driver. Each actor of the pool is a :class:`_CompleteFrames` instance that
keeps its compiled batch functions (:func:`jaxdepth.batch.runner.batched_completion`,
:func:`jaxdepth.batch.runner.batched_sweep_completion` for sweep jobs, both cached per process)
for the life of the actor, so a frame size compiles once per actor, not once
per batch. A nuScenes version (:func:`run_nuscenes_ray`) is the same pipeline
over sample records (token, output paths): each :class:`_CompleteSamples` actor
reads the version's tables once and completes its samples with the local
engine's per-sample path (:func:`jaxdepth.batch.nuscenes_job.complete_samples`).

Results are the same bytes as :func:`jaxdepth.batch.runner.run_jobs` with the same
``batch_size`` (same compiled function, same padding, same writer).

Paths must be visible under the same name on every node (a shared or network
file system), and jaxdepth must be installed on every node (or shipped with
``runtime_env={"py_modules": [jaxdepth]}``).

Ray is imported inside the functions only: importing this module without Ray
installed works, and calling it raises an :class:`ImportError` that says how to
install it. ``jaxdepth._src`` never imports Ray.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import logging
import os
import pathlib
import time
import warnings
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from jaxdepth._src import presets
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.types import LidarSpec

log = logging.getLogger("jaxdepth")

#: Resources of the throw-away local cluster started when no address is given.
LOCAL_NUM_CPUS = 2
LOCAL_OBJECT_STORE_BYTES = 256 * 1024 * 1024

#: Ray Data settings changed for the duration of a run (progress is reported per frame instead).
_QUIET_CONTEXT = {"enable_progress_bars": False, "print_on_execution_start": False, "enable_auto_log_stats": False}

_INSTALL_HINT = "the Ray engine needs Ray Data: pip install 'jaxdepth[ray]'"


@contextlib.contextmanager
def _quiet_ray_data(ray_data):
    """Ray Data without progress bars, execution-start prints and log stats for the block;
    its logger shows only errors unless jaxdepth logs at INFO. Both are restored after."""
    ctx = ray_data.DataContext.get_current()
    saved = {key: getattr(ctx, key) for key in _QUIET_CONTEXT}
    data_log = logging.getLogger("ray.data")
    saved_level = data_log.level
    for key, value in _QUIET_CONTEXT.items():
        setattr(ctx, key, value)
    if not log.isEnabledFor(logging.INFO):
        # Ray Data's own notes ("progress bars disabled", execution plans) are noise here; its
        # failures still surface as exceptions, and bad frames as rows.
        data_log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        for key, value in saved.items():
            setattr(ctx, key, value)
        data_log.setLevel(saved_level)


def _import_ray():
    """(ray, ray.data), or ImportError with the install command."""
    try:
        import ray
        import ray.data
    except ImportError as err:
        raise ImportError(f"{_INSTALL_HINT} (import failed: {err})") from err
    return ray, ray.data


# --------------------------------------------------------------------------- records

def _record(job) -> dict[str, Any]:
    """FrameJob -> a flat row that Arrow stores without Python objects."""
    has_K = job.K is not None
    K = np.asarray(job.K, np.float64).reshape(9) if has_K else np.zeros(9, np.float64)
    has_T = getattr(job, "T_cam_lidar", None) is not None
    T = np.asarray(job.T_cam_lidar, np.float64).reshape(16) if has_T else np.zeros(16, np.float64)
    return {
        "name": str(job.name),
        "sparse_path": os.fspath(job.sparse_path),
        "out_path": os.fspath(job.out_path),
        "intrinsics_path": "" if job.intrinsics_path is None else os.fspath(job.intrinsics_path),
        "has_K": has_K,
        "K": K.tolist(),
        "has_T": has_T,
        "T": T.tolist(),
        # sweep jobs: (height, width) of the image, values per point (0: none / inferred)
        "image_size": [0, 0] if job.image_size is None else [int(s) for s in job.image_size],
        "point_columns": 0 if job.point_columns is None else int(job.point_columns),
        # camera image for guided runs ("" none); full frame size it is cropped from ([0, 0]: no crop)
        "image_path": "" if getattr(job, "image_path", None) is None else os.fspath(job.image_path),
        "image_crop_from": ([0, 0] if getattr(job, "image_crop_from", None) is None
                            else [int(s) for s in job.image_crop_from]),
        # --force: inputs that fail the plausibility checks are used (logged on the worker)
        "force": bool(getattr(job, "force", False)),
    }


def _jobs_from_batch(batch: dict[str, Any]) -> list:
    """A numpy-format batch of records -> FrameJobs (inverse of :func:`_record`)."""
    from jaxdepth.batch.runner import FrameJob

    jobs = []
    for i in range(len(batch["name"])):
        intrinsics = str(batch["intrinsics_path"][i])
        K = None
        if bool(batch["has_K"][i]):
            # float32 K -> float64 record -> float32 again is exact.
            K = np.asarray(list(batch["K"][i]), np.float64).reshape(3, 3).astype(np.float32)
        T = None
        if bool(batch["has_T"][i]):
            T = np.asarray(list(batch["T"][i]), np.float64).reshape(4, 4).astype(np.float32)
        size = tuple(int(s) for s in batch["image_size"][i])
        columns = int(batch["point_columns"][i])
        image = str(batch["image_path"][i]) if "image_path" in batch else ""
        crop_from = tuple(int(s) for s in batch["image_crop_from"][i]) if "image_crop_from" in batch else (0, 0)
        jobs.append(FrameJob(name=str(batch["name"][i]), sparse_path=pathlib.Path(str(batch["sparse_path"][i])),
                             out_path=pathlib.Path(str(batch["out_path"][i])),
                             intrinsics_path=pathlib.Path(intrinsics) if intrinsics else None, K=K, T_cam_lidar=T,
                             image_size=size if size[0] > 0 else None, point_columns=columns or None,
                             image_path=pathlib.Path(image) if image else None,
                             image_crop_from=crop_from if crop_from[0] > 0 else None,
                             force=bool(batch["force"][i]) if "force" in batch else False))
    return jobs


# --------------------------------------------------------------------------- actor UDF

class _CompleteFrames:
    """Ray Data class UDF: one instance per actor, compiled functions kept across batches.

    ``__call__`` takes a numpy-format batch of job records and returns one status
    row per frame: ``name``, ``status`` ("done" or "failed") and ``message``
    (empty when done). A bad input, a failed computation or a failed write is a
    "failed" row, never an exception, so one bad frame cannot fail the dataset.
    Outputs are written atomically (:func:`jaxdepth.batch.extras.write_outputs`); a file an
    earlier attempt of the same task finished is kept (same bytes) unless ``overwrite``, so a
    retried task is idempotent.
    """

    def __init__(self, *, method: str, config: SGMConfig, lidar: LidarSpec, T_cam_lidar: np.ndarray,
                 batch_size: int, io_threads: int = 2, extras=None, overwrite: bool = False):
        import jax

        from jaxdepth.batch import extras as extra_outputs
        from jaxdepth.batch import runner

        # Extra outputs (jaxdepth.batch.extras): files beside each PNG; existing ones are kept unless
        # ``overwrite``, so a retried task skips what an earlier attempt finished.
        self.extras = extra_outputs.NONE if extras is None else extras
        self.overwrite = bool(overwrite)
        self._more = ({"max_seed_distance_px": self.extras.seed_limit} if self.extras.needs_seeds
                      else {})

        self._runner = runner
        self.method, self.config, self.lidar = method, config, lidar
        self.T = np.asarray(T_cam_lidar, np.float32)
        self.devices = len(jax.local_devices())
        # Same rounding as runner.run_jobs: identical compiled function, identical bytes.
        self.batch_size = -(-max(1, int(batch_size)) // self.devices) * self.devices
        self.strategy = runner.batch_strategy()
        self.io_threads = max(1, int(io_threads))
        # Guided configs (image-guided seeds) also read each frame's camera image, as run_jobs does.
        self._load = runner.loader(config)

    def _read(self, job):
        return self._runner.try_load(job, self._load)

    def _write(self, job, depth, valid=None, distance=None) -> str | None:
        from jaxdepth.batch import extras as extra_outputs

        return self._runner.write_failure(job.out_path, lambda: extra_outputs.write_outputs(
            job.out_path, depth, extras=self.extras, valid=valid, distance=distance, overwrite=self.overwrite))

    def __call__(self, batch: dict[str, Any]) -> dict[str, np.ndarray]:
        jobs = _jobs_from_batch(batch)
        failure: dict[str, str] = {}
        groups: dict[tuple[int, int], list] = {}
        with cf.ThreadPoolExecutor(self.io_threads) as pool:
            for job, (loaded, message) in zip(jobs, pool.map(self._read, jobs)):
                if loaded is None:
                    failure[job.name] = message
                else:
                    key, item = self._runner.batch_item(job, loaded, self.T)
                    groups.setdefault(key, []).append(item)
            writes = []
            for key, items in groups.items():
                for start in range(0, len(items), self.batch_size):
                    chunk = items[start:start + self.batch_size]
                    try:
                        # The runner's compiled functions (cached per process, so per actor) and padding.
                        fn, args, _ = self._runner._group_call(
                            key, chunk, batch_size=self.batch_size, method=self.method, config=self.config,
                            lidar=self.lidar, strategy=self.strategy, devices=self.devices, **self._more)
                        out = fn(*args)
                        result = tuple(np.asarray(o) for o in out) if isinstance(out, tuple) else (np.asarray(out),)
                    except Exception as err:  # a compute failure costs this chunk, not the dataset
                        for job, *_ in chunk:
                            failure[job.name] = f"completion failed: {err}"
                        continue
                    writes += [(job, pool.submit(self._write, job, *(r[i] for r in result)))
                               for i, (job, *_) in enumerate(chunk)]
            for job, future in writes:
                message = future.result()
                if message is not None:
                    failure[job.name] = message
        names = [job.name for job in jobs]
        return {
            "name": np.array(names, dtype=object),
            "status": np.array(["failed" if n in failure else "done" for n in names], dtype=object),
            "message": np.array([failure.get(n, "") for n in names], dtype=object),
        }


# --------------------------------------------------------------------------- nuScenes samples

def _sample_record(job) -> dict[str, str]:
    """A planned nuScenes sample (``nuscenes_job._SampleJob``) -> a flat row: its token, and the
    channels and output paths still to write as JSON lists (strings only, for Arrow)."""
    return {"name": job.token, "channels": json.dumps(list(job.channels)),
            "out_paths": json.dumps([os.fspath(p) for p in job.out_paths])}


def _samples_from_batch(batch: dict[str, Any]) -> list:
    """A numpy-format batch of sample records -> ``_SampleJob``s (inverse of :func:`_sample_record`)."""
    from jaxdepth.batch.nuscenes_job import _SampleJob

    return [_SampleJob(token=str(batch["name"][i]), channels=tuple(json.loads(str(batch["channels"][i]))),
                       out_paths=tuple(pathlib.Path(p) for p in json.loads(str(batch["out_paths"][i]))))
            for i in range(len(batch["name"]))]


class _CompleteSamples:
    """Ray Data class UDF for nuScenes samples: one instance per actor.

    The version's tables are read once per actor; each batch of sample records
    goes through :func:`jaxdepth.batch.nuscenes_job.complete_samples`, the local
    engine's own per-sample path (load, compiled rig completion cached per
    process, atomic writes), so the PNGs are the local engine's bytes. Returns one
    status row per sample (``name`` = sample token, ``status``, ``message``); a
    bad sample is a "failed" row, never an exception.
    """

    def __init__(self, *, dataroot: str, version: str, sweeps: int, ego_motion: bool, config: SGMConfig,
                 extras, overwrite: bool, png_compression: int, io_threads: int = 2, force: bool = False):
        from jaxdepth.io import nuscenes as nusc

        self.tables = nusc.load_tables(dataroot, version)
        self.options = dict(sweeps=sweeps, ego_motion=ego_motion, config=config, extras=extras,
                            overwrite=overwrite, png_compression=png_compression, io_threads=max(1, int(io_threads)),
                            force=force)

    def __call__(self, batch: dict[str, Any]) -> dict[str, np.ndarray]:
        from jaxdepth.batch.nuscenes_job import complete_samples
        from jaxdepth.batch.runner import RunSummary

        jobs = _samples_from_batch(batch)
        summary = RunSummary()
        complete_samples(self.tables, jobs, summary, lambda name, status: None, **self.options)
        failure = dict(summary.failed)
        names = [job.token for job in jobs]
        return {
            "name": np.array(names, dtype=object),
            "status": np.array(["failed" if n in failure else "done" for n in names], dtype=object),
            "message": np.array([failure.get(n, "") for n in names], dtype=object),
        }


# --------------------------------------------------------------------------- cluster

def _restore_env(saved: dict[str, str | None]) -> None:
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


@contextlib.contextmanager
def _local_ray(ray, *, runtime_env: dict | None = None) -> Iterator[None]:
    """A throw-away single-node Ray on loopback only (no dashboard, no usage stats), shut down on exit.

    ``ray.init`` turns ``_node_ip_address="127.0.0.1"`` into the machine's
    network address, and Ray then listens on every interface. Ray's one switch
    for a local-only node is ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` (read into
    ``ray_constants.ENABLE_RAY_CLUSTER`` when Ray is imported): it is set in the
    environment the started processes inherit and, for this process, the
    already-imported flag is switched off while ``ray.init`` runs; both are
    restored right after, so a later connection to a real cluster is unaffected.
    ``RAY_USAGE_STATS_ENABLED`` defaults to 0 while the cluster lives (Ray Data
    otherwise starts usage pollers in the driver).
    """
    saved = {key: os.environ.get(key) for key in ("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "RAY_USAGE_STATS_ENABLED")}
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    try:
        try:
            from ray._private import ray_constants  # private: absent or renamed only loses the loopback pin
        except ImportError:  # pragma: no cover - depends on the Ray version
            ray_constants = None
        saved_flag = getattr(ray_constants, "ENABLE_RAY_CLUSTER", None)
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
        try:
            if saved_flag is not None:
                ray_constants.ENABLE_RAY_CLUSTER = False
            ray.init(address="local", num_cpus=LOCAL_NUM_CPUS, include_dashboard=False,
                     object_store_memory=LOCAL_OBJECT_STORE_BYTES, runtime_env=runtime_env,
                     logging_level=logging.WARNING)
        finally:
            if saved_flag is not None:
                ray_constants.ENABLE_RAY_CLUSTER = saved_flag
            _restore_env({"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": saved["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"]})
        node_ip = ray.util.get_node_ip_address()
        if node_ip not in ("127.0.0.1", "::1"):
            log.warning("ray: the local Ray could not be pinned to loopback (node address %s)", node_ip)
        try:
            yield
        finally:
            ray.shutdown()
    finally:
        _restore_env(saved)


@contextlib.contextmanager
def _connected(ray, address: str | None, runtime_env: dict | None) -> Iterator[None]:
    """Reuses a connected Ray, connects to ``address`` / ``RAY_ADDRESS``, or starts a local one.

    On exit a local Ray started here is shut down; a connection opened here is
    closed (``ray.shutdown`` in a driver that connected only disconnects it: the
    cluster keeps running); a connection that was already open is left alone.
    """
    if ray.is_initialized():
        log.info("ray: using the Ray instance this process is already connected to")
        yield
        return
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address:
        log.info("ray: connecting to %s", address)
        ray.init(address=address, runtime_env=runtime_env, logging_level=logging.WARNING)
        try:
            yield
        finally:
            ray.shutdown()
        return
    log.info("ray: starting a local Ray (%d CPUs, loopback only)", LOCAL_NUM_CPUS)
    with _local_ray(ray, runtime_env=runtime_env):
        yield


def _fitting_nodes(ray, cpus: float, gpus: float) -> int:
    """Alive nodes with room for one actor (a CPU-less head node does not count); at least 1."""
    try:
        nodes = ray.nodes()
    except Exception:  # pragma: no cover - only a hint for the pool size
        return 1
    fits = 0
    for node in nodes:
        resources = node.get("Resources", {})
        if node.get("Alive") and resources.get("CPU", 0.0) >= cpus and resources.get("GPU", 0.0) >= gpus:
            fits += 1
    return max(1, fits)


def _run_pool(ray, ray_data, records: list, udf, summary, notify, *, batch_size: int, num_actors: int | None,
              cpus_per_actor: float, gpus_per_actor: float, max_restarts: int, max_task_retries: int,
              constructor_kwargs: dict) -> None:
    """Maps ``records`` through a pool of ``udf`` actors (Ray Data ``map_batches``, ``batch_size``
    records per call) and records each status row (``name``, ``status``, ``message``) in
    ``summary`` and ``notify`` as it arrives. Needs a connected Ray."""
    actors = int(num_actors) if num_actors is not None else _fitting_nodes(ray, cpus_per_actor, gpus_per_actor)
    blocks = max(1, min(len(records), -(-len(records) // batch_size)))
    with _quiet_ray_data(ray_data):
        ds = ray_data.from_items(records, override_num_blocks=blocks)
        with warnings.catch_warnings():
            # Ray >= 2.5x deprecates the **ray_remote_args of map_batches in favour of named
            # parameters, but has none yet for max_restarts / max_task_retries / scheduling.
            warnings.filterwarnings("ignore", message=".*ray_remote_args.*deprecated")
            ds = ds.map_batches(
                udf,
                batch_size=batch_size,
                batch_format="numpy",
                compute=ray_data.ActorPoolStrategy(size=actors),
                fn_constructor_kwargs=constructor_kwargs,
                num_cpus=cpus_per_actor,
                num_gpus=gpus_per_actor,
                max_restarts=max_restarts,
                max_task_retries=max_task_retries,
                scheduling_strategy="SPREAD",
            )
        for row in ds.iter_rows():
            name, status, message = str(row["name"]), str(row["status"]), str(row["message"])
            if status == "done":
                summary.done.append(name)
                if summary.first_output_at is None:
                    summary.first_output_at = time.perf_counter()
                notify(name, "done")
            else:
                summary.failed.append((name, message))
                notify(name, f"failed: {message}")


# --------------------------------------------------------------------------- public API

def run_jobs_ray(jobs: Sequence, *, method: str = "sgm", config: SGMConfig = SGMConfig(),
                 lidar: LidarSpec = presets.KITTI_HDL64, T_cam_lidar: np.ndarray | None = None,
                 batch_size: int = 4, overwrite: bool = False, address: str | None = None,
                 num_actors: int | None = None, cpus_per_actor: float = 1.0, gpus_per_actor: float = 0.0,
                 max_restarts: int = 3, max_task_retries: int = 3, runtime_env: dict | None = None,
                 on_progress: Callable[[str, str], None] | None = None, extras=None):
    """Completes every job on a Ray cluster; never raises for a bad frame.

    Same contract as :func:`jaxdepth.batch.runner.run_jobs` (and the same output
    bytes for the same ``batch_size``), with the frames spread over a pool of
    Ray actors.

    Args:
      jobs: :class:`jaxdepth.batch.runner.FrameJob` list. Paths must be readable and
        writable under the same name on every node.
      method, config, lidar, T_cam_lidar, batch_size, overwrite: as in
        :func:`jaxdepth.batch.runner.run_jobs`. ``batch_size`` frames of one size go
        through one compiled call (the last is padded, never recompiled). A guided
        ``config`` (``guidance_weight > 0``): each actor reads the jobs' camera images
        (``FrameJob.image_path``) as the local runner does, same bytes.
      address: Ray cluster address (``"ray://host:10001"``, ``"host:6379"`` or
        ``"auto"``): the driver connects, and disconnects at the end, leaving the
        cluster running. None: the ``RAY_ADDRESS`` environment variable if set,
        else a local Ray on loopback (2 CPUs, no dashboard) that is shut down at
        the end. A Ray this process is already connected to is reused as is.
      num_actors: size of the actor pool (default: one per alive node with room
        for an actor; the actors are spread over the nodes).
        Each actor's XLA already uses every core of its node.
      cpus_per_actor, gpus_per_actor: Ray resources reserved per actor. Ray
        hides GPUs from an actor that reserves none, so set ``gpus_per_actor=1``
        to complete on GPUs.
      max_restarts, max_task_retries: fault tolerance of the actors. A dead
        actor (crash, lost node, out of memory) is restarted up to
        ``max_restarts`` times, and the batch it was working on is retried up to
        ``max_task_retries`` times (on another actor when one is free). A
        retried batch rewrites its outputs atomically with the same bytes.
      runtime_env: passed to ``ray.init`` (e.g. ``{"py_modules": [jaxdepth]}``
        when the cluster does not have jaxdepth installed).
      on_progress: ``on_progress(name, status)`` once per frame on the driver,
        status "done", "skipped" or "failed: <message>", as rows arrive.
      extras: :class:`jaxdepth.batch.extras.ExtraOutputs` (default none), as in
        :func:`jaxdepth.batch.runner.run_jobs`.

    Returns:
      :class:`jaxdepth.batch.runner.RunSummary` with ``done``, ``skipped`` (output
      already there and ``overwrite`` False; checked on the driver before the
      dataset is built, so a re-run resumes) and ``failed`` ``(name, message)``.

    Raises:
      ImportError: Ray Data is not installed (``pip install 'jaxdepth[ray]'``).
      ValueError: bad ``batch_size``, ``num_actors`` or duplicate output paths.
      ray.exceptions.RayError: the cluster failed beyond the retries above
        (bad frames never raise).
    """
    from jaxdepth.batch.runner import RunSummary, check_sgm_only, is_guided

    if int(batch_size) < 1:
        raise ValueError(f"run_jobs_ray: field 'batch_size' expected >= 1, got {batch_size}")
    if num_actors is not None and int(num_actors) < 1:
        raise ValueError(f"run_jobs_ray: field 'num_actors' expected >= 1 or None, got {num_actors}")
    outs = [os.fspath(job.out_path) for job in jobs]
    if len(set(outs)) != len(outs):
        dup = next(o for o in outs if outs.count(o) > 1)
        raise ValueError(f"run_jobs_ray: field 'jobs' expected distinct output paths, got {dup!r} twice")
    if method != "sgm" and any(job.image_size is not None for job in jobs):
        raise ValueError(f"run_jobs_ray: sweep jobs (image_size set) complete with method 'sgm' only, got {method!r}")
    check_sgm_only(method, where="run_jobs_ray", extras=extras, guided=is_guided(config))
    ray, ray_data = _import_ray()

    summary = RunSummary()
    notify = on_progress or (lambda name, status: None)
    from jaxdepth.batch.runner import pending_jobs
    todo = pending_jobs(jobs, overwrite=overwrite, summary=summary, notify=notify, extras=extras)
    if not todo:
        return summary
    T = np.asarray(presets.KITTI_T_CAM2_LIDAR if T_cam_lidar is None else T_cam_lidar, np.float32)
    if T.shape != (4, 4):
        raise ValueError(f"run_jobs_ray: field 'T_cam_lidar' expected shape (4, 4), got {T.shape}")
    batch_size = int(batch_size)

    with _connected(ray, address, runtime_env):
        _run_pool(ray, ray_data, [_record(job) for job in todo], _CompleteFrames, summary, notify,
                  batch_size=batch_size, num_actors=num_actors, cpus_per_actor=cpus_per_actor,
                  gpus_per_actor=gpus_per_actor, max_restarts=max_restarts, max_task_retries=max_task_retries,
                  constructor_kwargs=dict(method=method, config=config, lidar=lidar, T_cam_lidar=T,
                                          batch_size=batch_size, extras=extras, overwrite=overwrite))
    return summary


def complete_folder_ray(src, dst, *, method: str = "sgm", config: SGMConfig = SGMConfig(), batch_size: int = 4,
                        overwrite: bool = False, address: str | None = None, K: np.ndarray | None = None,
                        on_progress: Callable[[str, str], None] | None = None):
    """Completes a KITTI depth-completion folder on Ray: ``dst/<name>.png`` per input frame.

    Args:
      src: folder in a layout :func:`jaxdepth.io.kitti_layout.list_depth_completion_folder`
        accepts (``velodyne_raw/*.png`` + ``intrinsics/*.txt``, or flat).
      dst: output folder (created if missing); one 16-bit KITTI depth PNG per
        frame, same file name as the input.
      K: optional (3, 3) intrinsics used for every frame instead of the files.
      method, config, batch_size, overwrite, address, on_progress: see :func:`run_jobs_ray`.

    Returns:
      :class:`jaxdepth.batch.runner.RunSummary`.

    Raises:
      InputError: ``src`` is not a readable depth-completion folder.
      OutputError: ``dst`` cannot be created.
    """
    from jaxdepth.io.errors import OutputError
    from jaxdepth.io.kitti_layout import list_depth_completion_folder
    from jaxdepth.batch.runner import FrameJob

    dst = pathlib.Path(dst)
    frames = list_depth_completion_folder(src)
    try:
        dst.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{dst}: cannot create output folder ({err.strerror or err})") from None
    K = None if K is None else np.asarray(K, np.float32)
    if K is not None and K.shape != (3, 3):
        raise ValueError(f"complete_folder_ray: field 'K' expected shape (3, 3), got {K.shape}")
    jobs = [FrameJob(name=name, sparse_path=png, out_path=dst / png.name, intrinsics_path=txt, K=K)
            for name, png, txt in frames]
    return run_jobs_ray(jobs, method=method, config=config, batch_size=batch_size, overwrite=overwrite,
                        address=address, on_progress=on_progress)


def run_nuscenes_ray(dataroot, dst, *, version: str, sweeps: int = 1, ego_motion: bool = True,
                     config: SGMConfig | None = None, overwrite: bool = False, png_compression: int | None = None,
                     extras=None, batch_size: int = 4, address: str | None = None, num_actors: int | None = None,
                     cpus_per_actor: float = 1.0, gpus_per_actor: float = 0.0, max_restarts: int = 3,
                     max_task_retries: int = 3, runtime_env: dict | None = None,
                     on_progress: Callable[[str, str], None] | None = None, tables=None, force: bool = False):
    """Completes every sample of a nuScenes version on Ray; never raises for a bad sample.

    Same contract and outputs as :func:`jaxdepth.batch.nuscenes_job.run_nuscenes`
    (``<dst>/<version>/<CHANNEL>/<sample_data_token>.png``, same bytes, same extras),
    with the samples spread over a pool of Ray actors. The driver reads the
    tables, plans the samples (finished ones are skipped, unless ``overwrite``)
    and creates the output folders; Ray Data carries only sample records (token,
    channels, output paths). Each actor reads the tables once and completes its
    samples with the local engine's per-sample path
    (:func:`jaxdepth.batch.nuscenes_job.complete_samples`), reading the LiDAR files
    and writing the PNGs itself.

    Args:
      dataroot, dst, version, sweeps, ego_motion, config, overwrite, png_compression, extras,
        on_progress, tables, force: as in :func:`~jaxdepth.batch.nuscenes_job.run_nuscenes` (``tables``
        is used by the driver only; every actor reads its own from ``dataroot``).
      batch_size: samples per Ray Data batch (default 4): an actor loads the next samples of
        its batch while completing one; smaller batches balance the actors more finely.
      address, num_actors, cpus_per_actor, gpus_per_actor, max_restarts, max_task_retries,
        runtime_env: as in :func:`run_jobs_ray`. ``dataroot`` and ``dst`` must be visible
        under the same path on every node.

    Returns:
      :class:`jaxdepth.batch.runner.RunSummary` over sample tokens.

    Raises:
      ImportError: Ray Data is not installed (``pip install 'jaxdepth[ray]'``).
      ValueError: bad ``sweeps``, ``batch_size`` or ``num_actors``.
      InputError: the version folder or one of its tables is missing or malformed.
      OutputError: an output folder cannot be created.
      ray.exceptions.RayError: the cluster failed beyond the retries (bad samples never raise).
    """
    from jaxdepth.batch import nuscenes_job
    from jaxdepth.batch.extras import NONE
    from jaxdepth.batch.runner import RunSummary
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION

    if isinstance(sweeps, bool) or not isinstance(sweeps, int) or sweeps < 1:
        raise ValueError(f"run_nuscenes_ray: field 'sweeps' expected an integer >= 1, got {sweeps!r}")
    if int(batch_size) < 1:
        raise ValueError(f"run_nuscenes_ray: field 'batch_size' expected >= 1, got {batch_size}")
    if num_actors is not None and int(num_actors) < 1:
        raise ValueError(f"run_nuscenes_ray: field 'num_actors' expected >= 1 or None, got {num_actors}")
    ray, ray_data = _import_ray()
    extras = NONE if extras is None else extras
    summary = RunSummary(started_at=time.perf_counter())
    notify = on_progress or (lambda name, status: None)
    tables = nusc.load_tables(dataroot, version) if tables is None else tables
    # absolute on the driver: the actors' working folder is not the driver's
    dataroot, dst = pathlib.Path(dataroot).absolute(), pathlib.Path(dst).absolute()
    todo = nuscenes_job.plan(tables, dst, overwrite=overwrite, summary=summary, notify=notify, extras=extras)
    if not todo:
        return summary
    nuscenes_job.make_folders(todo)
    options = dict(dataroot=os.fspath(dataroot), version=version, sweeps=sweeps, ego_motion=ego_motion,
                   config=SGMConfig() if config is None else config, extras=extras, overwrite=overwrite,
                   png_compression=DEFAULT_PNG_COMPRESSION if png_compression is None else png_compression,
                   force=force)
    with _connected(ray, address, runtime_env):
        _run_pool(ray, ray_data, [_sample_record(job) for job in todo], _CompleteSamples, summary, notify,
                  batch_size=int(batch_size), num_actors=num_actors, cpus_per_actor=cpus_per_actor,
                  gpus_per_actor=gpus_per_actor, max_restarts=max_restarts, max_task_retries=max_task_retries,
                  constructor_kwargs=options)
    return summary


__all__ = ["run_jobs_ray", "complete_folder_ray", "run_nuscenes_ray"]
