"""Step 1: spherical range image and normals, against ray-cast analytic planes and NumPy loops.

Synthetic sweeps are ray-cast here: a spinning sensor fires one ray per
(beam, azimuth) and each ray that hits the plane within ``max_range`` gives the
exact intersection point. The analytic normal of a plane ``n . p = d`` that
faces the sensor is ``-sign(d) n``.

Tolerances: finite differences on the range image estimate the normal of a
plane with an error of the order of the angular pitch between neighbouring rays
times the curvature of r(theta, phi) (the secant is tilted against the
tangent); the robust least squares is close to a central difference, measured
<= 0.5 degrees on interior points for 0.18 x 0.42 degree cells, and float32
rounding adds less. We assert 1 degree for cell-centred rays and 2 degrees for
an irregular beam pattern with azimuth jitter (rays off the cell centres, rows
with two beams and empty rows; measured <= 1.4 degrees). The paper's printed
sign convention is wrong by tens of degrees here (tested too).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxdepth._src import compaction, fastmath
from jaxdepth._src import normals as N
from jaxdepth._src import pixel_normals as PN
from jaxdepth._src import range_image as RI
from jaxdepth._src.presets import KITTI_HDL64, NUSCENES_HDL32
from jaxdepth._src.types import LidarSpec

from oracles import normals_58cfbac as reference
from scenes import SMALL_LIDAR, lidar_to_camera, small_camera

LIDAR = KITTI_HDL64  # 64 x 2048, fov [-24.9, 2] degrees
SMALL = LidarSpec(beams=16, fov_up_deg=10.0, fov_down_deg=-20.0, columns=64)


# ----------------------------------------------------------------------------- ray casting


def ideal_angles(lidar: LidarSpec):
    """Beam elevations and azimuths on the range-image cell centres (radians)."""
    span = lidar.fov_up_deg - lidar.fov_down_deg
    elev = np.radians(lidar.fov_up_deg - (np.arange(lidar.beams) + 0.5) * span / lidar.beams)
    azim = np.pi - (np.arange(lidar.columns) + 0.5) * 2 * np.pi / lidar.columns
    return elev, azim


def irregular_angles(lidar: LidarSpec, seed: int = 0):
    """An HDL-64-like pattern: 32 beams 1/3 degree apart from the top, 32 beams 1/2 degree
    apart below (rows of the linear range image get 0, 1 or 2 beams), ~1900 azimuths
    per turn with a per-beam offset and +-0.3 column jitter (rays off the cell centres)."""
    rng = np.random.default_rng(seed)
    upper = 2.0 - np.arange(32) / 3.0
    lower = upper[-1] - 0.5 - np.arange(32) * 0.5
    elev = np.radians(np.concatenate([upper, lower]))
    n_az = 1900
    azim = np.pi - (np.arange(n_az) + 0.5) * 2 * np.pi / n_az
    azim = azim[None, :] + rng.uniform(-0.3, 0.3, (64, n_az)) * 2 * np.pi / lidar.columns
    return elev, azim


def cast_plane(normal, d, elev, azim, *, max_range=70.0):
    """Ray-casts the plane normal . p = d. Returns points (B, A, 3) float32 and hit (B, A) bool."""
    normal = np.asarray(normal, np.float64)
    normal = normal / np.linalg.norm(normal)
    azim = np.broadcast_to(azim, (len(elev),) + np.shape(azim)[-1:])
    e = elev[:, None]
    dirs = np.stack([np.cos(e) * np.cos(azim), np.cos(e) * np.sin(azim), np.sin(e) * np.ones_like(azim)], -1)
    den = dirs @ normal
    ok = np.abs(den) > 1e-9
    t = np.where(ok, d / np.where(ok, den, 1.0), -1.0)
    hit = (t > 0.5) & (t < max_range)
    pts = np.where(hit[..., None], dirs * t[..., None], 0.0)
    return pts.astype(np.float32), hit


def interior(hit: np.ndarray, margin: int) -> np.ndarray:
    """Rays whose (2 margin + 1)^2 ray-grid neighbourhood all hit (azimuth wraps)."""
    out = hit.copy()
    for di in range(-margin, margin + 1):
        for dj in range(-margin, margin + 1):
            shifted = np.roll(hit, dj, axis=1)
            if di > 0:
                shifted = np.concatenate([np.zeros_like(shifted[:di]), shifted[:-di]], 0)
            elif di < 0:
                shifted = np.concatenate([shifted[-di:], np.zeros_like(shifted[:-di])], 0)
            out &= shifted
    return out


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def padded(points: np.ndarray, hit: np.ndarray, size: int):
    p = np.zeros((size, 3), np.float32)
    v = np.zeros(size, bool)
    flat_p, flat_v = points.reshape(-1, 3), hit.reshape(-1)
    p[: len(flat_p)] = flat_p
    v[: len(flat_v)] = flat_v
    return jnp.asarray(p), jnp.asarray(v)


def wall(yaw_deg, d=8.0):
    a = math.radians(yaw_deg)
    return np.array([math.cos(a), math.sin(a), 0.0]), d


def ground(pitch_deg, roll_deg=0.0, height=1.73):
    p, r = math.radians(pitch_deg), math.radians(roll_deg)
    n = np.array([math.sin(p) * math.cos(r), -math.sin(r), math.cos(p) * math.cos(r)])
    return n, -height


SIZE = 131072
_point_normals = jax.jit(lambda p, v: N.point_normals(p, v, lidar=LIDAR))


def check_plane(normal, d, angles, tol_deg, margin=4):
    elev, azim = angles
    pts, hit = cast_plane(normal, d, elev, azim)
    assert hit.sum() > 2000
    p, v = padded(pts, hit, SIZE)
    n = np.asarray(_point_normals(p, v))[: hit.size].reshape(hit.shape + (3,))
    want = -np.sign(d) * np.asarray(normal) / np.linalg.norm(normal)
    inner = interior(hit, margin)
    assert inner.sum() > 1000
    err = angle_deg(n[inner], want[None, :])
    assert err.max() < tol_deg, (err.max(), np.median(err))
    # every valid point has a unit normal that faces the sensor
    assert np.allclose(np.linalg.norm(n[hit], axis=-1), 1.0, atol=1e-5)
    assert np.all(np.sum(n[hit] * pts[hit], -1) <= 1e-6)
    assert np.all(n[~hit] == 0)
    return err


# ----------------------------------------------------------------------------- analytic planes


@pytest.mark.xdist_group("normals_sweep")  # the 131,072-point _point_normals program: one worker compiles it once
@pytest.mark.parametrize("yaw", [0, 20, 40, 60, 90, -90, 180, 215])
def test_vertical_wall_matches_analytic_normal(yaw):
    # 180 and 215 put the wall behind the sensor, across the +-pi seam of the image.
    check_plane(*wall(yaw), ideal_angles(LIDAR), tol_deg=1.0)


@pytest.mark.xdist_group("normals_sweep")  # the 131,072-point _point_normals program: one worker compiles it once
@pytest.mark.parametrize("pitch,roll", [(0, 0), (4, 0), (-6, 0), (10, 0), (3, 5)])
def test_ground_plane_matches_analytic_normal(pitch, roll):
    check_plane(*ground(pitch, roll), ideal_angles(LIDAR), tol_deg=1.0)


@pytest.mark.xdist_group("normals_sweep")  # the 131,072-point _point_normals program: one worker compiles it once
@pytest.mark.parametrize("plane", [wall(40), wall(-120, 12.0), ground(5), ground(-3, 4)])
def test_irregular_beams_and_jitter(plane):
    check_plane(*plane, irregular_angles(LIDAR), tol_deg=2.0)


@pytest.mark.xdist_group("normals_sweep")  # the 131,072-point _point_normals program: one worker compiles it once
def test_paper_sign_convention_would_fail():
    """The paper's printed R (1, r_theta / (r cos phi), r_phi / r)^T is far off a yawed wall:
    rebuilding it from our own (correct) normal shows the sign matters."""
    normal, d = wall(40)
    elev, azim = ideal_angles(LIDAR)
    pts, hit = cast_plane(normal, d, elev, azim)
    p, v = padded(pts, hit, SIZE)
    n = np.asarray(_point_normals(p, v))[: hit.size].reshape(hit.shape + (3,))
    inner = interior(hit, 4)
    q = pts[inner].astype(np.float64)
    r = np.linalg.norm(q, axis=-1)
    th = np.arctan2(q[:, 1], q[:, 0])
    ph = np.arcsin(q[:, 2] / r)
    e_r = np.stack([np.cos(th) * np.cos(ph), np.sin(th) * np.cos(ph), np.sin(ph)], -1)
    e_t = np.stack([-np.sin(th), np.cos(th), 0 * th], -1)
    e_p = np.stack([-np.cos(th) * np.sin(ph), -np.sin(th) * np.sin(ph), np.cos(ph)], -1)
    m = n[inner].astype(np.float64)
    # our n = (-e_r + a e_t + b e_p) / |.|: recover a, b, then form the paper's vector.
    radial = -np.sum(m * e_r, -1)
    a = np.sum(m * e_t, -1) / radial
    b = np.sum(m * e_p, -1) / radial
    paper = e_r + a[:, None] * e_t + b[:, None] * e_p
    want = -normal
    ours = angle_deg(m, want[None, :])
    theirs = np.minimum(angle_deg(paper, want[None, :]), angle_deg(-paper, want[None, :]))
    assert ours.max() < 1.0
    assert np.median(theirs) > 20.0


# ----------------------------------------------------------------------------- range image


def np_range_image(points: np.ndarray, valid: np.ndarray, lidar: LidarSpec):
    """Brute-force loop in float64 angles; r from float32 like the library."""
    L, C = lidar.beams, lidar.columns
    r_img = np.zeros((L, C), np.float32)
    index = -np.ones((L, C), np.int64)
    cell = -np.ones(len(points), np.int64)
    span = lidar.fov_up_rad - lidar.fov_down_rad
    for i, (p, ok) in enumerate(zip(points, valid)):
        if not ok or not np.all(np.isfinite(p)):
            continue
        r = np.float32(np.sqrt(np.float64(p[0]) ** 2 + np.float64(p[1]) ** 2 + np.float64(p[2]) ** 2))
        if not r > RI.MIN_RANGE_M:
            continue
        th = math.atan2(p[1], p[0])
        ph = math.atan2(p[2], math.hypot(p[0], p[1]))
        col = int(math.floor((math.pi - th) * C / (2 * math.pi))) % C
        row = min(max(int(math.floor((lidar.fov_up_rad - ph) * L / span)), 0), L - 1)
        c = row * C + col
        cell[i] = c
        cur = index.flat[c]
        if cur < 0 or r < r_img.flat[c]:
            index.flat[c] = i
            r_img.flat[c] = r
    return r_img, index, cell


def near_boundary(points: np.ndarray, lidar: LidarSpec, tol=1e-4) -> np.ndarray:
    """Points whose float64 bin coordinate is within tol of a cell edge (float32 may differ)."""
    p = points.astype(np.float64)
    th = np.arctan2(p[:, 1], p[:, 0])
    ph = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
    u = (np.pi - th) * lidar.columns / (2 * np.pi)
    span = lidar.fov_up_rad - lidar.fov_down_rad
    v = (lidar.fov_up_rad - ph) * lidar.beams / span
    frac = lambda x: np.abs(x - np.round(x))  # noqa: E731
    return (frac(u) < tol) | (frac(v) < tol)


def random_cloud(rng, n, *, dup=0.2, origin=3, nan=2):
    dirs = rng.normal(size=(n, 3))
    dirs[:, 2] *= 0.3
    pts = dirs / np.linalg.norm(dirs, axis=1, keepdims=True) * rng.uniform(0.5, 40.0, (n, 1))
    k = int(dup * n)
    pts[rng.choice(n, k)] = pts[rng.choice(n, k)]  # exact duplicates
    pts[rng.choice(n, origin)] = 0.0
    pts[rng.choice(n, nan), rng.integers(0, 3, nan)] = np.nan
    valid = rng.uniform(size=n) > 0.1
    return pts.astype(np.float32), valid


@pytest.mark.parametrize("lidar", [SMALL, NUSCENES_HDL32])
def test_range_image_matches_numpy_loop(lidar):
    rng = np.random.default_rng(1)
    pts, valid = random_cloud(rng, 1024)
    valid &= ~near_boundary(np.nan_to_num(pts), lidar)
    r_ref, idx_ref, cell_ref = np_range_image(pts, valid, lidar)
    ri = RI.range_image(jnp.asarray(pts), jnp.asarray(valid), lidar=lidar)
    assert ri.r.dtype == jnp.float32 and ri.index.dtype == jnp.int32 and ri.cell.dtype == jnp.int32
    assert ri.r.shape == (lidar.beams, lidar.columns)
    np.testing.assert_array_equal(np.asarray(ri.cell), cell_ref)
    np.testing.assert_array_equal(np.asarray(ri.index), idx_ref)
    np.testing.assert_allclose(np.asarray(ri.r), r_ref, rtol=2e-7, atol=0)
    has = idx_ref >= 0
    src = pts[idx_ref[has]].astype(np.float64)
    th = np.arctan2(src[:, 1], src[:, 0])
    ph = np.arctan2(src[:, 2], np.hypot(src[:, 0], src[:, 1]))
    np.testing.assert_allclose(np.asarray(ri.theta)[has], th, atol=3e-7, rtol=0)
    np.testing.assert_allclose(np.asarray(ri.phi)[has], ph, atol=3e-7, rtol=0)
    th_c, ph_c = RI.cell_centres(lidar)
    np.testing.assert_allclose(np.asarray(ri.theta)[~has], np.broadcast_to(th_c, has.shape)[~has], atol=1e-6)
    np.testing.assert_allclose(np.asarray(ri.phi)[~has], np.broadcast_to(ph_c, has.shape)[~has], atol=1e-6)


def test_range_image_ties_go_to_smaller_index():
    """Four points in one cell, padded (invalid) to the 1024 points of the random clouds: their program."""
    p = np.zeros((1024, 3), np.float32)
    p[:4] = [[5, 1, 0], [5, 1, 0], [10, 2, 0], [5, 1, 0]]
    ri = RI.range_image(jnp.asarray(p), jnp.asarray(np.arange(1024) < 4), lidar=SMALL)
    cells = np.asarray(ri.cell)
    assert len(set(cells[:4].tolist())) == 1 and np.all(cells[4:] < 0)
    assert int(np.asarray(ri.index).flat[cells[0]]) == 0
    assert (np.asarray(ri.index) >= 0).sum() == 1


def test_polynomial_atan2_and_sin_cos():
    """Compiled, as the normals run them (an op-by-op run compiles every primitive of each new shape)."""
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(size=20000), [0, 0, 1, -1, 0, 0, -1, 1]]).astype(np.float32)
    y = np.concatenate([rng.normal(size=20000), [0, 1, 0, 0, -1, -0.0, 1e-30, -1e-30]]).astype(np.float32)
    got = np.asarray(jax.jit(fastmath.atan2)(jnp.asarray(y), jnp.asarray(x)))
    want = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    err = np.abs(got - want)
    err = np.minimum(err, np.abs(err - 2 * np.pi))  # -pi and pi are the same direction
    assert err.max() < 4e-7
    a = rng.uniform(-np.pi / 2, np.pi / 2, 20000).astype(np.float32)
    s, c = jax.jit(fastmath.sin_cos_small, static_argnums=1)(jnp.asarray(a), np.pi / 2)
    assert np.abs(np.asarray(s) - np.sin(a.astype(np.float64))).max() < 3e-7
    assert np.abs(np.asarray(c) - np.cos(a.astype(np.float64))).max() < 3e-7
    cols = 2048
    centre = np.pi - (np.arange(cols) + 0.5) * 2 * np.pi / cols
    th = (centre[None, :] + rng.uniform(-0.5, 0.5, (4, cols)) * 2 * np.pi / cols)
    th = np.where(th > np.pi, th - 2 * np.pi, th).astype(np.float32)
    s, c = jax.jit(N._azimuth_basis)(jnp.asarray(th))
    assert np.abs(np.asarray(s) - np.sin(th.astype(np.float64))).max() < 3e-7
    assert np.abs(np.asarray(c) - np.cos(th.astype(np.float64))).max() < 3e-7


# ----------------------------------------------------------------------------- every point


@pytest.mark.xdist_group("normals_small_cloud")  # shared point_normals / range_image_normals programs: one worker
def test_every_valid_point_gets_a_unit_normal_random_cloud():
    rng = np.random.default_rng(2)
    pts, valid = random_cloud(rng, 1024)
    n = np.asarray(N.point_normals(jnp.asarray(pts), jnp.asarray(valid), lidar=SMALL))
    good = valid & np.all(np.isfinite(pts), 1) & (np.linalg.norm(np.nan_to_num(pts), axis=1) > 0)
    assert np.all(np.isfinite(n))
    np.testing.assert_allclose(np.linalg.norm(n[good], axis=1), 1.0, atol=1e-5)
    assert np.all(n[~good] == 0)
    assert np.all(np.sum(n[good] * pts[good], 1) <= 1e-5)


@pytest.mark.xdist_group("normals_small_cloud")  # shared point_normals / range_image_normals programs: one worker
def test_sparse_isolated_points_face_the_sensor():
    """A point with no measured neighbour has r_theta = r_phi = 0: n = -p / |p|. (The 16 x 64 sensor,
    1024 points: the programs of the random clouds and of the stage table's rows.)"""
    rng = np.random.default_rng(3)
    # 8 points on distinct, far-apart cells of the 16 x 64 image.
    cols = rng.choice(64 // 8, 8, replace=False) * 8
    rows = rng.integers(0, 4, 8) * 4
    elev, azim = ideal_angles(SMALL)
    e, a = elev[rows], azim[cols]
    r = rng.uniform(2, 50, 8)
    pts = (np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], 1) * r[:, None]).astype(np.float32)
    p, v = padded(pts, np.ones(8, bool), 1024)
    n = np.asarray(N.point_normals(p, v, lidar=SMALL))
    want = -pts / np.linalg.norm(pts, axis=1, keepdims=True)
    np.testing.assert_allclose(n[:8], want, atol=2e-6)
    assert np.all(n[8:] == 0)
    full = np.asarray(N.range_image_normals(RI.range_image(p, v, lidar=SMALL)))
    assert full.shape == (3, 16, 64)
    np.testing.assert_allclose(np.linalg.norm(full, axis=0), 1.0, atol=1e-5)


