"""Float32 angle functions written as fused polynomials (no transcendental library calls).

XLA's CPU ``atan2``, ``asin``, ``sin`` and ``cos`` are much slower than a fused
polynomial, so the range image (:mod:`~jaxdepth._src.normals`) and the outlier
test (:mod:`~jaxdepth._src.outliers`) use these instead:

* :func:`atan2`: octant reduction and a least-squares polynomial, max error < 1e-7 rad;
* :func:`sin_cos_small`: Taylor series on a static interval, error < 1e-7;
* :func:`wrap_angle`: an angle difference back into [-pi, pi];
* :func:`pseudo_angle`: a strictly increasing stand-in for ``atan2`` where only
  the order of angles matters.

Every division is guarded with the safe-``where`` pattern: finite input gives
finite output (and finite gradients).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

PI = math.pi
_TAN_PI_8 = math.tan(math.pi / 8.0)
# atan(u) ~= u + u^3 P(u^2) on |u| <= tan(pi/8): least-squares fit of
# (atan(u)/u - 1)/u^2 by a cubic in s = u^2 on 4000 Chebyshev nodes (float64,
# numpy.linalg.lstsq); measured max abs error 4.8e-8 rad in float32.
_ATAN_COEFFS = (-0.3333328808480196, 0.19991394133810128, -0.14026550211532, 0.08529792624477861)


def atan2(y: jax.Array, x: jax.Array) -> jax.Array:
    """Polynomial float32 ``atan2(y, x)`` in [-pi, pi] (max error < 1e-7 rad); atan2(0, 0) = 0.

    Args:
      y, x: float32 arrays of one shape (any units, only the ratio matters).

    Returns:
      float32 angle in radians, of that shape. Oracle: ``numpy.arctan2`` in float64.

    Examples:
      >>> import jax.numpy as jnp
      >>> round(float(atan2(jnp.float32(1.0), jnp.float32(-1.0))), 5)
      2.35619
    """
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
    a = jnp.where(big, a + PI / 4, a)
    a = jnp.where(ay > ax, PI / 2 - a, a)
    a = jnp.where(x < 0, PI - a, a)
    return jnp.where(y < 0, -a, a)


def sin_cos_small(t: jax.Array, half_width: float):
    """Float32 (sin t, cos t) by Taylor series for |t| <= half_width (static bound).

    Args:
      t: float32 angles, radians, any shape, within ``[-half_width, half_width]``.
      half_width: static Python float, radians; terms are added until the next
        one is below 1e-8 at ``half_width``.

    Returns:
      ``(sin t, cos t)``, float32 of ``t``'s shape. Oracle: ``numpy.sin``/``cos``.

    Examples:
      >>> import jax.numpy as jnp
      >>> s, c = sin_cos_small(jnp.float32(0.5), 1.0)
      >>> round(float(s), 6), round(float(c), 6)
      (0.479426, 0.877583)
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


def wrap_angle(d: jax.Array) -> jax.Array:
    """Wraps a float32 angle difference in (-2 pi, 2 pi) (radians) to [-pi, pi]; same shape."""
    d = jnp.where(d > PI, d - 2 * PI, d)
    return jnp.where(d < -PI, d + 2 * PI, d)


def pseudo_angle(a: jax.Array, b: jax.Array) -> jax.Array:
    """A cheap strictly increasing function of ``atan2(a, b)`` on (-pi, pi].

    ``s = a / (|a| + |b|)`` runs over [-1, 1] for ``b >= 0`` (angles in
    [-pi/2, pi/2]); the back half continues to (1, 2] and [-2, -1).
    ``a = b = 0`` gives 0, as ``atan2(0, 0)`` does. Only the order of the
    result is meaningful (float32, unitless, in [-2, 2], of the inputs' shape).

    Examples:
      >>> import jax.numpy as jnp
      >>> [float(pseudo_angle(jnp.float32(a), jnp.float32(b))) for a, b in ((0, 1), (1, 1), (1, -1))]
      [0.0, 0.5, 1.5]
    """
    den = jnp.abs(a) + jnp.abs(b)
    ok = den > 0
    s = jnp.where(ok, a / jnp.where(ok, den, 1.0), 0.0)
    return jnp.where(b >= 0, s, jnp.where(a >= 0, 2.0, -2.0) - s)
