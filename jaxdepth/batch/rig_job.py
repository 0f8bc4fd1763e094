"""One LiDAR sweep completed for every camera of a rig JSON: the job behind ``jaxdepth complete-rig``.

Reads the sweep and the rig (and, when guided, the camera images), checks the sweep
against its LiDAR (:func:`jaxdepth.io.prepare_sweep`) and applies its trust policy
(outlier removal off when the sweep's beam angles cannot be trusted), completes
every camera in one call (the depth program of :func:`jaxdepth.complete_rig`, or
:func:`jaxdepth.complete_rig_stages` when an extra output needs the seeds; or a baseline, ``method``
``"nearest"`` / ``"ip-basic"``, of the same points: :func:`rig_results`) and writes
``<out_dir>/<camera name>.png`` per camera (plus the extra outputs asked for),
atomically, skipping finished outputs unless ``overwrite``.

Messages go to ``report(kind, text)``: ``"note"`` (what the sweep check found),
``"warning"`` (a camera no point projects into), ``"skipped"`` (an output that
exists) and ``"written"`` (one line per camera written). The command line decides
which to show.
"""

from __future__ import annotations

import dataclasses
import logging
import pathlib
from typing import Callable

import numpy as np

from jaxdepth._src.config import SGMConfig
from jaxdepth.batch import extras as extra_outputs

log = logging.getLogger("jaxdepth")


@dataclasses.dataclass
class RigJobSummary:
    """What :func:`run_rig_job` did: outputs written and skipped (paths), cameras that saw no point."""

    written: list = dataclasses.field(default_factory=list)
    skipped: list = dataclasses.field(default_factory=list)
    empty_cameras: list = dataclasses.field(default_factory=list)
    exit_code: int = 0


def _ignore(kind: str, text: str) -> None:
    return None


def rig_images(rig, rig_path, image_dir):
    """The rig's (C, H, W[, 3]) uint8 camera images: ``image_dir``, else the rig JSON's image fields."""
    from jaxdepth.io.rig_images import read_rig_images, rig_image_paths
    paths = rig_image_paths(rig.cameras, image_dir=image_dir, rig_json=rig_path,
                            json_images={c.name: c.image for c in rig.cameras if c.image is not None})
    return read_rig_images(paths, rig.cameras)


def _output_identities(rig, points_path, rig_path, out_dir, image_dir, *, guided: bool) -> dict:
    """``{<out_dir>/<camera>.png: input identity}``: every camera's output is made from the sweep (or
    sweeps JSON and every point file it names) and the rig JSON, and its own image when ``guided``
    (:func:`jaxdepth.batch.run_record.input_identity`)."""
    from jaxdepth.batch.run_record import input_identity
    from jaxdepth.io.rig_images import rig_image_paths
    images = (rig_image_paths(rig.cameras, image_dir=image_dir, rig_json=rig_path,
                              json_images={c.name: c.image for c in rig.cameras if c.image is not None})
              if guided else [None] * len(rig.cameras))
    files = sweep_input_files(points_path)
    return {pathlib.Path(out_dir) / f"{camera.name}.png": input_identity([*files, rig_path, image])
            for camera, image in zip(rig.cameras, images)}


def sweep_input_files(points_path) -> list:
    """The files one sweep argument is read from: the point file, or a sweeps JSON and every point file it
    names (the reference first), so that a rewritten member counts as a changed input. A sweeps JSON that
    cannot be read: itself only (reading it for the completion reports the problem)."""
    from jaxdepth.io.errors import JaxdepthError
    from jaxdepth.io.sweeps import is_sweeps_json, read_sweeps_json
    if not is_sweeps_json(points_path):
        return [points_path]
    try:
        return [points_path, *(entry.file for entry in read_sweeps_json(points_path))]
    except JaxdepthError:
        return [points_path]


@dataclasses.dataclass
class PreparedSweep:
    """One sweep read and checked on the host (:func:`prepare_rig_sweep`), ready for the rig's program.

    ``rig`` and ``config`` as the sweep check left them (origin moved, outlier removal off when the
    check does not trust it); ``points`` the padded ``(points, valid)`` of one LiDAR, or the checked
    :class:`~jaxdepth.io.sources.SourceCloud` when ``multi``.
    """

    rig: object
    config: SGMConfig
    points: object
    multi: bool