def test_losers_read_their_cell_normal():
    normal, d = wall(30)
    elev, azim = ideal_angles(SMALL)
    pts, hit = cast_plane(normal, d, elev[4:12], azim, max_range=40)  # 512 rays
    pts, hit = pts.reshape(-1, 3), hit.reshape(-1)
    # add a slightly farther copy of every hit point: same cell, loses the scatter-min
    far = pts * np.float32(1.0 + 1e-4)
    allp = np.concatenate([pts, far])
    allv = np.concatenate([hit, hit])
    ri = RI.range_image(jnp.asarray(allp), jnp.asarray(allv), lidar=SMALL)
    n = np.asarray(N.point_normals(jnp.asarray(allp), jnp.asarray(allv), lidar=SMALL))
    img = np.asarray(N.range_image_normals(ri)).reshape(3, -1).T
    cell = np.asarray(ri.cell)
    k = len(pts)
    assert np.all(np.asarray(ri.index).reshape(-1)[cell[k:][hit]] < k)  # the copies lost
    np.testing.assert_allclose(n[k:][hit], img[cell[k:][hit]], atol=1e-6)
    np.testing.assert_allclose(n[:k][hit], n[k:][hit], atol=1e-6)


@pytest.mark.xdist_group("normals_small_cloud")  # shared point_normals / range_image_normals programs: one worker
def test_range_image_normals_fill_every_cell():
    """Irregular beams on the 16 x 64 sensor (1024 points: the random clouds' programs): 9 beams over
    the ground rows (one row with two, one row without a beam between measured rows), azimuths off the
    cell centres."""
    normal, d = ground(0)
    rng = np.random.default_rng(0)
    elev = np.radians([-4.0, -5.5, -7.0, -9.0, -10.5, -13.0, -14.5, -17.0, -19.0])  # rows 7-10, 12-15
    n_az = 113
    azim = np.pi - (np.arange(n_az) + 0.5) * 2 * np.pi / n_az
    azim = azim[None, :] + rng.uniform(-0.3, 0.3, (len(elev), n_az)) * 2 * np.pi / SMALL.columns
    pts, hit = cast_plane(normal, d, elev, azim, max_range=30)
    p, v = padded(pts, hit, 1024)
    ri = RI.range_image(p, v, lidar=SMALL)
    meas = np.asarray(ri.index) >= 0
    assert 0.2 < meas.mean() < 0.9  # empty rows, columns and the sky are all present
    for smoothing, gap in [(1, 2), (0, 0)]:
        img = np.asarray(N.range_image_normals(ri, smoothing=smoothing, fill_max_gap=gap))
        assert np.all(np.isfinite(img))
        np.testing.assert_allclose(np.linalg.norm(img, axis=0), 1.0, atol=1e-5)
        th, ph = np.asarray(ri.theta), np.asarray(ri.phi)
        e_r = np.stack([np.cos(th) * np.cos(ph), np.sin(th) * np.cos(ph), np.sin(ph)])
        assert np.all(np.sum(img * e_r, 0) <= 1e-6)
        # the empty rows between measured ground rows get the ground normal too
        rows_between = meas.any(1)
        ground_rows = np.where(rows_between)[0]
        gap_rows = [i for i in range(ground_rows.min(), ground_rows.max()) if not rows_between[i]]
        assert gap_rows
        err = angle_deg(np.moveaxis(img[:, gap_rows], 0, -1), normal[None, None, :])
        assert np.median(err) < 2.0


