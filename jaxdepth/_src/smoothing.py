"""Step 4b: separable Gaussian smoothing with OpenCV's default border.

Equivalent to ``cv2.GaussianBlur(image, (2r+1, 2r+1), sigma,
borderType=cv2.BORDER_REFLECT_101)`` and to ``scipy.ndimage.gaussian_filter(image,
sigma, mode="mirror", truncate=r/sigma)``: the kernel is the sampled Gaussian
normalised to sum 1 (OpenCV derives its kernel the same way for sigma > 0).
Written as shifted multiply-adds, which XLA runs far faster than a
single-channel convolution on CPU.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np


def gaussian_kernel_1d(sigma_px: float, radius_px: int) -> np.ndarray:
    """(2r+1,) float64 sampled Gaussian weights summing to 1 (host-side, static)."""
    if sigma_px <= 0 or radius_px <= 0:
        return np.ones((1,), np.float64)
    x = np.arange(-radius_px, radius_px + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma_px) ** 2)
    return k / k.sum()


def _reflect101_index(n: int, radius: int) -> np.ndarray:
    idx = np.arange(-radius, n + radius)
    period = max(2 * n - 2, 1)
    idx = np.abs(idx) % period
    return np.where(idx >= n, period - idx, idx)


def _blur_axis(image: jax.Array, weights: np.ndarray, axis: int) -> jax.Array:
    radius = (len(weights) - 1) // 2
    n = image.shape[axis]
    padded = jnp.take(image, jnp.asarray(_reflect101_index(n, radius)), axis=axis)
    out = None
    for k, weight in enumerate(weights):
        part = jax.lax.slice_in_dim(padded, k, k + n, axis=axis) * jnp.float32(weight)
        out = part if out is None else out + part
    return out


def gaussian_blur(image: jax.Array, *, sigma_px: float, radius_px: int) -> jax.Array:
    """Separable Gaussian blur of an (H, W) image (BORDER_REFLECT_101).

    Args:
      image: (H, W) float32.
      sigma_px: standard deviation in pixels (static); 0 returns the input.
      radius_px: kernel half width (static); the kernel is (2r+1) x (2r+1).

    Returns:
      (H, W) float32.
    """
    weights = gaussian_kernel_1d(float(sigma_px), int(radius_px))
    if len(weights) == 1:
        return image
    if min(image.shape[-2:]) < 2:
        raise ValueError(f"gaussian_blur: image expected at least 2x2, got shape {image.shape}")
    out = _blur_axis(image.astype(jnp.float32), weights, axis=image.ndim - 2)
    return _blur_axis(out, weights, axis=image.ndim - 1)


def default_radius(sigma_px: float) -> int:
    """OpenCV's automatic kernel size for 8-bit images: radius = round(3 sigma)."""
    return max(1, int(math.ceil(3.0 * sigma_px)))
