"""Complete Argoverse 2 sensor logs offline: every LiDAR sweep, every ring camera (``jaxdepth complete LOG``).

Input: one log folder (``.../sensor/val/<log_id>/``) or a folder of them (a split such as
``.../sensor/val/``), read by :mod:`jaxdepth.io.av2`. Per sweep (ordered by timestamp): the
sweep's two LiDARs as two sources (and, with ``sweeps = N``, up to N neighbouring sweeps on
each side, moved into the sweep's ego frame by the city poses: two more sources each), and
the chosen cameras at their calibrated sizes, go through
:func:`jaxdepth.batch.cloud_runner.complete_sources`.

Outputs: one uint16 KITTI-format depth PNG (metres x 256, 0 = empty) per camera per sweep,
``<dst>/<log_id>/<camera>/<lidar timestamp_ns>.png`` (:func:`output_path`), on the camera's
calibrated pixel grid (pinhole part of the intrinsics; see :mod:`jaxdepth.io.av2`), written
atomically. A sweep whose outputs all exist is skipped (resume) unless ``overwrite``; a bad
sweep or log is reported and the rest completes. Camera images are not needed (the job
writes depth for every camera whether or not the log holds its images).

Scheduling (:func:`jaxdepth.batch.cloud_runner.run_cloud_jobs`): a reader thread pool loads
sweeps ahead (Feather decoding, pose maths); the completion runs on the default device; writer
threads encode and write the PNGs.
"""

from __future__ import annotations

import functools
import pathlib
import time
from typing import Callable

from jaxdepth.batch.cloud_runner import CloudJob, run_cloud_jobs


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
            todo.append(CloudJob(name=name, outputs=tuple(missing), source=(folder, ts)))
    return tables, todo


def _load(job, *, tables: dict, sweeps: int, force: bool):
    from jaxdepth.io import av2

    folder, timestamp_ns = job.source
    log_, rig = tables[folder]
    return av2.read_cloud(log_, timestamp_ns, sweeps=sweeps, force=force), rig


def run_av2(root, dst, *, sweeps: int = 0, cameras=None, config=None, overwrite: bool = False,
            png_compression: int | None = None, io_threads: int = 2,
            on_progress: Callable[[str, str], None] | None = None, force: bool = False):
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
      force: complete sweeps that fail the plausibility checks (logged) instead of failing them.

    Returns:
      :class:`jaxdepth.batch.runner.RunSummary` over sweep names (never raises for a bad sweep or log).

    Raises:
      InputError: ``root`` holds no log. ValueError: a bad ``sweeps`` or ``cameras``.
    """
    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch.runner import RunSummary
    from jaxdepth.io import av2
    from jaxdepth.io.atomic import make_output_folders
    from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION

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
    make_output_folders(p for job in todo for _, p in job.outputs)
    run_cloud_jobs(todo, functools.partial(_load, tables=tables, sweeps=sweeps, force=force), summary, notify, config=config,
                   png_compression=png_compression, io_threads=io_threads)
    return summary


__all__ = ["run_av2", "plan", "find_logs", "is_av2_root", "output_path"]
