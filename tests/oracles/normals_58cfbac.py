"""FROZEN ORACLE: jaxdepth/_src/normals.py at commit 58cfbac, verbatim except this
header and the staging import (a frozen copy too, ``staging_58cfbac``).

The version before the fit, neighbour search and smoothing were re-fused for speed;
tests/test_normals.py checks the current normals equal it up to float32 rounding.
Do not edit or reformat: it is a reference, not library code.
"""
# flake8: noqa
# ruff: noqa

from __future__ import annotations

"""Step 1 of the Surface Geometry Model: spherical range image and surface normals.

Following the paper (its "Surface Normal" paragraph, after Badino et al. 2011),
every LiDAR point ``p = (x, y, z)`` (LiDAR frame, metres) is mapped to spherical
coordinates

* range ``r = |p|``,
* azimuth ``theta = atan2(y, x)`` in ``[-pi, pi]``,
* elevation ``phi = atan2(z, sqrt(x^2 + y^2)) = asin(z / r)`` in ``[-pi/2, pi/2]``,

and binned into an ``(L, C)`` range image (``L = lidar.beams`` rows,
``C = lidar.columns`` columns). The surface seen by the sensor is the graph
``r(theta, phi)``; its normal follows from the partial derivatives ``r_theta``,
``r_phi`` estimated by finite differences on the range image.

Range-image layout (a :class:`~jaxdepth.LidarSpec` is all that is assumed about the sensor):

* row ``i = floor((fov_up - phi) / (fov_up - fov_down) * L)`` clipped to
  ``[0, L - 1]``: row 0 is the highest elevation; points outside the vertical
  field of view fall in the first or last row.
* column ``j = floor((pi - theta) / (2 pi) * C) mod C``: column 0 starts behind
  the sensor (``theta = pi``), azimuth decreases to the right, and ``theta = 0``
  (straight ahead, +x) sits at column ``C / 2``; the image wraps around.
* the point with the smallest range wins a cell (scatter-min; equal ranges: the
  smaller point index).

Normal formula and its relation to the paper
-------------------------------------------
Let ``e_r, e_theta, e_phi`` be the columns of the paper's
``R(theta, phi) = Rz(theta) Ry(phi)``::

    e_r     = ( cos(theta) cos(phi),  sin(theta) cos(phi), sin(phi))
    e_theta = (-sin(theta),           cos(theta),          0       )
    e_phi   = (-cos(theta) sin(phi), -sin(theta) sin(phi), cos(phi))

The surface is the zero set of ``F(p) = |p| - r(theta(p), phi(p))``. With
``grad |p| = e_r``, ``grad theta = e_theta / (r cos phi)`` and
``grad phi = e_phi / r``::

    grad F = e_r - r_theta / (r cos phi) e_theta - r_phi / r e_phi.

The paper prints ``R (1, r_theta / (r cos phi), r_phi / r)^T``: the two
derivative terms carry the opposite sign relative to the radial term, which is
not a normal of the surface (a wall ``x = d`` seen at ``phi != 0`` gets a
spurious z component; a wall seen at a yaw gets the tangential component doubled
instead of cancelled). This module returns the sensor-facing normal

    n = normalize(-e_r + r_theta / (r cos phi) e_theta + r_phi / r e_phi)
      = -normalize(grad F)
      = R (-1, r_theta / (r cos phi), r_phi / r)^T / |...|,

i.e. the paper's vector with the sign of its first (radial) component flipped,
where ``r_theta`` and ``r_phi`` are true derivatives with respect to the
increasing angles (finite differences divide by the real, signed angle offsets
of the neighbouring points, so the column/row direction of the image does not
enter). The result satisfies ``n . p <= 0`` (it faces the sensor); tests check
it against ray-cast analytic planes.

Derivative scheme (robust at depth discontinuities)
--------------------------------------------------
For each measured cell the nearest measured cell is searched in each of the
four image directions within ``1 + fill_max_gap`` steps (columns wrap around
360 degrees, rows do not), keeping only neighbours inside the 90-degree cone of
that direction (a row of a linear range image can hold two beams; the other
beam's point next door is a vertical neighbour). Each neighbour k gives an
equation ``z_k = a x_k + b y_k`` with the real angle offsets
``x_k = dtheta_k cos(phi)``, ``y_k = dphi_k`` and ``z_k = dr_k / r``, where
``a = r_theta / (r cos phi)`` and ``b = r_phi / r``. (a, b) is their weighted
least-squares solution, normalised per equation by its angular length, in two
passes: Cauchy weights on the neighbour's slope |z_k| / |(x_k, y_k)| (a
neighbour across a depth edge is steep and drops out), then Cauchy weights on
its residual slope under the first fit (on a smooth surface both sides weigh
alike, which makes the estimate a central difference). The 2x2 system is
solved with exact pair-sum formulas and a tiny ridge, so collinear neighbours
give the minimum-norm answer (the unseen derivative is 0) and an isolated
point gets ``n = -p / |p|``. Such poorly constrained normals get a weight down
to ``_PARTIAL_WEIGHT`` in the smoothing, so a well-constrained neighbour wins.

Filling and smoothing (the paper's "extra step to fill in those empty pixels")
-----------------------------------------------------------------------------
Every cell takes the renormalised weighted mean of the raw normals of the
measured cells in its ``(2 max(1, smoothing) + 1)^2`` window (columns wrap,
rows are cut at the border); with ``smoothing = 0`` measured cells keep their
raw normal. Empty cells still without a value are filled by ``fill_max_gap``
passes of the 3x3 mean of filled neighbours; cells still empty after that face
the sensor along their cell-centre ray (``-e_r``). Filling never changes a
measured cell. Every normal is oriented so that ``n . e_r <= 0`` along the ray
of its point (cell centre for empty cells). Points that lost their cell to a
nearer point read the normal of that cell, oriented towards the sensor along
their own ray, so every valid point has a unit normal.

Performance notes: XLA:CPU fuses a producer into every consumer, so shifted
slices and per-point gathers would re-run upstream work; heavy intermediates
are computed inside ``_stage`` conditionals (real buffers), and pairs of
float32 channels travel as one complex64 array so one fusion computes both.
Gathers and scatters cost ~2-5 ns per element on XLA:CPU, elementwise work far
less, so on image input (:func:`pixel_normals`) the few % of pixels with depth
are listed first with elementwise passes, small triangular matrix products
(prefix sums) and a scatter over the 32-pixel words of the mask only
(:func:`_compact_pixels`); back-projection, ``atan2`` binning, the
scatter-mins and the gathers then run on those points only.

Numerics: no transcendental library calls (XLA's CPU ``atan2``/``asin``/``sin``
are ~30x slower than a fused polynomial); ``atan2`` uses an octant reduction
and a least-squares polynomial (max error < 1e-7 rad), sine and cosine a
quadrant reduction and Taylor series (error < 1e-7). Every division is guarded
with the safe-``where`` pattern, and the derivative ratios are clipped to
``+-1e4`` (a surface within 0.006 degrees of grazing), so no NaN or Inf can
arise from finite input.
"""


