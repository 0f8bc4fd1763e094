"""The run record of an output folder: ``jaxdepth_run.json``, and the refusal to mix settings.

Every output folder of ``jaxdepth complete`` (every dataset layout, the nuScenes job,
the local and the Ray engine) and ``complete-rig`` holds one ``jaxdepth_run.json``,
written atomically before the first output::

    {"jaxdepth_version": "0.1.0", "output_version": "de5d6c957fb7", "png_encoder": "zlib 1.3.1",
     "command": "jaxdepth complete raw/ out/ --distance l2",
     "inputs": ["/abs/path/raw"],
     "settings": {"method": "sgm", "distance_metric": "l2", ..., "zero_invalid": false},
     "outputs": {"f0.png": {"files": [["/abs/path/raw/f0.png", 18211, 1764325...]], "values": "9c1f..."}}}

``settings`` holds every field of :class:`~jaxdepth._src.config.SGMConfig`, the method
and the options that change what is written (extra-output settings, crop, camera,
sweeps...). ``output_version`` is :data:`jaxdepth.__output_version__`, which changes
whenever the algorithm's outputs do. ``outputs`` holds, per output (path relative to the
folder), the identity of the inputs it was made from (:func:`input_identity`: each input
file's absolute path, size and modification time in ns, and a digest of the calibration
values). A re-run into the same folder:

* with the same settings and output version resumes: a finished output is skipped when
  its inputs are the ones recorded; an output whose input changed (another file, another
  size or time, other calibration; e.g. ``complete OTHER_FOLDER out/``) or that has no
  recorded input is removed, with its extra files, before the run and so recomputed; one
  warning counts them and names the first and what changed;
* with other settings, when the folder holds depth PNGs, is refused
  (:class:`RunSettingsError`, exit 1), the message
  listing each difference (``distance_metric: l1 -> l2``), unless ``overwrite``: then
  every output is recomputed and the record replaced;
* written by another output version (another algorithm; records older than the output
  version count as another) is refused the same way: resuming would mix two algorithms'
  outputs in one folder;
* into a folder that holds depth PNGs but no record (an older jaxdepth, another tool)
  is refused too: the settings of those files are unknown, so resuming could mix two
  runs. ``overwrite`` recomputes them and writes the record.

Which extra files are requested (``--preview``, ``--validity``...) is not a setting:
adding one on a re-run fills in the missing files, as before.

A single named output (``complete a.png out.png``) keeps its record beside it,
``out.jaxdepth_run.json`` (:func:`claim_output_file`): the same inputs, settings and output
version resume; anything else recomputes it; an ``out.png`` without a record is refused
unless ``overwrite``.

KITTI trees keep each run's outputs in ``<drive>/proj_depth/<name>/``: the record lives
there (:func:`record_folders`), so two methods completed into one output root (``sgm``
and ``ip-basic`` side by side) each keep their own record.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import pathlib
import shlex
import sys

from jaxdepth.io.errors import OutputError, PathLike

RUN_FILE = "jaxdepth_run.json"
#: The record of one named output ``out.png`` (``complete a.png out.png``): ``out.jaxdepth_run.json``.
OUTPUT_RECORD_SUFFIX = ".jaxdepth_run.json"

log = logging.getLogger("jaxdepth")


class RunSettingsError(OutputError):
    """The output folder holds outputs of a run with other (or unknown) settings."""


def settings_of(config, *, method: str, extras=None, **options) -> dict:
    """The settings that change a run's outputs, as a flat JSON-able dict.

    Args:
      config: the run's :class:`~jaxdepth._src.config.SGMConfig` (every field is recorded).
      method: completion method ("sgm", "nearest", "ip-basic").
      extras: :class:`jaxdepth.batch.extras.ExtraOutputs` or None; its value settings
        (``zero_invalid``, ``max_seed_distance_px`` (None: from the sensor),
        ``preview_range``) are recorded, not which files it asks for.
      options: further output-changing options (``crop``, ``camera``, ``sweeps``...; ``above_scan``: the
        rule a run of several LiDARs uses, :func:`lidars_above_scan`; ``complete-rig``'s jobs set the rule their
        sweeps resolve, :func:`rig_above_scan`; else ``"auto"`` is recorded as ``"plane"``).
    """
    settings = {"method": method}
    settings.update({f.name: _plain(getattr(config, f.name)) for f in dataclasses.fields(config)})
    settings["above_scan"] = lidars_above_scan(settings["above_scan"], lidars=1)    # options: a rig's choice
    if extras is not None:
        settings.update(zero_invalid=bool(extras.zero_invalid),
                        max_seed_distance_px=("sensor" if extras.max_seed_distance_px is None
                                              else float(extras.max_seed_distance_px)),
                        preview_range=None if extras.preview_range is None else list(extras.preview_range))
    settings.update({k: _plain(v) for k, v in options.items()})
    return settings


def lidars_above_scan(mode: str, *, lidars: int) -> str:
    """The ``above_scan`` rule a run with ``lidars`` LiDARs per sweep uses, recorded in place of ``"auto"``
    (:func:`jaxdepth._src.above_scan.above_scan_rule` of one sweep of ``lidars`` LiDARs scanning in lines)."""
    from jaxdepth._src.above_scan import above_scan_rule
    n = int(lidars)
    return above_scan_rule(mode, sweep=(0,) * n, lidars=(None,) * n)


#: The free-space grid of a LiDAR without a stated spec that its points give it (any grid but its spec).
_OWN_GRID = "a grid of its own points"


def rig_above_scan(mode: str, rig, prepared=None) -> str | None:
    """The ``above_scan`` rule a ``complete-rig`` run of ``rig`` (:class:`~jaxdepth.io.rig.Rig`) uses, recorded in
    place of ``"auto"``: :func:`jaxdepth._src.above_scan.above_scan_rule` of the inputs the run gives it.

    The rig JSON's LiDARs decide it (its ``lidars``, each a source of the reference sweep; one LiDAR without)
    unless one states no spec: such a LiDAR may scan in lines (laser rows, or points that fill its grid) or
    not (a rosette: a free-space grid of its own points), and where the two give different rules its sweep
    decides: ``prepared`` (the sweep read and checked, :class:`jaxdepth.batch.rig_job.PreparedSweep`), through
    the sources its program gets (:func:`jaxdepth.batch.sources_job.cloud_above_scan`); None without it.
    """
    from jaxdepth._src.above_scan import above_scan_rule
    specs = tuple(lidar.spec for lidar in rig.lidars) or (rig.lidar,)
    own_grids = tuple(_OWN_GRID if spec is None else spec for spec in specs)     # every spec-less one a rosette
    lines, rosettes = (above_scan_rule(mode, sweep=(0,) * len(specs), lidars=specs, witnesses=grids)
                       for grids in (None, own_grids))
    if lines == rosettes:
        return lines
    if prepared is None:
        return None
    from jaxdepth.batch.sources_job import cloud_above_scan
    return cloud_above_scan(prepared.points, prepared.rig, prepared.config.replace(above_scan=mode))


def _plain(value):
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, pathlib.PurePath):
        return str(value)
    if hasattr(value, "item") and callable(value.item):  # numpy scalars
        return value.item()
    return value


def output_version() -> str:
    """:data:`jaxdepth.__output_version__`: changes whenever completion outputs do."""
    import jaxdepth
    return jaxdepth.__output_version__


def make_record(settings: dict, *, inputs: list, command: list | None = None) -> dict:
    """The record's JSON object: versions, command line (default ``sys.argv``), inputs (absolute), settings.

    ``png_encoder`` (:func:`jaxdepth.io.png_encoder`, e.g. ``"isal 1.9.1"``) says which library
    compressed the PNGs: their file bytes depend on it, their values do not, so it is neither a
    setting nor part of the output version (a re-run with another encoder resumes).

    The per-output input identities are added by :func:`claim_folder` (its ``outputs``)."""
    from jaxdepth import __version__
    argv = list(sys.argv if command is None else command)
    if argv:
        argv[0] = "jaxdepth"
    from jaxdepth.io.depth_png import png_encoder
    return {"jaxdepth_version": __version__, "output_version": output_version(),
            "png_encoder": png_encoder(), "command": shlex.join(str(a) for a in argv),
            "inputs": [os.path.abspath(os.fspath(p)) for p in inputs], "settings": settings}


def file_identity(path: PathLike) -> list:
    """``[absolute path, size in bytes, modification time in ns]`` of an input file (size and time
    None when it cannot be read: the run itself reports that input)."""
    path = os.path.abspath(os.fspath(path))
    try:
        st = os.stat(path)
    except OSError:
        return [path, None, None]
    return [path, int(st.st_size), int(st.st_mtime_ns)]


def input_identity(files, *, values=()) -> dict:
    """What one output is made from: ``{"files": [file_identity, ...], "values": digest}``.

    Args:
      files: the input files read for this output (None entries are left out).
      values: further inputs given as values (K, T_cam_lidar, image size...: arrays, numbers,
        strings or None); the first 16 hex digits of their SHA-256 (None when there are none).
    """
    ident = {"files": [file_identity(f) for f in files if f is not None], "values": None}
    values = list(values)
    if values:
        digest = hashlib.sha256()
        for value in values:
            digest.update(b"|" + _value_bytes(value))
        ident["values"] = digest.hexdigest()[:16]
    return ident


def _value_bytes(value) -> bytes:
    if value is None:
        return b"None"
    if isinstance(value, (str, int, float, bool)):
        return repr(value).encode()
    import numpy as np
    a = np.ascontiguousarray(np.asarray(value, np.float64))
    return f"{a.shape}".encode() + a.tobytes()


def read_record(folder: PathLike) -> dict | None:
    """The record of ``folder`` (None when it has none or it is unreadable JSON)."""
    return read_record_file(pathlib.Path(folder) / RUN_FILE)


def read_record_file(path: PathLike) -> dict | None:
    """The record in the file ``path`` (None when it is missing or unreadable JSON)."""
    path = pathlib.Path(path)
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def find_record(path: PathLike, *, levels: int = 4) -> tuple[pathlib.Path, dict] | None:
    """The nearest record at ``path`` or up to ``levels`` folders above it: (record file, record)."""
    folder = pathlib.Path(path).resolve()
    if folder.is_file():
        folder = folder.parent
    for _ in range(levels + 1):
        record = read_record(folder)
        if record is not None:
            return folder / RUN_FILE, record
        if folder.parent == folder:
            break
        folder = folder.parent
    return None


def differences(old: dict, new: dict) -> list[str]:
    """``"key: old -> new"`` for every setting that differs (a missing key shows as ``(unset)``)."""
    lines = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key, "(unset)"), new.get(key, "(unset)")
        if a != b:
            lines.append(f"{key}: {_show(a)} -> {_show(b)}")
    return lines


def _show(value) -> str:
    return json.dumps(value) if not isinstance(value, str) else value


def _has_outputs(folder: pathlib.Path) -> bool:
    try:
        return any(p.suffix.lower() == ".png" for p in folder.rglob("*.png"))
    except OSError:
        return False


def claim_folder(folder: PathLike, record: dict, *, overwrite: bool, outputs=None) -> list[str]:
    """Checks ``folder`` against ``record`` (module docs) and writes the record atomically.

    Args:
      folder: the output folder (created if missing).
      record: :func:`make_record`'s object.
      overwrite: the run recomputes every output (``--overwrite``): no refusal.
      outputs: ``{output depth PNG path: input_identity(...)}`` of this run's outputs (those outside
        ``folder`` are ignored), or None when the job cannot list them up front: then a re-run
        whose input roots differ from the recorded ones is refused unless ``overwrite``.

    Returns:
      ``"<output>: <what changed>"`` for every output removed because its inputs changed (to be
      recomputed by the run; one warning is logged too).

    Raises:
      RunSettingsError: other or unknown settings, another output version or (``outputs`` None)
        other inputs made the outputs already there.
      OutputError: the folder or its record cannot be written.
    """
    from jaxdepth.io.atomic import atomic_write_bytes

    folder = pathlib.Path(folder)
    old = read_record(folder)
    has_outputs = folder.is_dir() and _has_outputs(folder)
    if not overwrite and has_outputs:
        _refuse_other_run(folder, old, record, per_output=outputs is not None)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{folder}: cannot create output folder ({err.strerror or err})") from None
    same_run = (old is not None and old.get("settings") == record["settings"]
                and old.get("output_version") == record.get("output_version"))
    recorded = old.get("outputs") if same_run else None
    recorded = dict(recorded) if isinstance(recorded, dict) else {}
    current = {}
    for path, ident in (outputs or {}).items():
        rel = _relative(folder, path)
        if rel is not None:
            current[rel] = ident
    changed = [] if overwrite or not has_outputs else _remove_changed(folder, recorded, current)
    new = dict(record, outputs={**recorded, **current})
    if old is None or _without_command(new) != _without_command(old):  # a plain resume leaves the record as is
        atomic_write_bytes(folder / RUN_FILE, (json.dumps(new, indent=1, sort_keys=True) + "\n").encode(),
                           overwrite=True)
    return changed


def _without_command(record: dict) -> dict:
    return {k: v for k, v in record.items() if k != "command"}


def _refuse_other_run(folder: pathlib.Path, old: dict | None, record: dict, *, per_output: bool) -> None:
    """Raises :class:`RunSettingsError` when ``folder``'s outputs were made by another kind of run."""
    again = ("Re-run with --overwrite to recompute them with the new {}, or write to another folder")
    if old is None:
        if (folder / RUN_FILE).exists():
            raise RunSettingsError(f"{folder / RUN_FILE}: unreadable run record; its outputs' settings are unknown "
                                   "(--overwrite recomputes them)")
        raise RunSettingsError(
            f"{folder}: holds depth PNGs but no {RUN_FILE} (written by an older jaxdepth or another tool), so "
            "their settings are unknown and resuming could mix two runs. Re-run with --overwrite to recompute "
            "them, or write to another folder")
    diff = differences(old.get("settings", {}), record["settings"])
    if diff:
        raise RunSettingsError(
            f"{folder}: holds outputs of a run with other settings ({folder / RUN_FILE}): "
            + "; ".join(diff) + ". " + again.format("settings"))
    if old.get("output_version") != record.get("output_version"):
        was = old.get("output_version") or "none recorded (written before output versions)"
        raise RunSettingsError(
            f"{folder}: holds outputs of another jaxdepth algorithm version ({folder / RUN_FILE}: output_version "
            f"{was} (jaxdepth {old.get('jaxdepth_version', '?')}), this jaxdepth writes "
            f"{record.get('output_version')}), so resuming would mix two algorithms' outputs. "
            + again.format("algorithm"))
    if not per_output and sorted(old.get("inputs", [])) != sorted(record["inputs"]):
        raise RunSettingsError(
            f"{folder}: holds outputs made from other inputs ({folder / RUN_FILE}: {', '.join(old.get('inputs', []))}; "
            f"now {', '.join(record['inputs'])}). " + again.format("inputs"))


