"""Complete Argoverse 2 sensor logs offline: every LiDAR sweep, every ring camera (``jaxdepth complete LOG``).

Input: the dataset root (``.../av2/``, holding ``sensor/``), ``sensor/``, a split (``sensor/val/``)
or one log (``sensor/val/<log_id>/``): every log found at most three folders down
(:func:`find_logs`), read by :mod:`jaxdepth.io.av2`. Per sweep (ordered by timestamp): the
sweep's two LiDARs as two sources, each with one range-image row per laser from its laser
numbers (and, with ``sweeps = N``, up to N neighbouring sweeps on each side, moved into the
sweep's ego frame by the city poses: two more sources each; N beyond what the log holds is
clamped, with a note), and the chosen cameras at their calibrated sizes, go through
:func:`jaxdepth.batch.cloud_runner.complete_sources`.

Time (``time``): ``"camera"`` (default) writes each camera's depth at the timestamp of its
image paired with the sweep (:func:`jaxdepth.io.av2.paired_image`: the nearest image, from
``sensors/cameras/<camera>/<ts>.jpg``), the ego motion between the sweep and that image
compensated through the city poses (:func:`jaxdepth.io.av2.camera_from_ego`, as the devkit's
motion-compensated projection does). A camera with no images in the log is written at the
LiDAR timestamp, with a note; a sweep whose nearest image belongs to another sweep has no
output for that camera. ``"lidar"``: every camera at the sweep's timestamp (calibration only).

Outputs: one uint16 KITTI-format depth PNG (metres x 256, 0 = empty) per camera per sweep,
``<dst>/<log_id>/<camera>/<timestamp_ns>.png`` (:func:`output_path`), named by the camera
image's timestamp at camera time and by the LiDAR sweep's at LiDAR time, on the camera's
calibrated pixel grid (pinhole part of the intrinsics; see :mod:`jaxdepth.io.av2`), written
atomically, with the extra outputs of :mod:`jaxdepth.batch.extras` beside it. A sweep whose
outputs all exist is skipped (resume) unless ``overwrite``; a bad sweep or log is reported and
the rest completes. Camera images are not read (only their timestamps).

Methods: ``"sgm"`` (default); ``"nearest"`` and ``"ip-basic"``, the baselines: every point of
the cloud (all sources) projected into each camera (nearest point per pixel, no outlier
removal) and filled by the nearest LiDAR pixel in the run's distance metric, or by IP_Basic,
each camera at its own size (the ``nearest`` / ``ip_basic`` columns of
``benchmarks/accuracy_multisource.py``).

Scheduling (:func:`jaxdepth.batch.cloud_runner.run_cloud_jobs`): a reader thread pool loads
sweeps ahead (Feather decoding, pose maths) and builds each sweep's program inputs (the sources
pytree: padding, the LiDARs' spec estimates); the main thread runs each sweep's program on the
default device and reads its depth back before it dispatches the next (two programs in flight ran
slower on 2 cores); writer threads encode and write the PNGs. ``devices`` N > 1 (the CLI's
``--cpu-devices N``): sweeps dealt round robin to N (host) devices, one in flight on each, each device
compiling its own copy; same bytes, 0.885x the wall on 2 idle cores, ~1.3 GB more memory, a
second compile (docs/speed.md, "Whole samples on two host devices").
"""

from __future__ import annotations

import functools
import logging
import pathlib
import time as _time
from typing import Callable

from jaxdepth.batch.cloud_runner import METHODS, CloudJob, check_method, cloud_baseline_depth, read_back, run_cloud_jobs
from jaxdepth.batch.devices import check_device_count, first_devices

log = logging.getLogger("jaxdepth")

#: Depth at each camera image's timestamp, or at the LiDAR sweep's.
TIMES = ("camera", "lidar")
#: Folders below the given root searched for logs (root/sensor/<split>/<log>).
SEARCH_DEPTH = 3


def _logs_below(root: pathlib.Path, depth: int) -> list:
    from jaxdepth.io import av2

    if av2.is_av2_log(root):
        return [root]
    if depth == 0:
        return []
    try:
        children = sorted(p for p in root.iterdir() if p.is_dir())
    except OSError:
        return []
    return [log_ for child in children for log_ in _logs_below(child, depth - 1)]


