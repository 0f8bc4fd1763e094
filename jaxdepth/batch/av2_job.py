"""Complete Argoverse 2 sensor logs offline: every LiDAR sweep, every ring camera (``jaxdepth complete LOG``).

Input: one log folder (``.../sensor/val/<log_id>/``) or a folder of them (a split such as
``.../sensor/val/``), read by :mod:`jaxdepth.io.av2`. Per sweep (ordered by timestamp): the
sweep's two LiDARs as two sources (and, with ``sweeps = N``, up to N neighbouring sweeps on
each side, moved into the sweep's ego frame by the city poses: two more sources each), and
the chosen cameras at their calibrated sizes, go through :func:`complete_sources`, the one
completion call of this job.

Outputs: one uint16 KITTI-format depth PNG (metres x 256, 0 = empty) per camera per sweep,
``<dst>/<log_id>/<camera>/<lidar timestamp_ns>.png`` (:func:`output_path`), on the camera's
calibrated pixel grid (pinhole part of the intrinsics; see :mod:`jaxdepth.io.av2`), written
atomically. A sweep whose outputs all exist is skipped (resume) unless ``overwrite``; a bad
sweep or log is reported and the rest completes. Camera images are not needed (the job
writes depth for every camera whether or not the log holds its images).

Scheduling: a reader thread pool loads sweeps ahead (Feather decoding, pose maths); the
completion runs on the default device; writer threads encode and write the PNGs.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import functools
import logging
import pathlib
import time
from typing import Callable

import numpy as np

log = logging.getLogger("jaxdepth")

#: Sweeps loaded ahead of the device.
READ_AHEAD = 2


@dataclasses.dataclass(frozen=True)
class _SweepJob:
    name: str  # "<log_id>/<timestamp_ns>"
    log_folder: pathlib.Path
    timestamp_ns: int
    cameras: tuple  # cameras still to write
    out_paths: tuple  # their outputs


def find_logs(root) -> list:
    """The log folders under ``root``: ``root`` itself when it is a log, else its sub-folders that are logs
    (sorted by name). InputError when there is none."""
    from jaxdepth.io import av2
    from jaxdepth.io.errors import file_error

    root = pathlib.Path(root)
    if av2.is_av2_log(root):
        return [root]
    logs = sorted(p for p in root.iterdir() if p.is_dir() and av2.is_av2_log(p)) if root.is_dir() else []
    if not logs:
        raise file_error(root, "no Argoverse 2 sensor log here (expected <log>/sensors/lidar/*.feather and "
                               "<log>/calibration/, or a folder of such logs)")
    return logs


def is_av2_root(root) -> bool:
    """True when :func:`find_logs` finds a log at or directly under ``root`` (layout detection)."""
    from jaxdepth.io import av2

    root = pathlib.Path(root)
    if av2.is_av2_log(root):
        return True
    try:
        return root.is_dir() and any(p.is_dir() and av2.is_av2_log(p) for p in root.iterdir())
    except OSError:
        return False


def output_path(dst, log_id: str, camera: str, timestamp_ns: int) -> pathlib.Path:
    """``<dst>/<log_id>/<camera>/<timestamp_ns>.png``: where a camera's completed depth of one sweep goes."""
    return pathlib.Path(dst) / log_id / camera / f"{int(timestamp_ns)}.png"


def plan(logs, dst, *, cameras, overwrite: bool, summary, notify) -> tuple[dict, list]:
    """``({log folder: (Av2Log, Rig)}, the sweeps still to complete)``. A sweep whose camera outputs all
    exist is skipped (unless ``overwrite``); a log whose tables cannot be read, or that lacks a camera's
    calibration, is reported failed under its log id."""
    from jaxdepth.io import av2
    from jaxdepth.io.errors import JaxdepthError

    tables, todo = {}, []
    for folder in logs:
        folder = pathlib.Path(folder)
        try:
            log_ = av2.read_log(folder)
            tables[folder] = (log_, av2.read_rig(log_, cameras))
        except (JaxdepthError, ValueError) as err:
            summary.failed.append((folder.name, str(err)))
            notify(folder.name, f"failed: {err}")
            continue
        for ts in log_.sweeps:
            name = f"{folder.name}/{ts}"
            paths = [(c, output_path(dst, folder.name, c, ts)) for c in cameras]
            missing = [(c, p) for c, p in paths if overwrite or not p.exists()]
            if not missing:
                summary.skipped.append(name)
                notify(name, "skipped")
                continue
            todo.append(_SweepJob(name=name, log_folder=folder, timestamp_ns=ts,
                                  cameras=tuple(c for c, _ in missing), out_paths=tuple(p for _, p in missing)))
    return tables, todo


def complete_sources(cloud, rig, *, config):
    """(C, H, W) float32 depth of every rig camera (on the largest camera's canvas) for a SourceCloud.

    The job's one completion call.
    """
    return _single_origin_completion(cloud, rig, config=config)


