"""KITTI calibration text files and plain intrinsics files.

Readers return float32 NumPy arrays; the arithmetic that combines matrices is
done in float64 and rounded once at the end.

Conventions (as in :mod:`jaxdepth._src.geometry`): ``p_cam = T_cam_lidar @ p_lidar``;
``K`` is the (3, 3) pinhole matrix of a *rectified* camera. KITTI gives each
rectified camera ``i`` as a (3, 4) projection ``P_rect_0i = K_i [I | t_i]``
acting on points in the rectified frame of camera 0, so

    T_cam_i_lidar = [I | t_i] @ R_rect_00 @ [R | T]_velo_to_cam,   t_i = K_i^-1 P_rect_0i[:, 3]

and ``K_i @ T_cam_i_lidar[:3] == P_rect_0i @ R_rect_00 @ [R | T]_velo_to_cam``:
projecting with ``(K_i, T_cam_i_lidar)`` is exactly KITTI's official projection.
"""

from __future__ import annotations

import pathlib
from typing import Any

import numpy as np

from jaxdepth._src.poses import rigid as _rigid
from jaxdepth.io.checks import ROTATION_TOL, pinhole_problem, rotation_problem  # noqa: F401 (ROTATION_TOL: public name)
from jaxdepth.io.errors import PathLike, field_error, file_error, read_input_bytes

#: Tolerance of the rotation checks (KITTI prints 7 significant digits).


def _read_text(path: pathlib.Path) -> str:
    data = read_input_bytes(path, expected="a text file")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise file_error(path, f"expected a UTF-8 text file, got undecodable bytes at offset {exc.start}") from None


def _require_line_end(path: pathlib.Path, text: str) -> str:
    """``text``, refused when its last line has no line end: a file cut inside its last number
    (``-2.717806e-01`` -> ``-2.7``) would otherwise read as a different, valid value."""
    if text.strip() and not text.endswith(("\n", "\r")):
        raise file_error(path, "the last line has no line end: the file seems cut short (a truncated copy?); "
                               "add a line end if it is complete")
    return text


def _parse_kv(path: pathlib.Path) -> dict[str, str]:
    """``key: value ...`` lines -> {key: value text}; blank lines are skipped; the last line must end
    with a line end (:func:`_require_line_end`)."""
    fields: dict[str, str] = {}
    for lineno, line in enumerate(_require_line_end(path, _read_text(path)).splitlines(), start=1):
        if not line.strip():
            continue
        key, sep, value = line.partition(":")
        key = key.strip()
        if not sep or not key:
            raise file_error(path, f"line {lineno}: expected 'key: values', got {line.strip()[:40]!r}")
        if key in fields:
            raise file_error(path, f"line {lineno}: field '{key}' appears twice")
        fields[key] = value
    return fields


def _parse_floats(path: pathlib.Path, field: str, text: str, count: int) -> np.ndarray:
    tokens = text.replace(",", " ").split()
    values = []
    for token in tokens:
        try:
            values.append(float(token))
        except ValueError:
            raise field_error(path, field, f"{count} floats", f"non-number {token[:20]!r}") from None
    if len(values) != count:
        raise field_error(path, field, f"{count} floats", len(values))
    array = np.asarray(values, np.float64)
    if not np.all(np.isfinite(array)):
        raise field_error(path, field, f"{count} finite floats", f"{array[~np.isfinite(array)][0]}")
    return array


def _floats(path: pathlib.Path, fields: dict[str, str], key: str, count: int) -> np.ndarray:
    if key not in fields:
        raise file_error(path, f"missing field '{key}' (expected {count} floats)")
    return _parse_floats(path, key, fields[key], count)


def _check_K(path: pathlib.Path, field: str, K: np.ndarray) -> None:
    problem = pinhole_problem(K)
    if problem is not None:
        raise field_error(path, field, *problem)


def _check_rotation(path: pathlib.Path, field: str, R: np.ndarray) -> None:
    problem = rotation_problem(R)
    if problem is not None:
        raise field_error(path, field, *problem)