def find_logs(root) -> list:
    """The log folders at or below ``root`` (the dataset root, ``sensor/``, a split or one log), at most
    :data:`SEARCH_DEPTH` folders down, sorted by path. InputError when there is none, or when two logs
    share an id (their outputs would collide)."""
    from jaxdepth.io.errors import file_error

    root = pathlib.Path(root)
    logs = _logs_below(root, SEARCH_DEPTH) if root.is_dir() else []
    if not logs:
        raise file_error(root, "no Argoverse 2 sensor log here (expected <log>/sensors/lidar/*.feather and "
                               "<log>/calibration/ in this folder or up to 3 levels below: the dataset root, "
                               "sensor/, a split or one log)")
    seen = {}
    for folder in logs:
        if folder.name in seen:
            raise file_error(folder, f"log id {folder.name!r} also at {seen[folder.name]}: outputs would collide")
        seen[folder.name] = folder
    return logs


def is_av2_root(root) -> bool:
    """True when :func:`find_logs` finds a log at or below ``root`` (layout detection)."""
    root = pathlib.Path(root)
    return root.is_dir() and bool(_logs_below(root, SEARCH_DEPTH))


def output_path(dst, log_id: str, camera: str, timestamp_ns: int) -> pathlib.Path:
    """``<dst>/<log_id>/<camera>/<timestamp_ns>.png``: where a camera's completed depth of one sweep goes
    (the camera image's timestamp at camera time, the sweep's at LiDAR time)."""
    return pathlib.Path(dst) / log_id / camera / f"{int(timestamp_ns)}.png"


def served_sweeps(log_, sweeps: int) -> int:
    """The neighbours on each side the log can serve: ``min(sweeps, sweeps in the log - 1)``."""
    return min(int(sweeps), max(len(log_.sweeps) - 1, 0))


def _camera_times(log_, cameras, ts: int, time: str) -> dict:
    """camera -> output timestamp for sweep ``ts`` (None: no image paired, no output)."""
    from jaxdepth.io import av2

    if time == "lidar":
        return {c: ts for c in cameras}
    return {c: (av2.paired_image(log_, c, ts) if c in log_.camera_times else ts) for c in cameras}


def _log_notes(folder, log_, *, cameras, sweeps: int, time: str) -> list:
    notes = []
    if sweeps > served_sweeps(log_, sweeps):
        notes.append(f"{folder.name}: --sweeps {sweeps} clamped to {served_sweeps(log_, sweeps)}: the log has "
                     f"{len(log_.sweeps)} sweeps")
    missing = [c for c in cameras if c not in log_.camera_times]
    if time == "camera" and missing:
        notes.append(f"{folder.name}: no images of {', '.join(missing)} in sensors/cameras/: depth at the LiDAR "
                     "timestamps (<lidar timestamp_ns>.png)")
    return notes


