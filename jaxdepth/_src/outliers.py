"""Step 2: occlusion outlier removal (the paper's Algorithm 1), as a fixed-shape mask.

Contract: one sparse depth image in, one boolean mask out. This module only
decides which LiDAR pixels to keep; it never edits a depth value.

The paper (Zhao et al., RA-L 2021, Sec. III-A) removes a projected LiDAR point
``i`` when some point ``j`` of its image neighbourhood

    S(i) = {j : |u_j - u_i| < W L / N  and  |v_j - v_i| < H / L}

(``W x H`` image, ``L`` beams, ``N`` points projected into the image) meets both

    condition 1:  (u_i - u_j)(theta_i - theta_j) < 0  or  (v_i - v_j)(phi_i - phi_j) < 0
    condition 2:  z_i > z_j + epsilon

i.e. the two points are ordered differently seen from the LiDAR than on the
image (parallax: the LiDAR saw ``i`` past the edge of something nearer), and
``i`` is more than ``epsilon`` behind ``j``.

Implementation: a dense sweep over window offsets. Each offset (du, dv) is one
shifted slice of padded canvases (angle keys, z, z + epsilon) and three to
five comparisons per pixel, OR-ed into the removal mask; the |du| = k columns
run in a ``fori_loop`` up to the run-time bound, and row bands without a
single point are skipped. Visiting each unordered pair once (condition 1 is
symmetric) would need the pair's result written back at the shifted pixel,
i.e. one materialised mask per offset, which costs more than the comparisons
it saves.
"""

from __future__ import annotations

import functools
import math
import numbers

import jax
import jax.numpy as jnp


def _pseudo_angle(a: jax.Array, b: jax.Array) -> jax.Array:
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


