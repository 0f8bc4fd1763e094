"""KITTI depth-completion metrics with the official devkit's semantics.

Contract (one image per call; ``vmap`` for batches):

* Depth maps are ``(H, W)`` float32 in metres; a pixel ``<= 0`` (or NaN) is empty.
* The score of one image is taken over its ground-truth pixels (``gt > 0``):
  RMSE and MAE in millimetres, iRMSE and iMAE in 1/km (inverse depth ``1/d`` with
  ``d`` in km).  A data set's score is the mean of the per-image scores
  (:func:`mean_metrics`), as in the devkit.
* Before scoring, empty predicted pixels are filled like the devkit's
  ``interpolateBackground`` (:func:`interpolate_background`).

Reference: the KITTI depth-completion devkit (Uhrig et al., "Sparsity Invariant
CNNs", 3DV 2017), ``evaluate_depth``; implemented here from its documented
behaviour, not from its code.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp

# The devkit stores an invalid depth as -1 m and scores whatever is left empty after
# interpolateBackground with that value; we do the same (see depth_metrics).
_DEVKIT_INVALID_M = -1.0

METRIC_KEYS = ("rmse", "mae", "irmse", "imae")


def _check_image(name: str, x: jax.Array) -> jax.Array:
    x = jnp.asarray(x)
    if x.ndim != 2:
        raise ValueError(f"{name}: expected shape (H, W), got {tuple(x.shape)}")
    return x.astype(jnp.float32)


def _nearest_valid_in_row(d: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Nearest valid depth to the left and to the right of every pixel (inclusive).

    ``d`` is (H, W) with empty pixels already 0 and valid ones > 0, so "no valid pixel"
    is simply 0.  One ``lax.scan`` over the W columns (the scanned axis leading)
    carries both directions at once: a (2, H) carry, no per-pixel Python loop.
    """
    dt = d.T  # (W, H)
    xs = jnp.stack([dt, dt[::-1]], axis=1)  # (W, 2, H): left-to-right and right-to-left

    def step(carry, x):
        carry = jnp.where(x > 0.0, x, carry)
        return carry, carry

    _, out = jax.lax.scan(step, jnp.zeros(xs.shape[1:], d.dtype), xs)
    return out[:, 0].T, out[::-1, 1].T


@jax.jit
def interpolate_background(depth: jax.Array) -> jax.Array:
    """Fills empty pixels of a predicted depth map like the KITTI devkit.

    Args:
      depth: (H, W) float32 depth, metres; pixels ``<= 0`` (or NaN) are empty.

    Returns:
      (H, W) float32.  Valid input pixels are unchanged.  Per row: every run of empty
      pixels with valid pixels on both sides takes the smaller (nearer) of the two
      bounding depths; the leading run takes the row's first valid depth and the
      trailing run its last valid depth.  Then per column: pixels above the first
      valid pixel take its depth, pixels below the last valid pixel take its depth.

    Note:
      Like the devkit, a completely empty row lying *between* non-empty rows stays
      empty (the column pass only extrapolates, it never interpolates); such pixels,
      and every pixel of an all-empty image, are returned as 0.  The devkit's
      quirk that a gap touching the left border is handled by extrapolation rather
      than interpolation gives the same values as described above, so it needs no
      special case.  Fixed-shape and jit-able: one ``lax.scan`` over columns carrying
      both directions, then a row-wise copy; no loops over pixels.
    """
    d = _check_image("depth", depth)
    valid = d > 0.0  # False for NaN too
    d = jnp.where(valid, d, 0.0)
    # Row pass: nearest valid depth on each side (0 = none).
    left, right = _nearest_valid_in_row(d)
    has_l, has_r = left > 0.0, right > 0.0
    row = jnp.where(valid, d, jnp.where(has_l & has_r, jnp.minimum(left, right),
                                        jnp.where(has_r, right, left)))
    # After the row pass a row is either completely filled or completely empty, so the
    # column pass (extrapolation above the first / below the last valid pixel of each
    # column) copies the first and the last non-empty row.
    height = d.shape[0]
    nonempty = row[:, 0] > 0.0
    any_row = jnp.any(nonempty)
    first = jnp.argmax(nonempty)
    last = height - 1 - jnp.argmax(nonempty[::-1])
    v = jnp.arange(height)[:, None]
    return jnp.where(
        nonempty[:, None], row,
        jnp.where(any_row & (v < first), row[first][None, :],
                  jnp.where(any_row & (v > last), row[last][None, :], 0.0)))


