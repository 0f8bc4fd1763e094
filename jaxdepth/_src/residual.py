"""Step 4a: the residual Delta z of the paper's local-plane model.

A pixel (u, v) whose nearest LiDAR pixel sits at (u + du, v + dv) with depth z'
and surface normal n shares that surface, so (paper, eq. for Delta z)::

    Delta z = n . (z' du / fu, z' dv / fv, 0) / n . ((u - pu) / fu, (v - pv) / fv, 1)

and the completed depth is z = z' + Delta z. For a planar scene and exact normals
this is exact. The model is the paper's zero-skew pinhole (K[0, 1] is ignored).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.geometry import pixel_grid

_DEFAULTS = DEFAULT_CONFIG


def plane_residual(seed_depth: jax.Array, seed_normal: jax.Array, du: jax.Array, dv: jax.Array,
                   K: jax.Array, *, min_abs_denom: float = _DEFAULTS.min_abs_denom,
                   max_residual_ratio: float = _DEFAULTS.max_residual_ratio) -> jax.Array:
    """Delta z for every pixel from its nearest seed.

    Args:
      seed_depth: (H, W) float32 metres, z' of the nearest seed (0 = no seed).
      seed_normal: (3, H, W) float32 unit normal n of the nearest seed, camera frame.
      du, dv: (H, W) int32 offsets in pixels; the seed is at (u + du, v + dv).
      K: (3, 3) intrinsics (fu = K[0,0], fv = K[1,1], pu = K[0,2], pv = K[1,2]).
      min_abs_denom: |denominator| at or below this (surface seen at a grazing
        angle, or a zero normal) gives Delta z = 0. The safe-where pattern keeps
        values and gradients finite. Default: ``SGMConfig().min_abs_denom``.
      max_residual_ratio: |Delta z| is clipped to this fraction of z'. Default:
        ``SGMConfig().max_residual_ratio``.

    Returns:
      (H, W) float32 Delta z in metres; 0 where there is no seed.

    Examples:
      A plane tilted about the camera's y axis, one seed at depth 10 m in the
      left pixel: the completed depths ``z' + Delta z`` lie on the plane
      through the seed point (10, 9.925, 9.8511 m, by hand from n . X = n . X').

      >>> import jax.numpy as jnp
      >>> import numpy as np
      >>> from jaxdepth._src.residual import plane_residual
      >>> K = jnp.array([[100.0, 0.0, 1.0], [0.0, 100.0, 0.0], [0.0, 0.0, 1.0]])
      >>> seed_depth = jnp.full((1, 3), 10.0)
      >>> seed_normal = jnp.broadcast_to(jnp.array([-0.6, 0.0, -0.8])[:, None, None], (3, 1, 3))
      >>> du = jnp.array([[0, -1, -2]], jnp.int32)
      >>> dz = plane_residual(seed_depth, seed_normal, du, jnp.zeros((1, 3), jnp.int32), K)
      >>> print(np.round(np.asarray(seed_depth + dz), 4))
      [[10.      9.925   9.8511]]
    """
    K = jnp.asarray(K, jnp.float32)
    fu, fv, pu, pv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    h, w = seed_depth.shape
    v, u = pixel_grid(h, w)
    nx, ny, nz = seed_normal[0], seed_normal[1], seed_normal[2]
    numer = seed_depth * (du.astype(jnp.float32) * nx / fu + dv.astype(jnp.float32) * ny / fv)
    denom = (u - pu) / fu * nx + (v - pv) / fv * ny + nz
    ok = (jnp.abs(denom) > min_abs_denom) & (seed_depth > 0)
    residual = jnp.where(ok, numer / jnp.where(ok, denom, 1.0), 0.0)
    bound = max_residual_ratio * seed_depth
    return jnp.clip(residual, -bound, bound)
