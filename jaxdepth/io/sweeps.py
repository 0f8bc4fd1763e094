"""Point files of several LiDARs and several sweeps -> one :class:`~jaxdepth.io.sources.SourceCloud`.

Two inputs, both named fields so that any tool can write them (``docs/multi_source.md``):

* one point file whose columns the rig JSON names (``columns``; ``lidar`` indexes the rig's
  ``lidars``): :func:`read_point_file_cloud`;
* a *sweeps JSON*, in place of one point file::

      {"sweeps": [{"file": "000009.bin", "T_ref_sweep": [...], "columns": ["x", "y", "z", "intensity"]},
                  {"file": "000010.bin", "T_ref_sweep": [[1, 0, 0, 0], ...]}]}

  ``file`` is relative to the JSON's folder (or absolute); ``T_ref_sweep`` (4x4) maps that
  sweep's points' frame into the reference sweep's points' frame (the frame the rig's
  ``T_cam_lidar`` maps from); the reference sweep is the one whose pose is the identity
  (exactly one); ``columns`` overrides the rig's for that file. The sweeps are listed in time
  order, so a sweep's number is its signed position from the reference's (negative = earlier,
  as every reader numbers sweeps). :func:`read_sweeps_cloud`.

Sources. With the rig's ``lidars``, every (sweep, LiDAR) pair is a source posed at
``T_ref_sweep @ T_points_lidar``; without them each sweep is one source posed at
``T_ref_sweep`` moved to ``lidar.origin_m`` (when the rig states it). A source's LidarSpec is
the one the rig states (``lidars[i].beams`` ..., or the ``lidar`` object's when it states
``beams``), else None: estimated from its own points.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np

from jaxdepth._src.poses import apply_pose
from jaxdepth.io.errors import PathLike, field_error, file_error, read_input_bytes
from jaxdepth.io.points import infer_point_columns, read_points, ring_column
from jaxdepth.io.sources import SourceCloud, rigid_pose_problem

_SWEEP_FIELDS = ("file", "T_ref_sweep")
_SWEEP_OPTIONAL = ("columns",)


@dataclasses.dataclass(frozen=True)
class SweepEntry:
    """One sweep of a sweeps JSON: its file (resolved), pose in the reference frame, optional columns,
    and its signed position in the list from the reference sweep (``sweep``: -1 the one listed just before)."""

    file: pathlib.Path
    T_ref_sweep: np.ndarray
    columns: tuple | None = None
    sweep: int = 0


def is_sweeps_json(path: PathLike) -> bool:
    """True when ``path`` names a ``.json`` file (a sweeps JSON rather than a point file)."""
    return pathlib.Path(path).suffix.lower() == ".json"


def read_sweeps_json(path: PathLike) -> list:
    """Reads and checks a sweeps JSON (format in the module docstring); the reference sweep first.

    Returns:
      list of :class:`SweepEntry`, the reference (identity pose) first, then the others in file order;
      ``sweep`` is each one's list position minus the reference's (the list is in time order).

    Raises:
      InputError naming the file and the field: invalid JSON, a missing or unknown field, a
      ``T_ref_sweep`` that is not a rigid 4x4 pose, a ``file`` that does not exist, no sweep or more
      than one with the identity pose.
    """
    path = pathlib.Path(path)
    raw = read_input_bytes(path, expected="a sweeps JSON file")
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise file_error(path, f"invalid JSON ({exc})") from None
    if not isinstance(doc, dict) or set(doc) != {"sweeps"}:
        raise field_error(path, "sweeps", "the only top-level field, a list of sweeps",
                          f"fields {sorted(doc) if isinstance(doc, dict) else type(doc).__name__}")
    items = doc["sweeps"]
    if not isinstance(items, list) or not items:
        raise field_error(path, "sweeps", "a non-empty list of {\"file\", \"T_ref_sweep\"} objects", repr(items)[:40])
    entries, reference = [], []
    for i, item in enumerate(items):
        where = f"sweeps[{i}]"
        if not isinstance(item, dict):
            raise field_error(path, where, "an object", type(item).__name__)
        unknown = sorted(set(item) - set(_SWEEP_FIELDS + _SWEEP_OPTIONAL))
        if unknown:
            raise field_error(path, f"{where}.{unknown[0]}", f"one of {list(_SWEEP_FIELDS + _SWEEP_OPTIONAL)}",
                              "an unknown field")
        for key in _SWEEP_FIELDS:
            if key not in item:
                raise field_error(path, f"{where}.{key}", "a field (required)", "nothing")
        if not isinstance(item["file"], str) or not item["file"]:
            raise field_error(path, f"{where}.file", "a non-empty path string", repr(item["file"])[:40])
        file = pathlib.Path(item["file"])
        file = file if file.is_absolute() else path.parent / file
        if not file.is_file():
            raise field_error(path, f"{where}.file", "an existing point file", f"{item['file']!r} (not found: {file})")
        try:
            T = np.asarray(item["T_ref_sweep"], np.float64)
        except (TypeError, ValueError):
            T = np.full((1,), np.nan)
        problem = rigid_pose_problem(T) if T.shape == (4, 4) else f"shape {T.shape}, expected (4, 4)"
        if problem is not None:
            raise field_error(path, f"{where}.T_ref_sweep", "a rigid 4x4 pose", problem)
        columns = None
        if "columns" in item:
            columns = item["columns"]
            if (not isinstance(columns, list) or not all(isinstance(c, str) and c for c in columns)
                    or not {"x", "y", "z"} <= set(columns) or len(set(columns)) != len(columns)):
                raise field_error(path, f"{where}.columns", "a list of unique column names including x, y, z",
                                  repr(columns)[:40])
            columns = tuple(columns)
        entries.append(SweepEntry(file=file, T_ref_sweep=T, columns=columns))
        if np.allclose(T, np.eye(4), atol=1e-9):
            reference.append(i)
    if len(reference) != 1:
        raise field_error(path, "sweeps", "exactly one sweep with the identity T_ref_sweep (the reference sweep)",
                          f"{len(reference)}")
    r = reference[0]
    entries = [dataclasses.replace(e, sweep=i - r) for i, e in enumerate(entries)]
    return [entries[r]] + entries[:r] + entries[r + 1:]


def _columns_of(file: pathlib.Path, names, point_columns):
    """(column count, names or None) of one point file."""
    if names is not None:
        return len(names), tuple(names)
    return infer_point_columns(file, point_columns), None


def _named(values: np.ndarray, names, name: str):
    """The column called ``name`` of (N, columns - 3) ``values`` (x, y, z removed), or None."""
    if names is None or name not in names:
        return None
    rest = [n for n in names if n not in ("x", "y", "z")]
    return values[:, rest.index(name)]


def _xyz(points: np.ndarray, extra: np.ndarray, names) -> tuple:
    """(N, 3) x, y, z and the (N, k) other columns in the order of ``names`` (x, y, z anywhere)."""
    if names is None or tuple(names[:3]) == ("x", "y", "z"):
        return points, extra
    full = np.concatenate([points, extra], axis=1)
    xyz = full[:, [names.index(a) for a in ("x", "y", "z")]]
    rest = full[:, [i for i, n in enumerate(names) if n not in ("x", "y", "z")]]
    return xyz, rest


def _sources_of_file(file, names, point_columns, rig, T_ref_sweep, sweep: int, where: str, json_path):
    """(points_ref, source_local, ring, [(T_ref_source, spec, name)]) of one point file."""
    count, names = _columns_of(file, names, point_columns)
    # Named columns: the plausibility check runs here with the named ring / intensity columns (the
    # reader's own check would take a 5th column for nuScenes' ring).
    points, extra = read_points(file, columns=count, force=names is not None, drop_far=names is None)
    points, extra = _xyz(points, extra, names)
    if names is not None:  # far points dropped once x, y, z are known
        from jaxdepth.io.plausibility import drop_far_points
        points = drop_far_points(points, path=file)
    # Unnamed columns: the ring of a 5-column sweep as the single-file path reads it (ring_column).
    ring_raw = _named(extra, names, "ring") if names is not None else ring_column(extra, count)
    # A ring index is a laser of one LiDAR: with a lidar column its elevation is judged about that
    # LiDAR's own origin and axes (below), not about the points' origin.
    per_lidar_rings = bool(rig.lidars) and ring_raw is not None and _named(extra, names, "lidar") is not None
    if names is not None:
        from jaxdepth.io.plausibility import check_sweep
        check_sweep(points, path=file, columns=count, intensity=_named(extra, names, "intensity"),
                    ring=None if per_lidar_rings else ring_raw)
    ring = None if ring_raw is None else np.where(np.isfinite(ring_raw), ring_raw, -1).astype(np.int32)
    pts = apply_pose(T_ref_sweep, points)
    if rig.lidars:
        lidar = _named(extra, names, "lidar")
        if lidar is None:
            if len(rig.lidars) > 1:
                raise file_error(file, f"expected a 'lidar' column (the rig lists {len(rig.lidars)} lidars), "
                                       f"got columns {list(names) if names else count}")
            lidar = np.zeros(points.shape[0], np.float32)
        finite = np.isfinite(lidar)
        bad = finite & ((lidar != np.round(lidar)) | (lidar < 0) | (lidar >= len(rig.lidars)))
        if np.any(bad):
            value = lidar[bad][0]
            raise field_error(file, "lidar", f"an index into the rig's {len(rig.lidars)} lidars "
                              f"(0..{len(rig.lidars) - 1}){where}", f"{value:g} (point {int(np.argmax(bad))})")
        local = np.where(finite, lidar, 0).astype(np.int32)
        if per_lidar_rings:
            from jaxdepth.io.plausibility import check_sweep
            for j, lid in enumerate(rig.lidars):
                mine = finite & (local == j)
                T = np.linalg.inv(np.asarray(lid.T_points_lidar, np.float64))
                check_sweep(points[mine].astype(np.float64) @ T[:3, :3].T + T[:3, 3], path=file, columns=count,
                            ring=ring_raw[mine])
        srcs = [(T_ref_sweep @ np.asarray(lid.T_points_lidar, np.float64), lid.spec, f"{lid.name}@{sweep}")
                for lid in rig.lidars]
        return pts, local, ring, srcs
    mount = np.eye(4)
    if rig.lidar_origin_m is not None:
        mount[:3, 3] = rig.lidar_origin_m
    spec = rig.lidar if "beams" in rig.lidar_stated else None
    return pts, np.zeros(points.shape[0], np.int32), ring, [(T_ref_sweep @ mount, spec, f"lidar@{sweep}")]


def _cloud(parts, path, offsets=(0,)) -> SourceCloud:
    """One SourceCloud of the parts of :func:`_sources_of_file`; ``offsets``: each part's signed sweep."""
    points, source, rings, poses, specs, names, sweeps = [], [], [], [], [], [], []
    any_ring = any(p[2] is not None for p in parts)
    for k, (pts, local, ring, srcs) in enumerate(parts):
        points.append(pts)
        source.append(local + len(poses))
        rings.append(ring if ring is not None else np.full(pts.shape[0], -1, np.int32))
        for T, spec, name in srcs:
            poses.append(T)
            specs.append(spec)
            names.append(name)
            sweeps.append(offsets[k])
    return SourceCloud(points=np.concatenate(points), source=np.concatenate(source).astype(np.int32),
                       T_ref_source=np.stack(poses), lidars=tuple(specs), sweep=np.asarray(sweeps, np.int32),
                       names=tuple(names), ring=np.concatenate(rings) if any_ring else None, path=str(path))


