"""Many sweeps of one rig in one process (``complete-rig`` over a folder, glob or list), and the rig warm-up.

:func:`run_rig_sweeps` completes every sweep that :func:`jaxdepth.io.sweep_list.list_sweeps` names into
``<out_dir>/<sweep stem>/<camera>.png``, each sweep exactly as one ``complete-rig`` call on it would
(:func:`jaxdepth.batch.rig_job.prepare_rig_sweep`, :func:`~jaxdepth.batch.rig_job.rig_results`: the same
bytes). It runs on the multi-source jobs' loop (:func:`jaxdepth.batch.cloud_runner.run_cloud_jobs`):
reader threads read and check the next sweeps and build their program inputs (the stacked cameras,
the sources pytree: :func:`jaxdepth.batch.rig_job.rig_call`) while the current one computes, writer
threads encode and write the previous sweep's PNGs, atomically. A sweep that cannot be read, checked or
completed is reported and skipped; the others carry on (so is a sweep whose LiDARs, stating no spec, resolve another
above-scan rule than the record's, the first sweep's: :func:`jaxdepth.batch.run_record.rig_above_scan`).
The run record (:mod:`jaxdepth.batch.run_record`) lists every output with its inputs, so a re-run skips
what is done and redoes what changed.

The rig's shapes do not change between sweeps, so the whole run uses one compiled program as long as
the sweeps fall in one point bucket (:func:`jaxdepth.io.bucket_size`) and the LiDAR check keeps one
sensor description: a rig JSON that leaves the LiDAR's field of view open gets each sweep's own
estimate, hence a program per distinct estimate (state ``fov_up_deg`` / ``fov_down_deg``, or pass
``--no-estimate``). Each new program after the first is reported as a note.

:func:`warm_rig` compiles the rig's program on an empty sweep (one LiDAR, or a rig's ``lidars``), or on
a sample sweep, into the persistent compile cache (:func:`jaxdepth.batch.devices.use_compile_cache`),
so that a later process's first sweep loads it.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import time
from typing import Callable

import numpy as np

from jaxdepth._src.config import SGMConfig
from jaxdepth.batch import extras as extra_outputs
from jaxdepth.batch import rig_job


def _ignore(kind: str, text: str) -> None:
    return None


def _notify_nothing(name: str, status: str) -> None:
    return None


@dataclasses.dataclass(frozen=True)
class _Loaded:
    stem: str
    prepared: rig_job.PreparedSweep
    notes: tuple


def _program_key(prepared: rig_job.PreparedSweep) -> tuple:
    """What selects the compiled program of a sweep, beyond the rig's fixed shapes."""
    if prepared.multi:
        cloud = prepared.points
        return ("sources", cloud.num_sources, prepared.rig.lidar, prepared.config)
    return ("points", prepared.points[0].shape[0], prepared.rig.lidar, prepared.config)


def _claim(out_dir, rig, sweeps, rig_path, *, record, overwrite: bool, columns) -> None:
    from jaxdepth.batch import run_record
    from jaxdepth.io.sweep_list import sweep_stem
    outputs = {out_dir / sweep_stem(path) / f"{camera.name}.png":  # a sweeps JSON: with the files it names
               run_record.input_identity([*rig_job.sweep_input_files(path), rig_path, None])
               for path in sweeps for camera in rig.cameras}
    record = dict(record, settings=dict(record["settings"], point_columns=columns))
    run_record.claim_folder(out_dir, record, overwrite=overwrite, outputs=outputs)


def _jobs(sweeps, rig, out_dir: pathlib.Path, *, extras, overwrite: bool, summary, notify) -> list:
    """The :class:`~jaxdepth.batch.cloud_runner.CloudJob` of every sweep with an output still to write;
    sweeps whose outputs all exist are recorded as skipped."""
    from jaxdepth.batch.cloud_runner import CloudJob
    from jaxdepth.io.sweep_list import sweep_stem
    jobs = []
    for path in sweeps:
        folder = out_dir / sweep_stem(path)
        outputs = tuple((c.name, folder / f"{c.name}.png") for c in rig.cameras
                        if overwrite or not extra_outputs.is_done(folder / f"{c.name}.png", extras))
        if not outputs:
            summary.skipped.append(os.fspath(path))
            notify(os.fspath(path), "skipped")
            continue
        jobs.append(CloudJob(name=os.fspath(path), outputs=outputs, source=pathlib.Path(path)))
    return jobs