def _relative(folder: pathlib.Path, path) -> str | None:
    rel = os.path.relpath(os.path.abspath(os.fspath(path)), os.path.abspath(folder))
    return None if rel.startswith("..") or os.path.isabs(rel) else pathlib.PurePath(rel).as_posix()


def _remove_changed(folder: pathlib.Path, recorded: dict, current: dict) -> list[str]:
    """Removes every existing output of ``current`` whose recorded inputs differ (and its extra files);
    ``"<output>: <what changed>"`` for each, logged as one warning."""
    changed = []
    for rel, ident in sorted(current.items()):
        path = folder / rel
        if recorded.get(rel) == ident or not path.exists():
            continue
        _remove_with_extras(path)
        changed.append(f"{rel}: {what_changed(recorded.get(rel), ident)}")
    if changed:
        log.warning("%s: %d output%s made from inputs that changed since they were written: removed, to be "
                    "recomputed (first: %s)", folder, len(changed), "s" if len(changed) > 1 else "", changed[0])
    return changed


def _remove_with_extras(path: pathlib.Path) -> None:
    """Removes the output depth PNG ``path`` and its extra files (those that exist)."""
    from jaxdepth.batch.extras import KINDS, extra_path
    for target in [path] + [extra_path(path, kind) for kind in KINDS]:
        try:
            target.unlink(missing_ok=True)
        except OSError as err:
            raise OutputError(f"{target}: cannot remove an output whose input changed "
                              f"({err.strerror or err})") from None


