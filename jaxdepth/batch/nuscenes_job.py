"""Complete a whole nuScenes version offline: every sample, every camera (``jaxdepth complete --nusc-version``).

Per sample (ordered by timestamp): the key-frame LIDAR_TOP sweep (or ``sweeps`` of
them, accumulated into the key frame's LiDAR frame) and every key-frame camera,
with K and the ego-motion compensated ``T_cam_lidar`` from the version's tables
(:mod:`jaxdepth.io.nuscenes`), go through the multi-camera path
(:func:`jaxdepth.io.prepare_sweep`, :func:`jaxdepth.complete_rig`): one range
image and normals per sample, the cameras vmapped. One compiled function per
(point bucket, camera canvas): sweeps are padded to power-of-two buckets
(:func:`jaxdepth.io.pad_points`).

Outputs: one uint16 KITTI-format depth PNG (metres x 256, 0 = empty) per camera
sample_data token, ``<dst>/<version>/<CHANNEL>/<sample_data_token>.png``
(:func:`jaxdepth.io.nuscenes.output_path`), written atomically. A sample whose
outputs all exist is skipped (resume) unless ``overwrite``; a bad sample is
reported and the rest completes.

Methods: ``"sgm"`` (default) and the baselines ``"nearest"`` / ``"ip-basic"``
(:func:`jaxdepth.batch.cloud_runner.baseline_depth`): every point the SGM would receive
(the prepared key-frame sweep, or all ``sweeps`` merged in the key frame's LiDAR frame)
projected into each camera, nearest point per pixel, no outlier removal, then the nearest
LiDAR pixel's depth in the run's distance metric, or IP_Basic; same outputs, resume and
progress. The seed-based extra outputs and image guidance need the SGM.

Image-guided seeds (``config.guidance_weight > 0``, issue 16): each sample's
key-frame camera JPEGs (the camera sample_data rows' ``filename``) are read with
its sweep (:func:`jaxdepth.io.rig_images.read_rig_images`: 8-bit colour, the
size the tables give, RGB) and passed to the rig completion; a missing or bad
image fails its sample with a message naming the file, the rest completes.
Unguided runs do not open the images.

Where the LiDAR sits: the points are in the key-frame LIDAR_TOP sensor frame by
the tables' definition, so its origin is stated (``lidar_origin_m = 0``), not
estimated, and outlier removal follows the run's config. With ``sweeps > 1`` every
sweep is its own source (:func:`jaxdepth.io.nuscenes.sweep_cloud`: its points and
where its LiDAR sat, from the ego poses) and the sample goes through
:func:`jaxdepth.batch.cloud_runner.complete_sources`: range image, normals and
Algorithm 1's LiDAR view per sweep, and points of earlier sweeps that lie in the key
frame's free space (moving objects' trails, registration errors) removed. ``sweeps = 1``
is the single-sweep path, unchanged. The seed-based extra outputs (validity, seed
distance, zero-invalid) need ``sweeps = 1``.

Scheduling: a reader thread pool loads samples ahead; each sample is dispatched
(asynchronously) before the previous result is collected; writer threads encode
and write the PNGs. One device by default (``devices``: whole samples dealt round
robin over several, one in flight on each beyond the one being dispatched, each device
compiling its own copy; the CLI's ``--cpu-devices N`` > 1 splits the CPU into N host
devices for it): XLA already spreads one sample over the cores (one call: ~1.7 cores
busy), splitting the cameras of a sample over two host devices is no faster on 2 cores,
and a whole sample on each of two gains 6.5 % of the wall at idle for a second compile
(same bytes; docs/speed.md, "Whole samples on two host devices").

The Ray engine (:func:`jaxdepth.batch.scale.run_nuscenes_ray`) plans the same way
(:func:`plan`) and runs :func:`complete_samples`, this module's per-sample path,
inside each actor on its batch of samples: same files, same bytes.
"""

from __future__ import annotations

import collections
import concurrent.futures as cf
import dataclasses
import functools
import logging
import pathlib
import time
from typing import Callable

import numpy as np

from jaxdepth.batch.cloud_runner import check_method
from jaxdepth.batch.devices import check_device_count, first_devices

log = logging.getLogger("jaxdepth")

#: Samples loaded ahead of the device.
READ_AHEAD = 4


@dataclasses.dataclass(frozen=True)
class _SampleJob:
    token: str
    channels: tuple  # channels still to write
    out_paths: tuple  # their outputs


