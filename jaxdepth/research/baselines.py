"""Reference baselines on the CPU with NumPy and OpenCV (not jit-able, not JAX).

:func:`ip_basic_opencv` is IP_Basic's fast mode (Ku, Harakeh, Waslander, "In Defense
of Classical Image Processing: Fast Depth Completion on the CPU", CRV 2018), written
from the paper's description with OpenCV's morphology and filters on float32.  It is
the oracle for the pure-JAX :func:`jaxdepth.ip_basic` (same steps, same thresholds,
same border rules).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["ip_basic_opencv", "DIAMOND_KERNEL_5"]

_VALID = 0.1

#: IP_Basic's 5x5 diamond structuring element (|dv| + |du| <= 2).
DIAMOND_KERNEL_5 = np.array([
    [0, 0, 1, 0, 0],
    [0, 1, 1, 1, 0],
    [1, 1, 1, 1, 1],
    [0, 1, 1, 1, 0],
    [0, 0, 1, 0, 0],
], np.uint8)


def _full(size: int) -> np.ndarray:
    return np.ones((size, size), np.uint8)


def _fill_empty(x: np.ndarray, filled: np.ndarray) -> np.ndarray:
    return np.where(x > _VALID, x, filled).astype(np.float32)


def ip_basic_opencv(sparse_depth: np.ndarray, *, max_depth: float = 100.0, extrapolate: bool = False,
                    blur_type: str = "bilateral") -> np.ndarray:
    """IP_Basic fast-mode depth completion with OpenCV.

    Args:
      sparse_depth: (H, W) depth in metres (any real dtype, used as float32); values
        <= 0.1 are empty.
      max_depth: inversion constant ``d -> max_depth - d``, metres.
      extrapolate: extend each column's top-most value to the top of the image.
      blur_type: ``"bilateral"`` (``cv2.bilateralFilter(x, 5, 1.5, 2.0)``, the
        published fast mode's default) or ``"gaussian"``
        (``cv2.GaussianBlur(x, (5, 5), 0)``).

    Returns:
      (H, W) float32 dense depth, metres; 0 where nothing was filled.

    The final blur is written back only at pixels valid before it (empty pixels stay
    empty).  All OpenCV calls use their default borders.
    """
    d = np.asarray(sparse_depth)
    if d.ndim != 2:
        raise ValueError(f"sparse_depth: expected shape (H, W), got {d.shape}")
    if blur_type not in ("gaussian", "bilateral"):
        raise ValueError(f"blur_type: expected one of ('gaussian', 'bilateral'), got {blur_type!r}")
    if not max_depth > _VALID:
        raise ValueError(f"max_depth: expected a value > {_VALID} m, got {max_depth}")
    d = d.astype(np.float32)
    x = np.where(d > _VALID, np.float32(max_depth) - d, 0.0).astype(np.float32)
    x = cv2.dilate(x, DIAMOND_KERNEL_5)
    x = cv2.morphologyEx(x, cv2.MORPH_CLOSE, _full(5))
    x = _fill_empty(x, cv2.dilate(x, _full(7)))
    if extrapolate:
        valid = x > _VALID
        has = valid.any(axis=0)
        first = np.argmax(valid, axis=0)
        top = x[first, np.arange(x.shape[1])]
        above = has[None, :] & (np.arange(x.shape[0])[:, None] < first[None, :])
        x = np.where(above, top[None, :], x).astype(np.float32)
    x = _fill_empty(x, cv2.dilate(x, _full(31)))
    x = cv2.medianBlur(x, 5)
    if blur_type == "gaussian":
        blurred = cv2.GaussianBlur(x, (5, 5), 0)
    else:
        blurred = cv2.bilateralFilter(x, 5, 1.5, 2.0)
    x = np.where(x > _VALID, blurred, x).astype(np.float32)
    return np.where(x > _VALID, np.float32(max_depth) - x, 0.0).astype(np.float32)
