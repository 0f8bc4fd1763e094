"""The spherical range image of a LiDAR sweep (the binning half of Step 1).

Following the paper (its "Surface Normal" paragraph, after Badino et al. 2011),
every LiDAR point ``p = (x, y, z)`` (LiDAR frame, metres) is mapped to spherical
coordinates

* range ``r = |p|``,
* azimuth ``theta = atan2(y, x)`` in ``[-pi, pi]``,
* elevation ``phi = atan2(z, sqrt(x^2 + y^2)) = asin(z / r)`` in ``[-pi/2, pi/2]``,

and binned into an ``(L, C)`` range image (``L = lidar.beams`` rows,
``C = lidar.columns`` columns), on which :mod:`jaxdepth._src.normals` fits the
surface normals.

Range-image layout (a :class:`~jaxdepth.LidarSpec` is all that is assumed about the sensor):

* row ``i = floor((fov_up - phi) / (fov_up - fov_down) * L)`` clipped to
  ``[0, L - 1]``: row 0 is the highest elevation; points outside the vertical
  field of view fall in the first or last row.
* column ``j = floor((pi - theta) / (2 pi) * C) mod C``: column 0 starts behind
  the sensor (``theta = pi``), azimuth decreases to the right, and ``theta = 0``
  (straight ahead, +x) sits at column ``C / 2``; the image wraps around.
* the point with the smallest range wins a cell (scatter-min; equal ranges: the
  smaller point index).

Angles come from the polynomial :func:`~jaxdepth._src.fastmath.atan2` (error
< 1e-7 rad, no transcendental library call).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.fastmath import PI, atan2
from jaxdepth._src.geometry import scatter_argmin
from jaxdepth._src.xla_tuning import stage
from jaxdepth._src.types import LidarSpec

#: Points closer than this to the sensor origin (metres) are treated as invalid.
MIN_RANGE_M = 1e-6


class RangeImage(NamedTuple):
    """A spherical range image of one sweep.

    Attributes:
      r: (L, C) float32 range of the winning point, metres; 0 where empty.
      theta: (L, C) float32 azimuth of the winning point, radians in [-pi, pi];
        the cell-centre azimuth where empty.
      phi: (L, C) float32 elevation of the winning point, radians; the
        cell-centre elevation where empty.
      index: (L, C) int32 index of the point that won the cell (nearest range;
        equal ranges: smaller index); -1 where empty.
      cell: (N,) int32 flat cell index ``row * C + col`` of every valid point
        (also of points that lost their cell); -1 for invalid points.
    """

    r: jax.Array
    theta: jax.Array
    phi: jax.Array
    index: jax.Array
    cell: jax.Array


# --------------------------------------------------------------------- validation


def check_points(points, valid):
    """Raises ValueError unless points is (N, 3) floating and valid is (N,)."""
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points: expected shape (N, 3), got {tuple(points.shape)}")
    if valid.shape != (points.shape[0],):
        raise ValueError(f"valid: expected shape ({points.shape[0]},) matching points, got {tuple(valid.shape)}")
    if not jnp.issubdtype(points.dtype, jnp.floating):
        raise ValueError(f"points: expected a floating dtype, got {points.dtype}")


def check_lidar(lidar):
    """Raises ValueError unless lidar is a LidarSpec."""
    if not isinstance(lidar, LidarSpec):
        raise ValueError(f"lidar: expected a LidarSpec, got {type(lidar).__name__}")


# -------------------------------------------------------------------- range image


def cell_centres(lidar: LidarSpec):
    """Static (1, C) azimuth and (L, 1) elevation of the cell centres, float32 numpy."""
    cols = np.arange(lidar.columns, dtype=np.float64)
    rows = np.arange(lidar.beams, dtype=np.float64)
    theta = PI - (cols + 0.5) * (2 * PI / lidar.columns)
    span = lidar.fov_up_rad - lidar.fov_down_rad
    phi = lidar.fov_up_rad - (rows + 0.5) * (span / lidar.beams)
    return theta.astype(np.float32)[None, :], phi.astype(np.float32)[:, None]


def _spherical(points: jax.Array, valid: jax.Array, lidar: LidarSpec):
    """Per-point range, angles, flat cell and validity of (N, 3) points."""
    pts = points.astype(jnp.float32)
    return _spherical_xyz(pts[:, 0], pts[:, 1], pts[:, 2], valid, lidar)


def _spherical_xyz(x, y, z, valid, lidar: LidarSpec):
    """Range, angles, flat cell and validity of points given as coordinate arrays (any shape)."""
    r, theta, phi, ok = angles_xyz(x, y, z, valid)
    row, col = row_col(theta, phi, lidar)
    cell = jnp.where(ok, row * lidar.columns + col, -1)
    return r, theta, phi, cell, ok


def angles_xyz(x, y, z, valid):
    """Range (0 where invalid), azimuth, elevation and validity of coordinate arrays."""
    rho2 = x * x + y * y
    r2 = rho2 + z * z
    ok = valid.astype(bool) & jnp.isfinite(r2) & (r2 > MIN_RANGE_M * MIN_RANGE_M)
    r = jnp.where(ok, jnp.sqrt(jnp.where(ok, r2, 1.0)), 0.0)  # safe sqrt: finite gradients
    rho_ok = ok & (rho2 > 0)
    rho = jnp.where(rho_ok, jnp.sqrt(jnp.where(rho_ok, rho2, 1.0)), 0.0)
    theta = atan2(y, x)
    phi = atan2(z, rho)
    return r, theta, phi, ok


def row_col(theta, phi, lidar: LidarSpec):
    """Range-image row and column (int32, in range) of azimuths and elevations."""
    n_rows, n_cols = lidar.beams, lidar.columns
    col = jnp.floor((PI - theta) * (n_cols / (2 * PI))).astype(jnp.int32)
    col = jnp.where(col >= n_cols, col - n_cols, col)
    col = jnp.clip(col, 0, n_cols - 1)
    span = lidar.fov_up_rad - lidar.fov_down_rad
    row_f = (lidar.fov_up_rad - phi) * (n_rows / span)
    row = jnp.clip(jnp.floor(jnp.clip(row_f, -1.0, n_rows)), 0, n_rows - 1).astype(jnp.int32)
    return row, col


def _slot_and_key(r, cell, ok, n_cells: int):
    """Scatter slot (``n_cells`` = dump for invalid points) and int32 order key of the range."""
    slot = jnp.where(ok, cell, n_cells)
    # Non-negative float32 ranges order like their int32 bit patterns.
    key = jnp.where(ok, jax.lax.bitcast_convert_type(r, jnp.int32), jnp.iinfo(jnp.int32).max)
    return slot, key


def range_image_and_slots(points: jax.Array, valid: jax.Array, lidar: LidarSpec, rows: jax.Array | None = None):
    """The range image and each point's materialised flat cell (``L * C`` for invalid points).

    ``rows``: optional (N,) int32 row of each point (its laser's rank by elevation, for sensors
    whose beams are not evenly spaced); -1 (or None) takes the row from the elevation.
    """
    n_cells = lidar.beams * lidar.columns

    def per_point(points, valid, *rows):
        r, theta, phi, cell, ok = _spherical(points, valid, lidar)
        if rows:
            given = jnp.clip(rows[0], 0, lidar.beams - 1) * lidar.columns + cell % lidar.columns
            cell = jnp.where(ok & (rows[0] >= 0), given, cell)
        return _slot_and_key(r, cell, ok, n_cells) + (r, theta, phi)

    slot, key, r, theta, phi = stage(per_point, (points, valid) + (() if rows is None else (rows,)),
                                     valid[0].astype(jnp.int32))
    return _bin(slot, key, r, theta, phi, lidar), slot


def _bin(slot, key, r, theta, phi, lidar: LidarSpec) -> RangeImage:
    """Scatter-min of (N,) points into the range image (nearest range; ties: smaller index)."""
    n = slot.shape[0]
    n_rows, n_cols = lidar.beams, lidar.columns
    n_cells = n_rows * n_cols
    _, idx = scatter_argmin(slot, key, n_cells, fill=jnp.iinfo(jnp.int32).max)
    has = idx < n
    safe = jnp.where(has, idx, 0)
    theta_c, phi_c = cell_centres(lidar)
    r_img = jnp.where(has, r.at[safe].get(mode="promise_in_bounds"), 0.0)
    th_img = jnp.where(has, theta.at[safe].get(mode="promise_in_bounds"),
                       jnp.broadcast_to(theta_c, (n_rows, n_cols)).reshape(-1))
    ph_img = jnp.where(has, phi.at[safe].get(mode="promise_in_bounds"),
                       jnp.broadcast_to(phi_c, (n_rows, n_cols)).reshape(-1))
    shape = (n_rows, n_cols)
    return RangeImage(r=r_img.reshape(shape), theta=th_img.reshape(shape), phi=ph_img.reshape(shape),
                      index=jnp.where(has, idx, -1).reshape(shape), cell=jnp.where(slot < n_cells, slot, -1))


@functools.partial(jax.jit, static_argnames=("lidar",))
def range_image(points: jax.Array, valid: jax.Array, *, lidar: LidarSpec) -> RangeImage:
    """Bins one LiDAR sweep into a spherical range image (nearest point per cell).

    Args:
      points: (N, 3) float LiDAR-frame points, metres.
      valid: (N,) bool. Points that are masked, non-finite or closer than
        ``MIN_RANGE_M`` (e.g. at the origin) are ignored.
      lidar: static :class:`~jaxdepth.LidarSpec` giving L = beams rows over
        [fov_down, fov_up] and C = columns over 360 degrees.

    Returns:
      :class:`RangeImage` with (L, C) fields ``r``, ``theta``, ``phi``, ``index``
      and the (N,) ``cell`` of every point (layout in the module docstring).

    Oracle: a NumPy loop over points (tests). Azimuth and elevation come from a
    float32 polynomial ``atan2`` (error < 1e-7 rad), so a point within ~1e-7 rad
    of a cell boundary may land in the neighbouring cell compared with float64.
    """
    check_lidar(lidar)
    points = jnp.asarray(points)
    valid = jnp.asarray(valid)
    check_points(points, valid)
    return range_image_and_slots(points, valid, lidar)[0]