def _lidar_angles(depth: jax.Array, K: jax.Array, t: jax.Array, points_cam: jax.Array | None,
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
    return _pseudo_angle(qx, qz), _pseudo_angle(qy, qz)


def _flip(du: int, dv: int, h_p, g_p, h_q, g_q):
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


def window_half_sizes(height: int, width: int, *, beams: int, max_half_width_px: int,
                      max_half_height_px: int) -> tuple[int, int]:
    """Static (half_width, half_height) of the window visited, pixels.

    The vertical bound ``|dv| < H / L`` is static: for integer ``dv`` it is
    ``|dv| <= ceil(H / L) - 1``. The horizontal bound depends on ``N`` at run
    time, so only its cap is static. Both are also clipped to the image.
    """
    half_height = min(int(max_half_height_px), math.ceil(height / beams) - 1, height - 1)
    half_width = min(int(max_half_width_px), width - 1)
    return max(half_width, 0), max(half_height, 0)


#: Rows per band: bands without a single valid pixel are skipped at run time.
_BAND_ROWS = 32


@functools.partial(jax.jit, static_argnames=("beams", "half_width", "half_height"))
def _keep_mask(sparse_depth, K, T_cam_lidar, points_cam, epsilon_m, *, beams, half_width, half_height):
    height, width = sparse_depth.shape
    hh, hw = half_height, half_width
    band = min(_BAND_ROWS, height)
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
    h_c, g_c = _lidar_angles(depth_c, K.astype(jnp.float32), T_cam_lidar.astype(jnp.float32)[:3, 3],
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
            flip = _flip(du_sign, dv, h_p, g_p, q(h_c), q(g_c))
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


def outlier_keep_mask(sparse_depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array, *, beams: int,
                      epsilon_m: float = 1.0, max_half_width_px: int = 12, max_half_height_px: int = 24,
                      points_cam: jax.Array | None = None) -> jax.Array:
    """Occlusion outlier mask of a sparse LiDAR depth image (the paper's Algorithm 1).

    Args:
      sparse_depth: (H, W) float32 camera depth z, metres; 0 (or any value that
        is not a finite positive number) marks an empty pixel.
      K: (3, 3) float32 camera intrinsics, pixels.
      T_cam_lidar: (4, 4) float32 LiDAR -> camera transform; only the LiDAR
        origin ``t = T_cam_lidar[:3, 3]`` (in the camera frame) is used.
      beams: static number of LiDAR beams L (64 for KITTI's HDL-64E).
      epsilon_m: condition 2's depth margin, metres (paper: 1.0); a traced
        scalar is accepted (changing it does not recompile).
      max_half_width_px: static cap on ``|du|``; offsets with ``|du| >=
        W L / N`` are skipped at run time, offsets beyond the cap never visited.
      max_half_height_px: static cap on ``|dv|``; the window uses
        ``|dv| <= min(cap, ceil(H / L) - 1)``, i.e. the paper's ``|dv| < H / L``.
      points_cam: optional (3, H, W) float32 camera-frame coordinates (x, y, z),
        metres, of the LiDAR point that won each pixel (raw sweep input). When
        None, each pixel's point is back-projected from its centre through
        ``K`` (image-only input: angles then carry the +-0.5 px rounding of
        the projection).

    Returns:
      (H, W) bool: True where a sparse pixel is kept; False where it is
      removed and where the pixel is empty.

    Angles. The paper uses the spherical angles (theta, phi) of each point in
    the LiDAR frame. Their orientation is a matter of axes (KITTI's LiDAR has
    theta growing to the left, against u), so here they are measured from the
    LiDAR origin in camera-aligned axes, ``q = p_cam - t``, with signs chosen
    so that they grow with u and v:

      theta = atan2(q_x, q_z)   (azimuth, grows with u),
      phi   = atan2(q_y, q_z)   (tilt in the y-z plane, grows with v).

    Condition 1 is then exactly the paper's test, read as "the order of the two
    points as seen from the LiDAR differs from their order on the image". Note
    phi is the tilt of the ray's y-z projection, not the elevation
    ``atan2(q_y, hypot(q_x, q_z))``: both agree on order when the two points
    share an azimuth, and for a zero LiDAR-camera offset (t = 0, no skew in
    ``K``) this choice makes angle order and pixel order identical, so nothing
    is ever removed without parallax; the elevation can disagree with the row
    order between points a few columns apart at wide field angles (scan lines
    bow in the image) and would then flag points no occlusion explains. Only
    order matters, so ``atan2`` is replaced by a strictly increasing stand-in
    (``_pseudo_angle``). Points closer than the LiDAR is ahead of the camera
    (``q_z <= 0``) get the continuation of atan2 past +-pi/2; their order has
    no meaning there.

    Differences from the paper's double loop (the test oracle):
      * one point per pixel (the projection's z-buffer winner); ``N`` is the
        number of valid pixels, counted at run time;
      * the horizontal window is capped at ``max_half_width_px`` (the paper's
        bound applies below the cap);
      * the test runs on all points at once: ``i`` is removed if any ``j`` in
        S(i) qualifies, whether or not ``j`` itself is removed, which is what
        the paper's loop does too (it never updates S during the loop).

    Condition 2 always uses ``sparse_depth`` as z, also when ``points_cam`` is
    given.

    Under ``vmap`` the skips become selects: every row band is computed, and
    the |du| loop runs to the largest bound in the batch (same result, more
    work).
    """
    sparse_depth = jnp.asarray(sparse_depth)
    if sparse_depth.ndim != 2:
        raise ValueError(f"outlier_keep_mask: field 'sparse_depth' expected shape (H, W), got {sparse_depth.shape}")
    K = jnp.asarray(K)
    if K.shape != (3, 3):
        raise ValueError(f"outlier_keep_mask: field 'K' expected shape (3, 3), got {K.shape}")
    T_cam_lidar = jnp.asarray(T_cam_lidar)
    if T_cam_lidar.shape != (4, 4):
        raise ValueError(f"outlier_keep_mask: field 'T_cam_lidar' expected shape (4, 4), got {T_cam_lidar.shape}")
    if points_cam is not None:
        points_cam = jnp.asarray(points_cam)
        if points_cam.shape != (3, *sparse_depth.shape):
            raise ValueError(
                f"outlier_keep_mask: field 'points_cam' expected shape {(3, *sparse_depth.shape)}, "
                f"got {points_cam.shape}")
    if int(beams) != beams or beams < 1:
        raise ValueError(f"outlier_keep_mask: field 'beams' expected a positive integer, got {beams!r}")
    if isinstance(epsilon_m, numbers.Real) and not (math.isfinite(epsilon_m) and epsilon_m >= 0):
        raise ValueError(f"outlier_keep_mask: field 'epsilon_m' expected a finite value >= 0, got {epsilon_m!r}")
    for name, value in (("max_half_width_px", max_half_width_px), ("max_half_height_px", max_half_height_px)):
        if int(value) != value or value < 0:
            raise ValueError(f"outlier_keep_mask: field {name!r} expected a non-negative integer, got {value!r}")
    height, width = sparse_depth.shape
    half_width, half_height = window_half_sizes(
        height, width, beams=int(beams), max_half_width_px=int(max_half_width_px),
        max_half_height_px=int(max_half_height_px))
    return _keep_mask(sparse_depth, K, T_cam_lidar, points_cam, jnp.asarray(epsilon_m, jnp.float32),
                      beams=int(beams), half_width=half_width, half_height=half_height)