def prepare_rig_sweep(points_path, rig, *, config, multi, columns, point_columns, estimate, force, report,
                      rig_path=None) -> PreparedSweep:
    """Reads the sweep (or sweeps JSON) ``points_path`` with complete-rig's sweep check and the calibration
    check against the sweep (:func:`jaxdepth.io.plausibility.check_rig_geometry`, naming ``rig_path``);
    the check's notes go to ``report("note", text)``. Host only: no JAX computation."""
    from jaxdepth.io import pad_points, prepare_sweep, read_points
    from jaxdepth.io.plausibility import check_rig_geometry
    from jaxdepth.io.points import ring_column
    from jaxdepth.io.sweeps import is_sweeps_json

    if multi:
        # Several sources (LiDARs x sweeps), each seen from its own origin (docs/multi_source.md).
        from jaxdepth.batch.sources_job import checked_cloud
        from jaxdepth.io.sweeps import read_point_file_cloud, read_sweeps_cloud
        read = read_sweeps_cloud if is_sweeps_json(points_path) else read_point_file_cloud
        cloud = read(points_path, rig, point_columns=point_columns)
        report("note", f"{cloud.num_sources} sources ({', '.join(cloud.names)}), {cloud.points.shape[0]} points")
        frame, config = checked_cloud(cloud, rig, config, estimate=estimate)     # the single path's decision
        for note in frame.notes:
            report("note", note)
        check_rig_geometry(frame.cloud.points, frame.rig.cameras, path=rig_path, force=force)
        return PreparedSweep(frame.rig, config, frame.cloud, True)
    points, extra = read_points(points_path, columns=columns, force=force)
    if rig.columns is not None:
        ring = extra[:, list(rig.columns[3:]).index("ring")] if "ring" in rig.columns[3:] else None
    else:
        ring = ring_column(extra, columns)
    frame = prepare_sweep(points, rig, ring=ring, estimate=estimate, drop_far=not force)
    if not frame.outlier_removal_trusted and config.outlier_removal:
        config = config.replace(outlier_removal=False)
    for note in frame.notes:
        report("note", note)
    check_rig_geometry(frame.points, frame.rig.cameras, path=rig_path, force=force)
    return PreparedSweep(frame.rig, config, pad_points(frame.points), False)


def rig_stages(prepared: PreparedSweep, *, images=None):
    """The rig's :class:`~jaxdepth.Stages` (C leading axis) of a :class:`PreparedSweep`:
    ``(stages, stacked cameras)``."""
    import jaxdepth
    rig, config = prepared.rig, prepared.config
    cameras = jaxdepth.stack_cameras([camera.as_camera() for camera in rig.cameras])
    if prepared.multi:
        from jaxdepth.batch.sources_job import complete_cloud
        stages = complete_cloud(prepared.points, rig, config=config, images=images, stages=True)
    else:
        padded, valid = prepared.points
        from jaxdepth.batch.program_cache import rig_stages as complete_rig_stages   # warm: no trace
        stages = complete_rig_stages(padded, valid, cameras, config=config, lidar=rig.lidar, images=images)
    return stages, cameras


def _depth_call(prepared: PreparedSweep, *, images=None):
    """The depth program's call (no seed extras), its host work done: ``call() -> (depth, seen)`` device arrays,
    (C, H, W) depth and ``(C,)`` pixels with a point (:func:`jaxdepth._src.rig.seen_pixels`); the same bytes as
    the :class:`~jaxdepth.Stages` program's ``depth`` and ``sparse_depth`` count (docs/speed.md, "The jobs'
    depth programs")."""
    import functools

    import jaxdepth
    rig, config = prepared.rig, prepared.config
    if prepared.multi:
        from jaxdepth.batch.sources_job import cloud_call
        return cloud_call(prepared.points, rig, config=config, images=images, seen=True)
    from jaxdepth.batch.program_cache import rig_stages as complete_rig_stages   # warm: no trace
    cameras = jaxdepth.stack_cameras(rig.cameras)       # the values RigCamera.as_camera's would hold
    return functools.partial(complete_rig_stages, *prepared.points, cameras, config=config, lidar=rig.lidar,
                             images=images, depth_only=True, seen=True)


