"""Step 1 of the Surface Geometry Model: surface normals from the spherical range image.

This module holds Step 1 for a LiDAR sweep (:func:`point_normals`, used by
``complete_points`` and ``complete_rig``) and the cell normals both inputs share;
for a sparse depth image (``complete``) Step 1 enters through
:mod:`jaxdepth._src.pixel_normals`, which bins the pixels and calls :func:`cell_normals`.

Following the paper (its "Surface Normal" paragraph, after Badino et al. 2011),
every LiDAR point ``p = (x, y, z)`` (LiDAR frame, metres) is mapped to spherical
coordinates

* range ``r = |p|``,
* azimuth ``theta = atan2(y, x)`` in ``[-pi, pi]``,
* elevation ``phi = atan2(z, sqrt(x^2 + y^2)) = asin(z / r)`` in ``[-pi/2, pi/2]``,

and binned into an ``(L, C)`` range image (``L = lidar.beams`` rows,
``C = lidar.columns`` columns). The surface seen by the sensor is the graph
``r(theta, phi)``; its normal follows from the partial derivatives ``r_theta``,
``r_phi`` estimated by finite differences on the range image
(:mod:`jaxdepth._src.range_image` bins the points and documents its layout).

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
are computed inside ``xla_tuning.stage`` conditionals (real buffers). Inside a stage XLA
gives every output its own fusion (which redoes all the cheap work it needs)
and materialises any division or square root that several outputs share, so
stages are cut to have few outputs: pairs of float32 channels travel as one
complex64 array, the two horizontal and the two vertical neighbour searches
each form one stage with three complex outputs, the robust fit runs in three
stages (pass 1 -> complex(a, b); pass-2 weights -> two complex pairs; final
solve -> complex(a, b) and the weight; five fusions instead of ~16 that each
re-read the rows), and the normal, its smoothing weight and the zero/wrap
padding for the box sums form one stage, the box's row sums a second and its
column sums with the renormalisation a third. Per point, the normal is read
with two gathers (complex (x, y) and z).
The image-plane entry (a sparse depth image and K instead of points) is
:func:`jaxdepth._src.pixel_normals.pixel_normals`; it builds the same range
image from the pixels with depth and reuses :func:`cell_normals` and
:func:`normals_at_points`.

Numerics: no transcendental library calls (XLA's CPU ``atan2``/``asin``/``sin``
are much slower than a fused polynomial): ``atan2``, sine and cosine come from
:mod:`jaxdepth._src.fastmath` (errors < 1e-7). Every division is guarded
with the safe-``where`` pattern, and the derivative ratios are clipped to
``+-1e4`` (a surface within 0.006 degrees of grazing), so no NaN or Inf can
arise from finite input.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.fastmath import PI, sin_cos_small, wrap_angle
from jaxdepth._src.range_image import RangeImage, check_lidar, check_points, range_image_and_slots
from jaxdepth._src.xla_tuning import stage, take_pair, wrap_pad, wrap_pad_slices
from jaxdepth._src.types import LidarSpec

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


# --------------------------------------------------------------------------- numerics


def _azimuth_basis(theta: jax.Array, window=None):
    """(sin, cos) of (L, C) azimuths that lie within half a column of their cell centre.

    Uses the static cell-centre angle and a short Taylor series of the offset.
    ``window = (col0, total_cols)``: the array holds the columns ``col0,
    col0 + 1, ...`` (mod ``total_cols``, ``col0`` traced) of a wider image.
    """
    cols = theta.shape[1]
    total = cols if window is None else window[1]
    centre = PI - (np.arange(total, dtype=np.float64) + 0.5) * (2 * PI / total)
    tables = (np.sin(centre).astype(np.float32), np.cos(centre).astype(np.float32), centre.astype(np.float32))
    if window is None:
        s_c, c_c, cen = (a[None, :] for a in tables)
    else:
        s_c, c_c, cen = (jax.lax.dynamic_slice(jnp.asarray(np.concatenate([a, a[:cols]])), (window[0],),
                                               (cols,))[None, :] for a in tables)
    delta = wrap_angle(theta - cen)
    s_d, c_d = sin_cos_small(delta, PI / total + 1e-5)
    return s_c * c_d + c_c * s_d, c_c * c_d - s_c * s_d


def _safe_div(num, den, ok):
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


# ------------------------------------------------------------------- image shifts
#
# Shifts are slices of a padded copy that is materialised first (an
# optimization barrier): XLA would otherwise fuse a concatenate into every
# consumer, which is much slower than reading a buffer at an offset.


def _at(padded: jax.Array, k: int, di: int, dj: int) -> jax.Array:
    """View of a ``_pad``-ed array: out[i, j] = a[i + di, (j + dj) mod C] (fill outside rows)."""
    rows = padded.shape[0] - 2 * k
    cols = padded.shape[1] - 2 * k
    return jax.lax.slice(padded, (k + di, k + dj), (k + di + rows, k + dj + cols))


def _box_sums(arrays, half: int, token):
    """(2 half + 1)^2 box sums; columns wrap, rows outside the image count as 0."""
    if half == 0:
        return tuple(arrays)
    padded = stage(lambda *a: tuple(wrap_pad_slices(x, half, 0.0) for x in a), arrays, token)
    horiz = stage(lambda *p: _row_box_sums(p, half), padded, token)
    return _column_box_sums(horiz, half)


def _row_box_sums(padded, half: int):
    """Sums of 2 half + 1 neighbouring columns of each (R, C + 2 half) array -> (R, C)."""
    out = []
    for p in padded:
        h = jax.lax.slice(p, (0, 0), (p.shape[0], p.shape[1] - 2 * half))
        for dj in range(1, 2 * half + 1):
            h = h + jax.lax.slice(p, (0, dj), (p.shape[0], p.shape[1] - 2 * half + dj))
        out.append(h)
    return tuple(out)


def _column_box_sums(horiz, half: int):
    """Sums of 2 half + 1 neighbouring rows of each (R + 2 half, C) array -> (R, C)."""
    out = []
    for h in horiz:
        rows = h.shape[0] - 2 * half
        v = jax.lax.slice(h, (0, 0), (rows, h.shape[1]))
        for di in range(1, 2 * half + 1):
            v = v + jax.lax.slice(h, (di, 0), (di + rows, h.shape[1]))
        out.append(v)
    return tuple(out)


# --------------------------------------------------------------------- validation


def check_options(smoothing, fill_max_gap):
    """Raises ValueError unless smoothing and fill_max_gap are non-negative Python integers."""
    for name, value in (("smoothing", smoothing), ("fill_max_gap", fill_max_gap)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 0:
            raise ValueError(f"{name}: expected a non-negative integer, got {value!r}")


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
    return _azimuth_basis(th, window), sin_cos_small(ph, PI / 2)


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


def _equations(rows):
    """Per-neighbour equations (ok, x, y, z, 1 / (x^2 + y^2)) of the four neighbours (left, right, up, down).

    ``rows``: (complex(x, y) left, complex(x, y) right, complex(z left, z right),
    then the same for up and down), (L, C) each.
    """
    pairs = []
    for xy0, xy1, zz in (rows[0:3], rows[3:6]):
        pairs.extend(((xy0, jnp.real(zz)), (xy1, jnp.imag(zz))))
    eqs = []
    for xy, z in pairs:
        x, y = jnp.real(xy), jnp.imag(xy)
        q = x * x + y * y
        ok = q > _MIN_ANGLE_STEP ** 2
        eqs.append((ok, x, y, z, _safe_div(1.0, q, ok)))
    return eqs


def _fit_pass1(*rows):
    """Pass 1 of the robust fit: complex(a, b) with Cauchy weights on each neighbour's slope."""
    eqs = _equations(rows)
    w1 = [jnp.where(ok, iq / (1.0 + z * z * iq), 0.0) for ok, x, y, z, iq in eqs]
    a, b, _ = _solve_gradient(eqs, w1)
    return (jax.lax.complex(a, b),)