# ----------------------------------------------------------------------------- invariants
# jit == eager, vmap == loop and no retrace of range_image, point_normals, range_image_normals and
# pixel_normals (with the analytic planes) are rows of tests/stage_table.py.


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_gradient_is_finite():
    """Gradients flow through ranges and angles (not through the integer cell
    choice) and stay finite, also for padding points at the origin."""
    normal, d = wall(25)
    elev = np.radians(np.linspace(9, -19, 16))
    azim = np.pi - (np.arange(64) + 0.5) * 2 * np.pi / 64
    pts, hit = cast_plane(normal, d, elev, azim, max_range=40)
    p, v = jnp.asarray(pts.reshape(-1, 3)), jnp.asarray(hit.reshape(-1))
    f = lambda q: jnp.sum(N.point_normals(q, v, lidar=SMALL, smoothing=0, fill_max_gap=0)  # noqa: E731
                          * jnp.array([1.0, 2.0, 3.0]))
    g = np.asarray(jax.jit(jax.grad(f))(p))   # one program (grad alone compiles the forward and the transpose apart)
    assert np.all(np.isfinite(g))
    assert np.abs(g[hit.reshape(-1)]).max() > 0


@settings(deadline=None, max_examples=12)
@given(seed=st.integers(0, 2**31 - 1))
def test_property_unit_normals_and_permutation_invariance(seed):
    rng = np.random.default_rng(seed)
    n = 1024
    pts, valid = random_cloud(rng, n, dup=0.3, origin=2, nan=1)
    out = np.asarray(N.point_normals(jnp.asarray(pts), jnp.asarray(valid), lidar=SMALL))
    good = valid & np.all(np.isfinite(pts), 1) & (np.linalg.norm(np.nan_to_num(pts), axis=1) > 0)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(np.linalg.norm(out[good], axis=1), 1.0, atol=1e-5)
    assert np.all(out[~good] == 0)
    perm = rng.permutation(n)
    out_p = np.asarray(N.point_normals(jnp.asarray(pts[perm]), jnp.asarray(valid[perm]), lidar=SMALL))
    np.testing.assert_allclose(out_p, out[perm], atol=1e-6)


