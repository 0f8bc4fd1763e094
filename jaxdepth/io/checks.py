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
#: Largest offset of a principal point from the image centre, as a fraction of the image's width /
#: height, for :func:`principal_point_scale` to call it centred (real cameras: <= 0.06, KITTI's
#: benchmark crop 0.07).
CENTRE_TOL = 0.15
#: Scale factors :func:`principal_point_scale` tries (K of a half / double / quarter size image).
K_SCALES = (0.5, 2.0, 0.25, 4.0)


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


def principal_point_scale(K: np.ndarray, width: int, height: int) -> float | None:
    """The factor ``s`` when ``K`` seems made for an image ``s`` times the size of ``width`` x ``height``.

    A lens's optical axis meets its sensor near the centre, and a K scaled with its image keeps
    the principal point there: a principal point off-centre by more than :data:`CENTRE_TOL` (in
    both the width's and the height's fraction) that lands within it once divided by one of
    :data:`K_SCALES` is a K scaled by that factor for this image size. A principal point off
    centre for another reason (a crop) is not judged (None).

    >>> principal_point_scale(np.array([[633.0, 0, 400], [0, 633, 225], [0, 0, 1]]), 1600, 900)
    0.5
    >>> principal_point_scale(np.array([[1266.0, 0, 816], [0, 1266, 491], [0, 0, 1]]), 1600, 900) is None
    True
    """
    cx, cy = float(K[0, 2]), float(K[1, 2])

    def centred(x: float, y: float) -> bool:
        return abs(x / width - 0.5) <= CENTRE_TOL and abs(y / height - 0.5) <= CENTRE_TOL

    if centred(cx, cy):
        return None
    for s in K_SCALES:
        if centred(cx / s, cy / s):
            return s
    return None