def _fit_weights2(ab1, *rows):
    """Pass-2 weights (Cauchy on the residual slope under the pass-1 fit), as two complex pairs."""
    a, b = jnp.real(ab1), jnp.imag(ab1)
    w2 = []
    for ok, x, y, z, iq in _equations(rows):
        e = z - a * x - b * y
        w2.append(jnp.where(ok, iq / (1.0 + e * e * iq), 0.0))
    return jax.lax.complex(w2[0], w2[1]), jax.lax.complex(w2[2], w2[3])


def _fit_pass2(w01, w23, *rows):
    """Pass 2 of the robust fit: clipped complex(a, b) and the smoothing weight."""
    w2 = [jnp.real(w01), jnp.imag(w01), jnp.real(w23), jnp.imag(w23)]
    a, b, spread = _solve_gradient(_equations(rows), w2)
    # Weight for the smoothing: 1 when the neighbours span both directions,
    # falling linearly to _PARTIAL_WEIGHT as they become collinear.
    full = jnp.clip(spread * (1.0 / _MIN_SPREAD), _PARTIAL_WEIGHT, 1.0)
    ab = jax.lax.complex(jnp.clip(a, -_MAX_SLOPE, _MAX_SLOPE), jnp.clip(b, -_MAX_SLOPE, _MAX_SLOPE))
    return ab, full