def run_rig_sweeps(sweeps, rig_path, out_dir, *, config: SGMConfig, extras: extra_outputs.ExtraOutputs,
                   point_columns: int | None = None, estimate: bool = True, overwrite: bool = False,
                   report: Callable[[str, str], None] = _ignore, force: bool = False, record: dict | None = None,
                   io_threads: int = 2, on_progress: Callable[[str, str], None] = _notify_nothing,
                   method: str = "sgm"):
    """Completes every sweep of ``sweeps`` for every camera of the rig JSON ``rig_path`` (module docs).

    Args:
      sweeps: point files or sweeps JSONs with distinct stems (:func:`jaxdepth.io.sweep_list.list_sweeps`).
      rig_path, config, extras, point_columns, estimate, force: as :func:`jaxdepth.batch.rig_job.run_rig_job`
        (image-guided seeds, ``config.guidance_weight > 0``, are refused: a sweep's images are not named).
      out_dir: output root; ``<out_dir>/<sweep stem>/<camera name>.png``.
      overwrite: recompute outputs that exist (default: skip them; a sweep with all its outputs is skipped
        unread).
      report: ``report(kind, text)``: ``"note"`` (the sweep check, prefixed with the sweep's stem and
        shown when it differs from the previous sweep's; a new compiled program) and ``"warning"`` (a camera no point projects into).
      record: the run record (:func:`jaxdepth.batch.run_record.make_record`), claimed for ``out_dir`` with
        one entry per output before any computation; None: no record.
      io_threads: reader threads, and as many writer threads.
      on_progress: ``on_progress(sweep path, "done" | "skipped" | "failed: <message>")``, from any thread.
      method: ``"sgm"`` (default), ``"nearest"`` or ``"ip-basic"`` (:func:`jaxdepth.batch.rig_job.rig_results`).

    Returns:
      :class:`jaxdepth.batch.runner.RunSummary` over sweeps (failed: ``(sweep path, message)``).

    Raises:
      JaxdepthError: an unreadable rig JSON, guided seeds, or an output folder or record that cannot
        be claimed. A bad sweep is a failure in the summary, never an exception.
    """
    from jaxdepth.batch import run_record
    from jaxdepth.batch.cloud_runner import read_back, run_cloud_jobs
    from jaxdepth.batch.runner import RunSummary
    from jaxdepth.io import read_rig_json
    from jaxdepth.io.atomic import ensure_output_dir
    from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION
    from jaxdepth.io.errors import InputError
    from jaxdepth.io.sweep_list import check_unique_stems, sweep_stem
    from jaxdepth.io.sweeps import is_sweeps_json

    if config.guidance_weight > 0:
        raise InputError(f"{rig_path}: image-guided seeds (--guidance-weight) take one sweep per call: the camera "
                         "images belong to one sweep")
    check_unique_stems(sweeps)
    rig = read_rig_json(rig_path)
    out_dir = pathlib.Path(out_dir)
    ensure_output_dir(out_dir)

    def prepare(path, report):
        multi = is_sweeps_json(path) or bool(rig.lidars)
        columns = rig_job.point_columns_of(rig, path, point_columns, multi=multi)
        return rig_job.prepare_rig_sweep(path, rig, config=config, multi=multi, columns=columns,
                                         point_columns=point_columns, estimate=estimate, force=force, report=report,
                                         rig_path=rig_path)

    # The record's above-scan rule: the rig JSON's LiDARs decide it, or (LiDARs without a stated spec) the
    # first sweep that reads does, and every sweep must resolve the same (else it fails, named).
    rule = run_record.rig_above_scan(config.above_scan, rig)
    per_sweep = record is not None and rule is None
    if per_sweep:
        rule = _first_sweep_rule(sweeps, prepare, config.above_scan, rig)
    if record is not None:
        _claim(out_dir, rig, sweeps, rig_path, record=dict(record, settings=dict(record["settings"], above_scan=rule)),
               overwrite=overwrite, columns=len(rig.columns) if rig.columns is not None else point_columns)
    summary = RunSummary(started_at=time.perf_counter())
    jobs = _jobs(sweeps, rig, out_dir, extras=extras, overwrite=overwrite, summary=summary, notify=on_progress)

    def load(job):
        notes = []
        prepared = prepare(job.source, lambda kind, text: notes.append(text))
        own = run_record.rig_above_scan(config.above_scan, rig, prepared) if per_sweep else rule
        if own != rule:
            raise InputError(f"{job.source}: its LiDARs resolve above_scan 'auto' to {own!r}, the run's first sweep "
                             f"(the run record) to {rule!r}: complete it apart, or state --above-scan")
        ensure_output_dir(out_dir / sweep_stem(job.source))      # once the sweep reads: none for a bad one
        return _Loaded(sweep_stem(job.source), prepared, tuple(notes)), prepared.rig

    programs, last_notes = set(), [()]

    def program_inputs(loaded: _Loaded, checked_rig):   # a reader thread: the host work of the sweep's program
        call = rig_job.rig_call(loaded.prepared, extras, method=method)
        return lambda: complete(loaded, checked_rig, call)

    def complete(loaded: _Loaded, checked_rig, call):   # the main thread, in the sweeps' order
        if loaded.notes != last_notes[0]:          # a log's sweeps mostly repeat one check's notes: shown once
            for note in loaded.notes:
                report("note", f"{loaded.stem}: {note}")
            last_notes[0] = loaded.notes
        key = _program_key(loaded.prepared)
        if programs and key not in programs:
            report("note", f"{loaded.stem}: compiles another program ({_key_text(key)})")
        programs.add(key)
        *outputs, seen = read_back(call())
        for i, camera in enumerate(checked_rig.cameras):
            if seen[i] == 0:
                report("warning", f"{loaded.stem}: " + rig_job.empty_camera_message(camera.name, rig_path))
        return outputs

    run_cloud_jobs(jobs, load, summary, on_progress, config=config, png_compression=DEFAULT_PNG_COMPRESSION,
                   io_threads=io_threads, prepare=program_inputs, extras=extras, overwrite=overwrite)
    return summary