@functools.lru_cache(maxsize=8)
def _depth_fn(config, lidar):
    """jit: (padded (B, 3), valid (B,), RigCameras[, images (C, H, W, 3) uint8 when guided]) -> (C, H, W)
    depth; one trace per bucket and canvas."""
    from jaxdepth._src.rig import complete_rig_stages
    from jaxdepth._src.xla_tuning import entry_jit
    from jaxdepth.batch.program_cache import Program

    def depth(points, valid, cameras, images=None):
        return complete_rig_stages(points, valid, cameras, config=config, lidar=lidar, images=images).depth

    return Program(entry_jit(depth), name="nuscenes_depth", statics=(config, lidar))


@functools.lru_cache(maxsize=8)
def _depth_and_validity_fn(config, lidar, max_seed_distance_px: float):
    """jit: as :func:`_depth_fn`, returning ((C, H, W) depth, valid, seed distance) for the extra outputs
    (:func:`jaxdepth._src.validity.validity_and_distance` per camera)."""
    from jaxdepth._src.rig import complete_rig_stages
    from jaxdepth._src.validity import rig_validity_and_distance
    from jaxdepth._src.xla_tuning import entry_jit
    from jaxdepth.batch.program_cache import Program

    def depth(points, valid, cameras, images=None):
        stages = complete_rig_stages(points, valid, cameras, config=config, lidar=lidar, images=images)
        return (stages.depth,) + rig_validity_and_distance(stages, cameras, lidar=lidar, metric=config.distance_metric,
                                                           max_seed_distance_px=max_seed_distance_px)

    return Program(entry_jit(depth), name="nuscenes_depth_validity", statics=(config, lidar, max_seed_distance_px))


def plan(tables, dst: pathlib.Path, *, overwrite: bool, summary, notify, extras=None) -> list:
    """The samples still to complete: every camera output of a sample exists -> skipped (unless
    ``overwrite``); a sample whose key frames cannot be found -> failed. With ``extras``
    (:class:`jaxdepth.batch.extras.ExtraOutputs`) a camera's output exists when its depth PNG and
    every requested extra do."""
    from jaxdepth.batch.extras import NONE, is_done
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io.errors import JaxdepthError

    extras = NONE if extras is None else extras
    todo = []
    for token in tables.samples():
        try:
            _, cams = nusc.sample_cameras(tables, token)
            paths = [(channel, nusc.output_path(dst, tables.version, channel, sd["token"])) for channel, sd in cams]
        except (JaxdepthError, ValueError) as err:
            summary.failed.append((token, str(err)))
            notify(token, f"failed: {err}")
            continue
        missing = [(c, p) for c, p in paths if overwrite or not is_done(p, extras)]
        if not missing:
            summary.skipped.append(token)
            notify(token, "skipped")
            continue
        todo.append(_SampleJob(token=token, channels=tuple(c for c, _ in missing),
                               out_paths=tuple(p for _, p in missing)))
    return todo


def output_identities(tables, dst: pathlib.Path, *, sweeps: int, guided: bool) -> dict:
    """``{output: input identity}`` (:func:`jaxdepth.batch.run_record.input_identity`) of every camera
    output: the sample's LiDAR sweeps (key frame and up to ``sweeps - 1`` earlier ones) and, when
    ``guided``, the camera image; the version's tables (poses, calibration) as a value. Samples whose
    key frames cannot be found are left out (the run reports them)."""
    from jaxdepth.batch.run_record import file_identity, input_identity
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io.errors import JaxdepthError

    table_files = sorted((pathlib.Path(tables.dataroot) / tables.version).glob("*.json"))
    tables_id = repr([file_identity(f) for f in table_files])
    out = {}
    for token in tables.samples():
        try:
            lidar_sd, cams = nusc.sample_cameras(tables, token)
            files, sd = [], lidar_sd
            for _ in range(sweeps):
                files.append(pathlib.Path(tables.dataroot) / str(sd.get("filename")))
                sd = tables.tables["sample_data"].get(sd.get("prev") or "")
                if sd is None:
                    break
            for channel, cam in cams:
                image = [nusc.camera_image_path(tables, cam)] if guided else []
                out[nusc.output_path(dst, tables.version, channel, cam["token"])] = input_identity(
                    files + image, values=(tables_id,))
        except (JaxdepthError, ValueError, KeyError, TypeError):
            continue
    return out