def read_point_file_cloud(path: PathLike, rig, *, point_columns: int | None = None) -> SourceCloud:
    """One point file as a SourceCloud: one source per LiDAR of ``rig.lidars`` (or one source).

    Columns: ``rig.columns`` when given, else ``point_columns`` / inferred (x, y, z first).

    Raises:
      InputError naming the file: unreadable points, a ``lidar`` value that is not an index into
      ``rig.lidars`` (field ``lidar``), a missing ``lidar`` column with several lidars.
    """
    path = pathlib.Path(path)
    part = _sources_of_file(path, rig.columns, point_columns, rig, np.eye(4), 0, "", path)
    return _cloud([part], path)


def read_sweeps_cloud(path: PathLike, rig, *, point_columns: int | None = None) -> SourceCloud:
    """Every sweep of a sweeps JSON as a SourceCloud in the reference sweep's frame (sweep 0).

    Each file's columns: its entry's ``columns``, else ``rig.columns``, else ``point_columns`` /
    inferred. Raises InputError as :func:`read_sweeps_json` and :func:`read_point_file_cloud`.
    """
    path = pathlib.Path(path)
    parts = []
    entries = read_sweeps_json(path)
    for entry in entries:
        names = entry.columns if entry.columns is not None else rig.columns
        parts.append(_sources_of_file(entry.file, names, point_columns, rig, entry.T_ref_sweep, entry.sweep,
                                      f" (sweep {entry.file.name} of {path})", path))
    return _cloud(parts, path, [entry.sweep for entry in entries])


__all__ = ["SweepEntry", "is_sweeps_json", "read_sweeps_json", "read_point_file_cloud", "read_sweeps_cloud"]