def _first_sweep_rule(sweeps, prepare, mode: str, rig) -> str:
    """The above-scan rule of the first of ``sweeps`` that ``prepare(path, report)`` reads and checks
    (:func:`jaxdepth.batch.run_record.rig_above_scan`); ``mode`` itself when none does (each sweep then fails
    as it would, nothing is written)."""
    from jaxdepth.batch import run_record
    from jaxdepth.io.errors import JaxdepthError
    for path in sweeps:
        try:
            prepared = prepare(path, _ignore)
        except (JaxdepthError, ValueError):      # what the job's reader counts as a failed sweep
            continue
        return run_record.rig_above_scan(mode, rig, prepared)
    return mode


def _key_text(key: tuple) -> str:
    kind, size, lidar, config = key
    what = f"{size} padded points" if kind == "points" else f"{size} sources"
    return (f"{what}, LiDAR fov {lidar.fov_up_deg:+.2f} / {lidar.fov_down_deg:+.2f} deg, "
            f"outlier removal {'on' if config.outlier_removal else 'off'}")


def default_warm_points(rig) -> int:
    """The point count a warm-up compiles for by default: the rig LiDAR's range-image cells (beams x columns),
    whose bucket holds a typical sweep (KITTI HDL-64E: 131072; nuScenes HDL-32E: 65536). With ``lidars``:
    the largest of each LiDAR's cells (its stated spec, else the rig's ``lidar``)."""
    specs = [lid.spec or rig.lidar for lid in rig.lidars] or [rig.lidar]
    return max(int(spec.beams) * int(spec.columns) for spec in specs)


def _estimated_lidars(rig) -> list:
    """The names of a rig's ``lidars`` whose spec each sweep estimates from its rings (so the program
    depends on the data: see :func:`jaxdepth.io.sweep_frame.source_spec`)."""
    rings = rig.columns is not None and "ring" in rig.columns
    return [lid.name for lid in rig.lidars if lid.spec is None and rings]


def _empty_cloud(rig, count: int):
    """A SourceCloud of the rig's ``lidars`` (one sweep), ``count`` missing points (NaN) per LiDAR: its
    padded shapes, specs and poses are those of a real sweep of ``count`` points or fewer per LiDAR."""
    from jaxdepth.io.sources import SourceCloud
    S = len(rig.lidars)
    return SourceCloud(points=np.full((S * count, 3), np.nan, np.float32),
                       source=np.repeat(np.arange(S, dtype=np.int32), count),
                       T_ref_source=np.stack([np.asarray(lid.T_points_lidar, np.float64) for lid in rig.lidars]),
                       lidars=tuple(lid.spec for lid in rig.lidars), sweep=np.zeros(S, np.int32),
                       names=tuple(f"{lid.name}@0" for lid in rig.lidars))