import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from oracles.staging_58cfbac import cond_all, stage
from jaxdepth._src.types import LidarSpec

#: Points closer than this to the sensor origin (metres) are treated as invalid.
MIN_RANGE_M = 1e-6
#: Neighbour angle offsets below this (radians) are not used for differences.
_MIN_ANGLE_STEP = 1e-6
#: |r_theta / (r cos phi)| and |r_phi / r| are clipped to this.
_MAX_SLOPE = 1e4
#: Ridge (relative to the trace) of the 2x2 least-squares system for the slopes:
#: biases well-spread systems (det ~ trace^2 / 4) by ~4e-5.
_RIDGE = 1e-5
#: det / trace^2 of that system (1/4 for neighbours at right angles) at which a
#: normal gets full weight in the smoothing.
_MIN_SPREAD = 0.05
#: Weight in the smoothing of a normal that lacks one of its two derivatives.
_PARTIAL_WEIGHT = 1e-3

_PI = math.pi
_TAN_PI_8 = math.tan(math.pi / 8.0)
# atan(u) ~= u + u^3 P(u^2) on |u| <= tan(pi/8): least-squares fit of
# (atan(u)/u - 1)/u^2 by a cubic in s = u^2 on 4000 Chebyshev nodes (float64,
# numpy.linalg.lstsq); measured max abs error 4.8e-8 rad in float32.
_ATAN_COEFFS = (-0.3333328808480196, 0.19991394133810128, -0.14026550211532, 0.08529792624477861)
# pi/2 split into a float32 head and a tail for the quadrant reduction.
_PIO2_HI = float(np.float32(math.pi / 2))
_PIO2_LO = math.pi / 2 - _PIO2_HI


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


# --------------------------------------------------------------------------- numerics


def _atan2(y: jax.Array, x: jax.Array) -> jax.Array:
    """Polynomial float32 ``atan2(y, x)`` in [-pi, pi] (max error < 1e-7 rad); atan2(0, 0) = 0."""
    ax = jnp.abs(x)
    ay = jnp.abs(y)
    hi = jnp.maximum(ax, ay)
    lo = jnp.minimum(ax, ay)
    ok = hi > 0
    t = jnp.where(ok, lo / jnp.where(ok, hi, 1.0), 0.0)  # in [0, 1]
    big = t > _TAN_PI_8
    u = jnp.where(big, (t - 1.0) / (t + 1.0), t)  # |u| <= tan(pi/8)
    s = u * u
    c0, c1, c2, c3 = _ATAN_COEFFS
    p = ((c3 * s + c2) * s + c1) * s + c0
    a = u + u * s * p
    a = jnp.where(big, a + _PI / 4, a)
    a = jnp.where(ay > ax, _PI / 2 - a, a)
    a = jnp.where(x < 0, _PI - a, a)
    return jnp.where(y < 0, -a, a)


