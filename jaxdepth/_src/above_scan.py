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

The milder rule (``SGMConfig.above_scan="capped"``, :func:`capped_above_scan`; the default,
``"auto"``, on a reference sweep of several LiDARs, :func:`above_scan_rule`) keeps the
nearest seed and its plane but follows the plane at most one scan-line spacing (``h / L``
rows, the column bracket's window) above the seed and holds its depth beyond: the gap
between two rings is where the paper's plane is what it assumes; tens of rows above the top
ring it extrapolates one top-ring normal.

Where the background rule is wrong: a near surface that does continue above the scan and is
narrower than one point spacing is lost, and the farther side of a depth edge
above the scan moves by up to one point spacing. Measured on the digital twins and
real data in docs/method.md ("Above the top scan line").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.xla_tuning import fence, first_row_and_count

_DEFAULTS = DEFAULT_CONFIG


def above_scan_rule(mode: str, *, sweep, lidars, witnesses=None) -> str:
    """The rule ``SGMConfig.above_scan=mode`` stands for on a multi-source call (static).

    ``"auto"``: ``"capped"`` where the reference sweep (``sweep == 0``) is two or more LiDARs that scan
    in lines (each one's free-space grid its own spec: not a rosette), ``"plane"`` otherwise. Any
    other mode is itself. The single-sweep path (one LiDAR) treats ``"auto"`` as ``"plane"``.

    Args:
      mode: ``SGMConfig.above_scan``.
      sweep: each source's sweep number (0: the reference sweep).
      lidars: each source's :class:`~jaxdepth.LidarSpec`.
      witnesses: each source's free-space grid spec, or None (every source's own spec).
    """
    if mode != "auto":
        return mode
    ref = [i for i, sw in enumerate(sweep) if int(sw) == 0]
    grids = lidars if witnesses is None else witnesses
    lines = all(grids[i] == lidars[i] for i in ref)
    return "capped" if len(ref) >= 2 and lines else "plane"


def resolved_config(config, sources):
    """``config`` (:class:`~jaxdepth.SGMConfig`) with ``above_scan`` resolved for ``sources`` (a multi-source
    call's :class:`~jaxdepth._src.sources.Sources`: its static ``sweep``, ``lidars``, ``witnesses``) by
    :func:`above_scan_rule`. The entry points resolve it on the host, before their ``jit``: the default
    ``"auto"`` and the explicit mode it stands for are then one static option, one compiled program (the
    same bytes: only the tail reads ``above_scan``)."""
    return config.replace(above_scan=above_scan_rule(config.above_scan, sweep=sources.sweep, lidars=sources.lidars,
                                                     witnesses=sources.witnesses))


def _shift_columns(x: jax.Array, k: int, fill) -> jax.Array:
    """``out[:, u] = x[:, u + k]`` (``fill`` outside the image), for a static ``k``."""
    if k == 0:
        return x
    pad = jnp.full((x.shape[0], abs(k)), fill, x.dtype)
    if k > 0:
        return jnp.concatenate([x[:, k:], pad], axis=1)
    return jnp.concatenate([pad, x[:, :k]], axis=1)


def paper_half_width(valid: jax.Array, *, beams: int, max_half_width_px: int, image_width=None,
                     n_points=None) -> jax.Array:
    """Largest ``|du|`` of the paper's window ``|du| < W L / N`` (int32, traced), capped.

    Args:
      valid: (H, W) bool, the pixels with depth (their count is N).
      beams: L, the LiDAR's beam count.
      max_half_width_px: static cap (``SGMConfig.outlier_max_half_width_px``).
      image_width: optional traced int32 w: the image is the left w columns of ``valid`` (a
        rig's canvas); W is then w (the cap stays the canvas's: columns past the image are empty).
      n_points: optional traced int32 N, the count of ``valid`` when the caller has it.
    """
    width = valid.shape[1]
    n_points = jnp.sum(valid, dtype=jnp.int32) if n_points is None else n_points
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
    top, n_points = _top_line_and_count(keep, valid)
    k_max = paper_half_width(valid, beams=beams, max_half_width_px=max_half_width_px,
                             image_width=None if image_size is None else image_size[1], n_points=n_points)
    if image_size is not None:      # the seeds of the canvas's padding columns are no part of the image
        seed_depth = jnp.where(jnp.arange(width)[None, :] < image_size[1], seed_depth, 0.0)
    top_window, farthest = _window_top_and_farthest(top, seed_depth, height=height, k_max=k_max,
                                                    max_half_width_px=max_half_width_px)
    rows = jnp.arange(height, dtype=jnp.int32)[:, None]
    return jnp.where((rows < top_window) & (seed_depth > 0), farthest, depth_raw)


def capped_above_scan(depth_raw: jax.Array, seed_depth: jax.Array, seed_normal: jax.Array, du: jax.Array,
                      dv: jax.Array, keep: jax.Array, valid: jax.Array, K: jax.Array, *, beams: int,
                      rows_px, max_half_width_px: int = _DEFAULTS.outlier_max_half_width_px,
                      min_abs_denom: float = _DEFAULTS.min_abs_denom,
                      max_residual_ratio: float = _DEFAULTS.max_residual_ratio, image_size=None) -> jax.Array:
    """Step 4's prediction with the seed's plane followed at most ``rows_px`` rows above the top scan line.

    Above the top scan line (judged as in :func:`background_above_scan`) a pixel ``(u, v)`` whose seed
    lies more than ``R = rows_px`` rows away takes the plane's depth at ``(u, v_e)``, ``v_e`` the row
    ``R`` rows from the seed towards the pixel: the plane is extrapolated over one scan-line spacing
    (the gap the laser left between two of its rings, where the paper's plane is what it assumes) and
    held constant beyond. With ``r(u, v) = ((u - pu) / fu, (v - pv) / fv, 1)`` and the seed's normal
    ``n``, depth ``z'`` at ``(u + du, v + dv)``::

        z = z' (n . r(u + du, v + dv)) / (n . r(u, v + dv - R sign(dv)))

    (the paper's ``z' + Delta z`` at that pixel), ``z'`` where ``|n . r(u, v_e)| <= min_abs_denom``, and
    ``|z - z'|`` clipped to ``max_residual_ratio z'`` as Step 4's residual is.

    Args:
      depth_raw: (H, W) float32 metres, Step 4's prediction (0 = no seed).
      seed_depth: (H, W) float32 metres, each pixel's nearest seed depth z' (0 = no seed).
      seed_normal: (3, H, W) float32, the seed's unit normal (camera frame).
      du, dv: (H, W) int32, the seed's offset: it sits at ``(u + du, v + dv)``.
      keep: (H, W) bool, the LiDAR pixels kept by Step 2 (the scan lines).
      valid: (H, W) bool, every pixel with depth (N of the window ``W L / N``).
      K: (3, 3) float32 intrinsics.
      beams: L, the LiDAR's beam count.
      rows_px: R, rows (float, static or traced): one scan-line spacing, ``h / L``.
      max_half_width_px: static cap on the window's half width, pixels.
      min_abs_denom, max_residual_ratio: Step 4's residual guards (``SGMConfig``).
      image_size: optional traced (2,) int32 (h, w): the image is the top-left h x w window.

    Returns:
      (H, W) float32 metres: ``depth_raw`` except above the top scan line where ``|dv| > R``.
    """
    height, width = depth_raw.shape
    top, n_points = _top_line_and_count(keep, valid)
    k_max = paper_half_width(valid, beams=beams, max_half_width_px=max_half_width_px,
                             image_width=None if image_size is None else image_size[1], n_points=n_points)
    top_window = _window_top(top, height=height, k_max=k_max, max_half_width_px=max_half_width_px)
    K = jnp.asarray(K, jnp.float32)
    fu, fv, pu, pv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    v = jnp.arange(height, dtype=jnp.float32)[:, None]
    u = jnp.arange(width, dtype=jnp.float32)[None, :]
    rows = jnp.asarray(rows_px, jnp.float32)
    dvf = dv.astype(jnp.float32)
    capped = (v < top_window) & (seed_depth > 0) & (jnp.abs(dvf) > rows)
    nx, ny, nz = seed_normal[0], seed_normal[1], seed_normal[2]
    at_seed = (u + du - pu) / fu * nx + (v + dvf - pv) / fv * ny + nz
    at_cap = (u - pu) / fu * nx + (v + dvf - jnp.sign(dvf) * rows - pv) / fv * ny + nz
    ok = capped & (jnp.abs(at_cap) > min_abs_denom)
    ratio = jnp.where(ok, at_seed / jnp.where(ok, at_cap, 1.0), 1.0)
    z = seed_depth * jnp.clip(ratio, 1.0 - max_residual_ratio, 1.0 + max_residual_ratio)
    return jnp.where(capped, z, depth_raw)


def _top_line_and_count(mask: jax.Array, valid: jax.Array):
    """``(top, N)``: each column's first True row of an (H, W) bool ``mask`` ((1, W) int32, H where none) and N,
    the int32 count of an (H, W) bool ``valid``.

    XLA:CPU: one loop over the rows (``xla_tuning.first_row_and_count``), no image-sized buffer written."""
    first, n_points = first_row_and_count(mask, valid)
    return first[None, :], n_points


def _window_extreme(row: jax.Array, *, fill, reduce, k_max, max_half_width_px: int) -> jax.Array:
    """``reduce`` (``jnp.minimum`` / ``jnp.maximum``) of ``row`` ((1, W) or (H, W)) over the columns within
    ``|du| <= k_max`` of each column (the paper's window; ``k_max`` traced, at most the static
    ``max_half_width_px``), ``fill`` beyond the image's sides; shaped as ``row``."""
    out = row
    for k in range(1, min(int(max_half_width_px), row.shape[1] - 1) + 1):
        on = k <= k_max
        for s in (k, -k):
            out = jnp.where(on, reduce(out, _shift_columns(row, s, fill)), out)
    return out


def _window_top(top: jax.Array, *, height: int, k_max, max_half_width_px: int) -> jax.Array:
    """(1, W) int32: the highest top-line row of ``top`` ((1, W) int32, ``height`` where a column has none)
    over the columns within ``|du| <= k_max`` of each column (:func:`_window_extreme`).

    XLA:CPU: a buffer (fenced), else the window's shifts are fused into every pixel of an (H, W) consumer."""
    return fence(_window_extreme(top, fill=height, reduce=jnp.minimum, k_max=k_max,
                                 max_half_width_px=max_half_width_px))[0]


def _window_top_and_farthest(top: jax.Array, depth: jax.Array, *, height: int, k_max, max_half_width_px: int):
    """:func:`_window_top` of ``top`` and, over the same columns, the largest ``depth`` ((1, W) or (H, W)
    float32 metres, 0 = none). Returns ``(top_window, farthest)``, shaped as ``top`` and ``depth``; a (1, W)
    ``farthest`` is fenced with ``top_window`` (one conditional)."""
    window = dict(k_max=k_max, max_half_width_px=max_half_width_px)
    farthest = _window_extreme(depth, fill=0.0, reduce=jnp.maximum, **window)
    if farthest.shape[0] == 1:
        return fence(_window_extreme(top, fill=height, reduce=jnp.minimum, **window), farthest)
    return _window_top(top, height=height, **window), farthest


def top_line_keep(reference: jax.Array, depth: jax.Array, *, beams: int, epsilon_m: float = _DEFAULTS.epsilon_m,
                  max_half_width_px: int = _DEFAULTS.outlier_max_half_width_px, image_width=None) -> jax.Array:
    """(H, W) bool: the pixels an earlier sweep may seed, given the reference sweep's top scan line.

    The top scan line over the paper's window: a pixel is at or below it when some pixel of
    ``reference`` lies at or above its row in a column within ``|du| < W L / N`` of its own
    (``N`` the reference pixels; the window of :func:`background_above_scan`). Where no column of
    the window holds a reference pixel the reference sweep has no scan line there: every row counts
    as below it. Above the line a pixel is kept when its depth is not nearer, by more than
    ``epsilon_m`` (Algorithm 1's epsilon), than the farthest of the window columns' top reference
    pixels: the same surface or a farther one continues upward; a nearer one is a near object's
    top, seen only from an older origin, whose plane Step 4 would carry over the image above it.

    Args:
      reference: (H, W) bool, the kept pixels of the reference sweep's points.
      depth: (H, W) float32 metres, every pixel's depth (the merged sparse image).
      beams: L, the beams of the reference sweep's LiDARs.
      epsilon_m: the depth margin, metres.
      max_half_width_px: static cap on the window's half width, pixels.
      image_width: optional traced int32 w, the image's width on a rig's canvas.
    """
    height = reference.shape[0]
    top, n_points = _top_line_and_count(reference, reference)
    k_max = paper_half_width(reference, beams=beams, max_half_width_px=max_half_width_px, image_width=image_width,
                             n_points=n_points)
    top_depth = jnp.take_along_axis(jnp.where(reference, depth, 0.0), jnp.minimum(top, height - 1), axis=0)
    top_window, far = _window_top_and_farthest(top, top_depth, height=height, k_max=k_max,
                                               max_half_width_px=max_half_width_px)
    top_window = jnp.where(top_window < height, top_window, 0)    # no reference pixel in the window: no line
    return (jnp.arange(height, dtype=jnp.int32)[:, None] >= top_window) | (depth >= far - epsilon_m)
