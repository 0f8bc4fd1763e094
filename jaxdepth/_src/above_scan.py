"""Step 4c (beyond the paper): what the SGM writes above the top scan line.

Above the highest kept LiDAR pixel of its neighbourhood a pixel has no measurement
over it: the paper's Step 4 extrapolates its nearest seed's plane upward, from a
point that the top laser hit at the *bottom* of whatever stands there. What stands
above the scan is the part of the scene that reaches higher than the laser:
facades and other backgrounds continue, while the near things the top laser hit
(posts, signs, people, the edge of a nearer facade) end somewhere above it, so a
near seed's plane carried upward paints a column of foreground over the
background (the nearest fill does the same, without the plane).

The rule (``SGMConfig.above_scan="background"``): a pixel above the top scan line
takes the depth of the *farthest* seed among the pixels of its row within the
paper's horizontal window of Algorithm 1, ``|du| < W L / N`` (one LiDAR point
spacing; ``N`` the pixels with depth, counted at run time), and no plane
extrapolation (Delta z = 0: the seed's plane was fitted where the laser was, not
above it). "Above the top scan line" is judged over the same window: the pixel
lies above every kept LiDAR pixel of the columns within ``|du| < W L / N``, so a
column that no point projects into (sparse horizontal sampling) does not count as
open to the top. The window is the paper's S(i), as in Step 2; no constant is
added. Below the top scan line nothing changes.

Where it is wrong: a near surface that does continue above the scan and is
narrower than one point spacing is lost, and the farther side of a depth edge
above the scan moves by up to one point spacing. Measured on the digital twins and
real data in docs/method.md ("Above the top scan line").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdepth._src.config import DEFAULT_CONFIG

_DEFAULTS = DEFAULT_CONFIG


def _shift_columns(x: jax.Array, k: int, fill) -> jax.Array:
    """``out[:, u] = x[:, u + k]`` (``fill`` outside the image), for a static ``k``."""
    if k == 0:
        return x
    pad = jnp.full((x.shape[0], abs(k)), fill, x.dtype)
    if k > 0:
        return jnp.concatenate([x[:, k:], pad], axis=1)
    return jnp.concatenate([pad, x[:, :k]], axis=1)


def paper_half_width(valid: jax.Array, *, beams: int, max_half_width_px: int, image_width=None) -> jax.Array:
    """Largest ``|du|`` of the paper's window ``|du| < W L / N`` (int32, traced), capped.

    Args:
      valid: (H, W) bool, the pixels with depth (their count is N).
      beams: L, the LiDAR's beam count.
      max_half_width_px: static cap (``SGMConfig.outlier_max_half_width_px``).
      image_width: optional traced int32 w: the image is the left w columns of ``valid`` (a
        rig's canvas); W is then w (the cap stays the canvas's: columns past the image are empty).
    """
    width = valid.shape[1]
    n_points = jnp.sum(valid, dtype=jnp.int32)
    wl = width * beams if image_width is None else jnp.asarray(image_width, jnp.int32) * beams
    return jnp.where(n_points > 0, jnp.minimum((wl - 1) // jnp.maximum(n_points, 1),
                                               min(max_half_width_px, width - 1)), 0)


def background_above_scan(depth_raw: jax.Array, seed_depth: jax.Array, keep: jax.Array, valid: jax.Array, *,
                          beams: int,
                          max_half_width_px: int = _DEFAULTS.outlier_max_half_width_px,
                          image_size=None) -> jax.Array:
    """Step 4's prediction with the pixels above the top scan line set to the farthest seed in the window.

    Args:
      depth_raw: (H, W) float32 metres, Step 4's prediction (0 = no seed).
      seed_depth: (H, W) float32 metres, each pixel's nearest seed depth z' (0 = no seed).
      keep: (H, W) bool, the LiDAR pixels kept by Step 2 (the scan lines).
      valid: (H, W) bool, every pixel with depth (N of the window ``W L / N``).
      beams: L, the LiDAR's beam count.
      max_half_width_px: static cap on the window's half width, pixels.
      image_size: optional traced (2,) int32 (h, w): the image is the top-left h x w window of
        the arrays (a rig's canvas); the result inside it is that of the (h, w) image alone.

    Returns:
      (H, W) float32 metres: ``depth_raw`` where some kept pixel of the window's
      columns lies at or above the pixel's row; elsewhere the maximum of
      ``seed_depth`` over the row's pixels with ``|du| < W L / N``.
    """
    height, width = depth_raw.shape
    k_max = paper_half_width(valid, beams=beams, max_half_width_px=max_half_width_px,
                             image_width=None if image_size is None else image_size[1])
    if image_size is not None:      # the seeds of the canvas's padding columns are no part of the image
        seed_depth = jnp.where(jnp.arange(width)[None, :] < image_size[1], seed_depth, 0.0)
    cap = min(int(max_half_width_px), width - 1)
    top = jnp.where(jnp.any(keep, axis=0), jnp.argmax(keep, axis=0), height).astype(jnp.int32)[None, :]
    top_window, farthest = top, seed_depth
    for k in range(1, cap + 1):
        on = k <= k_max
        for s in (k, -k):
            top_window = jnp.where(on, jnp.minimum(top_window, _shift_columns(top, s, height)), top_window)
            farthest = jnp.where(on, jnp.maximum(farthest, _shift_columns(seed_depth, s, 0.0)), farthest)
    rows = jnp.arange(height, dtype=jnp.int32)[:, None]
    return jnp.where((rows < top_window) & (seed_depth > 0), farthest, depth_raw)
