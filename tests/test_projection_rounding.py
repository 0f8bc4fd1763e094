"""The projection gives a point the same pixel and depth bits in every program (issue 37).

A rig's camera is projected under ``vmap``, its single-camera call unbatched. With a plain float32
transform the two rounded ``R p + t`` apart: for three or more cameras in a vmapped group XLA:CPU
computes the batched product with another kernel than the unbatched one (two cameras round alike,
hence no small test rig showed it), and it contracts ``a * b + c`` into an FMA at its default
optimisation level depending on fusion. On the real Argoverse 2 sweep 8-11 % of the points got
other z bits and 58-123 per camera another pixel (docs/multi_source.md). ``geometry.fixed_dot`` forms every product from 12-bit halves, so each
product is exact and FMA or not gives the same result.

Oracles: NumPy float32 evaluation of the same formula (NumPy does no FMA; with exact products the
bits must agree), the float64 transform (a few ulps), the exact split ``x = hi + lo``. The scene
that broke the old projection: points whose float64 pixel lies exactly on a rounding edge
(u and v = k + 0.5) seen by cameras with general rotations (the small test rigs' axis-aligned
rotations have exact products, which is why they never showed it): vmapped over the cameras ==
one camera at a time == the NumPy oracle, bit for bit; at the suite's XLA flags and at the
production ones (FMA contraction on).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxdepth._src import geometry
from jaxdepth._src.pipeline import gather_channels, project_with_normals

from _harness import assert_close, check_stage

H, W, F = 24, 40, 30.0


# ----------------------------------------------------------------------------- NumPy oracle
def _np_halves(x):
    x = np.asarray(x, np.float32)
    hi = (x.view(np.int32) & np.int32(-4096)).view(np.float32)
    return hi, (x - hi).astype(np.float32)


def _np_fixed_dot(weights, values, offset=None):
    """The formula of geometry.fixed_dot in NumPy float32 (no FMA): high terms, offset, cross, low."""
    high, cross, low = [], [], []
    for w, x in zip(weights, values):
        wh, wl = _np_halves(w)
        xh, xl = _np_halves(x)
        high.append(wh * xh)
        cross.append(wh * xl + wl * xh)
        low.append(wl * xl)
    total = high[0]
    for t in high[1:]:
        total = total + t
    if offset is not None:
        total = total + np.float32(offset)
    c, lo = cross[0], low[0]
    for t in cross[1:]:
        c = c + t
    for t in low[1:]:
        lo = lo + t
    return (total + (c + lo)).astype(np.float32)


def _np_camera_points(T, points):
    T = np.asarray(T, np.float32)
    cols = tuple(points[:, k] for k in range(3))
    return np.stack([_np_fixed_dot(T[i, :3], cols, T[i, 3]) for i in range(3)], axis=-1)


def _np_project(points, valid, K, T, *, height, width):
    """z-buffer of the NumPy-fixed pixels: nearest depth, then the smallest index."""
    K = np.asarray(K, np.float32)
    p = _np_camera_points(T, points)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    ok = valid & np.isfinite(p).all(1) & (z > np.float32(0.1))
    zs = np.where(ok, z, np.float32(1.0))
    xs, ys = np.where(ok, x, 0).astype(np.float32) / zs, np.where(ok, y, 0).astype(np.float32) / zs
    u = np.round(_np_fixed_dot((K[0, 0], K[0, 1]), (xs, ys), K[0, 2]))
    v = np.round(_np_fixed_dot((K[1, 1],), (ys,), K[1, 2]))
    depth = np.zeros((height, width), np.float32)
    index = -np.ones((height, width), np.int32)
    for i in np.flatnonzero(ok & (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)):
        r, c = int(v[i]), int(u[i])
        if index[r, c] < 0 or z[i] < depth[r, c]:
            depth[r, c], index[r, c] = z[i], i
    return depth, index


# ----------------------------------------------------------------------------- the edge scene
def _edge_rig(seed: int = 37, cameras: int = 4, per_camera: int = 300):
    """(points (N, 3), valid (N,), K (C, 3, 3), T (C, 4, 4)) float32: C cameras looking around
    (yaw 90 degrees apart, odd pitch / roll, so no rotation entry is 0 or 1), and for each camera
    points whose float64 pixel is exactly (k + 0.5, m + 0.5) at 2-40 m: every point sits on a
    rounding edge of u and v, neighbours at other depths."""
    rng = np.random.default_rng(seed)
    Ks, Ts, pts = [], [], []
    base = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], np.float64)   # LiDAR x forward -> camera z
    for c in range(cameras):
        R = base @ Rotation.from_euler("zyx", [90.0 * c + 7.3, 3.1 + c, -2.2]).as_matrix().T
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, R @ -np.array([0.31, 0.07 * c, 0.23])
        K = np.array([[F + c, 0.0, (W - 1) / 2 + 0.17], [0, F + c, (H - 1) / 2 - 0.31], [0, 0, 1]])
        u = rng.integers(0, W - 1, per_camera) + 0.5
        v = rng.integers(0, H - 1, per_camera) + 0.5
        z = rng.uniform(2.0, 40.0, per_camera)
        K32, T32 = K.astype(np.float32).astype(np.float64), T.astype(np.float32).astype(np.float64)
        p_cam = np.stack([(u - K32[0, 2]) / K32[0, 0] * z, (v - K32[1, 2]) / K32[1, 1] * z, z], 1)
        pts.append((p_cam - T32[:3, 3]) @ T32[:3, :3])                   # R^T (p - t), float64
        Ks.append(K)
        Ts.append(T)
    points = np.concatenate(pts).astype(np.float32)
    valid = rng.random(len(points)) < 0.95
    return points, valid, np.asarray(Ks, np.float32), np.asarray(Ts, np.float32)


@pytest.fixture(scope="module")
def edge_rig():
    return _edge_rig()


# ----------------------------------------------------------------------------- tests
def test_split_halves_is_exact_and_twelve_bits():
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.standard_normal(2000) * 10.0 ** rng.integers(-6, 7, 2000),
                        [0.0, -0.0, 1.0, -1.0, 1 / 3, np.float32(np.pi) * 1e5]]).astype(np.float32)
    hi, lo = (np.asarray(a) for a in jax.jit(geometry.split_halves)(x))
    np.testing.assert_array_equal(hi.astype(np.float64) + lo, x.astype(np.float64))   # exact split
    np.testing.assert_array_equal(hi.view(np.int32) & 4095, 0)                      # 12 significant bits
    _, lo_lo = _np_halves(lo)
    np.testing.assert_array_equal(lo_lo, 0)              # the low half needs no more than 12 bits either
    # so every product of halves is exact: float32 product == float64 product
    h2, l2 = _np_halves(x[::-1])
    for a, b in ((hi, h2), (hi, l2), (lo, h2), (lo, l2)):
        np.testing.assert_array_equal((a * b).astype(np.float64), a.astype(np.float64) * b)


def test_fixed_dot_matches_numpy_and_float64():
    rng = np.random.default_rng(1)
    w = rng.standard_normal((4, 3)).astype(np.float32)
    x = (rng.standard_normal((4, 3, 500)) * 30).astype(np.float32)
    t = rng.standard_normal(4).astype(np.float32)

    def dot(w, x, t):
        return geometry.fixed_dot(tuple(w), tuple(x), t)

    outs = check_stage(dot, [(w[i], x[i], t[i]) for i in range(4)], ulps=0,
                       oracle=lambda w, x, t: _np_fixed_dot(tuple(w), tuple(x), t), oracle_ulps=0)
    for i, got in enumerate(outs):
        exact = (w[i].astype(np.float64) @ x[i].astype(np.float64)) + t[i]
        scale = np.abs(w[i].astype(np.float64))[:, None] * np.abs(x[i]) + abs(t[i])
        assert_close(got, exact, ulps=4, scale=scale.sum(0), err_msg="fixed_dot against float64")
    # differentiable as the plain dot: d/dx_k = w_k, d/dw_k = x_k, d/dt = 1 (the split's integer mask has no tangent)
    gw, gx, gt = jax.jit(jax.grad(lambda w, x, t: dot(w, x, t).sum(), argnums=(0, 1, 2)))(w[0], x[0], t[0])  # one program
    np.testing.assert_allclose(np.asarray(gx), np.broadcast_to(w[0][:, None], x[0].shape), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(gw), x[0].astype(np.float64).sum(1), rtol=1e-5)
    assert float(gt) == x.shape[-1]


def test_camera_points_matches_numpy_and_float64(edge_rig):
    points, _, _, Ts = edge_rig
    inputs = [(T, points) for T in Ts]
    outs = check_stage(geometry.camera_points, inputs, ulps=0, oracle=_np_camera_points, oracle_ulps=0)
    for (T, _), got in zip(inputs, outs):
        exact = points.astype(np.float64) @ T[:3, :3].T.astype(np.float64) + T[:3, 3]
        assert_close(got, exact, ulps=8, scale=np.abs(points).sum(1, keepdims=True) + 1, err_msg="float64")


def _vmap_and_loop(points, valid, Ks, Ts):
    project = jax.jit(lambda K, T: geometry.project_to_image(points, valid, K, T, height=H, width=W))
    batched = jax.jit(jax.vmap(lambda K, T: geometry.project_to_image(points, valid, K, T, height=H, width=W)))
    together = [np.asarray(x) for x in batched(jnp.asarray(Ks), jnp.asarray(Ts))]
    return together, [[np.asarray(x) for x in project(K, T)] for K, T in zip(Ks, Ts)]


def test_edge_points_land_on_the_same_pixel_vmapped_and_alone(edge_rig):
    """Failed with the plain float32 transform (89-120 of ~220 pixels per camera got another point, at
    the suite's flags and the production ones): the batched product rounds z, u, v apart."""
    points, valid, Ks, Ts = edge_rig
    (depth_b, index_b), singles = _vmap_and_loop(points, valid, Ks, Ts)
    for c, (depth, index) in enumerate(singles):
        want_depth, want_index = _np_project(points, valid, Ks[c], Ts[c], height=H, width=W)
        assert (want_index >= 0).sum() > 150                           # the camera sees its edge points
        np.testing.assert_array_equal(index, want_index, err_msg=f"camera {c}: single call != NumPy")
        np.testing.assert_array_equal(depth, want_depth, err_msg=f"camera {c}: single call != NumPy")
        np.testing.assert_array_equal(index_b[c], index, err_msg=f"camera {c}: vmapped != single call")
        np.testing.assert_array_equal(depth_b[c], depth, err_msg=f"camera {c}: vmapped != single call")


@pytest.mark.production_flags   # FMA contraction happens only at XLA:CPU's default optimisation level
def test_project_with_normals_vmapped_equals_single_call(edge_rig):
    """The rig programs' projection (z-buffer, each pixel's point and normal), bit for bit."""
    points, valid, Ks, Ts = edge_rig
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    size = jnp.array([H, W], jnp.int32)

    def run(K, T):
        return project_with_normals(points, valid, normals, T, K, height=H, width=W, image_size=size)

    batched = jax.jit(jax.vmap(run))(Ks, Ts)
    one = jax.jit(run)
    for c in range(len(Ks)):
        single = one(Ks[c], Ts[c])
        for name, b, s in zip(("sparse_depth", "index", "points_cam", "normals_cam"), batched, single):
            np.testing.assert_array_equal(np.asarray(b[c]), np.asarray(s), err_msg=f"camera {c}: {name}")
        hit = np.asarray(single[1]) >= 0
        np.testing.assert_array_equal(np.asarray(single[2])[2][hit], np.asarray(single[0])[hit],
                                      err_msg=f"camera {c}: the pixel's point is the z-buffer's depth")


def test_project_with_normals_apart_equals_stacked(edge_rig):
    """``apart=True`` (the rig views: three (H, W) channels each, written point by point by ``project_apart``)
    == the stacked (3, H, W) channels gathered at the z-buffer's index, and the same depth and index, bit for
    bit, one camera and vmapped."""
    points, valid, Ks, Ts = edge_rig
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    size = jnp.array([H, W], jnp.int32)

    def run(K, T, apart):
        return project_with_normals(points, valid, normals, T, K, height=H, width=W, image_size=size, apart=apart)

    stacked = jax.jit(jax.vmap(lambda K, T: run(K, T, False)))(Ks, Ts)
    apart = jax.jit(jax.vmap(lambda K, T: run(K, T, True)))(Ks, Ts)
    for k in (0, 1):
        assert np.asarray(apart[k]).tobytes() == np.asarray(stacked[k]).tobytes()
    for k in (2, 3):
        assert isinstance(apart[k], tuple) and len(apart[k]) == 3
        assert np.asarray(jnp.stack(apart[k], axis=1)).tobytes() == np.asarray(stacked[k]).tobytes()
    one = jax.jit(lambda K, T: run(K, T, True))(Ks[0], Ts[0])    # one camera, compiled like the pipeline
    assert np.asarray(jnp.stack(one[2])).tobytes() == np.asarray(stacked[2][0]).tobytes()


def _np_gathered(values, index):
    """Oracle of ``gather_channels``: the (H W, C) row gather, transposed, 0 where the index is -1."""
    values, index = np.asarray(values), np.asarray(index)
    rows = values[np.where(index >= 0, index, 0)]                      # (H, W, C)
    return np.where((index >= 0)[None], np.moveaxis(rows, -1, 0), 0).astype(values.dtype)


def test_gather_channels_matches_the_row_gather():
    """The projection's per-pixel gather (1-D gathers from a column with a 0 slot) == the row gather, bit for
    bit, with -1 (empty) pixels, repeated and first / last indices; jit == eager, vmap == loop."""
    rng = np.random.default_rng(3)
    n = 50

    def case(seed):
        r = np.random.default_rng(seed)
        values = r.normal(size=(n, 3)).astype(np.float32)
        values[0] = -0.0                                         # a -0.0 point stays -0.0, empty pixels +0.0
        index = r.integers(-1, n, size=(6, 7)).astype(np.int32)
        index[0, :3] = (-1, 0, n - 1)
        return values, index

    inputs = [case(int(s)) for s in rng.integers(0, 2**31, 3)]
    outs = check_stage(gather_channels, inputs, oracle=_np_gathered, oracle_ulps=0, ulps=0)
    for (values, index), out in zip(inputs, outs):
        got = np.asarray(out)
        want = _np_gathered(values, index)
        assert got.tobytes() == want.tobytes()                  # bits: signed zeros included
        assert np.all(np.signbit(got[:, index < 0]) == 0)
