"""The digital twins' sensors: scan patterns, ray casting and what real LiDARs do to a return.

A *unit* is one emitter with its own origin: a spinning LiDAR (one laser per row at a measured
elevation, columns uniform in azimuth), a raster-scan unit (non-uniform scan lines, denser near
the horizon, over a limited azimuth) or a rosette (one non-repetitive scan path). Its rays form a
``(rows, cols)`` grid in scan order: along a row, neighbouring rays are neighbours on the scan
path (a ring of a spinning LiDAR, a scan line of a raster unit, the path of a rosette).

Sensor effects (:class:`SensorEffects`), applied to each ray's exact first hit ``r``:

- mixed returns: a ray whose scan-path neighbour hit a surface at a different depth (more than
  ``max(edge_m, edge_rel * r)`` away) sits at a depth edge; its footprint spans both surfaces with
  probability ``mixed``, and it then returns ``r + w (r_neighbour - r)`` with ``w ~ U(0.1, 0.9)``
  (the share of the footprint on the other surface) instead of ``r``;
- range noise: ``+ noise_m * N(0, 1)`` along the ray;
- dropouts: each return is lost with probability ``dropout``;
- range bands (optional, nusc13): a ray whose exact range lies below ``band_upper_m[i]`` (the first
  such band) takes ``band_noise_m[i]`` and ``band_dropout[i]`` instead of ``noise_m`` and ``dropout``
  (the real nuScenes sweep's near returns are less noisy and drop less than its far ones).

With all three rates 0 every point lies exactly on a scene surface. Random draws come from
``numpy.random.default_rng`` on the host, keyed by the caller (deterministic).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.poses import rotation_rpy
from jaxdepth._src.scene import SceneArrays, camera_rays, cast_rays


@dataclasses.dataclass(frozen=True)
class SensorEffects:
    """Rates of what a real sensor does to a return (see the module docstring).

    Attributes:
      noise_m: standard deviation of the range noise, metres.
      dropout: probability that a return is lost.
      mixed: probability that a ray at a depth edge returns a blend of the two depths.
      edge_m, edge_rel: two neighbouring returns are on different surfaces when their ranges
        differ by more than ``max(edge_m, edge_rel * range)``.
      band_upper_m, band_noise_m, band_dropout: range bands (ascending upper limits, metres) with their
        own noise and dropout rates, by the ray's exact range; beyond the last band (and by default:
        no bands) ``noise_m`` and ``dropout``.
    """

    noise_m: float = 0.0
    dropout: float = 0.0
    mixed: float = 0.0
    edge_m: float = 0.3
    edge_rel: float = 0.03
    band_upper_m: tuple = ()
    band_noise_m: tuple = ()
    band_dropout: tuple = ()

    def __post_init__(self):
        n = len(self.band_upper_m)
        if len(self.band_noise_m) != n or len(self.band_dropout) != n:
            raise ValueError("SensorEffects: fields 'band_upper_m', 'band_noise_m', 'band_dropout' expected one "
                             f"length, got {n}, {len(self.band_noise_m)}, {len(self.band_dropout)}")
        if any(b <= a for a, b in zip(self.band_upper_m, self.band_upper_m[1:])):
            raise ValueError(f"SensorEffects: field 'band_upper_m' expected ascending, got {self.band_upper_m!r}")

    def bands(self) -> np.ndarray:
        """(B, 3) float32 rows ``(upper_m, noise_m, dropout)`` of the range bands (B = 0 by default)."""
        return np.array(list(zip(self.band_upper_m, self.band_noise_m, self.band_dropout)), np.float32).reshape(-1, 3)


NO_EFFECTS = SensorEffects()


@dataclasses.dataclass(frozen=True, eq=False)
class Unit:
    """One emitter: unit ray directions on a ``(rows, cols)`` scan grid, in the unit's own frame.

    Attributes:
      name: e.g. ``"up_lidar"``.
      directions: (rows * cols, 3) float32 unit vectors, row major.
      rows, cols: the scan grid (rows: lasers / scan lines; cols: samples along each).
      apex: (3,) float64 where the rays start in the unit's frame (a spinning LiDAR's cone apex).
      max_range_m: rays without a hit within this range return nothing.
      ring: (rows * cols,) int32 the row of each ray (the laser index of a spinning LiDAR).
    """

    name: str
    directions: np.ndarray
    rows: int
    cols: int
    apex: np.ndarray
    max_range_m: float
    ring: np.ndarray


def _spherical(elevation: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    e, a = np.broadcast_arrays(elevation, azimuth)
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)


def spinning_unit(name: str, elevations_deg, *, cols: int, phase: float = 0.0, apex_m: float = 0.0,
                  max_range_m: float = 120.0) -> Unit:
    """A spinning LiDAR: row i is the laser at ``elevations_deg[i]`` (in the given order: the ring index).

    Column j points at azimuth ``pi - 2 pi (j + 0.5 + phase) / cols`` (as
    :func:`jaxdepth._src.synthetic.lidar_rays`, shifted by ``phase`` columns: real sweeps do not
    start at the same azimuth). Rays start ``apex_m`` above the unit's origin.
    """
    el = np.radians(np.asarray(elevations_deg, np.float64))[:, None]
    az = math.pi - 2.0 * math.pi * (np.arange(cols) + 0.5 + phase) / cols
    rows = el.shape[0]
    return Unit(name, _spherical(el, az[None, :]).astype(np.float32), rows, int(cols),
                np.array([0.0, 0.0, apex_m]), float(max_range_m), np.repeat(np.arange(rows, dtype=np.int32), cols))


def stagger_lasers(unit: Unit, *, seed: int = 0) -> Unit:
    """``unit`` (a spinning LiDAR) with each laser sampling at its own azimuth phase, uniform over one column.

    Real spinning LiDARs do (``benchmarks.studies.edge_input``: the phases of KITTI's, nuScenes' and both
    Argoverse 2 LiDARs' rings are spread over a column: resultant length 0.08-0.22, 1 for one shared phase);
    :func:`spinning_unit`'s lasers share one, so their columns line up and many image columns get no point.
    Row i is turned by ``-2 pi phase_i / cols`` about the unit's z axis (``phase_i ~ U(-0.5, 0.5)``, drawn
    from ``seed``: a property of the sensor, the same every sweep).
    """
    phase = np.random.default_rng([int(seed), 39]).uniform(-0.5, 0.5, unit.rows)
    R = np.stack([rotation_rpy(0.0, 0.0, -2.0 * math.pi * p / unit.cols) for p in phase])     # (rows, 3, 3)
    d = unit.directions.reshape(unit.rows, unit.cols, 3).astype(np.float64)
    turned = np.einsum("rij,rcj->rci", R, d)
    return dataclasses.replace(unit, directions=turned.reshape(-1, 3).astype(np.float32))


def raster_lines_deg(lines: int, *, top_deg: float = 10.0, bottom_deg: float = -20.0, squeeze: float = 3.0):
    """(lines,) scan-line elevations, top first, denser near the horizon: ``A sinh(squeeze (h - u))``
    over ``u`` uniform in [0, 1], with ``A`` and the horizon's ``h`` set by the two ends."""
    # Solve sinh(s h) / sinh(s (1 - h)) = top / -bottom for h by bisection (monotone in h).
    lo, hi = 0.0, 1.0
    for _ in range(60):
        h = 0.5 * (lo + hi)
        if math.sinh(squeeze * h) * -bottom_deg < math.sinh(squeeze * (1.0 - h)) * top_deg:
            lo = h
        else:
            hi = h
    amp = top_deg / math.sinh(squeeze * h)
    return amp * np.sinh(squeeze * (h - np.linspace(0.0, 1.0, lines)))


