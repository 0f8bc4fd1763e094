"""Run multi-source completions (one :class:`~jaxdepth.io.sources.SourceCloud` + rig per frame) over many frames.

The shared loop of the dataset jobs that complete several sources at once (Argoverse 2
logs, KITTI raw drives with ``--sweeps``): a reader thread pool loads frames ahead (each
job's ``load`` returns the frame's cloud and rig) and builds each frame's program inputs
(:func:`cloud_preparation`), the main thread runs the program (:func:`complete_sources`' SGM or a baseline
of the same points) for every camera of the rig, and writer threads write one KITTI depth PNG per camera, atomically. A
frame that cannot be read or completed is reported and the rest carries on; a frame is
recorded done once all its PNGs are in place.

The baselines of every multi-source job (``--method nearest`` / ``ip-basic``, :func:`baseline_depth`):
every point of the frame (all sources merged, as the SGM receives them) projected into each camera
with the z-buffer (nearest point per pixel, no outlier removal), then filled by
:func:`jaxdepth._src.methods.complete_with`'s nearest fill or IP_Basic.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import functools
import pathlib
from typing import Callable

import numpy as np

#: Frames loaded ahead of the device.
READ_AHEAD = 2
#: The methods of the multi-source jobs: the SGM and the two baselines (:func:`baseline_depth`).
METHODS = ("sgm", "nearest", "ip-basic")


def check_method(method: str, *, where: str, extras, config=None, guided: bool = False) -> None:
    """ValueError naming ``where`` for a ``method`` that is none of :data:`METHODS`, or a baseline with options
    that need the SGM (:func:`jaxdepth.batch.runner.check_sgm_only`; guided: ``guided`` or a guided ``config``)."""
    from jaxdepth.batch.runner import check_sgm_only, is_guided

    if method not in METHODS:
        raise ValueError(f"{where}: field 'method' expected one of {METHODS}, got {method!r}")
    check_sgm_only(method, where=where, extras=extras, guided=guided or (config is not None and is_guided(config)))


@dataclasses.dataclass(frozen=True)
class CloudJob:
    """One frame: its name (progress, failures), ``outputs`` ((camera name, PNG path), ...) still to write,
    and ``source``: whatever the job's loader needs to read the frame."""

    name: str
    outputs: tuple
    source: object


def complete_sources(cloud, rig, *, config, images=None, window: tuple | None = None) -> np.ndarray:
    """(C, H, W) float32 depth of every camera of ``rig`` (on the largest camera's canvas) from a SourceCloud.

    The one completion call of the multi-source jobs:
    :func:`jaxdepth.batch.sources_job.complete_cloud` with free space on (range image, normals and
    Algorithm 1's viewpoint per source; other sweeps' points in the reference sweep's free space
    removed). ``images``: (C, H, W[, 3]) uint8 camera images on the canvas for image-guided seeds
    (``config.guidance_weight > 0``), else None. ``window``: the sweep numbers of a frame with all its
    neighbours, so that frames with fewer share its compiled program
    (:func:`jaxdepth.batch.sources_job.fit_to_window`).
    """
    from jaxdepth.batch.sources_job import complete_cloud

    return complete_cloud(cloud, rig, config=config, free_space=True, images=images, window=window)


@functools.lru_cache(maxsize=8)
def _baseline_fn(method: str, metric: str, height: int, width: int):
    """jit: (points (B, 3), valid (B,), K (C, 3, 3), T (C, 4, 4)) -> (C, height, width) baseline depth."""
    import jax

    from jaxdepth._src.config import SGMConfig
    from jaxdepth._src.geometry import project_to_image
    from jaxdepth._src.methods import METHODS as FILLS
    from jaxdepth._src.presets import KITTI_HDL64

    config = SGMConfig(distance_metric=metric, outlier_removal=False)

    def one(points, valid, K, T):
        sparse = project_to_image(points, valid, K, T, height=height, width=width)[0]
        return FILLS[method](sparse, K, T, config=config, lidar=KITTI_HDL64)  # the spec: read by outlier removal only

    return jax.jit(jax.vmap(one, in_axes=(None, None, 0, 0)))