# ----------------------------------------------------------------------------- validation


def test_bad_inputs_raise_value_error():
    p = jnp.zeros((8, 3))
    v = jnp.ones(8, bool)
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 3\), got \(8, 2\)"):
        N.point_normals(jnp.zeros((8, 2)), v, lidar=SMALL)
    with pytest.raises(ValueError, match=r"valid: expected shape \(8,\)"):
        RI.range_image(p, jnp.ones(7, bool), lidar=SMALL)
    with pytest.raises(ValueError, match="smoothing: expected a non-negative integer, got -1"):
        N.point_normals(p, v, lidar=SMALL, smoothing=-1)
    with pytest.raises(ValueError, match="lidar: expected a LidarSpec"):
        RI.range_image(p, v, lidar="kitti")
    with pytest.raises(ValueError, match="ri: expected a RangeImage"):
        N.range_image_normals((1, 2, 3, 4, 5))


def test_options_are_keyword_only():
    p = jnp.zeros((8, 3))
    v = jnp.ones(8, bool)
    with pytest.raises(TypeError):
        RI.range_image(p, v, SMALL)  # noqa


# ----------------------------------------------------------------------------- real data


@pytest.mark.xdist_group("normals_sweep")  # the 131,072-point _point_normals program: one worker compiles it once
def test_kitti_sweep_every_point_and_ground(kitti):
    pts = kitti.scan
    p, v = padded(pts, np.ones(len(pts), bool), SIZE)
    n = np.asarray(_point_normals(p, v))[: len(pts)]
    assert np.all(np.isfinite(n))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert np.all(np.sum(n * pts, 1) <= 1e-4)
    # the road just ahead of the car (sensor 1.73 m above it) is nearly horizontal
    road = (pts[:, 0] > 4) & (pts[:, 0] < 15) & (np.abs(pts[:, 1]) < 3) & (pts[:, 2] < -1.4)
    assert road.sum() > 1000
    err = angle_deg(n[road], np.array([[0.0, 0.0, 1.0]]))
    assert np.median(err) < 5.0