def raster_unit(name: str, *, lines: int = 64, cols: int = 600, h_fov_deg: float = 120.0, phase: float = 0.0,
                max_range_m: float = 200.0) -> Unit:
    """A raster-scan unit looking along +x: ``lines`` non-uniform scan lines (:func:`raster_lines_deg`),
    ``cols`` samples across ``h_fov_deg`` per line (left to right), shifted by ``phase`` samples."""
    el = np.radians(raster_lines_deg(lines))[:, None]
    az = np.radians(h_fov_deg) * (0.5 - (np.arange(cols) + phase) / cols)
    return Unit(name, _spherical(el, az[None, :]).astype(np.float32), int(lines), int(cols), np.zeros(3),
                float(max_range_m), np.repeat(np.arange(lines, dtype=np.int32), cols))


def rosette_unit(name: str, *, points: int = 40000, half_fov_deg: float = 35.0, start: float = 0.0,
                 max_range_m: float = 200.0) -> Unit:
    """A non-repetitive rosette (two counter-rotating prisms, Livox-like) looking along +x.

    The direction's offset from the axis is ``half_fov * (e^{i a t} + e^{-i b t}) / 2`` with an
    irrational speed ratio ``b / a``, so each sweep (``start`` = the sweep's first sample time,
    in samples) covers new directions. One scan path: ``rows = 1``.
    """
    t = (np.arange(points) + start) * (2.0 * math.pi / 4000.0)
    b = 1.0 / ((1.0 + math.sqrt(5.0)) / 2.0) * 0.9
    z = 0.5 * (np.exp(1j * t) + np.exp(-1j * b * t * 7.3))
    rho = np.radians(half_fov_deg) * np.abs(z)
    ang = np.angle(z)
    az, el = rho * np.cos(ang), rho * np.sin(ang)
    return Unit(name, _spherical(el, az).astype(np.float32), 1, int(points), np.zeros(3), float(max_range_m),
                np.zeros(points, np.int32))


