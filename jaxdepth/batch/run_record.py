"""The run record of an output folder: ``jaxdepth_run.json``, and the refusal to mix settings.

Every output folder of ``jaxdepth complete`` (every dataset layout, the nuScenes job,
the local and the Ray engine) and ``complete-rig`` holds one ``jaxdepth_run.json``,
written atomically before the first output::

    {"jaxdepth_version": "0.4.0",
     "command": "jaxdepth complete raw/ out/ --distance l2",
     "inputs": ["/abs/path/raw"],
     "settings": {"method": "sgm", "distance_metric": "l2", ..., "zero_invalid": false}}

``settings`` holds every field of :class:`~jaxdepth._src.config.SGMConfig`, the method
and the options that change what is written (extra-output settings, crop, camera,
sweeps...). A re-run into the same folder:

* with the same settings resumes (finished outputs are skipped);
* with other settings, when the folder holds depth PNGs, is refused
  (:class:`RunSettingsError`, exit 1), the message
  listing each difference (``distance_metric: l1 -> l2``), unless ``overwrite``: then
  every output is recomputed and the record replaced;
* into a folder that holds depth PNGs but no record (an older jaxdepth, another tool)
  is refused too: the settings of those files are unknown, so resuming could mix two
  runs. ``overwrite`` recomputes them and writes the record.

Which extra files are requested (``--preview``, ``--validity``...) is not a setting:
adding one on a re-run fills in the missing files, as before.

KITTI trees keep each run's outputs in ``<drive>/proj_depth/<name>/``: the record lives
there (:func:`record_folders`), so two methods completed into one output root (``sgm``
and ``ip-basic`` side by side) each keep their own record.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import shlex
import sys

from jaxdepth.io.errors import OutputError, PathLike

RUN_FILE = "jaxdepth_run.json"


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
      options: further output-changing options (``crop``, ``camera``, ``sweeps``...).
    """
    settings = {"method": method}
    settings.update({f.name: _plain(getattr(config, f.name)) for f in dataclasses.fields(config)})
    if extras is not None:
        settings.update(zero_invalid=bool(extras.zero_invalid),
                        max_seed_distance_px=("sensor" if extras.max_seed_distance_px is None
                                              else float(extras.max_seed_distance_px)),
                        preview_range=None if extras.preview_range is None else list(extras.preview_range))
    settings.update({k: _plain(v) for k, v in options.items()})
    return settings


def _plain(value):
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, pathlib.PurePath):
        return str(value)
    if hasattr(value, "item") and callable(value.item):  # numpy scalars
        return value.item()
    return value


def make_record(settings: dict, *, inputs: list, command: list | None = None) -> dict:
    """The record's JSON object: version, command line (default ``sys.argv``), inputs (absolute), settings."""
    from jaxdepth import __version__
    argv = list(sys.argv if command is None else command)
    if argv:
        argv[0] = "jaxdepth"
    return {"jaxdepth_version": __version__, "command": shlex.join(str(a) for a in argv),
            "inputs": [os.path.abspath(os.fspath(p)) for p in inputs], "settings": settings}


def read_record(folder: PathLike) -> dict | None:
    """The record of ``folder`` (None when it has none or it is unreadable JSON)."""
    path = pathlib.Path(folder) / RUN_FILE
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


def claim_folder(folder: PathLike, record: dict, *, overwrite: bool) -> None:
    """Checks ``folder`` against ``record`` (module docs) and writes the record atomically.

    Args:
      folder: the output folder (created if missing).
      record: :func:`make_record`'s object.
      overwrite: the run recomputes every output (``--overwrite``): no refusal.

    Raises:
      RunSettingsError: other or unknown settings made the outputs already there.
      OutputError: the folder or its record cannot be written.
    """
    from jaxdepth.io.atomic import atomic_write_bytes

    folder = pathlib.Path(folder)
    old = read_record(folder)
    if not overwrite and folder.is_dir() and _has_outputs(folder):
        if old is not None:
            diff = differences(old.get("settings", {}), record["settings"])
            if diff:
                raise RunSettingsError(
                    f"{folder}: holds outputs of a run with other settings ({folder / RUN_FILE}): "
                    + "; ".join(diff) + ". Re-run with --overwrite to recompute them with the new settings, "
                    "or write to another folder")
        elif (folder / RUN_FILE).exists():
            raise RunSettingsError(f"{folder / RUN_FILE}: unreadable run record; its outputs' settings are unknown "
                                   "(--overwrite recomputes them)")
        else:
            raise RunSettingsError(
                f"{folder}: holds depth PNGs but no {RUN_FILE} (written by an older jaxdepth or another tool), so "
                "their settings are unknown and resuming could mix two runs. Re-run with --overwrite to recompute "
                "them, or write to another folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{folder}: cannot create output folder ({err.strerror or err})") from None
    if old is not None and old.get("settings") == record["settings"]:
        return  # same settings: resume, the first run's record stays
    atomic_write_bytes(folder / RUN_FILE, (json.dumps(record, indent=2, sort_keys=True) + "\n").encode(),
                       overwrite=True)


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
    lines = [f"{head}: jaxdepth {record.get('jaxdepth_version', '?')}, {main}"]
    rest = {k: v for k, v in settings.items() if k not in ("method", "distance_metric", "outlier_removal")}
    if rest:
        lines.append("  " + ", ".join(f"{k}={_show(v)}" for k, v in sorted(rest.items())))
    lines.append(f"  command: {record.get('command', '?')}")
    return lines


__all__ = ["RUN_FILE", "RunSettingsError", "settings_of", "make_record", "read_record", "find_record",
           "find_records_below", "record_folders", "differences", "claim_folder", "summary_lines"]