# ----------------------------------------------------------------------------- image input (pixel_normals)

PIX_LIDAR = SMALL_LIDAR
#: points of the pixel oracle's point_normals program (every pixel of a 96 x 160 frame; smaller frames pad)
PIX_ORACLE_POINTS = 96 * 160


def _pix_camera(f=120.0, h=96, w=160):
    return small_camera(f=f, h=h, w=w)


def _pix_frame(seed, camera):
    from jaxdepth._src import synthetic
    from jaxdepth._src.geometry import project_to_image
    frame = synthetic.make_street_scene(seed, lidar=PIX_LIDAR, cameras=[camera])
    depth, _ = project_to_image(frame.points, frame.valid, camera.K, camera.T_cam_lidar,
                                height=camera.height, width=camera.width)
    return np.asarray(depth)


@jax.jit
def _pixel_oracle_points(depth, K, T):
    from jaxdepth._src.geometry import invert_rigid, transform_points, unproject_depth
    return transform_points(invert_rigid(T), unproject_depth(depth, K).reshape(-1, 3))


def pixel_oracle(depth, K, T, lidar, **options):
    """The composition pixel_normals replaces: every pixel as a point, point_normals, rotation.

    With KITTI's LiDAR and the default options the pixels with depth, in order, padded to the sweeps'
    SIZE, run through ``_point_normals`` (the KITTI sweep tests' program): a point's normal depends only
    on the valid points and their order (ties go to the smaller index), not on invalid padding. Other
    frames pad every pixel's point to at least ``PIX_ORACLE_POINTS`` (96 x 160): the 48 x 80 and 96 x 160
    frames with the default options share one ``point_normals`` program."""
    pts = _pixel_oracle_points(depth, K, T)
    valid = np.asarray(depth > 0).reshape(-1)
    if lidar == LIDAR and not options:
        listed = np.flatnonzero(valid)
        p, v = padded(np.asarray(pts)[listed], np.ones(len(listed), bool), SIZE)
        n = np.zeros((valid.size, 3), np.float32)
        n[listed] = np.asarray(_point_normals(p, v))[: len(listed)]
    else:
        p, v = padded(np.asarray(pts), valid, max(valid.size, PIX_ORACLE_POINTS))
        n = np.asarray(N.point_normals(p, v, lidar=lidar, **options))[: valid.size]
    R = np.asarray(T, np.float64)[:3, :3]
    return (R @ np.asarray(n, np.float64).T).reshape(3, *depth.shape), np.asarray(pts)