def plan(logs, dst, *, cameras, overwrite: bool, summary, notify, time: str = "camera", sweeps: int = 0,
         extras=None, note: Callable[[str], None] = log.info) -> tuple[dict, list]:
    """``({log folder: (Av2Log, neighbours served)}, the sweeps still to complete)``.

    A sweep whose camera outputs (and requested extras) all exist is skipped (unless
    ``overwrite``); a log whose tables cannot be read, or that lacks a camera's calibration, is
    reported failed under its log id. ``note(text)`` receives the clamped ``sweeps`` and the
    cameras without images (camera time); a camera whose images are all paired with other sweeps
    is noted with the count of sweeps it has no output for.
    """
    from jaxdepth.batch.extras import NONE, is_done
    from jaxdepth.io import av2
    from jaxdepth.io.errors import JaxdepthError

    extras = NONE if extras is None else extras
    tables, todo = {}, []
    for folder in logs:
        folder = pathlib.Path(folder)
        try:
            log_ = av2.read_log(folder)
            av2.read_rig(log_, cameras)  # every camera calibrated
        except (JaxdepthError, ValueError) as err:
            summary.failed.append((folder.name, str(err)))
            notify(folder.name, f"failed: {err}")
            continue
        for text in _log_notes(folder, log_, cameras=cameras, sweeps=sweeps, time=time):
            note(text)
        tables[folder] = (log_, served_sweeps(log_, sweeps))
        unpaired = dict.fromkeys(cameras, 0)
        for ts in log_.sweeps:
            name = f"{folder.name}/{ts}"
            times = _camera_times(log_, cameras, ts, time)
            for c, t in times.items():
                unpaired[c] += t is None
            paths = [(c, output_path(dst, folder.name, c, t)) for c, t in times.items() if t is not None]
            missing = [(c, p) for c, p in paths if overwrite or not is_done(p, extras)]
            if not missing:
                summary.skipped.append(name)
                notify(name, "skipped")
                continue
            todo.append(CloudJob(name=name, outputs=tuple(missing), source=(folder, ts, times)))
        for c, n in unpaired.items():
            if n:
                note(f"{folder.name}: {c}: {n} of {len(log_.sweeps)} sweeps have no image of their own "
                     "(the nearest image is paired with another sweep): no output for them")
    return tables, todo


def _load(job, *, tables: dict, cameras, force: bool):
    """The sweep's cloud and rig, the rig's calibration checked against the cloud (the log's
    calibration/egovehicle_SE3_sensor.feather named: :func:`jaxdepth.io.plausibility.check_rig_geometry`)."""
    from jaxdepth.io import av2
    from jaxdepth.io.plausibility import check_rig_geometry

    folder, timestamp_ns, times = job.source
    log_, sweeps = tables[folder]
    camera_ns = {c: t for c, t in times.items() if t is not None}
    rig = av2.read_rig(log_, cameras, sweep_ns=timestamp_ns, camera_ns=camera_ns)
    cloud = av2.read_cloud(log_, timestamp_ns, sweeps=sweeps, force=force)
    check_rig_geometry(cloud.points, rig.cameras, path=pathlib.Path(log_.folder) / "calibration" /
                       "egovehicle_SE3_sensor.feather", force=force)
    return cloud, rig


#: The job's baseline of a sweep's cloud (``--method nearest`` / ``ip-basic``), the one every multi-source job runs.
baseline_depth = cloud_baseline_depth


@functools.lru_cache(maxsize=8)
def _validity_fn(lidar, metric: str, max_seed_distance_px):
    import jax

    from jaxdepth._src.validity import rig_validity_and_distance

    return jax.jit(functools.partial(rig_validity_and_distance, lidar=lidar, metric=metric,
                                     max_seed_distance_px=max_seed_distance_px))


def completion(*, method: str, config, extras) -> Callable:
    """``prepare(cloud, rig) -> call`` of :func:`run_cloud_jobs` for ``method``: ``call()`` returns
    ``(depth, valid, distance)`` (device arrays of the SGM, read back by the job
    (:func:`~jaxdepth.batch.cloud_runner.read_back`); NumPy of a baseline); the validity mask and seed distance (``extras.needs_seeds``, SGM
    only) use the rig's LiDAR spec."""
    import jaxdepth
    from jaxdepth.batch.cloud_runner import cloud_preparation
    from jaxdepth.batch.sources_job import cloud_call

    if method != "sgm" or not extras.needs_seeds:
        return cloud_preparation(method, config=config)

    def with_validity(cloud, rig):
        stages = cloud_call(cloud, rig, config=config, free_space=True, stages=True)
        cameras = jaxdepth.stack_cameras(rig.cameras)
        validity = _validity_fn(rig.lidar, config.distance_metric, extras.max_seed_distance_px)

        def call():
            out = stages()
            return (out.depth, *validity(out, cameras))
        return call

    return with_validity


def _check_options(sweeps, cameras, time, method, extras) -> None:
    if isinstance(sweeps, bool) or not isinstance(sweeps, int) or sweeps < 0:
        raise ValueError(f"run_av2: field 'sweeps' expected an integer >= 0, got {sweeps!r}")
    if not cameras or len(set(cameras)) != len(cameras) or not all(isinstance(c, str) and c for c in cameras):
        raise ValueError(f"run_av2: field 'cameras' expected distinct camera names, got {cameras!r}")
    if time not in TIMES:
        raise ValueError(f"run_av2: field 'time' expected one of {TIMES}, got {time!r}")
    check_method(method, where="run_av2", extras=extras)