def _fit_slopes(rows, token):
    """Robust slopes (complex(a, b), smoothing weight) from the neighbour rows (see :func:`_equations`).

    Pass 1 down-weights steep neighbours (likely across a depth edge), pass 2
    re-weights by the residual slope of the pass-1 fit (IRLS, Cauchy weights);
    each equation is normalised by its angular length.

    Three stages (five fusions): XLA:CPU gives every output its own fusion and
    materialises each division that several of them share, so written as one
    function the fit took ~16 fusions that re-read the rows and redid the
    pair sums. Here pass 1 has a single (complex) output, the pass-2 weights
    two complex pairs, and the final solve reads those weights.
    """
    rows = tuple(rows)
    ab1, = stage(_fit_pass1, rows, token)
    w01, w23 = stage(_fit_weights2, (ab1,) + rows, token)
    return stage(_fit_pass2, (w01, w23) + rows, token)


def _slopes(ri: RangeImage, fill_max_gap: int, window=None, token=None):
    """Measured mask, basis (complex(cos, sin) of theta and phi), slopes complex(a, b) and smoothing weight.

    ``a = r_theta / (r cos phi)``, ``b = r_phi / r`` (see the module docstring);
    ``full`` in [_PARTIAL_WEIGHT, 1] is 1 where the neighbours constrain both
    derivatives and small where they are (nearly) collinear (the unseen
    derivative is then ~0). All (L, C) and materialised (stage outputs). ``token``: the stages'
    (:func:`~jaxdepth._src.xla_tuning.stage`; default ``ri.index[0, 0]``).
    """
    meas = ri.index >= 0
    r, th, ph = ri.r, ri.theta, ri.phi
    k = 1 + fill_max_gap
    token = ri.index[0, 0] if token is None else token

    def pad(meas, r, th, ph):
        # Columns wrap; azimuths in the pads are unwrapped (left of column 0
        # lie azimuths just above +pi, right of the last column just below -pi).
        return (wrap_pad(meas, k, False), wrap_pad(r, k, 0.0), wrap_pad(th, k, 0.0, seam=2 * PI),
                wrap_pad(ph, k, 0.0))

    padded = stage(pad, (meas, r, th, ph), token)
    # Complex numbers carry two float32 channels through one fusion (XLA:CPU
    # would otherwise compute each output in its own fusion, repeating the work).
    # (The window start is an operand: a stage may not close over traced values.)
    start = () if window is None else (window[0],)
    e_th, e_ph = stage(
        lambda th, ph, *start: tuple(jax.lax.complex(c, s) for s, c in _basis_pairs(
            th, ph, None if window is None else (start[0], window[1]))),
        (th, ph) + start, token)

    def neighbours(pm, pr, pt, pp, meas, r, th, ph, e_ph, *, dirs):
        # Two opposite directions per stage, three complex outputs:
        # (x, y) of each and (z, z'); cos(phi) and 1 / r are recomputed here
        # (cheaper than materialising them).
        centre = (meas, r, th, ph, jnp.real(e_ph), _safe_div(1.0, r, meas))
        (xy0, z0), (xy1, z1) = (_neighbour((pm, pr, pt, pp), k, di, dj, centre) for di, dj in dirs)
        return xy0, xy1, jax.lax.complex(z0, z1)

    rows = []
    for dirs in (((0, -1), (0, 1)), ((-1, 0), (1, 0))):
        rows.extend(stage(functools.partial(neighbours, dirs=dirs), padded + (meas, r, th, ph, e_ph), token))
    ab, full = _fit_slopes(rows, token)
    return meas, e_th, e_ph, ab, full


def _normal_of_slopes(meas, e_th, e_ph, ab):
    """Unit ``-e_r + a e_theta + b e_phi`` (normalised; the basis is orthonormal); zeros where not ``meas``."""
    c_th, s_th, c_ph, s_ph = jnp.real(e_th), jnp.imag(e_th), jnp.real(e_ph), jnp.imag(e_ph)
    a, b = jnp.real(ab), jnp.imag(ab)
    inv = jnp.where(meas, jax.lax.rsqrt(1.0 + a * a + b * b), 0.0)  # |(-1, a, b)| >= 1
    nx = (-c_th * c_ph - a * s_th - b * c_th * s_ph) * inv
    ny = (-s_th * c_ph + a * c_th - b * s_th * s_ph) * inv
    nz = (-s_ph + b * c_ph) * inv
    return nx, ny, nz


