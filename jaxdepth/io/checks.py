"""Shape-free checks of calibration matrices shared by every reader.

Each check returns ``None`` when the matrix is fine, else ``(expected, got)``:
the two halves of the one message format every reader uses,
``<file>: field '<field>' expected <expected>, got <got>``
(:func:`jaxdepth.io.errors.field_error`).
"""

from __future__ import annotations

import numpy as np

#: Tolerance of the rotation / rigid-transform checks: max |R^T R - I| and |det R - 1|.
ROTATION_TOL = 1e-3


def pinhole_problem(K: np.ndarray) -> tuple[str, str] | None:
    """A (3, 3) pinhole K: positive focal lengths, K[1, 0] = 0, last row (0, 0, 1).

    >>> pinhole_problem(np.diag([700.0, 700.0, 1.0])) is None
    True
    >>> pinhole_problem(np.diag([700.0, 0.0, 1.0]))
    ('positive focal lengths fx, fy', 'fx=700, fy=0')
    """
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        return "positive focal lengths fx, fy", f"fx={K[0, 0]:g}, fy={K[1, 1]:g}"
    if abs(K[1, 0]) > 1e-9 or np.max(np.abs(K[2] - [0.0, 0.0, 1.0])) > 1e-6:
        return ("a pinhole matrix with K[1, 0] = 0 and last row (0, 0, 1)",
                f"K[1, 0]={K[1, 0]:g}, last row {K[2].tolist()}")
    return None


def rotation_problem(R: np.ndarray, *, tol: float = ROTATION_TOL) -> tuple[str, str] | None:
    """A (3, 3) rotation: R^T R = I and det R = +1, both within ``tol``.

    >>> rotation_problem(np.eye(3)) is None
    True
    >>> rotation_problem(np.diag([1.0, 1.0, -1.0]))[1]
    'max |R^T R - I| = 0, det R = -1'
    """
    with np.errstate(over="ignore", invalid="ignore"):  # huge entries give inf / nan: rejected below
        err = float(np.max(np.abs(R.T @ R - np.eye(3))))
        det = float(np.linalg.det(R))
    if not (err <= tol and abs(det - 1.0) <= tol):
        return f"a rotation (R^T R = I within {tol:g}, det R = +1)", f"max |R^T R - I| = {err:.3g}, det R = {det:.6g}"
    return None


def rigid_problem(T: np.ndarray, *, tol: float = ROTATION_TOL) -> tuple[str, str] | None:
    """A (4, 4) rigid transform: last row (0, 0, 0, 1) and a rotation block (:func:`rotation_problem`).

    >>> rigid_problem(np.eye(4)) is None
    True
    """
    if np.max(np.abs(T[3] - [0.0, 0.0, 0.0, 1.0])) > 1e-6:
        return "last row [0, 0, 0, 1]", str(T[3].tolist())
    problem = rotation_problem(T[:3, :3], tol=tol)
    if problem is not None:
        return "a rigid transform with " + problem[0], problem[1]
    return None