def rig_outputs(prepared: PreparedSweep, stages, cameras, extras: extra_outputs.ExtraOutputs):
    """``(depth, valid, distance)``: (C, H, W) NumPy arrays on the rig's canvas; ``valid`` and
    ``distance`` None unless ``extras`` needs the seeds."""
    depth = np.asarray(stages.depth)
    valid = distance = None
    if extras.needs_seeds:
        from jaxdepth._src.validity import rig_validity_and_distance
        valid, distance = (np.asarray(a) for a in rig_validity_and_distance(
            stages, cameras, lidar=prepared.rig.lidar, metric=prepared.config.distance_metric,
            max_seed_distance_px=extras.max_seed_distance_px))
    return depth, valid, distance


def rig_results(prepared: PreparedSweep, extras: extra_outputs.ExtraOutputs, *, method: str = "sgm", images=None):
    """``(depth, valid, distance, seen)`` of a :class:`PreparedSweep` by ``method``: the three (C, H, W) NumPy
    arrays of :func:`rig_outputs` and ``seen`` (C,), the sparse pixels of each camera (0: no point projects
    into it). ``"sgm"``: the depth program (:func:`rig_call`) unless ``extras`` needs the seeds, then
    :func:`rig_stages`; ``"nearest"`` / ``"ip-basic"``: the baselines of the same points
    (every LiDAR and sweep merged, :func:`jaxdepth.batch.cloud_runner.baseline_depth`), ``seen`` counted on
    the filled depth (a fill has depth where some point projects), ``valid`` and ``distance`` None."""
    from jaxdepth.batch.cloud_runner import read_back
    return read_back(rig_call(prepared, extras, method=method, images=images)())


def rig_call(prepared: PreparedSweep, extras: extra_outputs.ExtraOutputs, *, method: str = "sgm", images=None):
    """:func:`rig_results`'s host work done now (the stacked cameras, the sources pytree), its program left for
    ``call()``, which returns ``(depth, valid, distance, seen)``: the depth program's device arrays (the SGM
    without seed extras; ``valid``, ``distance`` None), NumPy otherwise (computed whole in ``call()``).
    Read back with :func:`jaxdepth.batch.cloud_runner.read_back`: :func:`rig_results`' values."""
    if method == "sgm" and not extras.needs_seeds:
        program = _depth_call(prepared, images=images)

        def depth_program():
            depth, seen = program()
            return depth, None, None, seen
        return depth_program
    if method == "sgm":
        def seeds():
            stages, cameras = rig_stages(prepared, images=images)
            seen = np.count_nonzero(np.asarray(stages.sparse_depth), axis=(1, 2))
            return (*rig_outputs(prepared, stages, cameras, extras), seen)
        return seeds
    from jaxdepth.batch.cloud_runner import baseline_depth, check_method, cloud_baseline_depth
    check_method(method, where="complete-rig", extras=extras, guided=images is not None)
    options = dict(method=method, config=prepared.config)

    def baseline():
        depth = (cloud_baseline_depth(prepared.points, prepared.rig, **options) if prepared.multi
                 else baseline_depth(*prepared.points, prepared.rig, **options))
        return depth, None, None, np.count_nonzero(depth, axis=(1, 2))
    return baseline


def empty_camera_message(camera_name: str, rig_path) -> str:
    """The warning for a camera into which no point of the sweep projects."""
    return (f"{camera_name}: no LiDAR point projects into this camera; its depth image is all zero "
            f"(check T_cam_lidar in {rig_path}: it maps the sweep's frame into the camera, which "
            "looks along +z, x right, y down)")


def point_columns_of(rig, points_path, point_columns, *, multi: bool):
    """The float32 values per point record: the rig JSON's ``columns``, else given or inferred from the file."""
    from jaxdepth.io import infer_point_columns
    if multi or rig.columns is not None:
        return len(rig.columns) if rig.columns is not None else point_columns
    return infer_point_columns(points_path, point_columns)