def _load(tables, job: _SampleJob, *, sweeps: int, ego_motion: bool, guided: bool = False, force: bool = False):
    """Host side of one sample: (padded points, valid, Rig after prepare_sweep, sample inputs, images):
    ``images`` (C, H, W, 3) uint8 RGB on the canvas when ``guided``, else None. With ``sweeps > 1``
    the padded points and valid are None and ``inputs.cloud`` holds the sweeps as sources."""
    from jaxdepth._src.presets import NUSCENES_HDL32
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io.errors import field_error
    from jaxdepth.io.points import pad_points
    from jaxdepth.io.rig import Rig, RigCamera
    from jaxdepth.io.sweep_frame import prepare_sweep

    inputs = nusc.sample_inputs(tables, job.token, sweeps=sweeps, ego_motion=ego_motion, sources=sweeps > 1,
                                force=force)
    cameras = []
    for cam in inputs.cameras:
        try:
            cameras.append(RigCamera(cam.channel, cam.width, cam.height, cam.K, cam.T_cam_lidar))
        except ValueError as err:  # a non-rigid pose or a bad K: name the tables it came from
            raise field_error(tables.table_path("calibrated_sensor"), f"{cam.channel} of sample {job.token}",
                              "a pinhole K and rigid poses", str(err)) from None
    rig = Rig(lidar=NUSCENES_HDL32, cameras=tuple(cameras), lidar_origin_m=(0.0, 0.0, 0.0))
    from jaxdepth.io.plausibility import check_rig_geometry  # K and T_cam_lidar against the sweep
    check_rig_geometry(inputs.points[:, :3] if inputs.cloud is None else inputs.cloud.points, rig.cameras,
                       path=tables.table_path("calibrated_sensor"), force=force)
    images = None
    if guided:  # read before the sweep is prepared: a bad image costs no work
        from jaxdepth.io.rig_images import read_rig_images
        paths = [nusc.camera_image_path(tables, tables.tables["sample_data"][cam.token]) for cam in inputs.cameras]
        images = read_rig_images(paths, rig.cameras, colour=True)
    if inputs.cloud is not None:
        return None, None, rig, inputs, images
    frame = prepare_sweep(inputs.points[:, :3], rig, estimate=False, drop_far=not force)
    padded, valid = pad_points(frame.points)
    return padded, valid, frame.rig, inputs, images