def _warm_inputs(rig, rig_path, config, counts, report) -> list:
    """``[(label, PreparedSweep), ...]``: what warm_rig compiles for a rig without a sample sweep."""
    from jaxdepth.io import bucket_size
    from jaxdepth.io.errors import InputError
    if rig.lidars:
        estimated = _estimated_lidars(rig)
        if estimated:
            raise InputError(f"{rig_path}: field 'lidars': {', '.join(estimated)} state no beams, so each sweep "
                             "estimates them from its rings: warm up on a real sweep with --sample SWEEP")
        from jaxdepth.batch.sources_job import POINT_BUCKET
        return [(f"{max(b, POINT_BUCKET)} padded points per LiDAR",
                 rig_job.PreparedSweep(rig, config, _empty_cloud(rig, b), True))
                for b in sorted({bucket_size(n) for n in counts})]
    if not {"fov_up_deg", "fov_down_deg"} <= set(rig.lidar_stated):
        report("note", f"{rig_path}: the LiDAR's field of view is left open: a sweep's own estimate makes its own "
                       "program; state lidar.fov_up_deg / fov_down_deg, or run complete-rig with --no-estimate, "
                       "to use the warmed one (or warm up on a real sweep with --sample SWEEP)")
    return [(f"{bucket} padded points", rig_job.PreparedSweep(
                rig, config, (np.zeros((bucket, 3), np.float32), np.zeros((bucket,), bool)), False))
            for bucket in sorted({bucket_size(n) for n in counts})]


def warm_rig(rig_path, *, config: SGMConfig, extras: extra_outputs.ExtraOutputs = extra_outputs.NONE,
             points=None, sample=None, estimate: bool = True, point_columns: int | None = None,
             report: Callable[[str, str], None] = _ignore) -> list:
    """Compiles the rig's ``complete-rig`` program(s) by running them once, writing nothing.

    With the persistent compile cache on (:func:`jaxdepth.batch.devices.use_compile_cache`, the CLI's
    default) the programs are stored, and a later process's first sweep of the same rig, options and
    point bucket loads them instead of compiling.

    Without ``sample`` no data is read: the program runs on an empty sweep of each bucket. A rig with
    ``lidars`` gets the multi-source program of one sweep of its LiDARs (each padded to the bucket,
    :func:`jaxdepth.batch.sources_job.cloud_sources`); it needs every LiDAR's ``beams`` stated, or no
    ``ring`` column (otherwise each sweep estimates its LiDARs, and only ``sample`` can say what).
    With ``sample`` (a sweep file or sweeps JSON like those to come) that sweep is read, checked and
    completed exactly as ``complete-rig`` would (its estimates, sources and bucket), and ``points`` is
    ignored: one program, serving every sweep whose estimates (fields of view on a 0.25 degree grid,
    :func:`jaxdepth.io.sweep_frame.source_spec`) and bucket match.

    Args:
      rig_path: the rig JSON.
      config, extras: the options the real run will use (each is part of the program).
      points: point counts of the sweeps to come, per LiDAR with ``lidars`` (one program per power-of-two
        bucket, :func:`jaxdepth.io.bucket_size`); default: :func:`default_warm_points`.
      sample: a sweep (or sweeps JSON) to warm up on; None: an empty sweep.
      estimate, point_columns: as ``complete-rig``'s (used with ``sample``; ``estimate`` is part of the
        single-LiDAR program only through the sweep check's decisions).
      report: ``report("note", text)``: a rig whose LiDAR field of view is left open (each sweep's
        estimate then makes its own program unless the run passes ``--no-estimate``).

    Returns:
      ``[(what, seconds), ...]``: each program compiled (and run once), with its wall time.

    Raises:
      JaxdepthError: an unreadable rig JSON or sample, ``lidars`` whose specs each sweep estimates (without
        ``sample``), image-guided seeds.
    """
    from jaxdepth.io import read_rig_json
    from jaxdepth.io.errors import InputError
    from jaxdepth.io.sweeps import is_sweeps_json

    rig = read_rig_json(rig_path)
    if config.guidance_weight > 0:
        raise InputError(f"{rig_path}: warm-up of image-guided seeds (--guidance-weight) is not supported")
    if sample is not None:
        multi = is_sweeps_json(sample) or bool(rig.lidars)
        columns = rig_job.point_columns_of(rig, sample, point_columns, multi=multi)
        inputs = [(f"the sweep {sample}", rig_job.prepare_rig_sweep(
            sample, rig, config=config, multi=multi, columns=columns, point_columns=point_columns,
            estimate=estimate, force=False, report=report, rig_path=rig_path))]
    else:
        counts = [default_warm_points(rig)] if not points else [int(n) for n in points]
        inputs = _warm_inputs(rig, rig_path, config, counts, report)
    done = []
    for label, prepared in inputs:
        start = time.perf_counter()
        rig_job.rig_results(prepared, extras)        # the run's program; NumPy: waits for the result
        done.append((label, time.perf_counter() - start))
    return done


__all__ = ["run_rig_sweeps", "warm_rig", "default_warm_points"]