def run_av2(root, dst, *, sweeps: int = 0, cameras=None, config=None, overwrite: bool = False,
            png_compression: int | None = None, io_threads: int = 2,
            on_progress: Callable[[str, str], None] | None = None, force: bool = False, time: str = "camera",
            method: str = "sgm", extras=None, on_note: Callable[[str], None] | None = None, devices: int = 1):
    """Completes every sweep of the Argoverse 2 log(s) at ``root`` into ``<dst>/<log_id>/<camera>/<ts>.png``.

    Args:
      root: the dataset root, ``sensor/``, a split or one log (:func:`find_logs`).
      dst: output root.
      sweeps: neighbouring sweeps on each side added to each sweep (default 0: the sweep alone);
        more than a log holds is clamped, with a note.
      cameras: camera names (default: the 7 ring cameras, :data:`jaxdepth.io.av2.RING_CAMERAS`).
      config: :class:`~jaxdepth.SGMConfig` (default: the library's).
      overwrite: recompute outputs that exist (default False: resume).
      png_compression: zlib level 0-9 of the PNGs (default: the library's fast level).
      io_threads: reader and writer threads each.
      on_progress: called once per sweep with ("<log_id>/<ts>", "done" / "skipped" / "failed: ...").
      force: complete sweeps that fail the plausibility checks (logged) instead of failing them.
      time: ``"camera"`` (default: depth at each camera image's timestamp, ego motion compensated)
        or ``"lidar"`` (at the sweep's timestamp); see the module docstring.
      method: ``"sgm"`` (default), ``"nearest"`` or ``"ip-basic"`` (the baselines, module docstring).
      extras: :class:`jaxdepth.batch.extras.ExtraOutputs` beside each PNG (default none); validity,
        seed distance and zero-invalid need ``method="sgm"``.
      on_note: called with each note (a clamped ``sweeps``, cameras without images); default: logged.
      devices: local devices to deal sweeps out to, round robin, one sweep in flight on each (default 1;
        on CPU the CLI's ``--cpu-devices N`` makes N host devices first; each compiles its own copy).

    Returns:
      :class:`jaxdepth.batch.runner.RunSummary` over sweep names (never raises for a bad sweep or log).

    Raises:
      InputError: ``root`` holds no log. ValueError: a bad ``sweeps``, ``cameras``, ``time`` or ``method``.
    """
    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch.extras import NONE
    from jaxdepth.batch.runner import RunSummary
    from jaxdepth.io import av2
    from jaxdepth.io.atomic import make_output_folders
    from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION

    cameras = av2.RING_CAMERAS if cameras is None else tuple(cameras)
    extras = NONE if extras is None else extras
    _check_options(sweeps, cameras, time, method, extras)
    check_device_count(devices, where="run_av2")
    config = SGMConfig() if config is None else config
    png_compression = DEFAULT_PNG_COMPRESSION if png_compression is None else png_compression
    summary = RunSummary(started_at=_time.perf_counter())
    notify = on_progress or (lambda name, status: None)
    tables, todo = plan(find_logs(root), dst, cameras=cameras, overwrite=overwrite, summary=summary, notify=notify,
                        time=time, sweeps=sweeps, extras=extras, note=on_note or log.info)
    if not todo:
        return summary
    make_output_folders(p for job in todo for _, p in job.outputs)
    run_cloud_jobs(todo, functools.partial(_load, tables=tables, cameras=cameras, force=force), summary, notify,
                   config=config, png_compression=png_compression, io_threads=io_threads,
                   prepare=completion(method=method, config=config, extras=extras), extras=extras,
                   overwrite=overwrite, targets=_targets(devices) if method == "sgm" else None)
    return summary