def _single_origin_completion(cloud, rig, *, config):
    """Interim: every source's points measured from the rig's stated origin (``up_lidar``), with the
    merged rig's 64 lasers as one range image (what ``complete-rig`` does with ``lidar.origin_m``)."""
    from jaxdepth._src.rig import stack_cameras
    from jaxdepth._src.types import LidarSpec
    from jaxdepth.io.points import pad_points
    from jaxdepth.io.rig import Rig
    from jaxdepth.io.sweep_frame import prepare_sweep

    merged = LidarSpec(beams=2 * rig.lidar.beams, fov_up_deg=rig.lidar.fov_up_deg,
                       fov_down_deg=rig.lidar.fov_down_deg, columns=rig.lidar.columns)
    frame = prepare_sweep(cloud.points, Rig(lidar=merged, cameras=rig.cameras, lidar_origin_m=rig.lidar_origin_m),
                          estimate=False)
    padded, valid = pad_points(frame.points)
    cameras = stack_cameras([c.as_camera() for c in frame.rig.cameras])
    return np.asarray(_rig_depth_fn(config, frame.rig.lidar)(padded, valid, cameras))


@functools.lru_cache(maxsize=8)
def _rig_depth_fn(config, lidar):
    import jax

    from jaxdepth._src.rig import complete_rig_stages

    return jax.jit(lambda points, valid, cameras: complete_rig_stages(points, valid, cameras, config=config,
                                                                      lidar=lidar).depth)


def _load(job: _SweepJob, *, tables: dict, sweeps: int):
    from jaxdepth.io import av2

    log_, rig = tables[job.log_folder]
    return av2.read_cloud(log_, job.timestamp_ns, sweeps=sweeps), rig


def run_av2(root, dst, *, sweeps: int = 0, cameras=None, config=None, overwrite: bool = False,
            png_compression: int | None = None, io_threads: int = 2,
            on_progress: Callable[[str, str], None] | None = None):
    """Completes every sweep of the Argoverse 2 log(s) at ``root`` into ``<dst>/<log_id>/<camera>/<ts>.png``.

    Args:
      root: a log folder or a folder of logs.
      dst: output root.
      sweeps: neighbouring sweeps on each side added to each sweep (default 0: the sweep alone).
      cameras: camera names (default: the 7 ring cameras, :data:`jaxdepth.io.av2.RING_CAMERAS`).
      config: :class:`~jaxdepth.SGMConfig` (default: the library's).
      overwrite: recompute outputs that exist (default False: resume).
      png_compression: zlib level 0-9 of the PNGs (default: the library's fast level).
      io_threads: reader and writer threads each.
      on_progress: called once per sweep with ("<log_id>/<ts>", "done" / "skipped" / "failed: ...").

    Returns:
      :class:`jaxdepth.batch.runner.RunSummary` over sweep names (never raises for a bad sweep or log).

    Raises:
      InputError: ``root`` holds no log. ValueError: a bad ``sweeps`` or ``cameras``.
    """
    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch.runner import Ledger, RunSummary, read_ahead, write_failure
    from jaxdepth.io import av2
    from jaxdepth.io.atomic import make_output_folders
    from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION, write_depth_png
    from jaxdepth.io.errors import JaxdepthError

    if isinstance(sweeps, bool) or not isinstance(sweeps, int) or sweeps < 0:
        raise ValueError(f"run_av2: field 'sweeps' expected an integer >= 0, got {sweeps!r}")
    cameras = av2.RING_CAMERAS if cameras is None else tuple(cameras)
    if not cameras or len(set(cameras)) != len(cameras) or not all(isinstance(c, str) and c for c in cameras):
        raise ValueError(f"run_av2: field 'cameras' expected distinct camera names, got {cameras!r}")
    config = SGMConfig() if config is None else config
    png_compression = DEFAULT_PNG_COMPRESSION if png_compression is None else png_compression
    summary = RunSummary(started_at=time.perf_counter())
    notify = on_progress or (lambda name, status: None)
    tables, todo = plan(find_logs(root), dst, cameras=cameras, overwrite=overwrite, summary=summary, notify=notify)
    if not todo:
        return summary
    make_output_folders(p for job in todo for p in job.out_paths)
    ledger = Ledger(summary, notify)
    load = functools.partial(_load, tables=tables, sweeps=sweeps)

    def write(job, rig, depth):
        index = {c.name: i for i, c in enumerate(rig.cameras)}
        for camera, path in zip(job.cameras, job.out_paths):
            cam = rig.cameras[index[camera]]
            window = depth[index[camera], :cam.height, :cam.width]
            message = write_failure(path, lambda: write_depth_png(path, window, compression=png_compression))
            if message is not None:
                ledger.fail(job.name, message)
                return
        ledger.done(job.name)

    with cf.ThreadPoolExecutor(io_threads) as readers, cf.ThreadPoolExecutor(io_threads) as writers:
        written = []
        for job, (loaded, message) in read_ahead(todo, readers, window=READ_AHEAD, load=load,
                                                 os_error=lambda job, err: f"cannot read: {err}"):
            if message is not None:
                ledger.fail(job.name, message)
                continue
            cloud, rig = loaded
            try:
                depth = complete_sources(cloud, rig, config=config)
            except (JaxdepthError, ValueError) as err:
                ledger.fail(job.name, f"completion failed: {err}")
                continue
            written.append(writers.submit(write, job, rig, depth))
        for f in written:
            f.result()
    return summary


__all__ = ["run_av2", "plan", "find_logs", "is_av2_root", "output_path", "complete_sources"]