def sphere_hits(origin: jax.Array, d: jax.Array, spheres: jax.Array) -> jax.Array:
    """(N,) first-hit ray parameter of rays ``origin (3,) + t d (N, 3)`` on solid spheres, inf if none.

    ``spheres`` (S, 4) ``[cx, cy, cz, radius]``; visited by ``lax.scan`` (O(N) working set). A ray
    starting inside a sphere returns its exit. Closest-approach form: ``t = t_c -+ sqrt((r^2 - m^2) / a)``.
    """
    a = jnp.sum(d * d, axis=1)
    inv_a = 1.0 / jnp.where(a > 0, a, 1.0)

    def body(t_best, sph):
        oc = origin - sph[:3]
        t_c = -(d @ oc) * inv_a
        m = oc + t_c[:, None] * d
        h2 = (sph[3] * sph[3] - jnp.sum(m * m, axis=1)) * inv_a
        half = jnp.sqrt(jnp.where(h2 >= 0, h2, 0.0))
        t_in = t_c - half
        t = jnp.where(t_in > 1e-6, t_in, t_c + half)
        return jnp.minimum(t_best, jnp.where((h2 >= 0) & (t > 1e-6), t, jnp.inf)), None

    t, _ = jax.lax.scan(body, jnp.full(d.shape[:1], jnp.inf, jnp.float32), jnp.asarray(spheres, jnp.float32))
    return t


def first_hits(origin, d, scene: SceneArrays, spheres) -> jax.Array:
    """(N,) first hit on the scene's primitives (:func:`jaxdepth._src.scene.cast_rays`) or the spheres."""
    return jnp.minimum(cast_rays(origin, d, scene), sphere_hits(origin, d, spheres))


@jax.jit
def render_twin_depth(camera, scene: SceneArrays, spheres, max_range_m) -> jax.Array:
    """(H, W) float32 exact camera-frame depth of ``scene`` plus ``spheres`` (0 = nothing within
    ``max_range_m`` along the ray), as :func:`jaxdepth._src.synthetic.render_depth`."""
    origin, d = camera_rays(camera)
    t = first_hits(origin, d, scene, spheres)
    hit = t * jnp.linalg.norm(d, axis=1) <= max_range_m
    return jnp.where(hit, t, 0.0).reshape(camera.height, camera.width)