def check_pixel_normals(got, depth, K, T, lidar, **options):
    want, pts = pixel_oracle(depth, K, T, lidar, **options)
    got = np.asarray(got)
    assert got.shape == (3, *depth.shape) and got.dtype == np.float32
    # a pixel whose point lies within float32 rounding of a cell boundary may bin differently
    stable = ~near_boundary(pts, lidar, tol=1e-5).reshape(depth.shape)
    np.testing.assert_allclose(got[:, stable], want[:, stable], atol=1e-4)
    assert np.all(got[:, depth == 0] == 0)
    return stable


# The synthetic frames have ~5000 points in 96 x 160 pixels, more than the default
# capacity of the listed path (H W / 16): max_points=LISTED takes the listed path.
LISTED = 8192


def _dense_frame(seed, camera):
    """The rendered (dense) depth of the street: more pixels with depth than LISTED."""
    from jaxdepth._src import synthetic
    frame = synthetic.make_street_scene(seed, lidar=PIX_LIDAR, cameras=[camera])
    return np.asarray(frame.dense_depth[0], np.float32)


def test_pixel_normals_equal_point_normals_of_backprojected_pixels():
    """One compiled program (default window, capacity LISTED, 48 x 80: the stage table's pixel_normals
    row), two paths picked at run time: the listed window; the dense fallback for a camera wider than
    the window (f = 20 px: ~127 degrees, more than the 100-degree window). The dense fallback for more
    pixels with depth than the capacity: the test below (its dense frame)."""
    narrow, wide = _pix_camera(f=60.0, h=48, w=80), _pix_camera(f=20.0, h=48, w=80)
    cases = [(narrow, _pix_frame(0, narrow)), (wide, _pix_frame(1, wide)), (narrow, _pix_frame(3, narrow))]
    assert (cases[0][1] > 0).sum() > 500
    for camera, depth in cases:
        got = PN.pixel_normals(depth, camera.K, camera.T_cam_lidar, lidar=PIX_LIDAR, max_points=LISTED)
        stable = check_pixel_normals(got, depth, camera.K, camera.T_cam_lidar, PIX_LIDAR)
        assert stable[depth > 0].mean() > 0.99
        norms = np.linalg.norm(np.asarray(got)[:, depth > 0], axis=0)
        np.testing.assert_allclose(norms, 1.0, atol=1e-5)