def _normalise(nx, ny, nz, ok):
    n2 = nx * nx + ny * ny + nz * nz
    good = ok & (n2 > 1e-12)
    inv = jnp.where(good, jax.lax.rsqrt(jnp.where(good, n2, 1.0)), 0.0)
    return good, nx * inv, ny * inv, nz * inv


def cell_normals(ri: RangeImage, smoothing: int, fill_max_gap: int, window=None, token=None):
    """Smoothed normals of the cells packed for per-point gathers: (complex(nx, ny), nz), (L, C),
    materialised (:func:`_smoothed_cells` of :func:`_slopes`; ``smoothing`` 0: the raw normals).
    ``token``: the stages' (default ``ri.index[0, 0]``; a caller's own token saves that one's
    predicate kernel)."""
    token = ri.index[0, 0] if token is None else token
    return _smoothed_cells(_slopes(ri, fill_max_gap, window, token), smoothing, token, wrap=window is None)


def _smoothed_cells(slopes, smoothing: int, token, *, wrap: bool = True):
    """The one normal smoothing: the weighted box mean of the measured cells' raw normals.

    Normals with both derivatives weigh 1, those with a missing derivative
    (taken as 0) weigh ``_PARTIAL_WEIGHT``, so they only matter where no full
    estimate is in the window; the mean is renormalised. Returns
    (complex(nx, ny), nz), (L, C): unit where a measured cell lies within
    ``smoothing`` cells (columns wrap, rows are cut), zero elsewhere; with
    ``smoothing`` 0 the raw normals (zero at empty cells). The weighted normals
    are formed in one stage, padded and summed along the rows in a second,
    and the column sums with the renormalisation in a third; (x, y) travel as
    one complex channel, so each stage has two outputs. ``wrap`` False (a
    window of the range image's columns): the columns are padded with zeros,
    not wrapped, which changes only the cells within ``smoothing`` columns of
    the window's edges (no listed point reads them: its margin) and lets XLA
    fuse the pad into the row sums (no slice and concatenate kernels).
    """
    if smoothing == 0:
        def raw(meas, e_th, e_ph, ab):
            nx, ny, nz = _normal_of_slopes(meas, e_th, e_ph, ab)
            return jax.lax.complex(nx, ny), nz
        return stage(raw, slopes[:4], token)
    half = smoothing

    def weighted(meas, e_th, e_ph, ab, full):
        nx, ny, nz = _normal_of_slopes(meas, e_th, e_ph, ab)
        return jax.lax.complex(nx * full, ny * full), nz * full

    def vertical(*horiz):
        sxy, sz = _column_box_sums(horiz, half)
        _, nx, ny, nz = _normalise(jnp.real(sxy), jnp.imag(sxy), sz, True)
        return jax.lax.complex(nx, ny), nz

    cells = stage(weighted, slopes, token)
    pad = (lambda x: wrap_pad_slices(x, half, 0.0)) if wrap else (lambda x: jnp.pad(x, half))
    horiz = stage(lambda *c: _row_box_sums(tuple(pad(x) for x in c), half), cells, token)
    return stage(vertical, horiz, token)


def _normal_channels(ri: RangeImage, smoothing: int, fill_max_gap: int):
    """Every cell's sensor-facing unit normal (three (L, C) channels)."""
    token = ri.index[0, 0]
    slopes = _slopes(ri, fill_max_gap)
    nxy, nz = _smoothed_cells(slopes, max(1, smoothing), token)
    nx, ny = jnp.real(nxy), jnp.imag(nxy)
    has = (nx != 0) | (ny != 0) | (nz != 0)  # the smoothed normal is unit or zero
    if smoothing == 0:  # measured cells keep their own normal, empty ones the 3x3 mean
        meas = slopes[0]
        rxy, rz = _smoothed_cells(slopes, 0, token)
        nx, ny, nz = (jnp.where(meas, a, b) for a, b in ((jnp.real(rxy), nx), (jnp.imag(rxy), ny), (rz, nz)))
        has = has | meas
    for _ in range(fill_max_gap):
        nx, ny, nz, has = stage(lambda *a: a, (nx, ny, nz, has), ri.index[0, 0])
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