def what_changed(old: dict | None, new: dict) -> str:
    """What differs between two :func:`input_identity` values, in words."""
    if not isinstance(old, dict):
        return "no input recorded for it"
    old_files = [f for f in old.get("files", []) if isinstance(f, list) and len(f) == 3]
    new_files = new.get("files", [])
    old_by_path = {f[0]: f for f in old_files}
    for f in new_files:
        was = old_by_path.get(f[0])
        if was is None:
            gone = [g[0] for g in old_files if g[0] not in {h[0] for h in new_files}]
            return f"input {gone[0]} -> {f[0]}" if gone else f"new input {f[0]}"
        if was[1] != f[1]:
            return f"{f[0]} changed size ({was[1]} -> {f[1]} bytes)"
        if was[2] != f[2]:
            return f"{f[0]} modified since (mtime_ns {was[2]} -> {f[2]})"
    if len(old_files) != len(new_files):
        return "its input files differ"
    if old.get("values") != new.get("values"):
        return "its calibration (K, T_cam_lidar) or image size changed"
    return "its recorded inputs differ"


def output_record_path(path: PathLike) -> pathlib.Path:
    """The record of a single output ``<dir>/<stem>.png``: ``<dir>/<stem>.jaxdepth_run.json`` beside it."""
    path = pathlib.Path(path)
    return path.with_name(path.stem + OUTPUT_RECORD_SUFFIX)


