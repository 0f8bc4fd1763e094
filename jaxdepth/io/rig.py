"""Rig JSON: the LiDAR and the cameras of one sensor setup.

Format (metres, pixels; ``p_cam = T_cam_lidar @ p_lidar``)::

    {"lidar": {"beams": 64},
     "cameras": [{"name": "CAM_FRONT", "width": 1600, "height": 900,
                  "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                  "T_cam_lidar": [[r11, r12, r13, tx], [r21, r22, r23, ty],
                                  [r31, r32, r33, tz], [0, 0, 0, 1]]}]}

``lidar`` may also give ``fov_up_deg``, ``fov_down_deg``, ``columns`` (defaults
from the beam count: 64 -> :data:`~jaxdepth._src.presets.KITTI_HDL64`, 32 ->
:data:`~jaxdepth._src.presets.NUSCENES_HDL32`, otherwise fov +2 / -24.9 degrees
and 2048 columns), ``units`` (only ``"m"``) and ``origin_m``: ``[x, y, z]``, where
the sensor sits in the frame the sweep's points are given in (metres). Leave it
out when the points are in the LiDAR's own frame (KITTI, nuScenes) or when the
library should estimate it from the sweep (:mod:`jaxdepth.io.sweep_frame`);
``T_cam_lidar`` always maps points of the sweep's frame into the camera. Cameras take exactly the five
fields above, plus an optional ``image``: the camera's image file for image-guided seeds
(``complete-rig --guidance-weight``; a path relative to the JSON file's folder, or absolute; see
:mod:`jaxdepth.io.rig_images`). Unknown fields are errors (a misspelt optional field would
otherwise be ignored silently).

Several LiDARs (see ``docs/multi_source.md``): ``lidars`` lists each LiDAR whose points the
point file holds, ``{"name", "T_points_lidar"}`` (4x4, the LiDAR's pose in the points' frame)
plus optional ``beams``, ``fov_up_deg``, ``fov_down_deg`` (left out: estimated from that LiDAR's
own points); ``columns`` names each float32 column of the point file (``x``, ``y``, ``z`` required;
``lidar``: the index into ``lidars`` of each point's LiDAR; ``ring``, ``time``, ``intensity`` other
known names; any other name is carried along and ignored). With ``lidars`` the ``lidar`` object may
be left out (it then only gives defaults: the range-image columns). A ``lidar`` column needs
``lidars``; ``lidars`` with more than one entry needs a ``lidar`` column.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
from typing import Any, Iterable

import numpy as np

from jaxdepth._src.presets import KITTI_HDL64, NUSCENES_HDL32
from jaxdepth._src.types import Camera, LidarSpec
from jaxdepth.io.atomic import atomic_write_bytes
from jaxdepth.io.calib import read_kitti_object_calib, read_kitti_raw_calib
from jaxdepth.io.checks import ROTATION_TOL, pinhole_problem, rigid_problem
from jaxdepth.io.errors import PathLike, field_error, file_error, read_input_bytes
from jaxdepth.io.kitti_layout import BENCHMARK_SIZE, benchmark_crop_offsets

#: Tolerance of the rigid-transform check: |R^T R - I| and |det R - 1|.
RIGID_TOL = ROTATION_TOL

_LIDAR_DEFAULTS = {64: KITTI_HDL64, 32: NUSCENES_HDL32}
_LIDAR_FIELDS = ("beams", "fov_up_deg", "fov_down_deg", "columns", "units", "origin_m")
_CAMERA_FIELDS = ("name", "width", "height", "K", "T_cam_lidar")
_CAMERA_OPTIONAL = ("image",)
_LIDARS_FIELDS = ("name", "T_points_lidar")
_LIDARS_OPTIONAL = ("beams", "fov_up_deg", "fov_down_deg")
#: Column names with a meaning (``columns`` may hold other names too: carried along, unused).
KNOWN_COLUMNS = ("x", "y", "z", "intensity", "lidar", "ring", "time")


class _Bad(Exception):
    """A field problem: (field path, expected, got); formatted by the caller."""

    def __init__(self, field: str, expected: str, got: object):
        super().__init__(field, expected, got)
        self.field, self.expected, self.got = field, expected, got


def default_lidar_spec(beams: int) -> LidarSpec:
    """The LidarSpec a rig with ``beams`` beams gets when it gives nothing else.

    >>> default_lidar_spec(32).columns, default_lidar_spec(16).fov_down_deg
    (1088, -24.9)
    """
    if beams in _LIDAR_DEFAULTS:
        return _LIDAR_DEFAULTS[beams]
    return LidarSpec(beams=beams, fov_up_deg=2.0, fov_down_deg=-24.9, columns=2048)


# ---------------------------------------------------------------- field checks


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _matrix(value: Any, shape: tuple[int, int], field: str) -> np.ndarray:
    """A nested list / array of plain finite numbers with the given shape -> float64."""
    rows, cols = shape
    want = f"a {rows}x{cols} matrix of finite numbers"
    if isinstance(value, np.ndarray):
        if value.shape != shape:
            raise _Bad(field, want, f"shape {value.shape}")
        if value.dtype.kind not in "fiu":
            raise _Bad(field, want, f"dtype {value.dtype}")
        out = value.astype(np.float64)
    else:
        if not isinstance(value, (list, tuple)) or len(value) != rows:
            raise _Bad(field, want, _describe(value))
        out = np.zeros(shape)
        for r, row in enumerate(value):
            if not isinstance(row, (list, tuple)) or len(row) != cols:
                raise _Bad(f"{field}[{r}]", f"a row of {cols} numbers", _describe(row))
            for c, x in enumerate(row):
                if not _is_number(x):
                    raise _Bad(f"{field}[{r}][{c}]", "a number", _describe(x))
                out[r, c] = float(x)
    if not np.all(np.isfinite(out)):
        raise _Bad(field, want, "a non-finite value")
    return out


def _describe(x: Any) -> str:
    if isinstance(x, (list, tuple)):
        return f"a list of {len(x)}"
    if isinstance(x, dict):
        return "an object"
    text = json.dumps(x) if isinstance(x, (str, bool, type(None), int, float)) else repr(x)
    return text if len(text) <= 40 else text[:37] + "..."


def _check_K(K: np.ndarray, field: str) -> None:
    problem = pinhole_problem(K)
    if problem is not None:
        raise _Bad(field, *problem)


def _check_T(T: np.ndarray, field: str) -> None:
    problem = rigid_problem(T, tol=RIGID_TOL)
    if problem is not None:
        raise _Bad(field, *problem)


def _positive_int(value: Any, field: str) -> int:
    if not _is_number(value) or not float(value).is_integer() or value < 1:
        raise _Bad(field, "a positive integer", _describe(value))
    return int(value)


def _camera_arrays(name: Any, width: Any, height: Any, K: Any, T: Any, where: str):
    if not isinstance(name, str) or not name:
        raise _Bad(f"{where}name", "a non-empty string", _describe(name))
    w = _positive_int(width, f"{where}width")
    h = _positive_int(height, f"{where}height")
    K = _matrix(K, (3, 3), f"{where}K")
    _check_K(K, f"{where}K")
    T = _matrix(T, (4, 4), f"{where}T_cam_lidar")
    _check_T(T, f"{where}T_cam_lidar")
    return name, w, h, _frozen(K), _frozen(T)


def _image_field(value: Any, field: str) -> str:
    if not isinstance(value, str) or not value:
        raise _Bad(field, "a non-empty string (the camera image's path)", _describe(value))
    return value


def _frozen(a: np.ndarray) -> np.ndarray:
    out = np.array(a, np.float32)
    out.setflags(write=False)
    return out


# ---------------------------------------------------------------- containers


@dataclasses.dataclass(frozen=True, eq=False)
class RigCamera:
    """One camera of a rig (NumPy, validated; see :meth:`as_camera` for the JAX pytree).

    Attributes:
      name: unique, non-empty camera name (``"CAM_FRONT"``, ``"image_02"``).
      width, height: image size in pixels.
      K: (3, 3) float32 pinhole intrinsics (read-only copy), positive focal
        lengths, last row (0, 0, 1).
      T_cam_lidar: (4, 4) float32 LiDAR -> camera transform (read-only copy),
        rigid: R^T R = I within 1e-3, det R = +1.
      image: optional camera image file (the rig JSON's ``image`` field, as
        written there: relative to the JSON's folder unless absolute), or None.

    Raises:
      ValueError: on construction with a field that breaks the rules above.
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    T_cam_lidar: np.ndarray
    image: str | None = None

    def __post_init__(self):
        try:
            values = _camera_arrays(self.name, self.width, self.height, self.K, self.T_cam_lidar, "")
            if self.image is not None:
                _image_field(self.image, "image")
        except _Bad as bad:
            raise ValueError(f"RigCamera: field '{bad.field}' expected {bad.expected}, got {bad.got}") from None
        for field, value in zip(_CAMERA_FIELDS, values):
            object.__setattr__(self, field, value)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RigCamera):
            return NotImplemented
        return (self.name, self.width, self.height, self.image) == (other.name, other.width, other.height,
                                                                    other.image) and \
            np.array_equal(self.K, other.K) and np.array_equal(self.T_cam_lidar, other.T_cam_lidar)

    __hash__ = None  # type: ignore[assignment]

    def as_camera(self) -> Camera:
        """The :class:`jaxdepth._src.types.Camera` pytree (K, T traced; size static)."""
        import jax.numpy as jnp

        return Camera(K=jnp.asarray(self.K), T_cam_lidar=jnp.asarray(self.T_cam_lidar),
                      height=self.height, width=self.width)