def _targets(devices: int):
    """The first ``devices`` local devices (:func:`~jaxdepth.batch.devices.first_devices`), or None (the default
    device) for one."""
    return None if devices == 1 else first_devices(devices)


def warm_av2(root, *, sweeps: int = 0, cameras=None, config=None, time: str = "camera", method: str = "sgm",
             extras=None, force: bool = False) -> tuple[str, float]:
    """Compiles the program :func:`run_av2` runs, on one sweep of the first log at ``root``, writing nothing.

    With the persistent compile cache on (the CLI's default) a later ``jaxdepth complete`` of any log of
    the same cameras and options loads it instead of compiling, as long as its sweeps fall in the same
    program: the sources' point bucket (65,536 for a VLP-32C, :func:`jaxdepth.batch.sources_job.cloud_sources`)
    and their estimated fields of view (on a 0.25 degree grid, :func:`jaxdepth.io.sweep_frame.source_spec`)
    match, and the sweep has all its ``sweeps`` neighbours (the log's first and last ``sweeps`` sweeps
    have fewer sources, hence programs of their own). The sweep used is the log's middle one.

    Args: as :func:`run_av2` (``root``: the first log found, :func:`find_logs`).

    Returns:
      ``("<log_id>/<timestamp_ns>", wall seconds)``.

    Raises:
      InputError: no log at ``root``; JaxdepthError: the sweep cannot be read. ValueError: bad options.
    """
    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch.extras import NONE
    from jaxdepth.io import av2

    cameras = av2.RING_CAMERAS if cameras is None else tuple(cameras)
    extras = NONE if extras is None else extras
    _check_options(sweeps, cameras, time, method, extras)
    config = SGMConfig() if config is None else config
    folder = find_logs(root)[0]
    log_ = av2.read_log(folder)
    ts = log_.sweeps[len(log_.sweeps) // 2]
    job = CloudJob(name=f"{folder.name}/{ts}", outputs=(), source=(folder, ts, _camera_times(log_, cameras, ts, time)))
    start = _time.perf_counter()
    cloud, rig = _load(job, tables={folder: (log_, served_sweeps(log_, sweeps))}, cameras=cameras, force=force)
    read_back(completion(method=method, config=config, extras=extras)(cloud, rig)())    # waits for the results
    return job.name, _time.perf_counter() - start


# ---------------------------------------------------------------- command line glue


def add_cli_options(parser) -> None:
    """The Argoverse 2 options of ``complete`` (no JAX import)."""
    parser.add_argument("--cameras", default=None, metavar="NAMES",
                        help="Argoverse 2: comma-separated cameras to complete (default: the 7 ring cameras)")
    parser.add_argument("--lidar-time", action="store_true",
                        help="Argoverse 2: depth at each LiDAR sweep's timestamp, <log>/<camera>/<lidar ts>.png "
                             "(default: at the timestamp of the camera image nearest the sweep, ego motion "
                             "compensated by the city poses, <log>/<camera>/<camera ts>.png)")


def cli_usage(args) -> str | None:
    """Why the parsed options of ``complete`` cannot be used with Argoverse 2 logs (None: they can; the extra
    outputs' own checks run before)."""
    given = [flag for flag, value in (("--intrinsics", args.intrinsics), ("--camera", args.camera),
                                      ("--calib-dir", args.calib_dir), ("--extrinsic", args.extrinsic),
                                      ("--image-dir", args.image_dir), ("--crop", args.crop or None))
             if value is not None]
    if given:
        return f"{', '.join(given)} cannot be used with an Argoverse 2 log (its calibration is used)"
    for message, bad in (("--guidance-weight is not supported (no camera images are read)", args.guidance_weight > 0),
                         ("--engine local only", args.engine != "local"),
                         (f"--sweeps expected an integer >= 0 (neighbours on each side), got {args.sweeps}",
                          args.sweeps is not None and args.sweeps < 0)):
        if bad:
            return f"an Argoverse 2 log: {message}"
    return None


__all__ = ["run_av2", "warm_av2", "plan", "find_logs", "is_av2_root", "output_path", "served_sweeps", "baseline_depth",
           "completion", "add_cli_options", "cli_usage", "TIMES", "METHODS"]
