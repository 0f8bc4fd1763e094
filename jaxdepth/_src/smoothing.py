"""Step 4b: separable Gaussian smoothing with OpenCV's default border.

Equivalent to ``cv2.GaussianBlur(image, (2r+1, 2r+1), sigma,
borderType=cv2.BORDER_REFLECT_101)`` and to ``scipy.ndimage.gaussian_filter(image,
sigma, mode="mirror", truncate=r/sigma)``: the kernel is the sampled Gaussian
normalised to sum 1 (OpenCV derives its kernel the same way for sigma > 0).
Written as shifted multiply-adds, which XLA runs far faster than a
single-channel convolution on CPU.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.xla_tuning import stage, stage_token


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


def _reflect101_pad(image: jax.Array, radius: int, axis: int) -> jax.Array:
    """Pads ``axis`` by ``radius`` mirrored rows/columns (edge not repeated), by slices."""
    n = image.shape[axis]
    idx = _reflect101_index(n, radius)
    lo = [jax.lax.slice_in_dim(image, int(i), int(i) + 1, axis=axis) for i in idx[:radius]]
    hi = [jax.lax.slice_in_dim(image, int(i), int(i) + 1, axis=axis) for i in idx[n + radius:]]
    return jnp.concatenate(lo + [image] + hi, axis=axis)


def _reflect101_pad_window(image: jax.Array, radius: int, axis: int, n) -> jax.Array:
    """:func:`_reflect101_pad` of the first ``n`` (traced int32, ``n >= 2``) entries of ``axis``: the image
    is a window of a canvas, mirrored at its own edge (index ``n - 1``), never read beyond it.

    Returns the canvas's length + 2 ``radius`` along ``axis``; the first ``n + 2 radius`` entries
    are those of :func:`_reflect101_pad` of the window, the rest any value. Entry ``i`` (from
    ``-radius``) is the window's entry ``i - s`` with ``s = i - reflect(i)``, even and within
    ``[-2 radius, 2 radius]`` for every ``i < n + radius`` and every ``n >= 2``: a select among
    ``2 radius + 1`` static shifts, elementwise. (A gather, the form before, ran the blur's taps inside
    XLA:CPU's gather kernel, ~2x the tail's blur time on a rig's 3 Mpx cameras under ``vmap``, and
    rounded them unlike every other kernel: docs/speed.md, "The rig's tail".)
    """
    length = image.shape[axis]
    i = jnp.arange(-radius, length + radius, dtype=jnp.int32)
    period = jnp.maximum(2 * n - 2, 1)
    idx = jnp.abs(i) % period
    shift = (i - jnp.where(idx >= n, period - idx, idx)).reshape((-1,) + (1,) * (image.ndim - 1 - axis))
    pad = [(0, 0, 0)] * image.ndim
    pad[axis] = (3 * radius, 3 * radius, 0)
    ext = jax.lax.pad(image, jnp.zeros((), image.dtype), pad)          # ext[k + 3 radius] = image[k]
    out = None
    for s in range(-2 * radius, 2 * radius + 1, 2):
        part = jax.lax.slice_in_dim(ext, 2 * radius - s, 2 * radius - s + length + 2 * radius, axis=axis)
        out = part if out is None else jnp.where(shift == s, part, out)
    return out


def _taps(padded: jax.Array, weights: np.ndarray, axis: int) -> jax.Array:
    n = padded.shape[axis] - (len(weights) - 1)
    out = None
    for k, weight in enumerate(weights):
        part = jax.lax.slice_in_dim(padded, k, k + n, axis=axis) * jnp.float32(weight)
        out = part if out is None else out + part
    return out


def gaussian_blur(image: jax.Array, *, sigma_px: float, radius_px: int, image_size=None,
                  copies: bool = False) -> jax.Array:
    """Separable Gaussian blur of an (H, W) image (BORDER_REFLECT_101).

    Args:
      image: (H, W) float32.
      sigma_px: standard deviation in pixels (static); 0 returns the input.
      radius_px: kernel half width (static); the kernel is (2r+1) x (2r+1).
      image_size: optional traced (2,) int32 (h, w), h, w >= 2: the image is the
        top-left h x w window of a canvas (rigs of mixed sizes). The border
        is then the window's own (mirrored at row h - 1 and column w - 1, the
        canvas beyond never read): inside the window the result equals the blur
        of the (h, w) image alone, bit for bit; outside it, any value.
      copies: static, with ``image_size`` None: the border's rows and columns are
        copies of the image's (the vertical taps read both axes' pads of the image),
        so the result is bit for bit that of ``image_size`` = the image's own
        (h, w), at less than the default's cost. The default fuses the column padding into
        the vertical pass: XLA:CPU emits the mirrored columns' taps apart from the
        interior's and may round them 1 ulp apart from the columns they mirror
        (docs/speed.md, "The one-source rig's blur border as copies").

    Returns:
      (H, W) float32.

    Examples:
      A unit impulse in a 3 x 3 image; the mirrored border (reflect-101) folds
      the kernel's tails back in, so the corners get the most weight:

      >>> import jax.numpy as jnp
      >>> import numpy as np
      >>> from jaxdepth._src.smoothing import gaussian_blur
      >>> impulse = jnp.zeros((3, 3)).at[1, 1].set(1.0)
      >>> print(np.round(np.asarray(gaussian_blur(impulse, sigma_px=1.0, radius_px=1)), 4))
      [[0.3005 0.2477 0.3005]
       [0.2477 0.2042 0.2477]
       [0.3005 0.2477 0.3005]]
    """
    weights = gaussian_kernel_1d(float(sigma_px), int(radius_px))
    if len(weights) == 1:
        return image
    if min(image.shape[-2:]) < 2:
        raise ValueError(f"gaussian_blur: field 'image' expected at least 2x2, got shape {image.shape}")
    # Each pass reads a materialised input (stage fences): XLA would otherwise
    # fuse the producer of ``image`` into every tap, and the vertical pass into
    # every tap of the horizontal one (25 re-runs of the upstream work).
    rows, cols = image.ndim - 2, image.ndim - 1
    radius = (len(weights) - 1) // 2
    image = image.astype(jnp.float32)
    token = stage_token(image)
    if image_size is None and copies:
        # The taps read the pads' copies of the materialised image (no arithmetic inside the concatenates)
        vertical = stage(lambda a: (_taps(_reflect101_pad(_reflect101_pad(a, radius, rows), radius, cols), weights,
                                          rows),), (image,), token)[0]
        return _taps(vertical, weights, cols)
    if image_size is None:
        padded = stage(lambda a: (_reflect101_pad(a, radius, rows),), (image,), token)[0]
        vertical = stage(lambda p: (_reflect101_pad(_taps(p, weights, rows), radius, cols),), (padded,), token)[0]
        return _taps(vertical, weights, cols)
    size = jnp.asarray(image_size, jnp.int32)
    padded = stage(lambda a, n: (_reflect101_pad_window(a, radius, rows, n[0]),), (image, size), token)[0]
    vertical = stage(lambda p, n: (_reflect101_pad_window(_taps(p, weights, rows), radius, cols, n[1]),),
                     (padded, size), token)[0]
    return _taps(vertical, weights, cols)


def gaussian_kernel_traced(sigma_px: jax.Array, radius_px: int) -> jax.Array:
    """(2r+1,) float32 sampled Gaussian weights summing to 1, for a traced ``sigma_px``.

    ``sigma_px <= 0`` gives the identity kernel (1 at the centre, 0 elsewhere).
    The safe-where pattern keeps values and gradients finite at ``sigma_px = 0``.
    """
    sigma = jnp.asarray(sigma_px, jnp.float32)
    x = jnp.arange(-radius_px, radius_px + 1, dtype=jnp.float32)
    positive = sigma > 0
    safe_sigma = jnp.where(positive, sigma, 1.0)
    k = jnp.exp(-0.5 * jnp.square(x / safe_sigma))
    k = k / jnp.sum(k)
    return jnp.where(positive, k, (x == 0).astype(jnp.float32))


def _blur_axis_traced(image: jax.Array, weights: jax.Array, radius: int, axis: int) -> jax.Array:
    n = image.shape[axis]
    padded = jnp.take(image, jnp.asarray(_reflect101_index(n, radius)), axis=axis)
    out = None
    for k in range(2 * radius + 1):
        part = jax.lax.slice_in_dim(padded, k, k + n, axis=axis) * weights[k]
        out = part if out is None else out + part
    return out


def gaussian_blur_traced(image: jax.Array, sigma_px: jax.Array, *, radius_px: int) -> jax.Array:
    """:func:`gaussian_blur` with a traced ``sigma_px``: one compiled function for every sigma.

    Use it to ``jax.vmap`` over sigma (parameter sweeps) or to differentiate
    with respect to it; :func:`gaussian_blur` takes sigma as a static value,
    folds the weights into constants and recompiles per sigma.

    Args:
      image: (H, W) float32 (H, W >= 2 when ``radius_px > 0``).
      sigma_px: scalar standard deviation in pixels (traced); ``<= 0`` returns
        the input unchanged (identity kernel).
      radius_px: static kernel half width; the kernel is (2r+1) x (2r+1); 0
        returns the input.

    Returns:
      (H, W) float32, equal to ``gaussian_blur(image, sigma_px=s, radius_px=r)``
      up to float32 rounding of the weights (computed here in float32, there in
      float64), i.e. ``cv2.GaussianBlur(image, (2r+1, 2r+1), s,
      borderType=cv2.BORDER_REFLECT_101)``.
    """
    if isinstance(radius_px, bool) or int(radius_px) != radius_px or radius_px < 0:
        raise ValueError(f"gaussian_blur_traced: field 'radius_px' expected a non-negative integer, got {radius_px!r}")
    radius_px = int(radius_px)
    image = jnp.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"gaussian_blur_traced: field 'image' expected shape (H, W), got {tuple(image.shape)}")
    if jnp.ndim(sigma_px) != 0:
        raise ValueError(f"gaussian_blur_traced: field 'sigma_px' expected a scalar, got shape {jnp.shape(sigma_px)}")
    image = image.astype(jnp.float32)
    if radius_px == 0:
        return image
    if min(image.shape) < 2:
        raise ValueError(f"gaussian_blur_traced: field 'image' expected at least 2x2, got shape {tuple(image.shape)}")
    weights = gaussian_kernel_traced(sigma_px, radius_px)
    out = _blur_axis_traced(image, weights, radius_px, axis=0)
    return _blur_axis_traced(out, weights, radius_px, axis=1)