def run_nuscenes(dataroot, dst, *, version: str, sweeps: int = 1, ego_motion: bool = True, config=None,
                 overwrite: bool = False, png_compression: int | None = None, devices: int = 1,
                 io_threads: int = 2, on_progress: Callable[[str, str], None] | None = None, tables=None,
                 extras=None, force: bool = False, method: str = "sgm"):
    """Completes every sample of ``<dataroot>/<version>`` into ``<dst>/<version>/<CHANNEL>/<token>.png``.

    Args:
      dataroot: nuScenes dataroot (holds ``<version>/`` and the ``samples/``, ``sweeps/`` files).
      dst: output root.
      version: ``"v1.0-mini"``, ``"v1.0-trainval"``, ``"v1.0-test"``, ...
      sweeps: LiDAR sweeps per sample (default 1: the key frame; more: the key frame and earlier
        sweeps as the devkit's ``from_file_multisweep`` picks them, see :mod:`jaxdepth.io.nuscenes`,
        each one source of :func:`jaxdepth.batch.cloud_runner.complete_sources`).
      ego_motion: compensate the vehicle's motion between the LiDAR and each
        camera's timestamp (default True).
      config: :class:`~jaxdepth.SGMConfig` (default: the library's).
      overwrite: recompute outputs that exist (default False: resume).
      png_compression: zlib level 0-9 of the PNGs (default: the library's fast level).
      devices: local devices to deal whole samples out to, round robin (default 1: each device
        compiles its own copy, and on CPU one device already uses every core within a sample;
        sharding a sample's cameras over 2 host devices is no faster, whole samples 0.935x the wall).
      on_progress: called once per sample with (sample token, "done" / "skipped" / "failed: ...").
      tables: the version's :class:`~jaxdepth.io.nuscenes.NuScenesTables` if already loaded
        (default: read from ``dataroot``).
      extras: :class:`jaxdepth.batch.extras.ExtraOutputs` (default none): preview, validity,
        seed distance, zero-invalid beside each PNG as ``<token>_<kind>.png``; validity
        uses the nuScenes HDL-32E field of view.
      force: complete sweeps that fail the plausibility checks of :mod:`jaxdepth.io.plausibility`
        (each is logged; default False: such a sample fails with the file named).
      method: ``"sgm"`` (default), ``"nearest"`` or ``"ip-basic"`` (the baselines, module docstring).

    Returns:
      :class:`jaxdepth.batch.runner.RunSummary` over sample tokens (never raises for a bad sample).

    Raises:
      InputError: the version folder or one of its tables is missing or malformed. ValueError: bad options.
    """
    from jaxdepth._src.config import SGMConfig
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION
    from jaxdepth.batch import extras as extra_outputs
    from jaxdepth.batch.runner import RunSummary

    extras = extra_outputs.NONE if extras is None else extras

    if isinstance(sweeps, bool) or not isinstance(sweeps, int) or sweeps < 1:
        raise ValueError(f"run_nuscenes: field 'sweeps' expected an integer >= 1, got {sweeps!r}")
    if sweeps > 1 and extras.needs_seeds:
        raise ValueError("run_nuscenes: the validity, seed-distance and zero-invalid outputs need sweeps = 1")
    check_method(method, where="run_nuscenes", extras=extras, config=config)
    config = SGMConfig() if config is None else config
    png_compression = DEFAULT_PNG_COMPRESSION if png_compression is None else png_compression
    dst = pathlib.Path(dst)
    summary = RunSummary(started_at=time.perf_counter())
    notify = on_progress or (lambda name, status: None)
    tables = nusc.load_tables(dataroot, version) if tables is None else tables
    todo = plan(tables, dst, overwrite=overwrite, summary=summary, notify=notify, extras=extras)
    if not todo:
        return summary
    make_folders(todo)
    check_device_count(devices, where="run_nuscenes")
    complete_samples(tables, todo, summary, notify, sweeps=sweeps, ego_motion=ego_motion, config=config,
                     extras=extras, overwrite=overwrite, png_compression=png_compression,
                     targets=first_devices(devices), io_threads=io_threads, force=force, method=method)
    return summary


def make_folders(todo) -> None:
    """Creates the output folders of the planned samples (OutputError naming the folder)."""
    from jaxdepth.io.atomic import make_output_folders

    make_output_folders(p for job in todo for p in job.out_paths)


def complete_samples(tables, todo, summary, notify, *, sweeps: int, ego_motion: bool, config, extras,
                     overwrite: bool, png_compression: int, targets=None, io_threads: int = 2,
                     force: bool = False, method: str = "sgm") -> None:
    """Completes the planned samples ``todo`` (from :func:`plan`; output folders exist) into their
    PNGs, recording each token in ``summary`` as done or failed (never raises for a bad sample).

    The per-sample path of both engines: :func:`run_nuscenes` calls it on the whole plan, and each
    actor of :func:`jaxdepth.batch.scale.run_nuscenes_ray` on its batch of samples, so both write the
    same bytes. ``targets``: devices dealt samples round robin (default: the first local device).
    ``method``: as :func:`run_nuscenes` (a baseline runs on the host's default device).
    """
    import jax

    if sweeps > 1 and extras.needs_seeds:
        raise ValueError("nuScenes job: the validity, seed-distance and zero-invalid outputs need sweeps = 1")
    check_method(method, where="nuScenes job", extras=extras, config=config)
    from jaxdepth._src.rig import stack_cameras
    from jaxdepth.batch.cloud_runner import complete_sources
    from jaxdepth.batch.runner import is_guided, read_ahead
    from jaxdepth.io.errors import JaxdepthError

    targets = first_devices(1) if targets is None else targets
    run = _SampleRun(summary, notify, extras=extras, overwrite=overwrite, png_compression=png_compression)
    load = functools.partial(_load, tables, sweeps=sweeps, ego_motion=ego_motion,
                             guided=is_guided(config), force=force)
    with cf.ThreadPoolExecutor(io_threads) as readers, cf.ThreadPoolExecutor(io_threads) as writers:
        loaded_samples = read_ahead(todo, readers, window=READ_AHEAD, load=load,
                                    os_error=lambda job, err: f"cannot read: {err}")
        dispatched = 0   # SGM samples dealt to the devices so far
        for job, (loaded, message) in loaded_samples:
            if message is not None:
                run.fail(job.token, message)
                continue
            padded, valid, rig, inputs, images = loaded
            if method != "sgm":
                _baseline(run, writers, job, rig, (padded, valid) if inputs.cloud is None else inputs.cloud,
                          method=method, config=config)
                continue
            if inputs.cloud is not None:  # several sweeps: one source each
                try:
                    out = complete_sources(inputs.cloud, rig, config=config, images=images,
                                           window=tuple(-k for k in range(sweeps)))  # one program for every sample
                except (JaxdepthError, ValueError) as err:
                    run.fail(job.token, f"completion failed: {err}")
                    continue
                run.in_flight.append((job, rig, out))
                run.collect(writers)
                continue
            # From the RigCameras' NumPy K and T (the values as_camera's would hold): a jax.Array read back
            # here would wait for the sample in flight, and the next sample could not be dispatched before.
            cameras = stack_cameras(rig.cameras)
            args = (padded, valid, cameras) + (() if images is None else (images,))
            if 0 < dispatched < len(targets):  # a device's first call compiles its copy here: hand the samples
                run.finish_in_flight(writers)    # done so far to the writers first (the cold first sample)
            try:
                fn = (_depth_and_validity_fn(config, rig.lidar, extras.max_seed_distance_px) if extras.needs_seeds
                      else _depth_fn(config, rig.lidar))
                out = fn(*jax.device_put(args, targets[dispatched % len(targets)]))
                dispatched += 1
            except Exception as err:
                run.fail(job.token, f"completion failed: {err}")
                continue
            run.in_flight.append((job, rig, out))
            if len(run.in_flight) > len(targets):
                run.collect(writers)
        run.finish(writers)


