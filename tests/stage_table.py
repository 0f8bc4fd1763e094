"""The stage table: one row per (stage function, inputs, oracle), run by tests/test_stages.py.

Every row goes through :func:`_harness.check_stage`: the output equals the row's oracle, ``jax.jit``
equals the op-by-op (eager) run, ``jax.vmap`` over the stacked inputs equals a loop, and a second
input of the same shape reuses the compiled function. ``check`` is a further property of the plain
outputs that does not fit an elementwise tolerance (an analytic normal on interior rays, the
footprint oracle's "unsure" points, ...).

Inputs are small (tens of pixels or a 16 x 64 sensor) so the eager runs stay short; the
property tests of each module keep the sizes a property needs. The oracles and input builders
live beside their property tests (``test_<stage>.py``) and are imported from there, so one
oracle serves both. A new public stage function gets a row here (``test_stages`` checks
that every one has a row or a stated reason).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, Callable

import numpy as np

from jaxdepth import SGMConfig
from jaxdepth._src import geometry, metrics, outliers, pipeline, validity
from jaxdepth._src import ip_basic as ipb
from jaxdepth._src import normals as N
from jaxdepth._src import pixel_normals as PN
from jaxdepth._src import range_image as RI
from jaxdepth._src.above_scan import background_above_scan, capped_above_scan
from jaxdepth._src.distance import gather_at_seed, nearest_seed
from jaxdepth._src.geodesic import _geodesic_seed, geodesic_seed
from jaxdepth._src.hypotheses import column_hypotheses
from jaxdepth._src.outliers import outlier_keep_mask
from jaxdepth._src.pipeline import complete, complete_points, complete_stages
from jaxdepth._src.residual import plane_residual
from jaxdepth._src.smoothing import gaussian_blur, gaussian_blur_traced


@dataclasses.dataclass(frozen=True)
class Row:
    """One stage check. ``inputs()`` builds two or more argument tuples of one shape (host arrays)."""

    name: str
    fn: Callable
    inputs: Callable[[], list]
    static: dict = dataclasses.field(default_factory=dict)
    oracle: Callable | None = None
    select: Callable = lambda out: out
    oracle_ulps: float = 4
    oracle_scale: Any = None
    ulps: float = 4
    scale: Any = None
    in_axes: Any = 0
    vmap: bool = True
    eager_inputs: int | None = None
    check: Callable | None = None  # check(outputs, inputs): a further property of the plain outputs
    covers: tuple = ()  # the public names this row checks (default: fn's name)
    slow: bool = False  # marked slow (docs/testing.md): left out of the quick subset
    # rows (and tests) that compile the same programs or op-by-op primitives: one xdist worker, not both at once
    group: str | None = None

    def names(self) -> tuple:
        return self.covers or (self.fn.__name__,)


class _OneLibraryJit:
    """A function whose body is host-side checks and ONE call of a library ``jax.jit`` object (the
    public pipeline wrappers, the outlier wrapper): the harness runs it as it is, like a jit stage
    (``lower`` / ``trace`` are the library jit's, and the retrace check counts that jit's traces).
    Its program is then the library's own, the one every other caller with the same call form compiles;
    a ``jax.jit`` around the wrapper would compile the same body a second time and compare the two
    compilations of one jaxpr (XLA's determinism, not a property of the stage)."""

    def __init__(self, fn: Callable, jitted):
        assert callable(getattr(jitted, "lower", None)), jitted
        self._fn, self._jitted = fn, jitted
        functools.update_wrapper(self, fn)

    def __call__(self, *args, **kwargs):
        return self._fn(*args, **kwargs)

    @property
    def lower(self):
        return self._jitted.lower

    @property
    def trace(self):
        return self._jitted.trace


def _cached(builder):
    """Build a row's inputs once per process (rows share inputs: range_image -> point_normals)."""
    return functools.lru_cache(maxsize=None)(builder)


# ----------------------------------------------------------------------------- step 1: normals
#: jit vs eager, vmap vs loop of the normals: ranges agree within an ulp (FMA contraction differs),
#: and the fit divides by range differences of ~1 % of r, amplifying an ulp ~100x: 200 eps.
NORMAL_ULPS = 200


@_cached
def _sweeps():
    """Three ray-cast planes on the 16 x 64 sensor and a random cloud (duplicates, NaN, origin points)."""
    from test_normals import SMALL, cast_plane, ground, near_boundary, random_cloud, wall
    elev = np.radians(np.linspace(9, -19, 16))
    azim = np.pi - (np.arange(64) + 0.5) * 2 * np.pi / 64
    planes = (wall(10), wall(-100, 5.0), ground(4))
    sweeps = [cast_plane(*plane, elev, azim, max_range=40) for plane in planes]
    inputs = [(pts.reshape(-1, 3), hit.reshape(-1)) for pts, hit in sweeps]
    pts, valid = random_cloud(np.random.default_rng(4), 1024)
    valid &= ~near_boundary(np.nan_to_num(pts), SMALL)  # float32 and float64 may bin these differently
    inputs.append((pts, valid))
    return planes, sweeps, inputs


def _range_image_oracle(points, valid, *, lidar):
    from test_normals import np_range_image
    r, index, _ = np_range_image(points, valid, lidar)
    return r, index.astype(np.int32)


def _planes_check(outs, inputs):
    """The planes' normals equal the analytic ones on interior rays (16 x 64 sensor: ~1.9 x 5.6 degree
    cells, so the secant error is larger than on KITTI's; 3 degrees)."""
    from test_normals import angle_deg, interior
    planes, sweeps, _ = _sweeps()
    for (normal, d), (pts, hit), n in zip(planes, sweeps, outs):
        want = -np.sign(d) * np.asarray(normal) / np.linalg.norm(normal)
        inner = interior(hit, 2)
        assert inner.sum() > 20
        assert angle_deg(n.reshape(hit.shape + (3,))[inner], want[None]).max() < 3.0


@_cached
def _range_images():
    from test_normals import SMALL
    import jax.numpy as jnp
    return [(RI.range_image(jnp.asarray(p), jnp.asarray(v), lidar=SMALL),) for p, v in _sweeps()[2]]


@_cached
def _ground_depths():
    """A flat ground seen by two 48 x 80 cameras (one inside the default window, one wider: the
    fallback), the exact depth at the pixels the LiDAR hits."""
    from jaxdepth._src import synthetic
    from scenes import SMALL_LIDAR, small_camera
    # 48 x 80: at 96 x 160 the fit's error on this plane reaches 2.1 degrees (measured), over the bound below
    cams = [small_camera(h=48, w=80), small_camera(f=40.0, h=48, w=80)]
    scene = synthetic.scene_arrays(planes=np.array([[0.0, 0.0, 1.0, -1.73]], np.float32))
    points, valid = synthetic.lidar_sweep(scene, lidar=SMALL_LIDAR)
    inputs = []
    for c in cams:
        hit = np.asarray(geometry.project_to_image(points, valid, c.K, c.T_cam_lidar, height=c.height, width=c.width)[0]) > 0
        exact = np.asarray(synthetic.render_depth(c, scene))  # through the pixel centres: on the plane
        inputs.append((np.where(hit, exact, 0.0).astype(np.float32), np.asarray(c.K), np.asarray(c.T_cam_lidar)))
    return inputs


def _ground_check(outs, inputs):
    """The first camera's normals are the analytic ground normal (the wide camera's pixels are sparser
    than the range image's rows: many get the documented face-the-sensor fallback)."""
    from test_normals import angle_deg
    for (depth, _, _), n in zip(inputs, outs):
        assert (depth > 0).sum() > 1000 and np.all(n[:, depth == 0] == 0)
    (depth, _, T), n = inputs[0], outs[0]
    up = np.asarray(T)[:3, :3] @ np.array([0.0, 0.0, 1.0])  # faces the sensor above it
    err = angle_deg(np.moveaxis(n, 0, -1)[depth > 0], up[None])
    assert err.max() < 2.0, (np.median(err), err.max())


# ----------------------------------------------------------------------------- step 2: outliers
@functools.lru_cache(maxsize=None)
def _outlier_frames(raw: bool):
    from test_outliers import _camera, _points_near_pixels, _random_sparse
    rng = np.random.default_rng(11)
    inputs = []
    for density in (0.05, 0.12, 0.3):
        K, T = _camera(rng, 24, 40)
        depth = _random_sparse(rng, 24, 40, density)
        inputs.append((depth, K, T, _points_near_pixels(rng, K, depth) if raw else None))
    return inputs


def _keep_mask_call(d, k, t, p, **kw):
    return outlier_keep_mask(d, k, t, points_cam=p, **kw)


_keep_mask = _OneLibraryJit(_keep_mask_call, outliers._keep_mask)


def _paper_loop(d, k, t, p, test, **kw):
    from test_outliers import paper_double_loop
    return paper_double_loop(d, k, t, points_cam=p, **kw)


def _removes_something(outs, inputs):
    assert any((keep != (args[0] > 0)).any() for keep, args in zip(outs, inputs))


def _footprint_check(outs, inputs):
    """The footprint double loop (float64) on every point whose decision is not within rounding."""
    from test_outliers import _assert_matches_footprint, footprint_double_loop
    for keep, (d, k, t, p) in zip(outs, inputs):
        _assert_matches_footprint(keep, *footprint_double_loop(d, k, t, points_cam=p, **_OUTLIER_STATIC))
    _removes_something(outs, inputs)


_OUTLIER_STATIC = dict(beams=6, max_half_width_px=4, max_half_height_px=24)  # test_outliers.CAPS: one program


def _outlier_rows():
    rows = []
    for raw in (False, True):
        kind = "raw" if raw else "image"
        rows.append(Row(f"outlier_keep_mask-paper-{kind}", _keep_mask, functools.partial(_outlier_frames, raw),
                        static=dict(_OUTLIER_STATIC, test="paper"), oracle=_paper_loop, check=_removes_something,
                        covers=("outlier_keep_mask",), group="outliers_24x40"))
        rows.append(Row(f"outlier_keep_mask-footprint-{kind}", _keep_mask, functools.partial(_outlier_frames, raw),
                        static=dict(_OUTLIER_STATIC, test="footprint"), check=_footprint_check,
                        covers=("outlier_keep_mask",), group="outliers_24x40"))
    return rows


# ----------------------------------------------------------------------------- step 3: seeds
def _seed_masks():
    from test_distance import _random_mask
    masks = [_random_mask((16, 21), d, seed=i) for i, d in enumerate([0.0, 0.02, 0.1, 0.6, 1.0])]
    masks[1][:] = False
    masks[1][15, 20] = True  # a single seed in the last pixel
    return [(m,) for m in masks]


def _seed_distance_oracle(mask, *, metric):
    from test_distance import _oracle_or_inf
    return _oracle_or_inf(mask, metric=metric)


def _seeds_check(metric, outs, inputs):
    """Shapes, dtypes, has_seed, and (v + dv, u + du) is a seed at the returned distance."""
    from jaxdepth._src.distance import NearestSeed
    from test_distance import _check_result
    for out, (mask,) in zip(outs, inputs):
        _check_result(NearestSeed(*out), mask, metric)


def _gather_inputs(channels):
    from test_distance import _random_offsets
    rng = np.random.default_rng(4)
    inputs = []
    for s in range(4):
        du, dv = _random_offsets((7, 9), s)
        inputs.append((rng.random(channels + (7, 9)).astype(np.float32), du, dv))
    return inputs


def _gather_oracle(field, du, dv):
    v, u = np.indices(du.shape)
    return field[..., v + dv, u + du]


def _geodesic_inputs():
    from test_geodesic import _scene
    return [_scene(s, h=9, w=10) for s in (0, 1, 2)]


def _geodesic_oracle(keep, img, *, color_weight, sweeps):
    """Multi-source Dijkstra (float64, heapq) on the same step costs; converged after 8 sweeps here."""
    from test_geodesic import _dijkstra
    return _dijkstra(list(zip(*np.nonzero(keep))), img, color_weight)


def _geodesic_check(outs, inputs):
    for out, (keep, _) in zip(outs, inputs):
        v, u = np.indices(keep.shape)
        assert keep[v + np.asarray(out.dv), u + np.asarray(out.du)].all()  # the chosen seed is a seed


# ----------------------------------------------------------------------------- step 4: residual, hypotheses, blur
def _residual_inputs():
    from test_residual import K
    rng = np.random.default_rng(1)
    h, w, min_abs_denom = 40, 64, 0.05
    inputs = []
    for b in range(3):
        seed_depth = rng.uniform(1, 50, (h, w)).astype(np.float32)
        seed_depth[rng.random((h, w)) < 0.1] = 0.0  # pixels without a seed
        n = rng.normal(size=(3, h, w)).astype(np.float32)
        n /= np.linalg.norm(n, axis=0, keepdims=True)
        Kb = (K * np.float32(1 + 0.1 * b)).astype(np.float32)
        Kb[2, 2] = 1
        v, u = np.indices((h, w))
        denom = (u - Kb[0, 2]) / Kb[0, 0] * n[0] + (v - Kb[1, 2]) / Kb[1, 1] * n[1] + n[2]
        n[:, np.abs(np.abs(denom) - min_abs_denom) < 1e-3] = ((0,), (0,), (-1,))  # no pixel on the guard's edge
        du = rng.integers(-3, 4, (h, w)).astype(np.int32)
        dv = rng.integers(-3, 4, (h, w)).astype(np.int32)
        inputs.append((seed_depth, n, du, dv, Kb))
    return inputs


def _residual_oracle(*args, **kw):
    from test_residual import numpy_residual
    return numpy_residual(*args, **kw)


def _hypotheses_inputs():
    from test_hypotheses import H, K, W, sparse_rows
    inputs = []
    for seed in (1, 2):
        rng = np.random.default_rng(seed)
        kept = np.where(sparse_rows(H, W, rng), rng.uniform(2, 40, (H, W)), 0.0).astype(np.float32)
        raw = rng.uniform(0.5, 60, (H, W)).astype(np.float32)
        dist = rng.integers(0, 8, (H, W)).astype(np.float32)
        normals = rng.normal(size=(3, H, W)).astype(np.float32)
        normals /= np.linalg.norm(normals, axis=0)
        inputs.append((raw, kept, dist, normals, K))
    return inputs


def _hypotheses_oracle(raw, kept, dist, normals, K, *, window_px, blend):
    """The per-pixel walk of test_hypotheses (bracket, and the blend of the two column hypotheses)."""
    from test_hypotheses import numpy_blend, numpy_bracket
    return numpy_blend(raw, kept, dist, normals, K, window_px) if blend else numpy_bracket(raw, kept, window_px)


def _hypotheses_check(outs, inputs):
    from helpers import numpy_column_hypotheses
    from test_hypotheses import numpy_bracket
    for (raw, kept, dist, normals, K), out in zip(inputs, outs):
        for blend in (False, True):  # the vectorised oracle (used by test_speed_equivalence) agrees with the walk
            np.testing.assert_allclose(
                numpy_column_hypotheses(raw, kept, 7.0, seed_distance=dist, normals=normals, K=K, blend=blend),
                _hypotheses_oracle(raw, kept, dist, normals, K, window_px=7.0, blend=blend), rtol=1e-6)
        assert (numpy_bracket(raw, kept, 7.0) != raw).mean() > 0.2  # random predictions often leave the bracket
        assert not np.array_equal(np.asarray(out), raw)


def _above_scan_inputs():
    from test_above_scan import above_scan_inputs
    return [above_scan_inputs(seed) for seed in (1, 2)]


def _above_scan_oracle(depth_raw, seed_depth, keep, valid, *, beams):
    from test_above_scan import numpy_above_scan
    return numpy_above_scan(depth_raw, seed_depth, keep, valid, beams=beams,
                            max_half_width_px=SGMConfig().outlier_max_half_width_px)


def _capped_inputs():
    from test_above_scan import capped_inputs
    return [capped_inputs(seed) for seed in (1, 2)]


def _capped_oracle(*args, **kw):
    from test_above_scan import numpy_capped_above_scan
    return numpy_capped_above_scan(*args, **kw)


def _blur_images(n, high):
    return np.random.default_rng(2 if n == 3 else 6).uniform(0, high, (n, 20, 30)).astype(np.float32)


def _cv2_blur(image, *, sigma_px, radius_px):
    from test_smoothing import _cv2_blur as oracle
    return oracle(image, sigma_px=sigma_px, radius_px=radius_px)


def _scipy_blur(image, sigma_px, *, radius_px):
    from test_smoothing import _scipy_blur as oracle
    return oracle(image, sigma_px, radius_px=radius_px)


_SIGMAS = np.array([0.0, 0.5, 1.0, 2.5], np.float32)


# ----------------------------------------------------------------------------- the pipeline
#: The pipeline against itself jitted / eager / vmapped: the same float32 maths fused differently
#: (FMA contraction); the residual divides by n . ray >= min_abs_denom = 0.01, amplifying a few
#: eps up to 100x, and depths are O(10 m): 4 / 0.01 eps of max(|depth|, 1).
PIPELINE_ULPS = 4 / SGMConfig().min_abs_denom


@functools.lru_cache(maxsize=None)
def _tiny_sparse(seeds):
    """(sparse, K, T) per seed: the 32 x 48 frames of ``scenes.tiny_street_frames`` (focal length 40 + 4 i)."""
    from scenes import tiny_frame
    return [tiny_frame(seed, f=40.0 + 4 * i) for i, seed in enumerate(seeds)]


def _mostly_filled(outs, inputs):
    assert all((np.asarray(d) > 0).mean() > 0.5 for d in outs)


_STAGE_FIELDS = ("inlier_mask", "du", "dv", "seed_depth", "depth")


def _reference_stages(sparse, K, T, *, lidar, config):
    """Steps 1-4 composed from the public stage functions (test_speed_equivalence.reference_stages)."""
    from test_speed_equivalence import reference_stages
    ref = reference_stages(sparse, K, T, config=config, lidar=lidar)
    return tuple(ref[k] for k in _STAGE_FIELDS)


# ----------------------------------------------------------------------------- metrics, validity, IP_Basic
def _metric_pairs():
    from test_metrics import random_sparse
    rng = np.random.default_rng(3)
    return [(random_sparse(rng, 6, 9, p), random_sparse(rng, 6, 9, g)) for p, g in ((0.05, 0.2), (0.3, 0.6), (0.9, 0.5))]


def _pair_inputs():
    """Sparse inputs overlapping the truth on every frame (no overlap gives NaN scores: test_metrics)."""
    from test_metrics import random_sparse
    rng = np.random.default_rng(4)
    return [(random_sparse(rng, 6, 9, s), random_sparse(rng, 6, 9, 0.7)) for s in (0.5, 0.7, 0.9)]


def _depth_metrics_oracle(pred, gt):
    from test_metrics import np_depth_metrics
    want = np_depth_metrics(pred, gt)
    return {k: want[k] for k in metrics.METRIC_KEYS}


def _pair_errors_oracle(sparse, gt):
    from test_metrics import np_pair_errors
    want = np_pair_errors(sparse, gt)
    return {k: want[k] for k in metrics.METRIC_KEYS}


def _background_inputs():
    from test_metrics import random_sparse
    rng = np.random.default_rng(0)
    return [(random_sparse(rng, 12, 20, dens, empty_rows=3),) for dens in (0.02, 0.1, 0.5)]


def _background_oracle(depth):
    from test_metrics import np_interpolate_background
    return np_interpolate_background(depth).astype(np.float32)


def _ip_basic_inputs():
    from test_ip_basic import sparse_image
    # test_ip_basic's 80 x 80 frames with extrapolation: its program (one worker, group ip_basic_synthetic); the
    # op-by-op run compiles the same primitives at any size (the shifts are static)
    return [(sparse_image(s, 80, 80, density=(0.02, 0.06, 0.3)[s]),) for s in range(3)]


def _ip_basic_oracle(depth, *, extrapolate):
    from jaxdepth.research import baselines
    return baselines.ip_basic_opencv(depth, extrapolate=extrapolate, blur_type="gaussian")


def _validity_inputs():
    from test_validity import H, W, _camera, _stages
    rng = np.random.default_rng(7)
    out = []
    for s in (3, 4, 5):
        K, T = _camera(s)
        out.append((_stages(rng.random((H, W)) < 0.06, "l1", rng), K, T))
    return out


def _validity_oracle(stages, K, T, *, lidar, metric, max_seed_distance_px):
    """FOV from the float64 per-pixel elevation loop, the seed distance from a brute-force minimum."""
    import math
    from test_validity import H, W, _elevation_loop, _seed_distance_loop
    elev = _elevation_loop(K, T, H, W)
    fov = (elev >= math.radians(lidar.fov_down_deg)) & (elev <= math.radians(lidar.fov_up_deg))
    spacing = K[1, 1] * math.radians(lidar.fov_up_deg - lidar.fov_down_deg) / (lidar.beams - 1)
    dist = _seed_distance_loop(np.asarray(stages.inlier_mask), metric)
    near = max_seed_distance_px
    return (fov & (dist <= near)) | (dist <= min(spacing, near)), dist.astype(np.float32)


def _validity_check(outs, inputs):
    from test_validity import LIDAR
    for (valid, _), (stages, K, T) in zip(outs, inputs):  # validity_mask is the first half
        got = validity.validity_mask(stages, K, T, lidar=LIDAR, metric="l1", max_seed_distance_px=3.0)
        np.testing.assert_array_equal(np.asarray(got), valid)


# ----------------------------------------------------------------------------- geometry
def _projection_inputs():
    from scenes import lidar_to_camera
    rng = np.random.default_rng(21)
    T = lidar_to_camera()
    out = []
    for b in range(3):
        K = np.array([[30.0 + b, 0, 23.5], [0, 30.0, 15.5], [0, 0, 1]], np.float32)
        pts = np.concatenate([rng.uniform((1, -8, -2), (40, 8, 2), (200, 3)),
                              rng.uniform((-20, -8, -2), (0, 8, 2), (20, 3))]).astype(np.float32)  # some behind
        pts[:5] = pts[5:10]  # duplicates: ties go to the smaller index
        valid = rng.random(len(pts)) < 0.9
        # points whose float64 pixel coordinate is within 1e-3 of a rounding edge may round either way
        q = pts.astype(np.float64) @ T[:3, :3].T.astype(np.float64) + T[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([K[0, 0] * q[:, 0] / q[:, 2] + K[0, 2], K[1, 1] * q[:, 1] / q[:, 2] + K[1, 2]])
        valid &= ~np.any(np.abs(np.abs(uv - np.floor(uv)) - 0.5) < 1e-3, 0)
        out.append((pts, valid, K, T))
    return out


def _projection_oracle(points, valid, K, T, *, height, width):
    """A float64 loop: each point to its rounded pixel, the nearest (then the first) one wins."""
    depth = np.zeros((height, width), np.float32)
    index = -np.ones((height, width), np.int32)
    p = (T[:3, :3].astype(np.float64) @ points.T.astype(np.float64)).T + T[:3, 3]
    for i, (x, y, z) in enumerate(p):
        if not valid[i] or not z > 0.1:
            continue
        u = int(np.round(K[0, 0] * x / z + K[0, 1] * y / z + K[0, 2]))
        v = int(np.round(K[1, 1] * y / z + K[1, 2]))
        if 0 <= v < height and 0 <= u < width and (index[v, u] < 0 or np.float32(z) < depth[v, u]):
            depth[v, u], index[v, u] = z, i
    return depth, index


def _unproject_inputs():
    rng = np.random.default_rng(22)
    return [(np.where(rng.random((12, 20)) < 0.5, rng.uniform(1, 50, (12, 20)), 0).astype(np.float32),
             np.array([[25.0 + b, 0.3, 9.5], [0, 24.0, 5.5], [0, 0, 1]], np.float32)) for b in range(3)]


def _unproject_oracle(depth, K):
    v, u = np.indices(depth.shape).astype(np.float64)
    rays = np.linalg.inv(K.astype(np.float64)) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    return np.moveaxis((rays * depth.ravel()).reshape(3, *depth.shape), 0, -1)


# ----------------------------------------------------------------------------- the table
def _rows() -> list[Row]:
    from scenes import SMALL_LIDAR, tiny_street_frames
    from test_normals import SMALL
    from test_validity import LIDAR as VALIDITY_LIDAR
    return [
        # step 1
        # the 16 x 64 sensor's 1024-point programs, and the op-by-op runs' primitives, are test_normals' small
        # clouds': one worker (suite18)
        Row("range_image", RI.range_image, lambda: _sweeps()[2], static=dict(lidar=SMALL), ulps=2,
            oracle=_range_image_oracle, select=lambda ri: (ri.r, ri.index), oracle_ulps=2, group="normals_small_cloud"),
        Row("point_normals", N.point_normals, lambda: _sweeps()[2], static=dict(lidar=SMALL), ulps=NORMAL_ULPS,
            check=_planes_check, group="normals_small_cloud"),
        Row("range_image_normals", N.range_image_normals, _range_images, ulps=NORMAL_ULPS, group="normals_small_cloud"),
        Row("pixel_normals", PN.pixel_normals, _ground_depths, static=dict(lidar=SMALL_LIDAR, max_points=8192),
            ulps=NORMAL_ULPS, check=_ground_check),
        # step 2
        *_outlier_rows(),
        # step 3
        *[Row(f"nearest_seed-{metric}", nearest_seed, _seed_masks, static=dict(metric=metric),
              oracle=_seed_distance_oracle, select=lambda r: r.distance, oracle_ulps=4, ulps=0,
              check=functools.partial(_seeds_check, metric), group="distance")  # test_distance's (16, 21) programs
          for metric in ("l1", "l2")],
        *[Row(f"gather_at_seed-{len(ch)}ch", gather_at_seed, functools.partial(_gather_inputs, ch),
              oracle=_gather_oracle, oracle_ulps=0, ulps=0) for ch in ((), (2,))],
        # op-by-op evaluation rounds the step costs differently (no fusion): a few ulps of the sums
        Row("geodesic_seed", _OneLibraryJit(geodesic_seed, _geodesic_seed), _geodesic_inputs, static=dict(color_weight=7.0, sweeps=8),
            oracle=_geodesic_oracle, select=lambda r: r.distance, oracle_ulps=32, ulps=16,
            check=_geodesic_check),
        # step 4
        Row("plane_residual", plane_residual, _residual_inputs,
            static=dict(min_abs_denom=0.05, max_residual_ratio=0.5), oracle=_residual_oracle,
            oracle_ulps=8 / 0.05, ulps=8 / 0.05),
        *[Row(f"column_hypotheses-{'blend' if blend else 'bracket'}", column_hypotheses, _hypotheses_inputs,
              static=dict(window_px=7.0, blend=blend), oracle=_hypotheses_oracle, oracle_ulps=64,
              in_axes=(0, 0, 0, 0, None), check=_hypotheses_check, group="stage_hypotheses") for blend in (False, True)],
        Row("background_above_scan", background_above_scan, _above_scan_inputs, static=dict(beams=16),
            oracle=_above_scan_oracle, oracle_ulps=0, ulps=0),
        Row("capped_above_scan", capped_above_scan, _capped_inputs, static=dict(beams=16, rows_px=3.0),
            oracle=_capped_oracle, oracle_ulps=16, ulps=16),
        Row("gaussian_blur", gaussian_blur, lambda: [(x,) for x in _blur_images(3, 80)],
            static=dict(sigma_px=1.2, radius_px=3), oracle=_cv2_blur, oracle_ulps=15, oracle_scale=80.0, group="stage_blur"),
        # one compiled function for every sigma (0 included), batched over images and sigmas ...
        Row("gaussian_blur_traced", gaussian_blur_traced, lambda: list(zip(_blur_images(4, 10), _SIGMAS)),
            static=dict(radius_px=3), oracle=_scipy_blur, oracle_ulps=15, oracle_scale=10.0, group="stage_blur"),
        # ... and over sigma alone with a shared image
        Row("gaussian_blur_traced-shared-image", gaussian_blur_traced,
            lambda: [(_blur_images(4, 10)[0], s) for s in _SIGMAS], static=dict(radius_px=3), in_axes=(None, 0),
            oracle=_scipy_blur, oracle_ulps=15, oracle_scale=10.0, group="stage_blur"),
        # the pipeline from a sweep (eager on one input: the one op-by-op run of a whole pipeline; its
        # exact point positions and 3-D outlier test have no plain composition to compare against)
        Row("complete_points", _OneLibraryJit(complete_points, pipeline._complete_points_depth), lambda: tiny_street_frames((0, 1, 2)), static=dict(lidar=SMALL_LIDAR),
            ulps=PIPELINE_ULPS, eager_inputs=1, check=_mostly_filled, slow=True),
        # stages against the plain composition of the public stage functions (masks and seeds exact;
        # depths within the composition's normals rounding, test_speed_equivalence's 1e-3 relative + 2e-3 m).
        # No op-by-op run: every stage composed has its own jit == eager row above, and the jitted
        # pipeline equals their composition (this oracle), so jit == eager of the whole adds nothing.
        Row("complete_stages", _OneLibraryJit(complete_stages, pipeline._complete_stages), lambda: _tiny_sparse((3, 4, 5)),
            static=dict(lidar=SMALL_LIDAR, config=SGMConfig()), in_axes=(0, 0, None),
            oracle=_reference_stages, select=lambda s: tuple(getattr(s, k) for k in _STAGE_FIELDS),
            oracle_ulps=2e-3 / float(np.finfo(np.float32).eps), ulps=PIPELINE_ULPS, eager_inputs=0, slow=True),
        # complete is complete_stages(...).depth in its own jit (no eager run, as above); its jit, vmap
        # and retrace are its own
        Row("complete", _OneLibraryJit(complete, pipeline._complete_depth), lambda: _tiny_sparse((3, 4, 5)), static=dict(lidar=SMALL_LIDAR, config=SGMConfig()),
            in_axes=(0, 0, None), ulps=PIPELINE_ULPS, eager_inputs=0, check=_mostly_filled, slow=True),
        # geometry
        Row("project_to_image", geometry.project_to_image, _projection_inputs, static=dict(height=32, width=48),
            in_axes=(0, 0, 0, None), oracle=_projection_oracle, oracle_ulps=8),
        Row("unproject_depth", geometry.unproject_depth, _unproject_inputs, oracle=_unproject_oracle, oracle_ulps=8),
        # metrics (devkit oracles), validity, IP_Basic
        Row("interpolate_background", metrics.interpolate_background, _background_inputs, oracle=_background_oracle,
            oracle_ulps=0, ulps=0),
        Row("depth_metrics", metrics.depth_metrics, _metric_pairs, oracle=_depth_metrics_oracle,
            select=lambda m: {k: m[k] for k in metrics.METRIC_KEYS}, oracle_ulps=128, ulps=16),
        Row("pair_errors", metrics.pair_errors, _pair_inputs, oracle=_pair_errors_oracle,
            select=lambda m: {k: m[k] for k in metrics.METRIC_KEYS}, oracle_ulps=128, ulps=16),
        Row("validity_and_distance", validity.validity_and_distance, _validity_inputs,
            static=dict(lidar=VALIDITY_LIDAR, metric="l1", max_seed_distance_px=3.0), oracle=_validity_oracle,
            oracle_ulps=4, ulps=0, check=_validity_check, covers=("validity_and_distance", "validity_mask")),
        Row("ip_basic", _OneLibraryJit(ipb.ip_basic, ipb._ip_basic), _ip_basic_inputs, static=dict(extrapolate=True), oracle=_ip_basic_oracle,
            oracle_ulps=8, oracle_scale=100.0, ulps=4, scale=100.0, eager_inputs=1, group="ip_basic_synthetic"),
    ]


ROWS = _rows()