@pytest.mark.xdist_group("pixel_normals_96x160")  # the 96 x 160 LISTED pixel_normals program: one worker compiles it
def test_pixel_normals_of_a_camera_facing_backwards():
    """A camera facing backwards (96 x 160, f = 120 px: 67 degrees, inside the 100-degree window) has
    its window across the range image's 360-degree seam, where the window's azimuths jump by 2 pi
    (the whole image unwraps them in its column padding). With points near the seam the frame takes
    the dense path on the whole range image; the listed window gave them normals from neighbours
    2 pi away (measured: 12 and 60 pixels off by up to 0.017 for seeds 0 and 1; none at 48 x 80)."""
    yaw = np.diag([-1.0, -1.0, 1.0, 1.0]).astype(np.float32)  # LiDAR -x ahead
    camera = small_camera(lidar_to_camera() @ yaw)
    for seed in (0, 1):
        depth = _pix_frame(seed, camera)
        assert (depth > 0).sum() <= LISTED
        got = PN.pixel_normals(depth, camera.K, camera.T_cam_lidar, lidar=PIX_LIDAR, max_points=LISTED)
        stable = check_pixel_normals(got, depth, camera.K, camera.T_cam_lidar, PIX_LIDAR)
        assert stable[depth > 0].mean() > 0.99


@pytest.mark.xdist_group("pixel_normals_96x160")  # the 96 x 160 LISTED pixel_normals program: one worker compiles it
def test_pixel_normals_whole_range_image_window_and_options():
    """A window as wide as the range image (the listed path without a window) with other smoothing /
    gap options: one compiled program, on a sparse frame (the listed path) and on a dense one (more
    pixels with depth than the capacity: the fallback), each against the oracle with the same options."""
    camera = _pix_camera()
    options = dict(smoothing=2, fill_max_gap=1)
    sparse, dense = _pix_frame(0, camera), _dense_frame(2, camera)
    assert (sparse > 0).sum() <= LISTED < (dense > 0).sum()
    for depth in (sparse, dense):
        got = PN.pixel_normals(depth, camera.K, camera.T_cam_lidar, lidar=PIX_LIDAR,
                               window_columns=PIX_LIDAR.columns, max_points=LISTED, **options)
        stable = check_pixel_normals(got, depth, camera.K, camera.T_cam_lidar, PIX_LIDAR, **options)
        assert stable[depth > 0].mean() > 0.99


