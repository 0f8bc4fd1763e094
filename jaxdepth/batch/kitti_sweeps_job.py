"""KITTI raw drives with neighbouring sweeps (``jaxdepth complete KITTI_RAW DST --sweeps N``).

Takes the sweep jobs :func:`jaxdepth.io.kitti_datasets.kitti_raw_jobs` lists (one per sweep
and camera, same outputs ``DST/<drive>/proj_depth/<name>/image_0X/<frame>.png``, same K,
extrinsics and benchmark crop) and completes each sweep once for all its cameras, with up to
``N`` neighbouring sweeps on each side moved into its Velodyne frame by the OXTS poses
(:func:`jaxdepth.io.kitti_oxts.read_drive_cloud`; each sweep one source). ``N = 0`` is not
this job: the plain KITTI raw path completes single sweeps. ``method``: the SGM (default) or a
baseline, ``"nearest"`` / ``"ip-basic"``, of the same merged points
(:func:`jaxdepth.batch.cloud_runner.baseline_depth`).
"""

from __future__ import annotations

import collections
import functools
import pathlib
import time
from typing import Callable

from jaxdepth.batch.cloud_runner import METHODS, CloudJob, cloud_preparation, run_cloud_jobs


def plan(jobs, *, overwrite: bool, summary, notify) -> list:
    """Groups the per-camera sweep jobs by sweep: one :class:`CloudJob` per sweep with the outputs still
    to write (all present -> skipped). ``source``: (drive folder, frame name, Rig of the sweep's cameras)."""
    from jaxdepth._src.presets import KITTI_HDL64
    from jaxdepth.io.rig import Rig, RigCamera

    by_sweep = collections.OrderedDict()
    for job in sorted(jobs, key=lambda j: (str(j.sparse_path), j.name)):
        by_sweep.setdefault(pathlib.Path(job.sparse_path), []).append(job)
    todo = []
    for sweep, group in by_sweep.items():
        drive = sweep.parent.parent.parent
        name = f"{drive.name}/{sweep.stem}"
        cameras = tuple(RigCamera(j.out_path.parent.name, int(j.image_size[1]), int(j.image_size[0]), j.K,
                                  j.T_cam_lidar) for j in group)
        outputs = tuple((c.name, j.out_path) for c, j in zip(cameras, group) if overwrite or not j.out_path.exists())
        if not outputs:
            summary.skipped.append(name)
            notify(name, "skipped")
            continue
        rig = Rig(lidar=KITTI_HDL64, cameras=cameras, lidar_origin_m=(0.0, 0.0, 0.0))
        todo.append(CloudJob(name=name, outputs=outputs, source=(drive, sweep.stem, rig)))
    return todo


def sweep_identities(jobs, *, sweeps: int) -> dict:
    """``{output: input identity}`` (:func:`jaxdepth.batch.run_record.input_identity`) of the sweep jobs:
    the sweep, its ``sweeps`` neighbours on each side and their OXTS packets, the date's
    ``calib_imu_to_velo.txt``; K, extrinsic, image size and crop as values."""
    from jaxdepth.batch.run_record import input_identity
    from jaxdepth.io.kitti_oxts import drive_frames, oxts_path

    frames_of = {}
    out = {}
    for job in jobs:
        sweep = pathlib.Path(job.sparse_path)
        drive = sweep.parent.parent.parent
        frames = frames_of.setdefault(drive, drive_frames(drive))
        i = frames.index(sweep.stem) if sweep.stem in frames else 0
        used = frames[max(0, i - sweeps):i + sweeps + 1] if sweep.stem in frames else [sweep.stem]
        files = [sweep.parent / f"{f}.bin" for f in used] + [oxts_path(drive, f) for f in used]
        files.append(drive.parent / "calib_imu_to_velo.txt")
        out[job.out_path] = input_identity(files, values=(job.K, job.T_cam_lidar, job.image_size,
                                                          job.image_crop_from, sweeps))
    return out


def _load(job: CloudJob, *, sweeps: int, force: bool):
    """The frame's cloud and rig, the rig's calibration checked against the cloud (the date folder's
    calib_*.txt named: :func:`jaxdepth.io.plausibility.check_rig_geometry`)."""
    from jaxdepth.io.kitti_oxts import read_drive_cloud
    from jaxdepth.io.plausibility import check_rig_geometry

    drive, frame, rig = job.source
    cloud = read_drive_cloud(drive, frame, sweeps=sweeps, force=force)
    check_rig_geometry(cloud.points, rig.cameras, path=drive.parent / "calib_velo_to_cam.txt", force=force)
    return cloud, rig


def window(sweeps: int) -> tuple:
    """The sweep numbers of a frame with all its ``sweeps`` neighbours on each side, in the sources' order
    (:func:`jaxdepth.io.kitti_oxts.read_drive_cloud`): 0, -1, 1, -2, 2, ..."""
    return (0,) + tuple(o for k in range(1, sweeps + 1) for o in (-k, k))


def run_kitti_raw_sweeps(jobs, *, sweeps: int, config=None, overwrite: bool = False,
                         png_compression: int | None = None, io_threads: int = 2,
                         on_progress: Callable[[str, str], None] | None = None, force: bool = False,
                         method: str = "sgm"):
    """Completes the KITTI raw sweep ``jobs`` (from :func:`~jaxdepth.io.kitti_datasets.kitti_raw_jobs`) with
    ``sweeps`` neighbours on each side.

    Returns:
      :class:`jaxdepth.batch.runner.RunSummary` over ``<drive>/<frame>`` names (a sweep whose
      neighbours, OXTS packets or calibration cannot be read is reported failed, the rest completes).
      ``force``: complete sweeps that fail the plausibility checks (logged) instead of failing them.
      ``method``: ``"sgm"`` (default; frames near a drive's ends, with fewer neighbours, are spread over the
      full window with empty sources, :func:`jaxdepth.batch.sources_job.fit_to_window`: one program per run),
      ``"nearest"`` or ``"ip-basic"`` (the merged points, module docstring).
    """
    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch.runner import RunSummary
    from jaxdepth.io.atomic import make_output_folders
    from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION

    if isinstance(sweeps, bool) or not isinstance(sweeps, int) or sweeps < 1:
        raise ValueError(f"run_kitti_raw_sweeps: field 'sweeps' expected an integer >= 1, got {sweeps!r}")
    if method not in METHODS:
        raise ValueError(f"run_kitti_raw_sweeps: field 'method' expected one of {METHODS}, got {method!r}")
    config = SGMConfig() if config is None else config
    png_compression = DEFAULT_PNG_COMPRESSION if png_compression is None else png_compression
    summary = RunSummary(started_at=time.perf_counter())
    notify = on_progress or (lambda name, status: None)
    todo = plan(jobs, overwrite=overwrite, summary=summary, notify=notify)
    if todo:
        make_output_folders(p for job in todo for _, p in job.outputs)
        run_cloud_jobs(todo, functools.partial(_load, sweeps=sweeps, force=force), summary, notify, config=config,
                       png_compression=png_compression, io_threads=io_threads,
                       prepare=cloud_preparation(method, config=config, window=window(sweeps)))
    return summary


__all__ = ["run_kitti_raw_sweeps", "plan", "sweep_identities", "window"]