def baseline_depth(points, valid, rig, *, method: str, config) -> np.ndarray:
    """(C, H_max, W_max) float32 depth of a baseline (``"nearest"`` or ``"ip-basic"``) for every camera of ``rig``.

    ``points`` (B, 3) float32 in the rig's reference frame (``rig.cameras[i].T_cam_lidar`` maps them into
    camera ``i``) with ``valid`` (B,) bool, e.g. :func:`jaxdepth.io.pad_points` of a cloud's points: all of
    them projected (nearest point per pixel), no outlier removal, filled by the nearest LiDAR pixel in
    ``config.distance_metric`` or by IP_Basic; each camera at its own size (one compiled function per
    size and point bucket), placed in the top-left corner of the largest camera's canvas.
    """
    if method not in METHODS[1:]:
        raise ValueError(f"baseline_depth: field 'method' expected 'nearest' or 'ip-basic', got {method!r}")
    cams = rig.cameras
    out = np.zeros((len(cams), max(c.height for c in cams), max(c.width for c in cams)), np.float32)
    for h, w in sorted({(c.height, c.width) for c in cams}):
        idx = [i for i, c in enumerate(cams) if (c.height, c.width) == (h, w)]
        K = np.stack([np.asarray(cams[i].K, np.float32) for i in idx])
        T = np.stack([np.asarray(cams[i].T_cam_lidar, np.float32) for i in idx])
        out[idx, :h, :w] = np.asarray(_baseline_fn(method, config.distance_metric, h, w)(points, valid, K, T))
    return out


def cloud_baseline_depth(cloud, rig, *, method: str, config) -> np.ndarray:
    """:func:`baseline_depth` of every point of ``cloud`` (a :class:`~jaxdepth.io.SourceCloud`, all its
    sources merged), padded to its point bucket (:func:`jaxdepth.io.pad_points`)."""
    from jaxdepth.io import pad_points
    return baseline_depth(*pad_points(cloud.points), rig, method=method, config=config)


def cloud_preparation(method: str, *, config, window: tuple | None = None) -> Callable:
    """``prepare(cloud, rig) -> call`` of :func:`run_cloud_jobs` for ``method``; ``call()`` returns
    ``(depth, None, None)``. The SGM's host work (cameras, sources pytree:
    :func:`jaxdepth.batch.sources_job.cloud_call`, as :func:`complete_sources` with ``window``) is done by
    ``prepare``, ``call()`` dispatches its program and returns device arrays; a baseline
    (:func:`cloud_baseline_depth`) runs whole in ``call()``, as before."""
    if method not in METHODS:
        raise ValueError(f"cloud_preparation: field 'method' expected one of {METHODS}, got {method!r}")
    if method == "sgm":
        from jaxdepth.batch.sources_job import cloud_call

        def prepare(cloud, rig):
            program = cloud_call(cloud, rig, config=config, free_space=True, window=window)
            return lambda: (program(), None, None)
        return prepare

    return lambda cloud, rig: lambda: (cloud_baseline_depth(cloud, rig, method=method, config=config), None, None)


def read_back(outputs) -> tuple:
    """``outputs`` (device arrays, NumPy or None) as NumPy: waits for the program that makes them."""
    return tuple(None if o is None else np.asarray(o) for o in outputs)