def _errors(pred: jax.Array, gt: jax.Array, mask: jax.Array) -> dict[str, jax.Array]:
    """RMSE/MAE (mm) and iRMSE/iMAE (1/km) of ``pred`` vs ``gt`` over ``mask``."""
    count = jnp.sum(mask, dtype=jnp.int32)
    safe_gt = jnp.where(mask, gt, 1.0)
    pred_ok = mask & (pred != 0.0)
    safe_pred = jnp.where(pred_ok, pred, 1.0)
    err_mm = jnp.where(mask, (pred - gt) * 1000.0, 0.0)
    # 1/d[1/km] = 1000 / d[m]; a zero prediction cannot occur in depth_metrics (empty
    # pixels are scored at -1 m) and is excluded from pair_errors by the mask.
    ierr = jnp.where(pred_ok, 1000.0 / safe_pred - 1000.0 / safe_gt, 0.0)
    ok = count > 0
    n = jnp.where(ok, count, 1).astype(jnp.float32)
    nan = jnp.float32(jnp.nan)
    return {
        "rmse": jnp.where(ok, jnp.sqrt(jnp.sum(err_mm * err_mm) / n), nan),
        "mae": jnp.where(ok, jnp.sum(jnp.abs(err_mm)) / n, nan),
        "irmse": jnp.where(ok, jnp.sqrt(jnp.sum(ierr * ierr) / n), nan),
        "imae": jnp.where(ok, jnp.sum(jnp.abs(ierr)) / n, nan),
        "count": count,
    }


@functools.partial(jax.jit, static_argnames=("fill",))
def depth_metrics(pred: jax.Array, gt: jax.Array, *, fill: bool = True) -> dict[str, jax.Array]:
    """KITTI depth-completion errors of one predicted depth map.

    Args:
      pred: (H, W) float32 predicted depth, metres; ``<= 0`` is empty.
      gt: (H, W) float32 ground truth, metres; ``<= 0`` is empty.
      fill: static; fill empty predicted pixels with :func:`interpolate_background`
        first (the devkit always does).

    Returns:
      dict of float32 scalars ``rmse``, ``mae`` (mm), ``irmse``, ``imae`` (1/km),
      and int32 ``count``, the number of ground-truth pixels scored.  When ``count``
      is 0 the four errors are NaN (a mean over no pixels; :func:`mean_metrics`
      skips such images).

    Note:
      Predicted pixels that are still empty when scored (all of them with
      ``fill=False``; with ``fill=True`` only empty rows between non-empty rows, or an
      all-empty prediction) are scored at depth -1 m, the devkit's stored value for
      an invalid depth, so every error stays finite.
    """
    p = _check_image("pred", pred)
    g = _check_image("gt", gt)
    if p.shape != g.shape:
        raise ValueError(f"pred: expected the shape of gt {tuple(g.shape)}, got {tuple(p.shape)}")
    if fill:
        p = interpolate_background(p)
    p = jnp.where(p > 0.0, p, _DEVKIT_INVALID_M)
    return _errors(p, g, g > 0.0)