def _sin_cos_small(t: jax.Array, half_width: float):
    """Float32 (sin t, cos t) by Taylor series for |t| <= half_width (static bound).

    Terms are added until the next one is below 1e-8 at ``half_width``.
    """
    t2 = t * t
    sin_terms, cos_terms = [], []
    n = 1
    while True:  # sin: t^n / n! for odd n; cos: t^(n-1) / (n-1)!
        sin_terms.append((-1) ** (n // 2) / math.factorial(n))
        cos_terms.append((-1) ** ((n - 1) // 2) / math.factorial(n - 1))
        if half_width ** (n + 1) / math.factorial(n + 1) < 1e-8 and half_width ** (n + 2) / math.factorial(
                n + 2) < 1e-8:
            break
        n += 2
    s = jnp.full_like(t, sin_terms[-1])
    c = jnp.full_like(t, cos_terms[-1])
    for a, b in zip(sin_terms[-2::-1], cos_terms[-2::-1]):
        s = s * t2 + a
        c = c * t2 + b
    return s * t, c


def _azimuth_basis(theta: jax.Array, window=None):
    """(sin, cos) of (L, C) azimuths that lie within half a column of their cell centre.

    Uses the static cell-centre angle and a short Taylor series of the offset.
    ``window = (col0, total_cols)``: the array holds the columns ``col0,
    col0 + 1, ...`` (mod ``total_cols``, ``col0`` traced) of a wider image.
    """
    cols = theta.shape[1]
    total = cols if window is None else window[1]
    centre = _PI - (np.arange(total, dtype=np.float64) + 0.5) * (2 * _PI / total)
    tables = (np.sin(centre).astype(np.float32), np.cos(centre).astype(np.float32), centre.astype(np.float32))
    if window is None:
        s_c, c_c, cen = (a[None, :] for a in tables)
    else:
        s_c, c_c, cen = (jax.lax.dynamic_slice(jnp.asarray(np.concatenate([a, a[:cols]])), (window[0],),
                                               (cols,))[None, :] for a in tables)
    delta = _wrap_angle(theta - cen)
    s_d, c_d = _sin_cos_small(delta, _PI / total + 1e-5)
    return s_c * c_d + c_c * s_d, c_c * c_d - s_c * s_d


def _wrap_angle(d: jax.Array) -> jax.Array:
    """Wraps an angle difference in (-2 pi, 2 pi) to [-pi, pi]."""
    d = jnp.where(d > _PI, d - 2 * _PI, d)
    return jnp.where(d < -_PI, d + 2 * _PI, d)


def _safe_div(num, den, ok):
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


# --------------------------------------------------------------- materialisation
#
# Heavy intermediates are computed inside ``_stage`` conditionals (real buffers
# that shifted slices and gathers read instead of re-running the producer):
# see :mod:`jaxdepth._src.staging`.

_stage = stage


# ------------------------------------------------------------------- image shifts
#
# Shifts are slices of a padded copy that is materialised first (an
# optimization barrier): XLA would otherwise fuse a concatenate into every
# consumer, which is ~6x slower than reading a buffer at an offset.


def _pad(arrays, k: int, fills, token, wrap=None):
    """Pads (L, C) arrays by k (materialised): columns wrap around 360 degrees
    (unless ``wrap[i]`` is False: the array is already column-padded), rows take ``fill``."""

    def pad(*arrays):
        out = []
        for i, (a, fill) in enumerate(zip(arrays, fills)):
            if k and (wrap is None or wrap[i]):
                a = jnp.concatenate([a[:, a.shape[1] - k:], a, a[:, :k]], axis=1)
            if k:
                rows = jnp.full((k, a.shape[1]), fill, a.dtype)
                a = jnp.concatenate([rows, a, rows], axis=0)
            out.append(a)
        return tuple(out)

    return _stage(pad, arrays, token)


def _at(padded: jax.Array, k: int, di: int, dj: int) -> jax.Array:
    """View of a ``_pad``-ed array: out[i, j] = a[i + di, (j + dj) mod C] (fill outside rows)."""
    rows = padded.shape[0] - 2 * k
    cols = padded.shape[1] - 2 * k
    return jax.lax.slice(padded, (k + di, k + dj), (k + di + rows, k + dj + cols))


def _box_sums(arrays, half: int, token):
    """(2 half + 1)^2 box sums; columns wrap, rows outside the image count as 0."""
    if half == 0:
        return tuple(arrays)
    padded = _pad(arrays, half, [0.0] * len(arrays), token)

    def horizontal(*padded):
        out = []
        for p in padded:
            h = jax.lax.slice(p, (0, 0), (p.shape[0], p.shape[1] - 2 * half))
            for dj in range(1, 2 * half + 1):
                h = h + jax.lax.slice(p, (0, dj), (p.shape[0], p.shape[1] - 2 * half + dj))
            out.append(h)
        return tuple(out)

    horiz = _stage(horizontal, padded, token)
    out = []
    for h in horiz:
        rows = h.shape[0] - 2 * half
        v = jax.lax.slice(h, (0, 0), (rows, h.shape[1]))
        for di in range(1, 2 * half + 1):
            v = v + jax.lax.slice(h, (di, 0), (di + rows, h.shape[1]))
        out.append(v)
    return tuple(out)


# --------------------------------------------------------------------- validation


def _check_points(points, valid):
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points: expected shape (N, 3), got {tuple(points.shape)}")
    if valid.shape != (points.shape[0],):
        raise ValueError(f"valid: expected shape ({points.shape[0]},) matching points, got {tuple(valid.shape)}")
    if not jnp.issubdtype(points.dtype, jnp.floating):
        raise ValueError(f"points: expected a floating dtype, got {points.dtype}")


def _check_options(smoothing, fill_max_gap):
    for name, value in (("smoothing", smoothing), ("fill_max_gap", fill_max_gap)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 0:
            raise ValueError(f"{name}: expected a non-negative integer, got {value!r}")


def _check_lidar(lidar):
    if not isinstance(lidar, LidarSpec):
        raise ValueError(f"lidar: expected a LidarSpec, got {type(lidar).__name__}")


# -------------------------------------------------------------------- range image


def _cell_centres(lidar: LidarSpec):
    """Static (1, C) azimuth and (L, 1) elevation of the cell centres, float32 numpy."""
    cols = np.arange(lidar.columns, dtype=np.float64)
    rows = np.arange(lidar.beams, dtype=np.float64)
    theta = _PI - (cols + 0.5) * (2 * _PI / lidar.columns)
    span = lidar.fov_up_rad - lidar.fov_down_rad
    phi = lidar.fov_up_rad - (rows + 0.5) * (span / lidar.beams)
    return theta.astype(np.float32)[None, :], phi.astype(np.float32)[:, None]


def _spherical(points: jax.Array, valid: jax.Array, lidar: LidarSpec):
    """Per-point range, angles, flat cell and validity of (N, 3) points."""
    pts = points.astype(jnp.float32)
    return _spherical_xyz(pts[:, 0], pts[:, 1], pts[:, 2], valid, lidar)


def _spherical_xyz(x, y, z, valid, lidar: LidarSpec):
    """Range, angles, flat cell and validity of points given as coordinate arrays (any shape)."""
    rho2 = x * x + y * y
    r2 = rho2 + z * z
    ok = valid.astype(bool) & jnp.isfinite(r2) & (r2 > MIN_RANGE_M * MIN_RANGE_M)
    r = jnp.where(ok, jnp.sqrt(jnp.where(ok, r2, 1.0)), 0.0)  # safe sqrt: finite gradients
    rho_ok = ok & (rho2 > 0)
    rho = jnp.where(rho_ok, jnp.sqrt(jnp.where(rho_ok, rho2, 1.0)), 0.0)
    theta = _atan2(y, x)
    phi = _atan2(z, rho)
    n_rows, n_cols = lidar.beams, lidar.columns
    col = jnp.floor((_PI - theta) * (n_cols / (2 * _PI))).astype(jnp.int32)
    col = jnp.where(col >= n_cols, col - n_cols, col)
    col = jnp.clip(col, 0, n_cols - 1)
    span = lidar.fov_up_rad - lidar.fov_down_rad
    row_f = (lidar.fov_up_rad - phi) * (n_rows / span)
    row = jnp.clip(jnp.floor(jnp.clip(row_f, -1.0, n_rows)), 0, n_rows - 1).astype(jnp.int32)
    cell = jnp.where(ok, row * n_cols + col, -1)
    return r, theta, phi, cell, ok


def _slot_and_key(r, cell, ok, n_cells: int):
    """Scatter slot (``n_cells`` = dump for invalid points) and int32 order key of the range."""
    slot = jnp.where(ok, cell, n_cells)
    # Non-negative float32 ranges order like their int32 bit patterns.
    key = jnp.where(ok, jax.lax.bitcast_convert_type(r, jnp.int32), jnp.iinfo(jnp.int32).max)
    return slot, key


def _range_image(points: jax.Array, valid: jax.Array, lidar: LidarSpec):
    """The range image and each point's materialised flat cell (``L * C`` for invalid points)."""
    n_cells = lidar.beams * lidar.columns

    def per_point(points, valid):
        r, theta, phi, cell, ok = _spherical(points, valid, lidar)
        return _slot_and_key(r, cell, ok, n_cells) + (r, theta, phi)

    slot, key, r, theta, phi = _stage(per_point, (points, valid), valid[0].astype(jnp.int32))
    return _bin(slot, key, r, theta, phi, lidar), slot


def _bin(slot, key, r, theta, phi, lidar: LidarSpec) -> RangeImage:
    """Scatter-min of (N,) points into the range image (nearest range; ties: smaller index)."""
    n = slot.shape[0]
    n_rows, n_cols = lidar.beams, lidar.columns
    n_cells = n_rows * n_cols
    best = jnp.full((n_cells + 1,), jnp.iinfo(jnp.int32).max, jnp.int32).at[slot].min(key)
    win = key == best.at[slot].get(mode="promise_in_bounds")
    ids = jnp.arange(n, dtype=jnp.int32)
    idx = jnp.full((n_cells + 1,), n, jnp.int32).at[jnp.where(win, slot, n_cells)].min(ids)[:n_cells]
    has = idx < n
    safe = jnp.where(has, idx, 0)
    theta_c, phi_c = _cell_centres(lidar)
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
    _check_lidar(lidar)
    points = jnp.asarray(points)
    valid = jnp.asarray(valid)
    _check_points(points, valid)
    return _range_image(points, valid, lidar)[0]


# ------------------------------------------------------------------------ normals


def _neighbour(padded, k: int, di: int, dj: int, centre):
    """Offsets to the nearest measured cell within k steps along (di, dj).

    Only neighbours inside the 90-degree cone of the search direction count
    (|x| >= |y| for columns, |y| >= |x| for rows): a row of the range image may
    hold two beams, and a point of the other beam next door is a vertical, not
    a horizontal, neighbour. Returns (xy, z): xy = complex(x, y) with
    x = dtheta cos(phi) and y = dphi (radians), z = dr / r; all 0 where there
    is no neighbour. (The padded azimuths are unwrapped across the 360-degree
    seam, so no wrapping is needed here.)
    """
    meas, r, th, ph, c_ph, inv_r = centre
    pm, pr, pt, pp = padded
    ok = x = y = z = None
    for s in range(k, 0, -1):  # nearest last, so it overrides farther ones
        cx = (_at(pt, k, s * di, s * dj) - th) * c_ph
        cy = _at(pp, k, s * di, s * dj) - ph
        cz = (_at(pr, k, s * di, s * dj) - r) * inv_r
        inside = jnp.abs(cx) >= jnp.abs(cy) if dj else jnp.abs(cy) >= jnp.abs(cx)
        cok = _at(pm, k, s * di, s * dj) & inside
        if ok is None:
            ok, x, y, z = cok, cx, cy, cz
        else:
            ok = ok | cok
            x, y, z = (jnp.where(cok, c, old) for c, old in ((cx, x), (cy, y), (cz, z)))
    ok = ok & meas
    x, y, z = (jnp.where(ok, v, 0.0) for v in (x, y, z))
    return jax.lax.complex(x, y), z


def _basis_pairs(th: jax.Array, ph: jax.Array, window=None):
    """((sin theta, cos theta), (sin phi, cos phi)) of the cell angles (``window``: see _azimuth_basis)."""
    return _azimuth_basis(th, window), _sin_cos_small(ph, _PI / 2)


def _solve_gradient(rows, weights):
    """Weighted least squares for (a, b) in z_k = a x_k + b y_k; returns (a, b, spread).

    The 2x2 normal equations are solved by Cramer's rule with the determinant
    and numerators written as sums over pairs of rows (Lagrange's identity),
    so a set of collinear neighbours gives exactly det = 0 instead of float32
    cancellation noise. A ridge of ``_RIDGE * trace`` then yields the
    minimum-norm solution (the unseen derivative is 0) and bounds the noise
    gain of nearly collinear sets. ``spread = det / trace^2`` is in [0, 1/4].
    """
    det = na = nb = 0.0
    trace = bx = by = 0.0
    for (_, x, y, z, _), w in zip(rows, weights):
        trace = trace + w * (x * x + y * y)
        bx, by = bx + w * x * z, by + w * y * z
    for j in range(len(rows)):
        for k in range(j + 1, len(rows)):
            _, xj, yj, zj, _ = rows[j]
            _, xk, yk, zk, _ = rows[k]
            ww = weights[j] * weights[k]
            c = xj * yk - xk * yj
            wc = ww * c
            det = det + wc * c
            na = na + wc * (yk * zj - yj * zk)
            nb = nb + wc * (xj * zk - xk * zj)
    lam = _RIDGE * trace
    den = det + lam * (trace + lam)
    ok = trace > 0
    a = _safe_div(na + lam * bx, den, ok)
    b = _safe_div(nb + lam * by, den, ok)
    spread = _safe_div(det, trace * trace, ok)
    return a, b, spread


def _fit_slopes(*rows):
    """Robust slopes (complex(a, b), smoothing weight) from four (complex(x, y), z) rows."""
    eqs = []
    for xy, z in zip(rows[0::2], rows[1::2]):
        x, y = jnp.real(xy), jnp.imag(xy)
        q = x * x + y * y
        ok = q > _MIN_ANGLE_STEP ** 2
        eqs.append((ok, x, y, z, _safe_div(1.0, q, ok)))
    # Pass 1 down-weights steep neighbours (likely across a depth edge), pass 2
    # re-weights by the residual slope of the pass-1 fit (IRLS, Cauchy weights);
    # each equation is normalised by its angular length.
    w1 = [jnp.where(ok, iq / (1.0 + z * z * iq), 0.0) for ok, x, y, z, iq in eqs]
    a, b, _ = _solve_gradient(eqs, w1)
    w2 = []
    for ok, x, y, z, iq in eqs:
        e = z - a * x - b * y
        w2.append(jnp.where(ok, iq / (1.0 + e * e * iq), 0.0))
    a, b, spread = _solve_gradient(eqs, w2)
    # Weight for the smoothing: 1 when the neighbours span both directions,
    # falling linearly to _PARTIAL_WEIGHT as they become collinear.
    full = jnp.clip(spread * (1.0 / _MIN_SPREAD), _PARTIAL_WEIGHT, 1.0)
    ab = jax.lax.complex(jnp.clip(a, -_MAX_SLOPE, _MAX_SLOPE), jnp.clip(b, -_MAX_SLOPE, _MAX_SLOPE))
    return ab, full


def _raw_normals(ri: RangeImage, fill_max_gap: int, window=None):
    """Sensor-facing unit normals of measured cells, zeros at empty cells.

    Returns (meas, weight, nx, ny, nz); ``weight`` in [_PARTIAL_WEIGHT, 1] is 1
    where the neighbours constrain both derivatives and small where they are
    (nearly) collinear (the unseen derivative is then ~0).
    """
    meas = ri.index >= 0
    r, th, ph = ri.r, ri.theta, ri.phi
    k = 1 + fill_max_gap
    token = ri.index[0, 0]
    # Columns wrap; azimuths in the pads are unwrapped (left of column 0 lie
    # azimuths just above +pi, right of the last column just below -pi).
    cols = th.shape[1]
    th_wrapped = jnp.concatenate([th[:, cols - k:] + 2 * _PI, th, th[:, :k] - 2 * _PI], axis=1)
    padded = _pad((meas, r, th_wrapped, ph), k, (False, 0.0, 0.0, 0.0), token, wrap=(True, True, False, True))
    # Complex numbers carry two float32 channels through one fusion (XLA:CPU
    # would otherwise compute each output in its own fusion, repeating the work).
    # (The window start is an operand: a stage may not close over traced values.)
    start = () if window is None else (window[0],)
    e_th, e_ph = _stage(
        lambda th, ph, *start: tuple(jax.lax.complex(c, s) for s, c in _basis_pairs(
            th, ph, None if window is None else (start[0], window[1]))),
        (th, ph) + start, token)
    c_th, s_th, c_ph, s_ph = jnp.real(e_th), jnp.imag(e_th), jnp.real(e_ph), jnp.imag(e_ph)
    inv_r = _safe_div(1.0, r, meas)
    centre = (meas, r, th, ph, c_ph, inv_r)
    rows = []
    for di, dj in ((0, -1), (0, 1), (-1, 0), (1, 0)):
        xy, z = _stage(lambda *a, di=di, dj=dj: _neighbour(a[:4], k, di, dj, a[4:]), padded + centre, token)
        rows.append((xy, z))
    ab, full = _stage(_fit_slopes, tuple(a for row in rows for a in row), token)
    a, b = jnp.real(ab), jnp.imag(ab)

    inv = jnp.where(meas, jax.lax.rsqrt(1.0 + a * a + b * b), 0.0)  # |(-1, a, b)| >= 1
    # n = -e_r + a e_theta + b e_phi, normalised (the basis is orthonormal), with
    # a = r_theta / (r cos phi) and b = r_phi / r.
    nx = (-c_th * c_ph - a * s_th - b * c_th * s_ph) * inv
    ny = (-s_th * c_ph + a * c_th - b * s_th * s_ph) * inv
    nz = (-s_ph + b * c_ph) * inv
    return meas, full, nx, ny, nz


def _normalise(nx, ny, nz, ok):
    n2 = nx * nx + ny * ny + nz * nz
    good = ok & (n2 > 1e-12)
    inv = jnp.where(good, jax.lax.rsqrt(jnp.where(good, n2, 1.0)), 0.0)
    return good, nx * inv, ny * inv, nz * inv


def _smoothed_normals(raw, radius: int, token):
    """Weighted box mean of the measured cells' raw normals within ``radius`` cells.

    Normals with both derivatives weigh 1, those with a missing derivative
    (taken as 0) weigh ``_PARTIAL_WEIGHT``, so they only matter where no full
    estimate is in the window. Returns (has, nx, ny, nz): ``has`` marks cells
    with a measured cell in the window (their normal is unit), others are zero.
    """
    meas, w, nx, ny, nz = raw
    if radius == 0:
        return meas, nx, ny, nz
    sx, sy, sz = _box_sums((nx * w, ny * w, nz * w), radius, token)
    return _normalise(sx, sy, sz, jnp.ones_like(meas))


def _normal_channels(ri: RangeImage, smoothing: int, fill_max_gap: int):
    """Every cell's sensor-facing unit normal (three (L, C) channels)."""
    token = ri.index[0, 0]
    raw = _raw_normals(ri, fill_max_gap)
    has, nx, ny, nz = _smoothed_normals(raw, max(1, smoothing), token)
    if smoothing == 0:  # measured cells keep their own normal, empty ones the 3x3 mean
        meas, _, rx, ry, rz = raw
        nx, ny, nz = (jnp.where(meas, a, b) for a, b in ((rx, nx), (ry, ny), (rz, nz)))
        has = has | meas
    for _ in range(fill_max_gap):
        nx, ny, nz, has = _stage(lambda *a: a, (nx, ny, nz, has), ri.index[0, 0])
        w = has.astype(jnp.float32)
        sx, sy, sz = _box_sums((nx * w, ny * w, nz * w), 1, ri.index[0, 0])
        grow, gx, gy, gz = _normalise(sx, sy, sz, ~has)
        nx, ny, nz = (jnp.where(grow, g, n) for g, n in ((gx, nx), (gy, ny), (gz, nz)))
        has = has | grow
    (s_th, c_th), (s_ph, c_ph) = _basis_pairs(ri.theta, ri.phi)
    ex, ey, ez = c_th * c_ph, s_th * c_ph, s_ph  # e_r along the cell's ray
    nx, ny, nz = (jnp.where(has, n, -e) for n, e in ((nx, ex), (ny, ey), (nz, ez)))
    sign = jnp.where(nx * ex + ny * ey + nz * ez > 0, -1.0, 1.0)
    return nx * sign, ny * sign, nz * sign


@functools.partial(jax.jit, static_argnames=("smoothing", "fill_max_gap"))
def range_image_normals(ri: RangeImage, *, smoothing: int = 1, fill_max_gap: int = 2) -> jax.Array:
    """Unit surface normals on the range image (Badino's spherical gradient, sign-corrected).

    Args:
      ri: a :class:`RangeImage` from :func:`range_image` (``theta`` must lie
        within half a column of its cell centre, as :func:`range_image` ensures).
      smoothing: static half width s of the box mean over measured cells'
        normals (0 disables smoothing of measured cells).
      fill_max_gap: static; derivatives look up to ``1 + fill_max_gap`` cells
        in each direction for a measured neighbour, and empty cells are filled
        by that many extra 3x3 passes.

    Returns:
      (3, L, C) float32 unit normals (x, y, z) in the LiDAR frame for every cell,
      facing the sensor (``n . e_r <= 0`` along the cell's ray). Measured cells
      (and empty cells with a measured cell within ``max(1, s)``) hold the
      renormalised weighted mean of the raw normals of the measured cells in their
      ``(2 max(1, s) + 1)^2`` window (with s = 0, measured cells keep their raw
      normal); remaining empty cells are filled by ``fill_max_gap`` passes of
      the 3x3 mean of filled neighbours; cells still empty face the sensor
      (``-e_r``). Filling never changes a measured cell.

    The formula is ``R(theta, phi) (-1, r_theta / (r cos phi), r_phi / r)^T``
    normalised: the paper's expression with the radial sign flipped, see the
    module docstring for the derivation and the derivative scheme.
    Oracle: ray-cast analytic planes (tests).
    """
    _check_options(smoothing, fill_max_gap)
    if not isinstance(ri, RangeImage):
        raise ValueError(f"ri: expected a RangeImage, got {type(ri).__name__}")
    if ri.r.ndim != 2 or any(f.shape != ri.r.shape for f in (ri.theta, ri.phi, ri.index)):
        raise ValueError(
            "ri: expected (L, C) fields r, theta, phi, index of one shape, got "
            f"{[tuple(f.shape) for f in (ri.r, ri.theta, ri.phi, ri.index)]}")
    return jnp.stack(_normal_channels(ri, smoothing, fill_max_gap), axis=0)


@functools.partial(jax.jit, static_argnames=("lidar", "smoothing", "fill_max_gap"))
def point_normals(points: jax.Array, valid: jax.Array, *, lidar: LidarSpec, smoothing: int = 1,
                  fill_max_gap: int = 2) -> jax.Array:
    """Unit surface normal of every valid LiDAR point (Step 1 of the paper).

    Args:
      points: (N, 3) float LiDAR-frame points, metres.
      valid: (N,) bool; masked, non-finite and origin points get a zero normal.
      lidar: static :class:`~jaxdepth.LidarSpec` of the range image.
      smoothing, fill_max_gap: static, see :func:`range_image_normals`.

    Returns:
      (N, 3) float32 LiDAR-frame normals: unit length and ``n . p <= 0`` for
      every valid point, zeros for invalid points. A point reads the normal of
      its range-image cell (also when a nearer point won the cell), i.e.
      ``range_image_normals(range_image(...))`` at ``cell``, flipped if needed to
      face the sensor along the point's own ray.
    """
    _check_lidar(lidar)
    _check_options(smoothing, fill_max_gap)
    points = jnp.asarray(points)
    valid = jnp.asarray(valid)
    _check_points(points, valid)
    ri, slot = _range_image(points, valid, lidar)
    # Points only sit in measured cells, so the filling of empty cells is skipped.
    _, nx, ny, nz = _smoothed_normals(_raw_normals(ri, fill_max_gap), smoothing, ri.index[0, 0])
    n_cells = nx.size

    def per_point(nx, ny, nz, slot, p):
        # Gathers inside their own stage read buffers (outside, XLA would
        # re-run the smoothing per gathered point).
        ok = slot < n_cells
        idx = jnp.where(ok, slot, 0)
        px, py, pz = (c.at[idx].get(mode="promise_in_bounds") for c in (nx, ny, nz))
        facing = px * p[:, 0] + py * p[:, 1] + pz * p[:, 2]
        sign = jnp.where(ok, jnp.where(facing > 0, -1.0, 1.0), 0.0)
        return (jnp.stack([px * sign, py * sign, pz * sign], axis=1),)

    return _stage(per_point, (nx.reshape(-1), ny.reshape(-1), nz.reshape(-1), slot, points.astype(jnp.float32)),
                  ri.index[0, 0])[0]


# ------------------------------------------------------------------ image input


def _pixel_lidar_xyz(depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array, v=None, u=None):
    """LiDAR-frame (x, y, z) of every pixel's back-projected point, three (H, W) planes.

    ``p_cam = depth K^-1 (u, v, 1)`` (as ``geometry.unproject_depth``) and
    ``p_lidar = R^T (p_cam - t)`` (as ``transform_points(invert_rigid(T), .)``),
    written per channel so no (H, W, 3) array is formed. ``v``, ``u`` (float32
    row and column of each depth value) default to the pixel grid of ``depth``.
    """
    if v is None:
        h, w = depth.shape
        v = jnp.arange(h, dtype=jnp.float32)[:, None]
        u = jnp.arange(w, dtype=jnp.float32)[None, :]
    yn = (v - K[1, 2]) / K[1, 1]
    xn = (u - K[0, 2] - K[0, 1] * yn) / K[0, 0]
    xc, yc, zc = xn * depth, yn * depth, depth
    R, t = T_cam_lidar[:3, :3], T_cam_lidar[:3, 3]
    ti = -(R.T @ t)
    return tuple(R[0, i] * xc + R[1, i] * yc + R[2, i] * zc + ti[i] for i in range(3))


# Bits per chunk of the validity mask in :func:`_compact_pixels` (one uint32 word).
_CHUNK = 32


def _upper_ones(n: int):
    return jnp.asarray(np.triu(np.ones((n, n), np.float32)))


def _inclusive_prefix(x: jax.Array) -> jax.Array:
    """Inclusive prefix sum of a (n,) float32 array of non-negative integers whose total is below 2^24.

    Written as small matrix products with a triangular matrix of ones (groups of
    ``_CHUNK``, recursively over the group totals): exact in float32 for such
    integers, and far faster on XLA:CPU than ``cumsum`` (a reduce-window).
    """
    n = x.shape[0]
    if n <= _CHUNK:
        return x @ _upper_ones(n)
    groups = -(-n // _CHUNK)
    within = jnp.pad(x, (0, groups * _CHUNK - n)).reshape(groups, _CHUNK) @ _upper_ones(_CHUNK)
    totals = within[:, -1]
    return (within + (_inclusive_prefix(totals) - totals)[:, None]).reshape(-1)[:n]


def _compact_pixels(valid: jax.Array, capacity: int, token):
    """Flat indices of the first ``capacity`` True entries of ``valid`` (increasing), and their count.

    Args:
      valid: (n,) bool, n < 2^24.
      capacity: static number of output slots.

    Returns:
      ``(pix, total)``: (capacity,) int32 indices of the True entries in order,
      ``n`` in the slots at or after ``total``; int32 number of True entries
      (may exceed ``capacity``: then only the first ``capacity`` are listed).

    No per-element scatter over the n entries (XLA:CPU scatters and gathers
    cost ~2-5 ns per element): the mask is packed into 32-bit words (a
    reduction along the minor axis), their population counts are prefix-summed
    (:func:`_inclusive_prefix`), and each output slot m finds its word as the
    number of words whose inclusive prefix is <= m (a scatter-add of a 1 per
    word at its prefix, then a prefix sum), then the rank-th set bit of that
    word by a 5-step binary search on population counts.
    """
    n = valid.shape[0]
    words = -(-n // _CHUNK)
    bits = jnp.pad(valid, (0, words * _CHUNK - n)).reshape(words, _CHUNK).astype(jnp.uint32)
    mask = jnp.sum(bits << jnp.arange(_CHUNK, dtype=jnp.uint32), axis=1, dtype=jnp.uint32)
    count = jax.lax.population_count(mask).astype(jnp.int32)
    incl = _inclusive_prefix(count.astype(jnp.float32)).astype(jnp.int32)
    hits = jnp.zeros((capacity,), jnp.float32).at[incl].add(1.0, mode="drop")
    word = jnp.minimum(_inclusive_prefix(hits).astype(jnp.int32), words - 1)
    packed = jnp.stack([incl - count, jax.lax.bitcast_convert_type(mask, jnp.int32)], axis=1)
    # Materialised before the gather (fused, the gather would re-run the prefix sums).
    word, packed, total = _stage(lambda *a: a, (word, packed, incl[-1]), token)
    start_mask = _stage(lambda p, w: (p.at[w].get(mode="promise_in_bounds"),), (packed, word), token)[0]
    slot = jnp.arange(capacity, dtype=jnp.int32)
    rank = slot - start_mask[:, 0]
    m = jax.lax.bitcast_convert_type(start_mask[:, 1], jnp.uint32)
    bit = jnp.zeros_like(rank)
    for w in (16, 8, 4, 2, 1):  # position of the rank-th set bit of m
        low = m & jnp.uint32((1 << w) - 1)
        pc = jax.lax.population_count(low).astype(jnp.int32)
        up = rank >= pc
        rank = jnp.where(up, rank - pc, rank)
        m = jnp.where(up, m >> w, low)
        bit = bit + jnp.where(up, w, 0)
    return jnp.where(slot < total, word * _CHUNK + bit, n), total


def _pixel_points(pix, depth, K, T, col0, token, *, lidar: LidarSpec, window_cols: int):
    """Per listed pixel: back-projected LiDAR-frame point, range-image window cell and scatter key.

    Args:
      pix: (P,) int32 flat pixel indices into ``depth`` (``H W`` or a pixel
        without depth: no point).
      depth: (H, W) float32 camera depth, 0 where empty.
      col0: int32 first range-image column of the window (0 for the whole image).

    Returns (stage outputs, real buffers): ``ok`` (P,) bool, ``col`` (P,) int32
    range-image column (relative to ``col0``, mod C), ``slot`` (P,) int32 flat
    window cell ``row * window_cols + col`` (``L window_cols`` for no point or a
    cell outside the window), ``key`` (P,) int32 range bits, ``r``, ``theta``,
    ``phi``, ``x``, ``y``, ``z`` (P,) float32. The float32 expressions are those
    of :func:`_range_image` applied to ``unproject_depth`` + ``transform_points``.
    """
    h, w = depth.shape
    n_rows, n_cols = lidar.beams, lidar.columns
    n_win = n_rows * window_cols

    def per_point(pix, depth, K, T, col0):
        listed = pix < h * w
        safe = jnp.where(listed, pix, 0)
        d = jnp.where(listed, depth.reshape(-1).at[safe].get(mode="promise_in_bounds"), 0.0)
        v = safe // w
        u = (safe - v * w).astype(jnp.float32)
        x, y, z = _pixel_lidar_xyz(d, K, T, v=v.astype(jnp.float32), u=u)
        r, theta, phi, cell, ok = _spherical_xyz(x, y, z, d > 0, lidar)
        row = cell // n_cols
        col = cell - row * n_cols - col0
        col = jnp.where(col < 0, col + n_cols, col)
        inside = ok & (col < window_cols)
        slot = jnp.where(inside, row * window_cols + col, n_win)
        key = jnp.where(ok, jax.lax.bitcast_convert_type(r, jnp.int32), jnp.iinfo(jnp.int32).max)
        return ok, col, slot, key, r, theta, phi, x, y, z

    return _stage(per_point, (pix, depth, K, T, col0), token)


def _pixel_normals_of_points(pix, pts, col0, R, shape, token, *, lidar: LidarSpec, window_cols: int,
                             smoothing: int, fill_max_gap: int, identity: bool):
    """Camera-frame (3, H, W) normals of the listed pixels (from :func:`_pixel_points`), zeros elsewhere.

    Every point's cell must lie in the window ``col0 .. col0 + window_cols - 1``
    (mod C) at least ``max(1 + fill_max_gap, smoothing)`` columns from its edges
    (unless the window is the whole image): then the neighbour search and the
    smoothing never reach the edges and the result equals that of the whole
    range image. ``identity``: ``pix`` is ``arange(H W)`` (the output needs no scatter).
    """
    ok, _, slot, key, r, theta, phi, x, y, z = pts
    n_pts = slot.shape[0]
    n_rows, n_cols = lidar.beams, lidar.columns
    n_win = n_rows * window_cols
    window = None if window_cols == n_cols else (col0, n_cols)
    # Nearest range wins a cell (scatter-min of the range bits), ties the
    # smaller point index = the smaller pixel index (points are listed in
    # pixel order). Slot n_win collects points without a cell.
    best = jnp.full((n_win + 1,), jnp.iinfo(jnp.int32).max, jnp.int32).at[slot].min(key, mode="promise_in_bounds")
    win = ok & (key == best.at[slot].get(mode="promise_in_bounds"))
    ids = jnp.arange(n_pts, dtype=jnp.int32)
    idx = jnp.full((n_win + 1,), n_pts, jnp.int32).at[jnp.where(win, slot, n_win)].min(
        ids, mode="promise_in_bounds")[:n_win]

    def per_cell(idx, r, theta, phi, col0):
        has = idx < n_pts
        safe = jnp.where(has, idx, 0)
        theta_c, phi_c = _cell_centres(lidar)
        theta_c = jax.lax.dynamic_slice(jnp.concatenate([theta_c, theta_c[:, :window_cols]], axis=1),
                                        (0, col0), (1, window_cols))
        img_shape = (n_rows, window_cols)
        get = lambda a: a.at[safe].get(mode="promise_in_bounds")  # noqa: E731
        th = jnp.where(has, get(theta), jnp.broadcast_to(theta_c, img_shape).reshape(-1))
        ph = jnp.where(has, get(phi), jnp.broadcast_to(phi_c, img_shape).reshape(-1))
        return (jnp.where(has, get(r), 0.0).reshape(img_shape), th.reshape(img_shape), ph.reshape(img_shape),
                jnp.where(has, idx, -1).reshape(img_shape))

    r_img, th_img, ph_img, index = _stage(per_cell, (idx, r, theta, phi, col0), token)
    ri = RangeImage(r=r_img, theta=th_img, phi=ph_img, index=index, cell=jnp.zeros((0,), jnp.int32))
    # Points only sit in measured cells, so the filling of empty cells is skipped.
    _, nx, ny, nz = _smoothed_normals(_raw_normals(ri, fill_max_gap, window), smoothing, token)

    def per_point(nx, ny, nz, slot, ok, x, y, z, R):
        # Gathers inside their own stage read buffers (outside, XLA would
        # re-run the smoothing per gathered point).
        cell = jnp.where(ok, slot, 0)
        px, py, pz = (c.reshape(-1).at[cell].get(mode="promise_in_bounds") for c in (nx, ny, nz))
        sign = jnp.where(ok, jnp.where(px * x + py * y + pz * z > 0, -1.0, 1.0), 0.0)
        return tuple((R[i, 0] * px + R[i, 1] * py + R[i, 2] * pz) * sign for i in range(3))

    n_cam = jnp.stack(_stage(per_point, (nx, ny, nz, slot, ok, x, y, z, R), token))
    h, w = shape
    if identity:
        return n_cam.reshape(3, h, w)
    out = jnp.zeros((3, h * w), jnp.float32).at[:, jnp.where(ok, pix, h * w)].set(n_cam, mode="drop")
    return out.reshape(3, h, w)


def default_window_columns(lidar: LidarSpec) -> int:
    """Static width of the range-image window used for camera images: 100 degrees
    of azimuth (a multiple of 8 columns), or all columns for a coarse LiDAR."""
    cols = -(-lidar.columns * 100 // 360)
    cols = -(-cols // 8) * 8
    return min(cols, lidar.columns)


def _window_start(K, T, height: int, width: int, lidar: LidarSpec, window_cols: int):
    """Range-image column at which a window centred on the image's central ray starts."""
    ray = jnp.stack([((width - 1) / 2 - K[0, 2] - K[0, 1] * ((height - 1) / 2 - K[1, 2]) / K[1, 1]) / K[0, 0],
                     ((height - 1) / 2 - K[1, 2]) / K[1, 1], jnp.float32(1.0)])
    d = T[:3, :3].T @ ray
    theta = jnp.arctan2(d[1], d[0])
    n_cols = lidar.columns
    centre = jnp.floor((_PI - theta) * (n_cols / (2 * _PI))).astype(jnp.int32)
    return jnp.mod(centre - window_cols // 2, n_cols).astype(jnp.int32)


@functools.partial(jax.jit, static_argnames=("lidar", "smoothing", "fill_max_gap", "window_columns", "max_points"))
def pixel_normals(sparse_depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array, *, lidar: LidarSpec,
                  smoothing: int = 1, fill_max_gap: int = 2, window_columns: int | None = None,
                  max_points: int | None = None) -> jax.Array:
    """Camera-frame unit normal of every pixel of a sparse depth image (Step 1 on image input).

    Each pixel with depth is back-projected through ``K`` (pixel centre) and
    carried into the LiDAR frame with ``T_cam_lidar``; these points are binned
    into the spherical range image and read their cell's normal, exactly as

        R @ point_normals(transform_points(invert_rigid(T), unproject_depth(d, K).reshape(-1, 3)),
                          (d > 0).reshape(-1), ...).T

    reshaped to (3, H, W) (``R = T_cam_lidar[:3, :3]``), up to float32 rounding.

    Fast path (a LiDAR image has depth at a few % of its pixels): the pixels
    with depth are listed first in pixel order (:func:`_compact_pixels`, no
    per-pixel scatter or gather), and only those points are back-projected,
    binned (scatter-min; ties go to the smaller pixel index as in the
    composition), given their cell's normal and scattered into the output.
    The normals are computed on a window of ``window_columns`` range-image
    columns around the camera's central ray when every point lies inside it
    (with the margin of the neighbour search and smoothing), which gives the
    whole image's normals exactly. Otherwise (more than ``max_points`` pixels
    with depth, or points outside the window) a dense path takes every pixel
    as a point slot and uses the whole range image: same result, slower.

    Args:
      sparse_depth: (H, W) float camera depth z, metres; 0 (or any value that
        is not a finite positive number) marks an empty pixel.
      K: (3, 3) float32 intrinsics of that image.
      T_cam_lidar: (4, 4) float32 LiDAR -> camera transform.
      lidar: static :class:`~jaxdepth.LidarSpec` of the range image.
      smoothing, fill_max_gap: static, see :func:`range_image_normals`.
      window_columns: static width of the range-image window (default
        :func:`default_window_columns`: 100 degrees of azimuth).
      max_points: static capacity of the listed path (default ``ceil(H W / 16)``,
        6.25 % of the pixels); frames with more pixels with depth take the
        dense path. Only speed depends on it.

    Args:
      sparse_depth: (H, W) float camera depth z, metres; 0 (or any value that
        is not a finite positive number) marks an empty pixel.
      K: (3, 3) float32 intrinsics of that image.
      T_cam_lidar: (4, 4) float32 LiDAR -> camera transform.

    Returns:
      (3, H, W) float32 camera-frame normals (x, y, z): unit length and facing
      the LiDAR (``n . (p_cam - t) <= 0``) at pixels with depth, zeros elsewhere.
    """
    _check_lidar(lidar)
    _check_options(smoothing, fill_max_gap)
    sparse_depth = jnp.asarray(sparse_depth)
    if sparse_depth.ndim != 2:
        raise ValueError(f"pixel_normals: field 'sparse_depth' expected shape (H, W), got {sparse_depth.shape}")
    K = jnp.asarray(K, jnp.float32)
    if K.shape != (3, 3):
        raise ValueError(f"pixel_normals: field 'K' expected shape (3, 3), got {K.shape}")
    T = jnp.asarray(T_cam_lidar, jnp.float32)
    if T.shape != (4, 4):
        raise ValueError(f"pixel_normals: field 'T_cam_lidar' expected shape (4, 4), got {T.shape}")
    depth = sparse_depth.astype(jnp.float32)
    depth = jnp.where(jnp.isfinite(depth) & (depth > 0), depth, 0.0)
    h, w = depth.shape
    n_pix = h * w
    n_cols = lidar.columns
    token = jax.lax.bitcast_convert_type(depth[0, 0], jnp.int32)
    R = T[:3, :3]
    options = dict(lidar=lidar, smoothing=smoothing, fill_max_gap=fill_max_gap)

    def dense(depth, K, T):
        # Every pixel is a point slot and the whole range image is used (as
        # fast as the listed path only when most pixels have depth).
        token = jax.lax.bitcast_convert_type(depth[0, 0], jnp.int32)  # (a branch may not close over tracers)
        pix = jnp.arange(n_pix, dtype=jnp.int32)
        pts = _pixel_points(pix, depth, K, T, jnp.int32(0), token, lidar=lidar, window_cols=n_cols)
        return _pixel_normals_of_points(pix, pts, jnp.int32(0), T[:3, :3], (h, w), token, window_cols=n_cols,
                                        identity=True, **options)

    capacity = -(-n_pix // 16) if max_points is None else int(max_points)
    capacity = min(max(capacity, 1), n_pix)
    if capacity == n_pix:
        return dense(depth, K, T)
    pix, total = _compact_pixels((depth > 0).reshape(-1), capacity, token)
    wc = default_window_columns(lidar) if window_columns is None else int(window_columns)
    margin = max(1 + fill_max_gap, smoothing)
    if wc + 2 * margin > n_cols:  # a window would not save work
        wc = n_cols
        col0 = jnp.int32(0)
        fits = total <= capacity
    else:
        col0 = _window_start(K, T, h, w, lidar, wc)
    pts = _pixel_points(pix, depth, K, T, col0, token, lidar=lidar, window_cols=wc)
    if wc < n_cols:
        # Every point must lie at least `margin` columns inside the window:
        # then the neighbour search and the smoothing never reach its edges
        # and the window gives exactly the whole image's normals.
        ok, col = pts[0], pts[1]
        fits = (total <= capacity) & ~jnp.any(ok & ((col < margin) | (col >= wc - margin)))

    def listed(pix, col0, R, depth, K, T, *pts):
        token = jax.lax.bitcast_convert_type(depth[0, 0], jnp.int32)
        return _pixel_normals_of_points(pix, pts, col0, R, (h, w), token, window_cols=wc, identity=False,
                                        **options)

    def fallback(pix, col0, R, depth, K, T, *pts):
        return dense(depth, K, T)

    return cond_all(fits, listed, fallback, pix, col0, R, depth, K, T, *pts)