def claim_output_file(path: PathLike, record: dict, identity: dict, *, overwrite: bool) -> str | None:
    """A single output's run (``jaxdepth complete a.png out.png``): its record beside it, not in its folder.

    The folder of one named output may hold anything (other runs' files, other tools'), so its record is
    ``out.jaxdepth_run.json`` (:func:`output_record_path`), :func:`make_record`'s object with
    ``outputs: {"out.png": identity}``. A re-run when ``out.png`` exists: the same inputs, settings and
    output version resume (skipped); otherwise ``out.png`` and its extra files are removed, to be
    recomputed, with one warning saying what changed (one named output cannot mix two runs, so other
    settings recompute rather than refuse). An ``out.png`` without a readable record is refused, as a
    folder of depth PNGs without one is, unless ``overwrite``.

    Args:
      path: the output depth PNG. record: :func:`make_record`'s object. identity: :func:`input_identity`
        of the output. overwrite: ``--overwrite``.

    Returns:
      What changed (the output was removed), or None.

    Raises:
      RunSettingsError: ``path`` exists without a record. OutputError: the record cannot be written.
    """
    from jaxdepth.io.atomic import atomic_write_bytes

    path = pathlib.Path(path)
    side = output_record_path(path)
    old = read_record_file(side)
    new = dict(record, outputs={path.name: identity})
    changed = None
    if path.exists() and not overwrite:
        if old is None:
            raise RunSettingsError(
                f"{path}: exists, but {side.name} beside it is missing or unreadable (written by an older jaxdepth "
                "or another tool), so what made it is unknown. Re-run with --overwrite to recompute it, or write "
                "to another file")
        changed = _single_change(old, new, path.name)
        if changed:
            _remove_with_extras(path)
            log.warning("%s: made from %s: removed, to be recomputed", path, changed)
    if old is None or _without_command(new) != _without_command(old):
        atomic_write_bytes(side, (json.dumps(new, indent=1, sort_keys=True) + "\n").encode(), overwrite=True)
    return changed