@pytest.mark.xdist_group("pixel_normals_96x160")  # the 96 x 160 LISTED pixel_normals program: one worker compiles it
def test_pixel_normals_listed_fits_is_the_per_point_margin_test():
    """``pixel_normals_listed`` (the KITTI job's program: no dense fallback) reads its ``fits`` from the
    range image's dump slot. Oracle: the per-point flags of the listed path (every pixel with depth at
    least the margin inside the window and off the seam, at most H W / 16 of them). Frames: every 4th
    row and column of a narrow camera (fits), a ~127-degree one wider than the window, a backwards one
    (window across the seam), a whole frame (overflow); where it fits, the normals of ``pixel_normals``."""
    opts = dict(smoothing=N.DEFAULT_CONFIG.normal_smoothing, fill_max_gap=N.DEFAULT_CONFIG.range_fill_max_gap)
    margin, wc = max(1 + opts["fill_max_gap"], opts["smoothing"]), PN.default_window_columns(PIX_LIDAR)
    yaw = np.diag([-1.0, -1.0, 1.0, 1.0]).astype(np.float32)
    cams = [_pix_camera(), _pix_camera(f=40.0), small_camera(lidar_to_camera() @ yaw), _pix_camera()]
    @jax.jit      # the per-point flags in one program (called plainly, every primitive compiles on its own)
    def listed_flags(sparse, K, T):
        pix, total = compaction.compact_indices(jnp.asarray(sparse > 0).reshape(-1), 96 * 160 // 16, 0)
        col0 = PN._window_start(K, T, 96, 160, PIX_LIDAR, wc)
        pts = PN._pixel_points(pix, sparse, K, T, col0, 0, lidar=PIX_LIDAR, window_cols=wc, margin=margin)
        return total, pts.edge.any()

    got_fits = []
    for i, camera in enumerate(cams):
        depth = _pix_frame(i, camera)
        sparse = depth if i == 3 else np.where(np.arange(96)[:, None] % 4 + np.arange(160) % 4 == 0, depth, 0)
        K, T = camera.K, camera.T_cam_lidar
        normals, fits = PN.pixel_normals_listed(sparse, K, T, lidar=PIX_LIDAR, **opts)
        total, edge = listed_flags(jnp.asarray(sparse, jnp.float32), K, T)
        assert bool(fits) == (int(total) <= 96 * 160 // 16 and not bool(edge))
        got_fits.append(bool(fits))
        if fits:    # capacity LISTED (the frame fits it too): the program of the backwards-camera test above
            want = PN.pixel_normals(sparse, K, T, lidar=PIX_LIDAR, max_points=LISTED)
            np.testing.assert_array_equal(np.asarray(normals), np.asarray(want))
    assert got_fits == [True, False, False, False]  # the frames' premise


def test_compact_indices_lists_true_entries_in_order():
    """Two shapes: several fill levels (none, sparse, more than the capacity, all) share one program."""
    rng = np.random.default_rng(7)
    compact = jax.jit(compaction.compact_indices, static_argnums=1)
    for n, p, capacity in ((5000, 0.05, 400), (5000, 0.3, 400), (5000, 0.0, 400), (5000, 1.0, 400), (64, 1.0, 64)):
        valid = rng.random(n) < p
        pix, total = compact(jnp.asarray(valid), capacity, jnp.int32(0))
        want = np.flatnonzero(valid)[:capacity]
        assert int(total) == valid.sum()
        np.testing.assert_array_equal(np.asarray(pix)[:len(want)], want)
        assert np.all(np.asarray(pix)[len(want):] == n)


def test_pixel_normals_bad_inputs_raise():
    camera = _pix_camera()
    depth = jnp.zeros((96, 160))
    with pytest.raises(ValueError, match=r"pixel_normals: field 'sparse_depth' expected shape \(H, W\)"):
        PN.pixel_normals(depth[None], camera.K, camera.T_cam_lidar, lidar=PIX_LIDAR)
    with pytest.raises(ValueError, match=r"pixel_normals: field 'K' expected shape \(3, 3\), got \(3, 4\)"):
        PN.pixel_normals(depth, jnp.zeros((3, 4)), camera.T_cam_lidar, lidar=PIX_LIDAR)
    with pytest.raises(TypeError):
        PN.pixel_normals(depth, camera.K, camera.T_cam_lidar, PIX_LIDAR)  # noqa


@pytest.mark.slow  # KITTI-size program (the frozen-oracle test below runs the same one)
@pytest.mark.xdist_group("normals_sweep")  # the KITTI-size pixel_normals and _point_normals: one worker
def test_pixel_normals_kitti_frame(kitti):
    depth, K, T = kitti.sparse[2], kitti.K[2], kitti.T_cam_lidar[2]
    got = PN.pixel_normals(depth, K, T, lidar=KITTI_HDL64)  # listed path (18.9k points, capacity 26.8k)
    stable = check_pixel_normals(got, depth, K, T, KITTI_HDL64)
    assert stable[depth > 0].mean() > 0.999


@pytest.mark.slow  # frozen oracle
@pytest.mark.xdist_group("normals_sweep")  # the KITTI-size pixel_normals and _point_normals: one worker
def test_kitti_equal_to_reference_version(kitti):
    """pixel_normals on the KITTI frame and point_normals on its sweep equal the version
    before the speed-up (tests/oracles/normals_58cfbac.py; measured: max difference 1.8e-7,
    a float32 ulp; bins identical)."""
    depth, K, T = kitti.sparse[2], kitti.K[2], kitti.T_cam_lidar[2]
    got = np.asarray(PN.pixel_normals(depth, K, T, lidar=KITTI_HDL64))
    want = np.asarray(reference.pixel_normals(depth, K, T, lidar=KITTI_HDL64))
    np.testing.assert_allclose(got, want, atol=1e-6, rtol=0)
    assert np.array_equal(got == 0, want == 0)
    p, v = padded(kitti.scan, np.ones(len(kitti.scan), bool), SIZE)
    got = np.asarray(_point_normals(p, v))
    want = np.asarray(reference.point_normals(p, v, lidar=LIDAR))
    np.testing.assert_allclose(got, want, atol=1e-6, rtol=0)