@functools.partial(jax.jit, static_argnames=("rows", "cols"))
def _cast_unit(scene: SceneArrays, spheres, origin, R, directions, draws, rates, bands, *, rows: int, cols: int):
    """Exact ranges and the returned ranges of one unit's rays (see :func:`cast_unit`)."""
    d = directions @ R.T
    t = first_hits(origin, d, scene, spheres)
    max_range, noise_m, dropout, mixed, edge_m, edge_rel = (rates[i] for i in range(6))
    hit = t <= max_range
    r = jnp.where(hit, t, jnp.inf).reshape(rows, cols)
    inf_col = jnp.full((rows, 1), jnp.inf, jnp.float32)
    left = jnp.concatenate([inf_col, r[:, :-1]], axis=1)
    right = jnp.concatenate([r[:, 1:], inf_col], axis=1)
    side, w, coin, gauss, drop = (draws[i].reshape(rows, cols) for i in range(5))

    def edge(n):
        finite = jnp.isfinite(n) & jnp.isfinite(r)
        gap = jnp.where(finite, jnp.abs(n - r), 0.0)
        return finite & (gap > jnp.maximum(edge_m, edge_rel * jnp.where(finite, r, 0.0)))

    use_left = edge(left) & ((side < 0.5) | ~edge(right))
    other = jnp.where(use_left, left, right)
    at_edge = edge(left) | edge(right)
    blend = at_edge & (coin < mixed)
    r_safe = jnp.where(jnp.isfinite(r), r, 0.0)
    # Range bands (none by default: the scalar rates, the same ops as before): the first band above r wins.
    for i in reversed(range(bands.shape[0])):
        inside = r < bands[i, 0]
        noise_m, dropout = jnp.where(inside, bands[i, 1], noise_m), jnp.where(inside, bands[i, 2], dropout)
    measured = jnp.where(blend, r_safe + w * (jnp.where(blend, other, 0.0) - r_safe), r_safe) + noise_m * gauss
    valid = jnp.isfinite(r) & (drop >= dropout) & (measured > 0)
    d = d.reshape(rows, cols, 3)
    points = jnp.where(valid[..., None], origin + d * jnp.where(valid, measured, 0.0)[..., None], 0.0)
    exact = jnp.where(jnp.isfinite(r)[..., None], origin + d * r_safe[..., None], 0.0)
    return points.reshape(-1, 3), valid.reshape(-1), exact.reshape(-1, 3), (blend & valid).reshape(-1)


def cast_unit(scene: SceneArrays, spheres: np.ndarray, unit: Unit, T_world_unit: np.ndarray, effects: SensorEffects,
              rng_key) -> dict:
    """One sweep of ``unit`` posed at ``T_world_unit`` (4, 4) in ``scene`` plus ``spheres`` (S, 4).

    Args:
      rng_key: a ``numpy.random.default_rng`` seed (e.g. ``[seed, sweep, unit]``) for the effects' draws.

    Returns:
      dict of NumPy arrays over the unit's rays: ``points`` (n, 3) float32 returned points (world
      frame), ``valid`` (n,) bool, ``exact`` (n, 3) float32 the exact first hits, ``mixed`` (n,)
      bool returns that are blends, ``ring`` (n,) int32, ``origin`` (3,) float64 the rays' start.
    """
    T = np.asarray(T_world_unit, np.float64)
    origin = T[:3, :3] @ unit.apex + T[:3, 3]
    rng = np.random.default_rng(rng_key)
    n = unit.rows * unit.cols
    draws = np.stack([rng.random(n), rng.uniform(0.1, 0.9, n), rng.random(n), rng.standard_normal(n),
                      rng.random(n)]).astype(np.float32)
    rates = np.array([unit.max_range_m, effects.noise_m, effects.dropout, effects.mixed, effects.edge_m,
                      effects.edge_rel], np.float32)
    pts, valid, exact, mixed = _cast_unit(scene, np.asarray(spheres, np.float32), origin.astype(np.float32), T[:3, :3].astype(np.float32),
                                          unit.directions, draws, rates, effects.bands(), rows=unit.rows,
                                          cols=unit.cols)
    return {"points": np.asarray(pts), "valid": np.asarray(valid), "exact": np.asarray(exact),
            "mixed": np.asarray(mixed), "ring": unit.ring, "origin": origin}


__all__ = ["SensorEffects", "NO_EFFECTS", "Unit", "spinning_unit", "stagger_lasers", "raster_unit", "raster_lines_deg",
           "rosette_unit", "cast_unit", "sphere_hits", "first_hits", "render_twin_depth"]
