"""FROZEN ORACLE: the dense-sweep ``outlier_keep_mask`` before the prefilter rewrite
(jaxdepth/_src/outliers.py at commit ac8f47d), with ``window_half_sizes`` as of c4c946c.

Moved here verbatim from benchmarks/bench_outliers.py (which imports it from here);
tests/test_outliers.py checks ``test="paper"`` is bit-identical to it. Do not edit.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp


def _frozen_window_half_sizes(height: int, width: int, *, beams: int, max_half_width_px: int,
                              max_half_height_px: int) -> tuple[int, int]:
    """Static (half_width, half_height) of the window visited, pixels.

    The vertical bound ``|dv| < H / L`` is static: for integer ``dv`` it is
    ``|dv| <= ceil(H / L) - 1``. The horizontal bound depends on ``N`` at run
    time, so only its cap is static. Both are also clipped to the image.
    """
    half_height = min(int(max_half_height_px), math.ceil(height / beams) - 1, height - 1)
    half_width = min(int(max_half_width_px), width - 1)
    return max(half_width, 0), max(half_height, 0)


# ----------------------------------------------------------------------------- frozen reference
# The dense-sweep implementation of outlier_keep_mask as it was before the
# prefilter rewrite (jaxdepth/_src/outliers.py at commit ac8f47d), kept verbatim
# (names prefixed) so that the benchmark times old and new in one process and
# tests/test_outliers.py checks the new mask is bit-identical to it.
def _frozen_pseudo_angle(a: jax.Array, b: jax.Array) -> jax.Array:
    """A cheap strictly increasing function of ``atan2(a, b)`` on (-pi, pi].

    ``s = a / (|a| + |b|)`` runs over [-1, 1] for ``b >= 0`` (angles in
    [-pi/2, pi/2]); the back half continues to (1, 2] and [-2, -1).
    ``a = b = 0`` gives 0, as ``atan2(0, 0)`` does. Only the order of the
    result is meaningful.
    """
    den = jnp.abs(a) + jnp.abs(b)
    ok = den > 0
    s = jnp.where(ok, a / jnp.where(ok, den, 1.0), 0.0)
    return jnp.where(b >= 0, s, jnp.where(a >= 0, 2.0, -2.0) - s)


def _frozen_lidar_angles(depth: jax.Array, K: jax.Array, t: jax.Array, points_cam: jax.Array | None,
                         *, row0: int = 0, col0: int = 0):
    """Order keys (h, g) of each pixel's point seen from the LiDAR origin ``t`` (camera axes).

    ``depth`` may be a padded canvas whose pixel (row0, col0) is image pixel (0, 0).
    """
    if points_cam is None:
        h, w = depth.shape
        v = jnp.arange(-row0, h - row0, dtype=jnp.float32)[:, None]
        u = jnp.arange(-col0, w - col0, dtype=jnp.float32)[None, :]
        y_n = (v - K[1, 2]) / K[1, 1]
        x_n = (u - K[0, 2] - K[0, 1] * y_n) / K[0, 0]
        qx = depth * x_n - t[0]
        qy = depth * y_n - t[1]
        qz = depth - t[2]
    else:
        qx = points_cam[0] - t[0]
        qy = points_cam[1] - t[1]
        qz = points_cam[2] - t[2]
    return _frozen_pseudo_angle(qx, qz), _frozen_pseudo_angle(qy, qz)


def _frozen_flip(du: int, dv: int, h_p, g_p, h_q, g_q):
    """Condition 1 for the pixel pair (p, q = p + (du, dv)); symmetric in p and q.

    ``(u_p - u_q)(h_p - h_q) < 0`` with ``u_p - u_q = -du`` is ``h_p > h_q`` for
    du > 0, ``h_p < h_q`` for du < 0 and never true for du = 0 (same for v, g).
    """
    terms = []
    if du > 0:
        terms.append(h_p > h_q)
    elif du < 0:
        terms.append(h_p < h_q)
    if dv > 0:
        terms.append(g_p > g_q)
    elif dv < 0:
        terms.append(g_p < g_q)
    return functools.reduce(jnp.logical_or, terms)


#: Rows per band: bands without a single valid pixel are skipped at run time.
_FROZEN_BAND_ROWS = 32


@functools.partial(jax.jit, static_argnames=("beams", "half_width", "half_height"))
def _frozen_keep_mask(sparse_depth, K, T_cam_lidar, points_cam, epsilon_m, *, beams, half_width, half_height):
    height, width = sparse_depth.shape
    hh, hw = half_height, half_width
    band = min(_FROZEN_BAND_ROWS, height)
    n_bands = -(-height // band)
    extra = n_bands * band - height            # empty rows completing the last band

    depth = sparse_depth.astype(jnp.float32)
    valid = (depth > 0) & jnp.isfinite(depth)
    row_points = jnp.sum(valid, axis=1, dtype=jnp.int32)
    n_points = jnp.sum(row_points)
    band_has_points = jnp.pad(row_points, (0, extra)).reshape(n_bands, band).sum(axis=1) > 0

    # Everything lives on one padded canvas (hh rows above, hh + extra below,
    # hw columns each side) so that every neighbour offset is a plain slice.
    # Empty pixels and padding have z + eps = +inf: condition 2 (z_p > z_q +
    # eps) is then false for them as neighbours, and as centres they are
    # masked out at the end.
    pad = ((hh, hh + extra), (hw, hw))
    depth_c = jnp.pad(jnp.where(valid, depth, 0.0), pad)
    points_c = None if points_cam is None else jnp.pad(points_cam.astype(jnp.float32), ((0, 0), *pad))
    h_c, g_c = _frozen_lidar_angles(depth_c, K.astype(jnp.float32), T_cam_lidar.astype(jnp.float32)[:3, 3],
                             points_c, row0=hh, col0=hw)
    z_c = jnp.where(depth_c > 0, depth_c, jnp.inf)
    z_eps_c = z_c + jnp.asarray(epsilon_m, jnp.float32)
    # Materialise the canvases once: XLA would otherwise fuse the angle maths
    # into every shifted slice that reads it (once per offset).
    h_c, g_c, z_c, z_eps_c = jax.lax.optimization_barrier((h_c, g_c, z_c, z_eps_c))

    wl = width * beams
    # |du| = k is in S(i) iff k < W L / N, i.e. k <= (W L - 1) // N (integers).
    k_max = jnp.where(n_points > 0, jnp.minimum((wl - 1) // jnp.maximum(n_points, 1), hw), 0)

    def band_removed(b):
        r0 = b * band
        centre = lambda a: jax.lax.dynamic_slice(a, (hh + r0, hw), (band, width))
        h_p, g_p, z_p = centre(h_c), centre(g_c), centre(z_c)

        def visit(removed, du_sign, dv, col):
            """ORs in the removals caused by the neighbours at (col - hw, dv)."""
            q = lambda a: jax.lax.dynamic_slice(a, (hh + r0 + dv, col), (band, width))
            flip = _frozen_flip(du_sign, dv, h_p, g_p, q(h_c), q(g_c))
            return removed | (flip & (z_p > q(z_eps_c)))

        removed = jnp.zeros((band, width), bool)
        for dv in range(-hh, hh + 1):
            if dv != 0:
                removed = visit(removed, 0, dv, hw)
        # One fusion for the du = 0 column; without the barrier XLA splits it
        # into one materialised mask per offset and carries them into the loop.
        removed = jax.lax.optimization_barrier(removed)

        def columns_at(k, removed):
            # The sign of du is static (it picks the comparison); k moves the slice.
            for du_sign in (1, -1):
                for dv in range(-hh, hh + 1):
                    removed = visit(removed, du_sign, dv, hw + du_sign * k)
            return removed

        # Offsets beyond the run-time bound are skipped, not masked; the body
        # compiles once whatever the cap.
        return jax.lax.fori_loop(1, k_max + 1, columns_at, removed)

    def per_band(b, removed):
        rows = jax.lax.cond(band_has_points[b], band_removed, lambda b: jnp.zeros((band, width), bool), b)
        return jax.lax.dynamic_update_slice(removed, rows, (b * band, 0))

    removed = jax.lax.fori_loop(0, n_bands, per_band, jnp.zeros((n_bands * band, width), bool))
    return valid & ~removed[:height]




def frozen_keep_mask(sparse_depth, K, T_cam_lidar, *, beams, epsilon_m=1.0, max_half_width_px=12,
                     max_half_height_px=24, points_cam=None):
    """The pre-rewrite dense sweep; same arguments and result as ``outlier_keep_mask``."""
    sparse_depth = jnp.asarray(sparse_depth)
    height, width = sparse_depth.shape
    half_width, half_height = _frozen_window_half_sizes(height, width, beams=int(beams),
                                                max_half_width_px=int(max_half_width_px),
                                                max_half_height_px=int(max_half_height_px))
    return _frozen_keep_mask(sparse_depth, jnp.asarray(K), jnp.asarray(T_cam_lidar),
                             None if points_cam is None else jnp.asarray(points_cam),
                             jnp.asarray(epsilon_m, jnp.float32), beams=int(beams), half_width=half_width,
                             half_height=half_height)