def run_rig_job(points_path, rig_path, out_dir, *, config: SGMConfig, extras: extra_outputs.ExtraOutputs,
                point_columns: int | None = None, estimate: bool = True, image_dir=None, overwrite: bool = False,
                report: Callable[[str, str], None] = _ignore, force: bool = False,
                record: dict | None = None, method: str = "sgm") -> RigJobSummary:
    """Completes the sweep ``points_path`` for every camera of the rig JSON ``rig_path`` into ``out_dir``.

    Args:
      points_path: the sweep (``.bin`` float32 records, ``.npy`` / ``.npz``), or a sweeps JSON
        (:mod:`jaxdepth.io.sweeps`: several sweeps with their poses). A sweeps JSON or a rig JSON
        with ``lidars`` runs the multi-source path
        (:func:`jaxdepth.batch.sources_job.complete_cloud`: each LiDAR and sweep seen from its
        own origin, free space of the reference sweep); ``columns`` in the rig JSON names the
        point file's columns.
      rig_path: the rig JSON (:func:`jaxdepth.io.read_rig_json`).
      out_dir: output folder (created); ``<camera name>.png`` per camera.
      config: the SGM configuration; guided (``guidance_weight > 0``) reads the camera
        images from ``image_dir`` or the rig JSON's ``image`` fields.
      extras: the extra outputs (:mod:`jaxdepth.batch.extras`).
      point_columns: float32 values per ``.bin`` record (None: inferred).
      estimate: check the sweep against its LiDAR (:func:`jaxdepth.io.prepare_sweep`; several sweeps:
        :func:`jaxdepth.io.sweep_frame.prepare_cloud`, the same decision).
      overwrite: replace existing outputs (default: skip them).
      report: ``report(kind, text)`` for every message (see the module docstring).
      force: use a sweep or a calibration that fails the plausibility checks
        (:mod:`jaxdepth.io.plausibility`: the sweep's values, K and T_cam_lidar against the sweep), logged.
      record: the run record (:func:`jaxdepth.batch.run_record.make_record`; the point columns and the
        above-scan rule the sweep resolves, :func:`jaxdepth.batch.run_record.rig_above_scan`, are set in its
        settings), checked against ``out_dir``'s and written once the sweep is read, before any
        computation (:func:`jaxdepth.batch.run_record.claim_folder`); None: no record.
      method: ``"sgm"`` (default), or the baselines ``"nearest"`` / ``"ip-basic"`` of the same checked points
        (every LiDAR and sweep merged, no outlier removal: :func:`rig_results`).

    Raises:
      JaxdepthError: unreadable or invalid inputs, unwritable outputs.
    """
    from jaxdepth.io import read_rig_json
    from jaxdepth.io.atomic import ensure_output_dir

    from jaxdepth.io.sweeps import is_sweeps_json

    rig = read_rig_json(rig_path)
    images = rig_images(rig, rig_path, image_dir) if config.guidance_weight > 0 else None
    multi = is_sweeps_json(points_path) or bool(rig.lidars)
    columns = point_columns_of(rig, points_path, point_columns, multi=multi)
    out_dir = pathlib.Path(out_dir)
    ensure_output_dir(out_dir)
    prepared = prepare_rig_sweep(points_path, rig, config=config, multi=multi, columns=columns,
                                 point_columns=point_columns, estimate=estimate, force=force, report=report,
                                 rig_path=rig_path)
    if record is not None:     # the above-scan rule the sweep's program resolves (it may depend on the points)
        from jaxdepth.batch import run_record
        record = dict(record, settings=dict(record["settings"], point_columns=columns,
                                            above_scan=run_record.rig_above_scan(config.above_scan, rig, prepared)))
        run_record.claim_folder(out_dir, record, overwrite=overwrite,
                                outputs=_output_identities(rig, points_path, rig_path, out_dir, image_dir,
                                                           guided=config.guidance_weight > 0))
    depth, valid, distance, seen = rig_results(prepared, extras, method=method, images=images)
    rig = prepared.rig
    summary = RigJobSummary()
    for i, camera in enumerate(rig.cameras):
        if seen[i] == 0:
            message = empty_camera_message(camera.name, rig_path)
            if report is _ignore:          # no reporter (the API): the log; the CLI prints it once itself
                log.warning("%s", message)
            report("warning", message)
            summary.empty_cameras.append(camera.name)
        target = out_dir / f"{camera.name}.png"
        if extra_outputs.is_done(target, extras) and not overwrite:
            report("skipped", f"{target}: exists, skipped (use --overwrite)")
            summary.skipped.append(target)
            continue
        window = (i, slice(0, camera.height), slice(0, camera.width))
        extra_outputs.write_outputs(target, depth[window], extras=extras,
                                    valid=None if valid is None else valid[window],
                                    distance=None if distance is None else distance[window],
                                    overwrite=overwrite)
        summary.written.append(target)
        written = extra_outputs.apply_zero_invalid(depth[window], None if valid is None else valid[window], extras)
        valid_px = int(np.count_nonzero(written))  # the pixels written non-zero (zero_invalid included)
        report("written", f"{camera.name}: {camera.width}x{camera.height}, {valid_px} completed pixels -> {target}")
    return summary