def normals_at_points(nxy, nz, slot, ok, xyz, token):
    """Each point's cell normal and the sign that turns it towards the sensor along the point's ray.

    Args:
      nxy, nz: (L, C) cell normals packed as by :func:`cell_normals`
        (complex64 (nx, ny) and float32 nz).
      slot: (N,) int32 flat cell of every point (read only where ``ok``).
      ok: (N,) bool, points that have a cell.
      xyz: three (N,) float32 LiDAR-frame coordinates of the points, metres.
      token: int32 scalar fencing the gather stage.

    Returns:
      ``(nx, ny, nz, sign)``: (N,) float32 cell normal and sign (+-1 where
      ``ok``, so that ``sign n . p <= 0``; 0 elsewhere). The gathers run in their
      own stage (fused into the output, XLA would gather once per output
      element): two gathers per point.
    """
    # XLA:CPU: (nx, ny) in one complex64 gather (take_pair).
    px, py, pz = stage(lambda nxy, nz, idx: (*take_pair(nxy.reshape(-1), idx),
                                            nz.reshape(-1).at[idx].get(mode="promise_in_bounds")),
                       (nxy, nz, jnp.where(ok, slot, 0)), token)
    x, y, z = xyz
    facing = px * x + py * y + pz * z
    sign = jnp.where(ok, jnp.where(facing > 0, -1.0, 1.0), 0.0)
    return px, py, pz, sign


@functools.partial(jax.jit, static_argnames=("smoothing", "fill_max_gap"))
def range_image_normals(ri: RangeImage, *, smoothing: int = DEFAULT_CONFIG.normal_smoothing,
                        fill_max_gap: int = DEFAULT_CONFIG.range_fill_max_gap) -> jax.Array:
    """Unit surface normals on the range image (Badino's spherical gradient, sign-corrected).

    Args:
      ri: a :class:`RangeImage` from :func:`~jaxdepth._src.range_image.range_image` (``theta`` must lie
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
    check_options(smoothing, fill_max_gap)
    if not isinstance(ri, RangeImage):
        raise ValueError(f"ri: expected a RangeImage, got {type(ri).__name__}")
    if ri.r.ndim != 2 or any(f.shape != ri.r.shape for f in (ri.theta, ri.phi, ri.index)):
        raise ValueError(
            "ri: expected (L, C) fields r, theta, phi, index of one shape, got "
            f"{[tuple(f.shape) for f in (ri.r, ri.theta, ri.phi, ri.index)]}")
    return jnp.stack(_normal_channels(ri, smoothing, fill_max_gap), axis=0)


@functools.partial(jax.jit, static_argnames=("lidar", "smoothing", "fill_max_gap"))
def point_normals(points: jax.Array, valid: jax.Array, *, lidar: LidarSpec,
                  smoothing: int = DEFAULT_CONFIG.normal_smoothing,
                  fill_max_gap: int = DEFAULT_CONFIG.range_fill_max_gap,
                  rows: jax.Array | None = None) -> jax.Array:
    """Unit surface normal of every valid LiDAR point (Step 1 of the paper).

    Args:
      points: (N, 3) float LiDAR-frame points, metres.
      valid: (N,) bool; masked, non-finite and origin points get a zero normal.
      lidar: static :class:`~jaxdepth.LidarSpec` of the range image.
      smoothing, fill_max_gap: static, see :func:`range_image_normals`.
      rows: optional (N,) int32 range-image row of each point (its laser's rank by
        elevation, for unevenly spaced beams); -1 or None: the row of its elevation.

    Returns:
      (N, 3) float32 LiDAR-frame normals: unit length and ``n . p <= 0`` for
      every valid point, zeros for invalid points. A point reads the normal of
      its range-image cell (also when a nearer point won the cell), i.e.
      ``range_image_normals(range_image(...))`` at ``cell``, flipped if needed to
      face the sensor along the point's own ray.
    """
    check_lidar(lidar)
    check_options(smoothing, fill_max_gap)
    points = jnp.asarray(points)
    valid = jnp.asarray(valid)
    check_points(points, valid)
    rows = None if rows is None else jnp.asarray(rows, jnp.int32)
    ri, slot = range_image_and_slots(points, valid, lidar, rows)
    token = ri.index[0, 0]
    # Points only sit in measured cells, so the filling of empty cells is skipped.
    nxy, nz = cell_normals(ri, smoothing, fill_max_gap)
    ok = slot < nz.size
    p = points.astype(jnp.float32)
    px, py, pz, sign = normals_at_points(nxy, nz, slot, ok, (p[:, 0], p[:, 1], p[:, 2]), token)
    return jnp.stack([px * sign, py * sign, pz * sign], axis=1)