@dataclasses.dataclass(frozen=True, eq=False)
class RigLidar:
    """One LiDAR of a rig whose point file holds several LiDARs' points.

    Attributes:
      name: non-empty string.
      T_points_lidar: (4, 4) float32 rigid pose of the LiDAR in the points' frame.
      spec: its :class:`LidarSpec`, or None to estimate it from its own points.
    """

    name: str
    T_points_lidar: np.ndarray
    spec: LidarSpec | None = None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RigLidar):
            return NotImplemented
        return (self.name == other.name and self.spec == other.spec
                and np.array_equal(self.T_points_lidar, other.T_points_lidar))

    __hash__ = None  # type: ignore[assignment]


@dataclasses.dataclass(frozen=True, eq=False)
class Rig:
    """A LiDAR and its cameras.

    Attributes:
      lidar: static :class:`LidarSpec` (beams, field of view, range-image columns).
      cameras: non-empty tuple of :class:`RigCamera` with distinct names.
      lidar_origin_m: where the LiDAR sits in the sweep's frame, metres, as a
        tuple of 3 floats; None when not stated (the points' origin, or an
        estimate from the sweep, see :func:`jaxdepth.io.prepare_sweep`).
      lidar_stated: names of the ``lidar`` fields the source stated (the rest
        are defaults that an estimate from the sweep may replace).
      lidars: the rig JSON's ``lidars``: a tuple of :class:`RigLidar` (empty: one LiDAR, ``lidar``).
      columns: the rig JSON's ``columns``: the name of each float32 column of the point
        files, or None (x, y, z, then ``--point-columns``).
    """

    lidar: LidarSpec
    cameras: tuple[RigCamera, ...]
    lidar_origin_m: tuple[float, float, float] | None = None
    lidar_stated: frozenset = frozenset(("beams", "fov_up_deg", "fov_down_deg", "columns"))
    lidars: tuple = ()
    columns: tuple | None = None

    def __post_init__(self):
        if not isinstance(self.lidar, LidarSpec):
            raise ValueError(f"Rig: field 'lidar' expected a LidarSpec, got {type(self.lidar).__name__}")
        cameras = tuple(self.cameras)
        if not cameras or not all(isinstance(c, RigCamera) for c in cameras):
            raise ValueError("Rig: field 'cameras' expected a non-empty sequence of RigCamera, "
                             f"got {[type(c).__name__ for c in cameras]}")
        names = [c.name for c in cameras]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"Rig: field 'cameras' expected distinct names, got duplicates {dupes}")
        object.__setattr__(self, "cameras", cameras)
        if self.lidar_origin_m is not None:
            origin = tuple(float(x) for x in np.asarray(self.lidar_origin_m, np.float64).reshape(-1))
            if len(origin) != 3 or not all(math.isfinite(x) for x in origin):
                raise ValueError(f"Rig: field 'lidar_origin_m' expected 3 finite floats, got {self.lidar_origin_m!r}")
            object.__setattr__(self, "lidar_origin_m", origin)
        object.__setattr__(self, "lidar_stated", frozenset(self.lidar_stated))
        lidars = tuple(self.lidars)
        if not all(isinstance(x, RigLidar) for x in lidars):
            raise ValueError("Rig: field 'lidars' expected a sequence of RigLidar, "
                             f"got {[type(x).__name__ for x in lidars]}")
        object.__setattr__(self, "lidars", lidars)
        if self.columns is not None:
            object.__setattr__(self, "columns", tuple(str(c) for c in self.columns))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Rig):
            return NotImplemented
        return (self.lidar == other.lidar and self.cameras == other.cameras
                and self.lidar_origin_m == other.lidar_origin_m and self.lidars == other.lidars
                and self.columns == other.columns)

    __hash__ = None  # type: ignore[assignment]

    def camera(self, name: str) -> RigCamera:
        """The camera called ``name`` (KeyError listing the names otherwise)."""
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise KeyError(f"no camera named {name!r}; the rig has {[c.name for c in self.cameras]}")