@jax.jit
def pair_errors(sparse: jax.Array, gt: jax.Array) -> dict[str, jax.Array]:
    """Error of a sparse depth map against ground truth, without any fill.

    The paper's Table 1 metric: over the pixels valid (``> 0``) in *both* ``sparse``
    and ``gt``.

    Args:
      sparse: (H, W) float32 sparse depth, metres; ``<= 0`` is empty.
      gt: (H, W) float32 ground truth, metres; ``<= 0`` is empty.

    Returns:
      dict of float32 scalars ``rmse``, ``mae`` (mm), ``irmse``, ``imae`` (1/km),
      int32 ``count`` (pixels valid in both; errors NaN when 0) and int32
      ``sparse_count`` (valid pixels of ``sparse``, the denominator-free half of a
      keep ratio, see :func:`keep_ratio`).
    """
    s = _check_image("sparse", sparse)
    g = _check_image("gt", gt)
    if s.shape != g.shape:
        raise ValueError(f"sparse: expected the shape of gt {tuple(g.shape)}, got {tuple(s.shape)}")
    sv = s > 0.0
    out = _errors(s, g, sv & (g > 0.0))
    out["sparse_count"] = jnp.sum(sv, dtype=jnp.int32)
    return out


@jax.jit
def keep_ratio(kept: jax.Array, original: jax.Array) -> jax.Array:
    """Share of the valid pixels of ``original`` that are still valid in ``kept``.

    Args:
      kept: (H, W) depth (``> 0`` valid) or bool mask after filtering.
      original: (H, W) depth (``> 0`` valid) or bool mask before filtering.

    Returns:
      float32 scalar in [0, 1] (the paper's Table 1 "keep ratio" as a fraction);
      NaN when ``original`` has no valid pixel.
    """
    k = jnp.asarray(kept)
    o = jnp.asarray(original)
    if k.shape != o.shape:
        raise ValueError(f"kept: expected the shape of original {tuple(o.shape)}, got {tuple(k.shape)}")
    kv = k if k.dtype == jnp.bool_ else k > 0
    ov = o if o.dtype == jnp.bool_ else o > 0
    n = jnp.sum(ov, dtype=jnp.int32)
    m = jnp.sum(kv & ov, dtype=jnp.int32)
    ok = n > 0
    return jnp.where(ok, m.astype(jnp.float32) / jnp.where(ok, n, 1).astype(jnp.float32),
                     jnp.float32(jnp.nan))


def mean_metrics(
    per_image: Sequence[Mapping[str, float]] | Mapping[str, jax.Array],
) -> dict[str, float]:
    """Data-set score: the mean of per-image scores, as the KITTI devkit reports it.

    Args:
      per_image: a sequence of :func:`depth_metrics` / :func:`pair_errors` results,
        or one such dict whose values carry a leading image axis (a ``vmap`` result).

    Returns:
      dict of Python floats: the mean of each error key present (``rmse``, ``mae``,
      ``irmse``, ``imae``) over the images with ``count > 0`` (images without any
      scored pixel have NaN errors and are skipped), plus ``images`` (the number of
      images averaged) and, when per-image ``count`` is given, ``count`` (their total).
      Plain float means (float64 accumulation) on the host; not jit-able.
    """
    if isinstance(per_image, Mapping):
        lengths = {len(jnp.atleast_1d(jnp.asarray(v))) for v in per_image.values()}
        if len(lengths) != 1:
            raise ValueError(f"per_image: expected values with one leading length, got {sorted(lengths)}")
        (n,) = lengths
        rows = [{k: jnp.atleast_1d(jnp.asarray(v))[i] for k, v in per_image.items()} for i in range(n)]
    else:
        rows = list(per_image)
    if not rows:
        raise ValueError("per_image: expected at least one image, got 0")
    keys = [k for k in METRIC_KEYS if k in rows[0]]
    if not keys:
        raise ValueError(f"per_image: expected keys {METRIC_KEYS}, got {sorted(rows[0])}")
    used = [r for r in rows if ("count" not in r or int(r["count"]) > 0)]
    out: dict[str, float] = {}
    for k in keys:
        vals = [float(r[k]) for r in used]
        out[k] = math.fsum(vals) / len(vals) if vals else math.nan
    out["images"] = float(len(used))
    if "count" in rows[0]:
        out["count"] = float(sum(int(r["count"]) for r in used))
    return out