def _baseline(run, writers, job, rig, points, *, method: str, config) -> None:
    """A baseline of one sample (``points``: the padded ``(points, valid)`` of one sweep, or the sweeps'
    SourceCloud), handed to the writers; a failure costs the sample."""
    from jaxdepth.batch.cloud_runner import baseline_depth, cloud_baseline_depth
    from jaxdepth.io.errors import JaxdepthError

    try:
        out = (baseline_depth(*points, rig, method=method, config=config) if isinstance(points, tuple)
               else cloud_baseline_depth(points, rig, method=method, config=config))
    except (JaxdepthError, ValueError) as err:
        run.fail(job.token, f"completion failed: {err}")
        return
    run.in_flight.append((job, rig, out))
    run.collect(writers)


class _SampleRun:
    """The dispatch side of :func:`run_nuscenes`: a sample's result is collected once the next
    sample is dispatched, and its cameras' PNGs are written on the writer threads."""

    def __init__(self, summary, notify, *, extras, overwrite: bool, png_compression: int):
        from jaxdepth.batch.runner import Ledger
        self.ledger = Ledger(summary, notify)
        self.extras, self.overwrite, self.png_compression = extras, overwrite, png_compression
        self.in_flight = collections.deque()  # (job, rig, device result), dispatched, not collected
        self.written = []

    def fail(self, token, message):
        self.ledger.fail(token, message)

    def write(self, job, rig, depth, valid=None, distance=None):
        from jaxdepth.batch import extras as extra_outputs
        from jaxdepth.batch.runner import write_failure
        by_name = {c.name: (i, c) for i, c in enumerate(rig.cameras)}
        for channel, path in zip(job.channels, job.out_paths):
            i, cam = by_name[channel]
            window = (i, slice(0, cam.height), slice(0, cam.width))
            message = write_failure(path, lambda: extra_outputs.write_outputs(
                path, depth[window], extras=self.extras, overwrite=self.overwrite,
                valid=None if valid is None else valid[window],
                distance=None if distance is None else distance[window], compression=self.png_compression))
            if message is not None:
                self.ledger.fail(job.token, message)
                return
        self.ledger.done(job.token)

    def collect(self, writers):
        job, rig, out = self.in_flight.popleft()
        try:
            arrays = tuple(np.asarray(o) for o in out) if isinstance(out, tuple) else (np.asarray(out),)
        except Exception as err:  # a compute failure costs this sample, not the run
            self.fail(job.token, f"completion failed: {err}")
            return
        self.written.append(writers.submit(self.write, job, rig, *arrays))

    def finish_in_flight(self, writers):
        while self.in_flight:
            self.collect(writers)

    def finish(self, writers):
        self.finish_in_flight(writers)
        for f in self.written:
            f.result()


__all__ = ["run_nuscenes", "plan", "complete_samples", "output_identities"]
