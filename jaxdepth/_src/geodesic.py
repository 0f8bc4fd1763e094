"""Step 3, image-guided: the nearest seed under a geodesic distance (GeoS raster passes).

For every pixel of an ``(H, W)`` seed mask this module finds the seed that
minimises the geodesic distance over **4-connected** paths, where one step
between neighbouring pixels ``p``, ``q`` costs

    1 + color_weight * ||I(p) - I(q)||_2

(its image-plane length, one pixel, plus the weighted Euclidean colour
difference of the guidance image ``I``; grey images have one channel).  Seeds
therefore spread along a surface of even colour and stop at image edges
(Criminisi, Sharp and Blake, "GeoS: Geodesic Image Segmentation", ECCV 2008).
With ``color_weight = 0`` every step costs 1 and the distance is the exact
city-block (L1) distance of :func:`~jaxdepth._src.distance.nearest_seed`.

Noise floor (beyond GeoS, optional; ``noise_floor``, the pipeline's
``SGMConfig.guidance_noise_floor``, 0 = off by default).  Each colour difference is first
reduced by ``noise_floor`` times the image's median step difference (its
sensor noise, JPEG blocks and fine texture; :func:`median_step_difference`,
from every 4th row and column) and floored at 0:

    1 + color_weight * max(||I(p) - I(q)|| - noise_floor * median, 0)

so a textured or noisy surface costs what a flat one does and only real
edges are charged, whatever the image's exposure and compression.  Measured
(docs/method.md, docs/studies.md): it helps on the synthetic renders and not on
the real KITTI and nuScenes photographs, hence off by default.  The costs stay
positive and symmetric, so everything below holds unchanged.

Passes.  GeoS's forward and backward raster scans read the left and upper
neighbours (resp. right and lower) in one pass, which is sequential along each
row.  Here each sweep is split into directional 1-D passes, each a
``lax.fori_loop`` over the leading axis of a row-major array with all other
pixels vectorised, updated in place like :mod:`~jaxdepth._src.distance`:

1. horizontal: on the transposed layout, a forward loop over the columns
   (left neighbour) and a backward loop (right neighbour);
2. vertical: a forward loop over the rows (upper neighbour) and a backward loop
   (lower neighbour).

Each 1-D pair is exact along its line (costs are positive and symmetric, so a
shortest path never reverses direction along a line).  Hence after ``sweeps``
sweeps the distance is *exactly* the minimum over 4-connected paths made of at
most ``2 * sweeps`` straight runs that alternate horizontal / vertical
(horizontal first); every path is a staircase of such runs, and the sweeps
only add runs, so the distance never increases with ``sweeps`` and reaches
the Dijkstra distance once ``2 * sweeps`` covers the runs of the shortest
paths.  With ``color_weight = 0`` one sweep is exact (an L1 shortest path is
one horizontal then one vertical run).  Approximation with fewer sweeps: a
pixel whose shortest path must wind around an edge (e.g. enter a U-shaped
region through its opening) keeps a longer path, so it may pick a seed
that is geodesically farther than the best one; it never picks an unreachable
or invalid seed.  Measured on the KITTI frame's inlier mask and colour image
(benchmarks/studies/geodesic_sweeps.py, against 16 sweeps): after 2 sweeps 0.9 % of
the pixels have another seed at colour_weight 1, 2.5 % at 2, 6.7 % at 10 and
19 % at 50; after 4 sweeps 0.06 / 0.2 / 2.1 / 8 %.  Larger weights make
shortest paths wind more and need more sweeps.

Each pass carries one complex64 array: the float32 distance and the flat
index ``v * W + u`` of the seed it comes from (as float32, exact for
H W <= 2**24).  A neighbour's path replaces the current one only when strictly
shorter, so the first path found wins ties and the result is deterministic.
One sweep reaches every pixel when any seed exists (a horizontal run to the
seed's row, then a vertical run), so ``du``, ``dv`` always name a seed.

Oracle: a multi-source Dijkstra (``heapq``) on the same edge costs in NumPy
(tests/test_geodesic.py); with ``color_weight = 0``, ``cv2.distanceTransform(
..., cv2.DIST_L1, 3)`` and ``nearest_seed(metric="l1")``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import lax

from jaxdepth._src.distance import NearestSeed
from jaxdepth._src.xla_tuning import stage

_F32_EXACT = 2**24  # float32 holds every integer up to here
_BLOCKED = 1e6  # pixels: the cost of a step next to a non-finite colour


def _check(keep: jax.Array, image: jax.Array, color_weight, sweeps) -> None:
    if keep.ndim != 2:
        raise ValueError(f"geodesic_seed: field 'keep' expected shape (H, W), got shape {tuple(keep.shape)}")
    if keep.dtype != jnp.bool_:
        raise ValueError(f"geodesic_seed: field 'keep' expected dtype bool, got {keep.dtype}")
    h, w = keep.shape
    if h < 1 or w < 1:
        raise ValueError(f"geodesic_seed: field 'keep' expected H >= 1 and W >= 1, got shape {(h, w)}")
    if h * w > _F32_EXACT:
        raise ValueError(f"geodesic_seed: keep shape {(h, w)} too large: expected H * W <= 2**24 "
                         f"(seed indices travel as float32), got {h * w}")
    if image.ndim not in (2, 3) or image.shape[:2] != (h, w) or (image.ndim == 3 and image.shape[2] not in (1, 3)):
        raise ValueError(
            f"geodesic_seed: field 'image' expected shape {(h, w)} or {(h, w, 3)} (same H, W as keep), "
            f"got {tuple(image.shape)}")
    if not jnp.issubdtype(image.dtype, jnp.floating):
        raise ValueError(f"geodesic_seed: field 'image' expected a floating dtype (e.g. float32 in [0, 1]), "
                         f"got {image.dtype}")
    if isinstance(sweeps, bool) or int(sweeps) != sweeps or sweeps < 1:
        raise ValueError(f"geodesic_seed: field 'sweeps' expected an integer >= 1, got {sweeps!r}")
    if isinstance(color_weight, (int, float)) and not color_weight >= 0:
        raise ValueError(f"geodesic_seed: field 'color_weight' expected >= 0, got {color_weight!r}")


def median_step_difference(dh: jax.Array, dv: jax.Array, *, stride: int = 4, iterations: int = 12) -> jax.Array:
    """Median colour difference of an image's 4-connected steps, from a fixed subsample.

    Args:
      dh, dv: (H, W - 1) and (H - 1, W) float32 colour differences of the
        horizontal and vertical steps (non-finite entries, e.g. the NaN padding
        of a rig's canvas, are left out).
      stride: every ``stride``-th row and column of both arrays is sampled
        (static; 4 samples 1/16 of the steps).
      iterations: bisection steps on ``[0, max]`` of the sample (static); the
        result is within ``max / 2**iterations`` of the sample's median.

    Returns:
      () float32, the median of the sample's finite values (0 if it has none).

    Counting below a bisected threshold instead of a sort-based ``jnp.median``
    of every step: the sort dominates the seed search on CPU
    (benchmarks/geodesic_sweeps.py).
    """
    sample = jnp.concatenate([dh[::stride, ::stride].ravel(), dv[::stride, ::stride].ravel()])
    finite = jnp.isfinite(sample)
    count = jnp.sum(finite)
    sample = jnp.where(finite, sample, 0.0)
    hi = jnp.max(sample)

    def halve(_, bounds):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        # The lower half holds at least half of the finite values: the median is <= mid.
        below = 2 * jnp.sum(finite & (sample <= mid)) >= count
        return jnp.where(below, lo, mid), jnp.where(below, mid, hi)

    lo, hi = lax.fori_loop(0, iterations, halve, (jnp.float32(0.0), hi))
    return jnp.where(count > 0, 0.5 * (lo + hi), 0.0)


def step_costs(image: jax.Array, color_weight, *, noise_floor: float = 0.0) -> tuple[jax.Array, jax.Array]:
    """Costs of the 4-connected steps.

    Args:
      image: (H, W) or (H, W, C) float guidance image.
      color_weight: pixels per unit of Euclidean colour difference (>= 0).
      noise_floor: static float >= 0. A step's colour difference is reduced by
        ``noise_floor`` times the image's median step difference
        (:func:`median_step_difference`) and floored at 0, so differences at the
        image's own noise and texture level cost nothing and only the excess
        is charged. 0 gives GeoS's plain cost.

    Returns:
      (horizontal, vertical): float32 (H, W - 1) cost of the step between
      ``(v, u)`` and ``(v, u + 1)``, and (H - 1, W) between ``(v, u)`` and
      ``(v + 1, u)``; each ``1 + color_weight * max(||I(p) - I(q)|| - floor, 0)``
      (floor = ``noise_floor`` x median), or 1e6 where that is not finite (NaN
      or inf colours).
    """
    img = jnp.asarray(image, jnp.float32)
    # Channel planes, summed one by one: a reduction over a trailing axis of
    # 3 vectorises badly on CPU.
    planes = [img] if img.ndim == 2 else [img[..., c] for c in range(img.shape[-1])]
    weight = jnp.asarray(color_weight, jnp.float32)
    dh = jnp.sqrt(sum(jnp.square(p[:, 1:] - p[:, :-1]) for p in planes))
    dv = jnp.sqrt(sum(jnp.square(p[1:] - p[:-1]) for p in planes))
    if noise_floor:
        floor = jnp.float32(noise_floor) * median_step_difference(dh, dv)
        # max() would turn NaN into the floor: keep non-finite steps blocked.
        dh, dv = (jnp.where(d > floor, d - floor, jnp.where(jnp.isfinite(d), 0.0, d)) for d in (dh, dv))
    # Non-finite colours (NaN, inf) give a finite, very large step: every pixel
    # stays reachable, so every pixel gets a real seed.
    return tuple(jnp.where(jnp.isfinite(c), c, _BLOCKED) for c in (1.0 + weight * dh, 1.0 + weight * dv))


def _line_pass(buf: jax.Array, cost: jax.Array) -> jax.Array:
    """Exact 1-D geodesic pass along the leading axis, forward then backward, in place.

    Args:
      buf: (L, M) complex64, real part the float32 distance, imaginary part
        the seed's flat index ``v * W + u`` as float32 (exact below 2**24).
      cost: (L - 1, M) float32, cost of the step between lines i and i + 1.

    Returns:
      ``buf`` after relaxing every line from its predecessor (forward) and then
      from its successor (backward); a line takes its neighbour's path plus the
      step cost only where that is strictly shorter.

    Both fields travel in one complex64 buffer (as the pipeline's gathers do)
    and the carry is the previous line itself, so a step is one fused kernel
    plus an in-place row write, as in :mod:`~jaxdepth._src.distance`.  With two
    buffers XLA recomputed the comparison from the already updated distance
    buffer and copied it whole on every step; an (L, 2, M) int32 buffer with a
    bitcast distance is slower too.
    """
    n = buf.shape[0]
    if n == 1:
        return buf

    def relax(i, c, state):
        prev, buf = state
        line = buf[i]
        d = jnp.real(line)
        cand = jnp.real(prev) + c
        take = cand < d
        new = lax.complex(jnp.where(take, cand, d), jnp.where(take, jnp.imag(prev), jnp.imag(line)))
        return new, lax.dynamic_update_index_in_dim(buf, new, i, 0)

    _, buf = lax.fori_loop(1, n, lambda i, st: relax(i, cost[i - 1], st), (buf[0], buf))
    _, buf = lax.fori_loop(1, n, lambda k, st: relax(n - 1 - k, cost[n - 1 - k], st), (buf[n - 1], buf))
    return buf


def geodesic_seed(keep: jax.Array, image: jax.Array, *, color_weight, sweeps: int,
                  noise_floor: float = 0.0) -> NearestSeed:
    """Seed of least geodesic distance for every pixel (GeoS raster passes).

    Args:
      keep: (H, W) bool, True at seed pixels (e.g. Step 2's inlier mask).
      image: (H, W) grey or (H, W, 3) colour guidance image, floating dtype,
        aligned with ``keep`` (the scale sets ``color_weight``'s unit; the
        pipeline passes colours in [0, 1]).
      color_weight: float >= 0 (may be traced), pixels of path length per unit
        of Euclidean colour difference between neighbours.  0 gives the exact
        L1 distance of ``nearest_seed(keep, metric="l1")``.
      sweeps: static int >= 1, number of (horizontal, vertical) sweep pairs;
        see the module docstring for what fewer sweeps approximate.
      noise_floor: static float >= 0; colour differences up to this many
        times the image's median step difference cost nothing (see
        :func:`step_costs`). 0 (the default) is GeoS's plain cost; the
        pipeline passes ``SGMConfig.guidance_noise_floor``.

    Returns:
      :class:`~jaxdepth._src.distance.NearestSeed` with the same contract as
      ``nearest_seed``: ``distance`` (H, W) float32 geodesic distance (``+inf``
      without seeds), ``du``, ``dv`` (H, W) int32 so the seed is at
      ``(v + dv, u + du)`` (a pixel of ``keep``), ``has_seed`` () bool.  A
      seed is its own seed (distance 0).  Works under ``jit`` and ``vmap``.

    Raises:
      ValueError (at trace time): shapes, dtypes, ``sweeps`` < 1 or a negative
      Python-number ``color_weight`` (a traced weight is not checked).
    """
    _check(keep, image, color_weight, sweeps)
    if not float(noise_floor) >= 0:
        raise ValueError(f"geodesic_seed: field 'noise_floor' expected >= 0, got {noise_floor!r}")
    return _geodesic_seed(keep, image, color_weight, sweeps=sweeps, noise_floor=float(noise_floor))


@functools.partial(jax.jit, static_argnames=("sweeps", "noise_floor"))
def _geodesic_seed(keep, image, color_weight, *, sweeps: int, noise_floor: float) -> NearestSeed:
    h, w = keep.shape
    # A stage fence: inside the pipeline XLA would otherwise fuse the cost
    # computation (uint8 conversion, differences, sqrt) into every loop step.
    cost_ht, cost_v = stage(lambda img, cw: (lambda c: (c[0].T, c[1]))(step_costs(img, cw, noise_floor=noise_floor)),
                            (image, jnp.asarray(color_weight, jnp.float32)), keep[0, 0].astype(jnp.int32))
    flat = jnp.arange(h * w, dtype=jnp.float32).reshape(h, w)
    buf = lax.complex(jnp.where(keep, 0.0, jnp.inf).astype(jnp.float32), jnp.where(keep, flat, 0.0))
    for _ in range(sweeps):
        buf = _line_pass(buf.T, cost_ht).T
        buf = _line_pass(buf, cost_v)
    dist = jnp.real(buf)
    src = jnp.imag(buf).astype(jnp.int32)
    has_seed = jnp.any(keep)
    v = jnp.arange(h, dtype=jnp.int32)[:, None]
    u = jnp.arange(w, dtype=jnp.int32)[None, :]
    dv = jnp.where(has_seed, src // w - v, 0)
    du = jnp.where(has_seed, src % w - u, 0)
    return NearestSeed(distance=jnp.where(has_seed, dist, jnp.inf), du=du, dv=dv, has_seed=has_seed)