def run_cloud_jobs(todo, load: Callable, summary, notify, *, config, png_compression: int,
                   io_threads: int = 2, prepare: Callable | None = None,
                   extras=None, overwrite: bool = True, targets=None) -> None:
    """Completes ``todo`` (:class:`CloudJob` s, output folders existing) into their PNGs.

    ``load(job) -> (SourceCloud, Rig)``; every output's camera name must be a camera of the rig.
    A frame's completion, in two steps: ``prepare(cloud, rig) -> call`` on the reader thread right after
    ``load`` (the host work of the frame's program: the main thread does not wait for it), then on the main
    thread ``call() -> (depth, valid, distance)``, each (C, H, W) on the rig's canvas (``valid`` and
    ``distance`` None unless ``extras`` needs them), device arrays or NumPy, read back (:func:`read_back`)
    at once: the next frame's program is not dispatched before (two programs of the rig in flight ran
    slower on the 2-core CPU, docs/speed.md "The multi-source jobs' host work on the reader threads").
    Default: :func:`cloud_preparation`'s SGM (a ``prepare`` that returns ``lambda: f(cloud, rig)`` runs ``f``
    whole on the main thread). A (Jaxdepth or Value) error of either step fails its frame
    as "completion failed: ..."; frames are completed and handed to the writers in ``todo``'s order.
    ``extras``: :class:`jaxdepth.batch.extras.ExtraOutputs` written beside each PNG (default none);
    ``overwrite``: replace files that exist (default True: the jobs list only outputs to write).
    ``targets``: devices (default None: JAX's default device, the above). With N > 1 of them, frame ``k``'s
    ``call()`` runs under ``jax.default_device(targets[k % N])`` and N frames are in flight, one per device
    (each device compiles its own copy; before a device's first call the frames in flight are read back and
    handed to the writers, so the first frame is not held behind the next device's compile).
    Records each job in ``summary`` as done or failed (never raises for a bad frame).
    """
    import collections
    import contextlib

    import jax

    from jaxdepth.batch import extras as extra_outputs
    from jaxdepth.batch.runner import Ledger, read_ahead, write_failure
    from jaxdepth.io.errors import JaxdepthError

    ledger = Ledger(summary, notify)
    extras = extra_outputs.NONE if extras is None else extras
    written = []                  # the writers' futures
    if prepare is None:
        prepare = cloud_preparation("sgm", config=config)

    def load_prepared(job):
        cloud, rig = load(job)
        try:
            return rig, prepare(cloud, rig), None
        except (JaxdepthError, ValueError) as err:
            return rig, None, f"completion failed: {err}"

    def write(job, rig, depth, valid, distance):
        index = {c.name: i for i, c in enumerate(rig.cameras)}
        for camera, path in job.outputs:
            cam = rig.cameras[index[camera]]
            window = (index[camera], slice(0, cam.height), slice(0, cam.width))
            message = write_failure(path, lambda path=path, window=window: extra_outputs.write_outputs(
                pathlib.Path(path), depth[window], extras=extras, overwrite=overwrite,
                valid=None if valid is None else valid[window],
                distance=None if distance is None else distance[window], compression=png_compression))
            if message is not None:
                ledger.fail(job.name, message)
                return
        ledger.done(job.name)

    targets = [None] if not targets else list(targets)
    in_flight = collections.deque()   # (job, rig, call() outputs), dispatched, not read back

    def collect(writers):
        job, rig, outputs = in_flight.popleft()
        try:
            outputs = read_back(outputs)
        except (JaxdepthError, ValueError) as err:
            ledger.fail(job.name, f"completion failed: {err}")
            return
        written.append(writers.submit(write, job, rig, *outputs))

    with cf.ThreadPoolExecutor(io_threads) as readers, cf.ThreadPoolExecutor(io_threads) as writers:
        dispatched = 0
        for job, (loaded, message) in read_ahead(todo, readers, window=READ_AHEAD, load=load_prepared,
                                                 os_error=lambda job, err: f"cannot read: {err}"):
            rig, call, message = loaded if message is None else (None, None, message)
            if message is not None:
                ledger.fail(job.name, message)
                continue
            while in_flight and 0 < dispatched < len(targets):   # a device's first call compiles its copy here
                collect(writers)
            target = targets[dispatched % len(targets)]
            try:
                with contextlib.nullcontext() if target is None else jax.default_device(target):
                    outputs = call()
            except (JaxdepthError, ValueError) as err:
                ledger.fail(job.name, f"completion failed: {err}")
                continue
            dispatched += 1
            in_flight.append((job, rig, outputs))
            if len(in_flight) >= len(targets):
                collect(writers)
        while in_flight:
            collect(writers)
        for f in written:
            f.result()


__all__ = ["CloudJob", "complete_sources", "run_cloud_jobs", "baseline_depth", "cloud_baseline_depth",
           "cloud_preparation", "read_back", "METHODS"]