def _single_change(old: dict, new: dict, name: str) -> str | None:
    """What differs between a single output's recorded run and this one, in words (None: the same)."""
    diff = differences(old.get("settings", {}), new["settings"])
    if diff:
        return "other settings (" + "; ".join(diff) + ")"
    if old.get("output_version") != new.get("output_version"):
        return f"another output version ({old.get('output_version')} -> {new.get('output_version')})"
    was = (old.get("outputs") or {}).get(name)
    if was != new["outputs"][name]:
        return "other inputs: " + what_changed(was, new["outputs"][name])
    return None


def record_folders(dst: PathLike, out_paths) -> list[pathlib.Path]:
    """The folders whose records cover ``out_paths``: ``<...>/proj_depth/<name>`` for outputs in a
    KITTI tree (``.../proj_depth/<name>/image_0X/<frame>.png``), else ``dst``; sorted, distinct."""
    dst = pathlib.Path(dst)
    folders = set()
    for path in out_paths:
        path = pathlib.Path(path)
        run = path.parent.parent
        folders.add(run if run.parent.name == "proj_depth" else dst)
    return sorted(folders) or [dst]


def find_records_below(path: PathLike, *, limit: int = 1000) -> list[tuple[pathlib.Path, dict]]:
    """The records in the tree under ``path`` (at most ``limit`` files looked at)."""
    found = []
    for i, file in enumerate(pathlib.Path(path).rglob(RUN_FILE)):
        if i >= limit:
            break
        record = read_record(file.parent)
        if record is not None:
            found.append((file, record))
    return sorted(found, key=lambda item: str(item[0]))


def summary_lines(record: dict, *, path: PathLike | None = None) -> list[str]:
    """Human-readable lines of a record for ``jaxdepth eval``."""
    settings = record.get("settings", {})
    head = f"prediction settings ({path})" if path else "prediction settings"
    main = ", ".join(f"{k} {_show(settings[k])}" for k in ("method", "distance_metric", "outlier_removal")
                     if k in settings)
    version = f"jaxdepth {record.get('jaxdepth_version', '?')} (output version {record.get('output_version', '?')})"
    lines = [f"{head}: {version}, {main}"]
    rest = {k: v for k, v in settings.items() if k not in ("method", "distance_metric", "outlier_removal")}
    if rest:
        lines.append("  " + ", ".join(f"{k}={_show(v)}" for k, v in sorted(rest.items())))
    lines.append(f"  command: {record.get('command', '?')}")
    return lines


__all__ = ["RUN_FILE", "RunSettingsError", "settings_of", "make_record", "read_record", "find_record",
           "find_records_below", "record_folders", "differences", "claim_folder", "summary_lines", "output_version",
           "file_identity", "input_identity", "what_changed", "claim_output_file", "output_record_path",
           "read_record_file", "OUTPUT_RECORD_SUFFIX"]
