"""Rigid poses on the host: rotations, quaternions, 4 x 4 transforms (NumPy float64, SciPy's ``Rotation``).

The one place the readers and the synthetic drives build, invert, interpolate and apply
poses; the jitted side keeps its own two 4 x 4 helpers (:func:`jaxdepth._src.geometry.transform_points`,
:func:`~jaxdepth._src.geometry.invert_rigid`). SciPy arrives with JAX (a dependency of
``jax``), so nothing is added.

Conventions:

* a pose ``T_a_b`` is a (4, 4) float64 ``[[R, t], [0, 0, 0, 1]]`` mapping points of frame
  ``b`` into frame ``a``: ``p_a = R p_b + t``;
* quaternions are scalar first, ``(w, x, y, z)`` (nuScenes, Argoverse 2, pyquaternion);
  SciPy's own order is scalar last, and the conversion happens here only;
* roll / pitch / yaw are the extrinsic x-y-z angles: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``
  (KITTI's OXTS, the synthetic rig's mounts).
"""

from __future__ import annotations

import numpy as np


def _rotation_class():
    from scipy.spatial.transform import Rotation     # deferred: SciPy's import is not free
    return Rotation


def rotation_rpy(roll: float, pitch: float, yaw: float = 0.0, *, degrees: bool = False) -> np.ndarray:
    """(3, 3) float64 ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (radians, or degrees with ``degrees=True``).

    >>> import math
    >>> rotation_rpy(0.0, 0.0, math.pi / 2).round(6).tolist()
    [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    return _rotation_class().from_euler("xyz", [roll, pitch, yaw], degrees=degrees).as_matrix()


def _floats(value, where: str) -> np.ndarray:
    """A flat float64 array of ``value``; ValueError naming ``where`` if it is not a list of numbers."""
    text = repr(value)
    text = text if len(text) <= 60 else text[:57] + "..."
    if not isinstance(value, (list, tuple, np.ndarray)):
        raise ValueError(f"field '{where}' expected a list of numbers, got {text}")
    try:
        return np.asarray(value, np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"field '{where}' expected a list of numbers, got {text}") from None


def quaternion_matrix(q, *, where: str = "rotation") -> np.ndarray:
    """(3, 3) float64 rotation of a quaternion ``(w, x, y, z)``, normalised first.

    Raises ValueError (naming ``where``) for a zero, non-finite or wrongly sized quaternion.

    >>> import math
    >>> np.round(quaternion_matrix([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)]), 6).tolist()
    [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    q = _floats(q, where)
    norm = float(np.linalg.norm(q)) if q.size == 4 else 0.0
    if q.size != 4 or not np.all(np.isfinite(q)) or norm < 1e-9:
        raise ValueError(f"field '{where}' expected a non-zero quaternion [w, x, y, z], got {q.tolist()}")
    return _rotation_class().from_quat(np.roll(q / norm, -1)).as_matrix()


def rigid(R, t) -> np.ndarray:
    """(4, 4) float64 ``[[R, t], [0, 0, 0, 1]]`` of a (3, 3) rotation and a (3,) translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def pose_matrix(translation, rotation, *, where: str = "pose") -> np.ndarray:
    """(4, 4) float64 pose of a translation (3,) and a quaternion ``(w, x, y, z)`` (child -> parent frame).

    Raises ValueError naming ``<where>.translation`` / ``<where>.rotation``.
    """
    t = _floats(translation, f"{where}.translation")
    if t.size != 3 or not np.all(np.isfinite(t)):
        raise ValueError(f"field '{where}.translation' expected 3 finite numbers, got {t.tolist()}")
    return rigid(quaternion_matrix(rotation, where=f"{where}.rotation"), t)


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4) transform: ``[[R^T, -R^T t], [0, 1]]``."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def slerp_rotation(R0: np.ndarray, R1: np.ndarray, a: float) -> np.ndarray:
    """(3, 3) float64 rotation a fraction ``a`` in [0, 1] of the shortest arc from ``R0`` to ``R1``.

    >>> import math
    >>> slerp_rotation(np.eye(3), rotation_rpy(0.0, 0.0, 0.5), 0.5).round(12).tolist() == (
    ...     rotation_rpy(0.0, 0.0, 0.25).round(12).tolist())
    True
    """
    from scipy.spatial.transform import Slerp
    Rotation = _rotation_class()
    return Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([R0, R1])))([float(a)]).as_matrix()[0]


def apply_pose(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) float32 ``R p + t`` of (N, 3) points, computed in float64."""
    T = np.asarray(T, np.float64)
    return (np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)


__all__ = ["rotation_rpy", "quaternion_matrix", "rigid", "pose_matrix", "invert_pose",
           "slerp_rotation", "apply_pose"]