# ---------------------------------------------------------------- JSON


def _load_json(path: pathlib.Path) -> Any:
    raw = read_input_bytes(path, expected="a JSON file")

    def no_duplicates(pairs):
        keys = [k for k, _ in pairs]
        dupes = sorted({k for k in keys if keys.count(k) > 1})
        if dupes:
            raise _Bad(dupes[0], "to appear once", "a duplicate key")
        return dict(pairs)

    try:
        return json.loads(raw.decode("utf-8"), object_pairs_hook=no_duplicates)
    except UnicodeDecodeError as exc:
        raise file_error(path, f"expected UTF-8 JSON, got undecodable bytes at offset {exc.start}") from None
    except json.JSONDecodeError as exc:
        raise file_error(path, f"invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except RecursionError:
        raise file_error(path, "invalid JSON: nested too deeply") from None
    except _Bad as bad:
        raise file_error(path, f"key '{bad.field}' appears more than once in one object") from None


def _object(value: Any, field: str, allowed: Iterable[str]) -> dict:
    if not isinstance(value, dict):
        raise _Bad(field or "(top level)", "an object", _describe(value))
    unknown = sorted(set(value) - set(allowed))
    if unknown:
        prefix = f"{field}." if field else ""
        raise _Bad(f"{prefix}{unknown[0]}", f"one of the known fields {list(allowed)}", "an unknown field")
    return value


def _number(value: Any, field: str) -> float:
    if not _is_number(value) or not math.isfinite(float(value)):
        raise _Bad(field, "a finite number", _describe(value))
    return float(value)


def _parse_origin(value: Any) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise _Bad("lidar.origin_m", "a list of 3 numbers [x, y, z] (metres)", _describe(value))
    return tuple(_number(x, f"lidar.origin_m[{i}]") for i, x in enumerate(value))


def _parse_lidar(value: Any) -> LidarSpec:
    lidar = _object(value, "lidar", _LIDAR_FIELDS)
    if "beams" not in lidar:
        raise _Bad("lidar.beams", "a positive integer (required)", "nothing")
    beams = _positive_int(lidar["beams"], "lidar.beams")
    units = lidar.get("units", "m")
    if units != "m":
        raise _Bad("lidar.units", "\"m\" (metres; unknown units)", _describe(units))
    default = default_lidar_spec(beams)
    up = _number(lidar["fov_up_deg"], "lidar.fov_up_deg") if "fov_up_deg" in lidar else default.fov_up_deg
    down = _number(lidar["fov_down_deg"], "lidar.fov_down_deg") if "fov_down_deg" in lidar else default.fov_down_deg
    columns = _positive_int(lidar["columns"], "lidar.columns") if "columns" in lidar else default.columns
    if not -90.0 <= down < up <= 90.0:
        raise _Bad("lidar.fov_up_deg", "-90 <= fov_down_deg < fov_up_deg <= 90", f"up={up:g}, down={down:g}")
    if columns < 4:
        raise _Bad("lidar.columns", "an integer >= 4", columns)
    return LidarSpec(beams=beams, fov_up_deg=up, fov_down_deg=down, columns=columns)


def _list_items(value: Any, field: str, what: str, required: tuple, optional: tuple):
    """Yields ``(i, "field[i]", object)`` for a non-empty JSON list of objects, each with its ``required`` keys."""
    if not isinstance(value, list) or not value:
        raise _Bad(field, f"a non-empty list of {what}", _describe(value))
    for i, item in enumerate(value):
        where = f"{field}[{i}]"
        doc = _object(item, where, required + optional)
        for key in required:
            if key not in doc:
                raise _Bad(f"{where}.{key}", "a field (required)", "nothing")
        yield i, where, doc


def _parse_lidars(value: Any, columns: int) -> tuple:
    out, seen = [], {}
    for i, where, doc in _list_items(value, "lidars", "LiDARs", _LIDARS_FIELDS, _LIDARS_OPTIONAL):
        name = doc["name"]
        if not isinstance(name, str) or not name:
            raise _Bad(f"{where}.name", "a non-empty string", _describe(name))
        if name in seen:
            raise _Bad(f"{where}.name", f"a unique name (lidars[{seen[name]}] is also {name!r})", _describe(name))
        seen[name] = i
        T = _matrix(doc["T_points_lidar"], (4, 4), f"{where}.T_points_lidar")
        _check_T(T, f"{where}.T_points_lidar")
        spec = None
        if "beams" in doc:
            beams = _positive_int(doc["beams"], f"{where}.beams")
            default = default_lidar_spec(beams)
            up = _number(doc["fov_up_deg"], f"{where}.fov_up_deg") if "fov_up_deg" in doc else default.fov_up_deg
            down = (_number(doc["fov_down_deg"], f"{where}.fov_down_deg") if "fov_down_deg" in doc
                    else default.fov_down_deg)
            if not -90.0 <= down < up <= 90.0:
                raise _Bad(f"{where}.fov_up_deg", "-90 <= fov_down_deg < fov_up_deg <= 90", f"up={up:g}, down={down:g}")
            spec = LidarSpec(beams=beams, fov_up_deg=up, fov_down_deg=down, columns=columns)
        elif "fov_up_deg" in doc or "fov_down_deg" in doc:
            raise _Bad(f"{where}.beams", "a positive integer (required with fov_up_deg / fov_down_deg)", "nothing")
        out.append(RigLidar(name=name, T_points_lidar=_frozen(T), spec=spec))
    return tuple(out)


def _parse_columns(value: Any) -> tuple:
    if not isinstance(value, list) or len(value) < 3:
        raise _Bad("columns", "a list of at least 3 column names (x, y, z, ...)", _describe(value))
    names = []
    for i, name in enumerate(value):
        if not isinstance(name, str) or not name:
            raise _Bad(f"columns[{i}]", "a non-empty string", _describe(name))
        if name in names:
            raise _Bad(f"columns[{i}]", "a name that appears once", _describe(name))
        names.append(name)
    for axis in ("x", "y", "z"):
        if axis not in names:
            raise _Bad("columns", f"names including {axis!r} (x, y and z are required)", _describe(value))
    return tuple(names)


def _parse_rig(doc: Any) -> Rig:
    top = _object(doc, "", ("lidar", "cameras", "lidars", "columns"))
    if "cameras" not in top:
        raise _Bad("cameras", "a field (required)", "nothing")
    if "lidar" not in top and "lidars" not in top:
        raise _Bad("lidar", "a field (required unless 'lidars' is given)", "nothing")
    lidar_doc = top.get("lidar", {"beams": 32})
    lidar = _parse_lidar(lidar_doc)
    origin = _parse_origin(lidar_doc["origin_m"]) if "origin_m" in lidar_doc else None
    stated = frozenset(k for k in ("beams", "fov_up_deg", "fov_down_deg", "columns") if k in lidar_doc) \
        if "lidar" in top else frozenset()
    lidars = _parse_lidars(top["lidars"], lidar.columns) if "lidars" in top else ()
    columns = _parse_columns(top["columns"]) if "columns" in top else None
    if columns is not None and "lidar" in columns and not lidars:
        raise _Bad("columns", "no 'lidar' column unless 'lidars' lists the LiDARs it indexes",
                   _describe(top["columns"]))
    if len(lidars) > 1 and (columns is None or "lidar" not in columns):
        raise _Bad("columns", f"a 'lidar' column saying which of the {len(lidars)} lidars measured each point",
                   "nothing" if columns is None else _describe(top["columns"]))
    cameras = []
    seen: dict[str, int] = {}
    for i, where, cam in _list_items(top["cameras"], "cameras", "cameras", _CAMERA_FIELDS, _CAMERA_OPTIONAL):
        values = _camera_arrays(*(cam[k] for k in _CAMERA_FIELDS), where=f"{where}.")
        image = _image_field(cam["image"], f"{where}.image") if "image" in cam else None
        if values[0] in seen:
            raise _Bad(f"{where}.name", f"a unique name (cameras[{seen[values[0]]}] is also {values[0]!r})",
                       _describe(values[0]))
        seen[values[0]] = i
        cameras.append(RigCamera(*values, image=image))
    return Rig(lidar=lidar, cameras=tuple(cameras), lidar_origin_m=origin, lidar_stated=stated, lidars=lidars,
               columns=columns)


def read_rig_json(path: PathLike) -> Rig:
    """Reads and validates a rig JSON file (format in the module docstring).

    Returns:
      A :class:`Rig` with float32 K / T_cam_lidar.

    Raises:
      InputError: missing or invalid JSON, a missing or unknown field, wrong
        shapes or types, non-finite numbers, a non-positive focal length, a
        ``T_cam_lidar`` that is not rigid (R^T R = I within 1e-3, det +1, last
        row 0 0 0 1), duplicate camera names, ``lidar.units`` other than "m".
        The message names the file and the field path, e.g.
        ``rig.json: field 'cameras[2].T_cam_lidar' expected a rigid transform ...``.
    """
    path = pathlib.Path(path)
    doc = _load_json(path)
    try:
        return _parse_rig(doc)
    except _Bad as bad:
        raise field_error(path, bad.field, bad.expected, bad.got) from None


def _num(x: float) -> str:
    """Shortest text that reads back to the same float32 (valid JSON)."""
    text = str(np.float32(x))
    return "0.0" if text == "-0.0" else text


def _matrix_text(a: np.ndarray, indent: str) -> str:
    rows = [indent + "  [" + ", ".join(_num(x) for x in row) + "]" for row in a]
    return "[\n" + ",\n".join(rows) + "\n" + indent + "]"


def rig_to_json_text(rig: Rig) -> str:
    """The JSON text :func:`write_rig_json` writes (deterministic; one matrix row per line)."""
    spec = rig.lidar
    fields = {"beams": int(spec.beams), "fov_up_deg": float(spec.fov_up_deg),
              "fov_down_deg": float(spec.fov_down_deg), "columns": int(spec.columns), "units": "m"}
    if rig.lidar_origin_m is not None:
        fields["origin_m"] = [float(x) for x in rig.lidar_origin_m]
    lidar = json.dumps(fields)
    cams = []
    for cam in rig.cameras:
        ind = "      "
        image = "" if cam.image is None else f"{ind}\"image\": {json.dumps(cam.image)},\n"
        cams.append("    {\n"
                    f"{ind}\"name\": {json.dumps(cam.name)},\n"
                    f"{image}"
                    f"{ind}\"width\": {int(cam.width)},\n"
                    f"{ind}\"height\": {int(cam.height)},\n"
                    f"{ind}\"K\": {_matrix_text(cam.K, ind)},\n"
                    f"{ind}\"T_cam_lidar\": {_matrix_text(cam.T_cam_lidar, ind)}\n"
                    "    }")
    extra = ""
    if rig.lidars:
        items = []
        for lid in rig.lidars:
            spec = "" if lid.spec is None else (f", \"beams\": {int(lid.spec.beams)}, \"fov_up_deg\": "
                                                f"{float(lid.spec.fov_up_deg)}, \"fov_down_deg\": "
                                                f"{float(lid.spec.fov_down_deg)}")
            items.append(f"    {{\"name\": {json.dumps(lid.name)}{spec},\n      \"T_points_lidar\": "
                         f"{_matrix_text(np.asarray(lid.T_points_lidar, np.float64), '      ')}}}")
        extra += ",\n  \"lidars\": [\n" + ",\n".join(items) + "\n  ]"
    if rig.columns is not None:
        extra += ",\n  \"columns\": " + json.dumps(list(rig.columns))
    return ("{\n  \"lidar\": " + lidar + ",\n  \"cameras\": [\n" + ",\n".join(cams) + "\n  ]" + extra
            + "\n}\n")


def write_rig_json(path: PathLike, rig: Rig, *, overwrite: bool = True) -> pathlib.Path:
    """Writes ``rig`` as JSON atomically; :func:`read_rig_json` reads back an equal Rig.

    Raises:
      ValueError: ``rig`` is not a :class:`Rig`.
      OutputError: the file cannot be written (see :func:`atomic_write_bytes`).
    """
    if not isinstance(rig, Rig):
        raise ValueError(f"write_rig_json: field 'rig' expected a Rig, got {type(rig).__name__}")
    return atomic_write_bytes(path, rig_to_json_text(rig).encode("utf-8"), overwrite=overwrite)


# ---------------------------------------------------------------- converters


def rig_from_kitti_raw(cam_to_cam: PathLike, velo_to_cam: PathLike, *, cameras: Iterable[int] = (2, 3),
                       crop: bool = False) -> Rig:
    """A rig from KITTI raw calibration files (see :func:`~jaxdepth.io.calib.read_kitti_raw_calib`).

    Args:
      cam_to_cam, velo_to_cam: ``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``.
      cameras: KITTI camera indices (0, 1 grey; 2, 3 colour); named ``image_0i``.
      crop: describe the 352 x 1216 benchmark crop instead of the full frame
        (principal point shifted as :func:`~jaxdepth.io.kitti_layout.crop_to_benchmark`).

    Returns:
      A :class:`Rig` with the HDL-64E preset :data:`KITTI_HDL64`.
    """
    indices = tuple(cameras)
    if not indices or any(isinstance(i, bool) or i not in (0, 1, 2, 3) for i in indices):
        raise ValueError(f"rig_from_kitti_raw: field 'cameras' expected KITTI indices in 0..3, got {indices}")
    calib = read_kitti_raw_calib(cam_to_cam, velo_to_cam)
    cams = calib["cameras"]
    return Rig(lidar=KITTI_HDL64, cameras=tuple(
        _kitti_camera(i, cams[i], cams[i]["width"], cams[i]["height"], crop=crop, path=cam_to_cam,
                      size_field=f"S_rect_0{i}") for i in indices))


def rig_from_kitti_object(calib_path: PathLike, *, width: int, height: int, cameras: Iterable[int] = (2,),
                          crop: bool = False) -> Rig:
    """A rig from one KITTI 3D-object calibration file (``training/calib/000000.txt``).

    Args:
      calib_path: the frame's calibration (``P0``..``P3``, ``R0_rect``,
        ``Tr_velo_to_cam``; see :func:`~jaxdepth.io.calib.read_kitti_object_calib`).
      width, height: image size in pixels (the object format does not store it: take it
        from the frame's ``image_2/<frame>.png``; KITTI's are 1224-1242 x 370-375).
      cameras: KITTI camera indices (2: ``image_2``, the left colour camera; 3: ``image_3``);
        named ``image_0i`` as in :func:`rig_from_kitti_raw`.
      crop: describe the 352 x 1216 benchmark crop (bottom rows, centre columns) instead
        of the full frame.

    Returns:
      A :class:`Rig` with the HDL-64E preset :data:`KITTI_HDL64`; ``K`` of camera i is
      the left 3x3 block of ``Pi``, ``T_cam_lidar`` as documented in :mod:`jaxdepth.io.calib`.

    Raises:
      ValueError: bad ``cameras``.
      InputError: a bad calibration file, or (named ``image``) a non-positive size or one
        smaller than the crop.
    """
    indices = tuple(cameras)
    if not indices or any(isinstance(i, bool) or i not in (0, 1, 2, 3) for i in indices):
        raise ValueError(f"rig_from_kitti_object: field 'cameras' expected KITTI indices in 0..3, got {indices}")
    calib = read_kitti_object_calib(calib_path)
    if isinstance(width, bool) or isinstance(height, bool) or int(width) < 1 or int(height) < 1:
        raise field_error(calib_path, "image", "a positive width and height", f"{width}x{height}")
    width, height = int(width), int(height)
    return Rig(lidar=KITTI_HDL64, cameras=tuple(
        _kitti_camera(i, calib["cameras"][i], width, height, crop=crop, path=calib_path, size_field="image")
        for i in indices))


def _kitti_camera(index: int, calib_camera: dict, width: int, height: int, *, crop: bool, path: PathLike,
                  size_field: str) -> RigCamera:
    """KITTI camera ``index`` as ``image_0<index>``, full frame or the 352 x 1216 benchmark crop."""
    K = np.array(calib_camera["K"], np.float64)
    if crop:
        try:
            top, left = benchmark_crop_offsets(height, width)
        except ValueError:
            raise field_error(path, size_field, f"an image of at least {BENCHMARK_SIZE[1]}x"
                              f"{BENCHMARK_SIZE[0]} for crop=True", f"{width}x{height}") from None
        K[0, 2] -= left
        K[1, 2] -= top
        height, width = BENCHMARK_SIZE
    return RigCamera(f"image_0{index}", width, height, K, calib_camera["T_cam_lidar"])


def rig_from_nuscenes_calibration(path: PathLike, *, width: int = 1600, height: int = 900) -> Rig:
    """A rig from a nuScenes calibration JSON (``{"cameras": {NAME: {"cam2img", "lidar2cam"}}}``).

    Args:
      path: JSON with, per camera, ``cam2img`` (3x3 K, or 4x4 with K in the top
        left and identity elsewhere) and ``lidar2cam`` (4x4 LiDAR -> camera).
        Other keys are ignored.
      width, height: image size (nuScenes cameras: 1600 x 900).

    Returns:
      A :class:`Rig` with the HDL-32E preset :data:`NUSCENES_HDL32`; cameras in
      file order.

    Raises:
      InputError: missing or malformed fields, named like ``cameras.CAM_FRONT.cam2img``.
    """
    path = pathlib.Path(path)
    doc = _load_json(path)
    try:
        if not isinstance(doc, dict) or not isinstance(doc.get("cameras"), dict) or not doc["cameras"]:
            raise _Bad("cameras", "an object mapping camera names to calibrations", _describe(
                doc.get("cameras") if isinstance(doc, dict) else doc))
        out = []
        for name, entry in doc["cameras"].items():
            where = f"cameras.{name}"
            if not isinstance(entry, dict):
                raise _Bad(where, "an object", _describe(entry))
            for key in ("cam2img", "lidar2cam"):
                if key not in entry:
                    raise _Bad(f"{where}.{key}", "a field (required)", "nothing")
            k_value = entry["cam2img"]
            if isinstance(k_value, list) and len(k_value) == 4:
                K4 = _matrix(k_value, (4, 4), f"{where}.cam2img")
                if np.any(K4[3] != [0, 0, 0, 1]) or np.any(K4[:3, 3] != 0):
                    raise _Bad(f"{where}.cam2img", "a 3x3 K or a 4x4 [[K, 0], [0, 1]]", "another 4x4 matrix")
                K = K4[:3, :3]
            else:
                K = _matrix(k_value, (3, 3), f"{where}.cam2img")
            _check_K(K, f"{where}.cam2img")
            T = _matrix(entry["lidar2cam"], (4, 4), f"{where}.lidar2cam")
            _check_T(T, f"{where}.lidar2cam")
            values = _camera_arrays(name, width, height, K, T, where=f"{where}.")
            out.append(RigCamera(*values))
    except _Bad as bad:
        raise field_error(path, bad.field, bad.expected, bad.got) from None
    return Rig(lidar=NUSCENES_HDL32, cameras=tuple(out))


__all__ = ["Rig", "RigCamera", "RigLidar", "KNOWN_COLUMNS", "read_rig_json", "write_rig_json", "rig_to_json_text", "rig_from_kitti_raw",
           "rig_from_kitti_object", "rig_from_nuscenes_calibration", "default_lidar_spec", "RIGID_TOL"]