def _split_P(path: pathlib.Path, field: str, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3, 4) rectified projection -> (K (3, 3), t (3,)) with P = K [I | t]."""
    K = P[:, :3]
    _check_K(path, field, K)
    return K, np.linalg.solve(K, P[:, 3])


def _cameras(path: pathlib.Path, P: dict[int, np.ndarray], names: dict[int, str], R_rect: np.ndarray,
             T_velo: np.ndarray, sizes: dict[int, tuple[int, int] | tuple[None, None]]) -> dict[str, Any]:
    R_rect4 = _rigid(R_rect, np.zeros(3))
    cams: dict[int, dict[str, Any]] = {}
    centres = {}
    for i in sorted(P):
        K, t = _split_P(path, names[i], P[i])
        T = _rigid(np.eye(3), t) @ R_rect4 @ T_velo
        width, height = sizes[i]
        cams[i] = {"K": K.astype(np.float32), "T_cam_lidar": T.astype(np.float32), "width": width, "height": height}
        centres[i] = -T[:3, :3].T @ T[:3, 3]  # camera centre in the LiDAR frame
    return {
        "cameras": cams,
        "baseline_m": float(np.linalg.norm(centres[2] - centres[3])),
        "baseline_gray_m": float(np.linalg.norm(centres[0] - centres[1])),
        "R_rect_00": R_rect.astype(np.float32),
        "T_cam0_unrect_lidar": T_velo.astype(np.float32),
    }


def read_intrinsics_txt(path: PathLike) -> np.ndarray:
    """Reads a KITTI depth-completion intrinsics file (9 numbers, row-major K).

    Args:
      path: text file with the 9 entries of K separated by white space (and/or
        commas) on one or several lines, as in ``val_selection_cropped/intrinsics/*.txt``.

    Returns:
      (3, 3) float32 K in pixels.

    Raises:
      InputError: missing file, not 9 numbers, non-finite values, non-positive
        focal length, or not a pinhole matrix (``K[1, 0] != 0`` or last row not
        ``(0, 0, 1)``, which :func:`jaxdepth._src.geometry.project_pixels` assumes).
    """
    path = pathlib.Path(path)
    K = _parse_floats(path, "K", _read_text(path), 9).reshape(3, 3)
    _check_K(path, "K", K)
    return K.astype(np.float32)


def read_extrinsic_txt(path: PathLike) -> np.ndarray:
    """Reads a LiDAR -> camera extrinsic: 12 (3 x 4) or 16 (4 x 4) numbers, row major.

    Args:
      path: text file with the numbers separated by white space and/or commas,
        on one or several lines; ``p_cam = T @ p_lidar``.

    Returns:
      (4, 4) float32 rigid transform.

    A 3 x 4 file must end with a line end (a file cut inside its last number, t_z,
    would read as another valid value).

    Raises:
      InputError: missing file, not 12 or 16 numbers, non-finite values, a
        rotation part that is not a rotation, or a 4 x 4 whose last row is not
        (0, 0, 0, 1). The message names the file and the field.
    """
    path = pathlib.Path(path)
    text = _read_text(path)
    count = len(text.replace(",", " ").split())
    if count == 12:  # the last number is t_z: a cut inside it would read as another value
        _require_line_end(path, text)
    if count not in (12, 16):
        raise field_error(path, "T_cam_lidar", "12 (3x4) or 16 (4x4) numbers, row major", f"{count} numbers")
    values = _parse_floats(path, "T_cam_lidar", text, count)
    T = np.eye(4)
    T[:3] = values[:12].reshape(3, 4)
    if count == 16 and np.max(np.abs(values[12:] - [0.0, 0.0, 0.0, 1.0])) > 1e-6:
        raise field_error(path, "T_cam_lidar", "last row (0, 0, 0, 1)", values[12:].tolist())
    _check_rotation(path, "T_cam_lidar", T[:3, :3])
    return T.astype(np.float32)


def read_kitti_raw_calib(cam_to_cam_path: PathLike, velo_to_cam_path: PathLike) -> dict[str, Any]:
    """Reads KITTI raw ``calib_cam_to_cam.txt`` + ``calib_velo_to_cam.txt``.

    Args:
      cam_to_cam_path: needs ``R_rect_00`` and, for cameras i = 0..3,
        ``P_rect_0i`` (12 floats) and ``S_rect_0i`` (width height).
      velo_to_cam_path: needs ``R`` (9 floats) and ``T`` (3 floats), the LiDAR
        -> unrectified camera 0 transform.

    Returns:
      A dict with

      - ``"cameras"``: ``{i: {"K": (3, 3) float32, "T_cam_lidar": (4, 4) float32,
        "width": int, "height": int}}`` for i = 0, 1 (grey) and 2, 3 (colour);
        ``K`` is the left 3x3 block of ``P_rect_0i``, the size comes from
        ``S_rect_0i``, ``T_cam_lidar`` is given in the module docstring;
      - ``"baseline_m"``: float, distance between the centres of cameras 2 and 3
        (the colour stereo pair); ``"baseline_gray_m"``: cameras 0 and 1;
      - ``"R_rect_00"``: (3, 3) float32; ``"T_cam0_unrect_lidar"``: (4, 4) float32
        ``[R | T]`` of the velo-to-cam file.

    Raises:
      InputError: a file is missing, a field is missing or has the wrong number
        of floats, a value is not finite, a focal length is not positive, or
        ``R`` / ``R_rect_00`` is not a rotation. The message names file and field.
    """
    c2c = pathlib.Path(cam_to_cam_path)
    v2c = pathlib.Path(velo_to_cam_path)
    fc = _parse_kv(c2c)
    fv = _parse_kv(v2c)
    R = _floats(v2c, fv, "R", 9).reshape(3, 3)
    _check_rotation(v2c, "R", R)
    T = _floats(v2c, fv, "T", 3)
    R_rect = _floats(c2c, fc, "R_rect_00", 9).reshape(3, 3)
    _check_rotation(c2c, "R_rect_00", R_rect)
    P, names, sizes = {}, {}, {}
    for i in range(4):
        names[i] = f"P_rect_0{i}"
        P[i] = _floats(c2c, fc, names[i], 12).reshape(3, 4)
        size = _floats(c2c, fc, f"S_rect_0{i}", 2)
        if np.any(size < 1) or np.any(size != np.round(size)):
            raise field_error(c2c, f"S_rect_0{i}", "a positive integer width and height", size.tolist())
        sizes[i] = (int(size[0]), int(size[1]))
    return _cameras(c2c, P, names, R_rect, _rigid(R, T), sizes)


def read_kitti_object_calib(path: PathLike) -> dict[str, Any]:
    """Reads a KITTI 3D-object calibration file (``training/calib/000000.txt``).

    Args:
      path: needs ``P0``..``P3`` (12 floats each), ``R0_rect`` (9) and
        ``Tr_velo_to_cam`` (12, row-major 3x4).

    Returns:
      The same dict as :func:`read_kitti_raw_calib`, except that ``"width"`` and
      ``"height"`` are ``None`` (the object format does not store image sizes).

    Raises:
      InputError: as :func:`read_kitti_raw_calib`.
    """
    path = pathlib.Path(path)
    fields = _parse_kv(path)
    Tr = _floats(path, fields, "Tr_velo_to_cam", 12).reshape(3, 4)
    _check_rotation(path, "Tr_velo_to_cam", Tr[:, :3])
    R_rect = _floats(path, fields, "R0_rect", 9).reshape(3, 3)
    _check_rotation(path, "R0_rect", R_rect)
    P = {i: _floats(path, fields, f"P{i}", 12).reshape(3, 4) for i in range(4)}
    names = {i: f"P{i}" for i in range(4)}
    sizes = {i: (None, None) for i in range(4)}
    return _cameras(path, P, names, R_rect, _rigid(Tr[:, :3], Tr[:, 3]), sizes)


__all__ = ["read_extrinsic_txt", "read_intrinsics_txt", "read_kitti_raw_calib", "read_kitti_object_calib"]
