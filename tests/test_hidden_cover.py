"""The held-out protocol's independent occlusion test (jaxdepth.research.hidden.covered_targets).

Oracles: a brute-force NumPy walk over every window, an analytic scene (a
near wall in front of a far one, sampled on scan lines), jit == eager,
vmap == loop; and hidden_point_scores' "uncovered" scores equal the devkit
metrics at the targets the test keeps. The Euclidean nearest fill ("nearest_l2") against a
brute-force NumPy search.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdepth
from helpers import square_before_plane
from jaxdepth.research.hidden import covered_targets, euclidean_fill, euclidean_fill_jit, scan_line_spacing_px


def numpy_covered(target, full, h, w):
    """Per pixel: nearer full-sweep points on both sides, vertically or horizontally."""
    H, W = target.shape
    out = np.zeros((H, W), bool)

    def nearer(y, x, rows, cols, limit):
        for dy in range(rows[0], rows[1] + 1):
            for dx in range(cols[0], cols[1] + 1):
                yy, xx = y + dy, x + dx
                if 0 <= yy < H and 0 <= xx < W and 0 < full[yy, xx] < limit:
                    return True
        return False

    for y in range(H):
        for x in range(W):
            z = target[y, x]
            if z <= 0:
                continue
            limit = z - max(1.0, 0.05 * z)
            vertical = nearer(y, x, (-h, -1), (-2, 2), limit) and nearer(y, x, (1, h), (-2, 2), limit)
            horizontal = nearer(y, x, (-1, 1), (-w, -1), limit) and nearer(y, x, (-1, 1), (1, w), limit)
            out[y, x] = vertical or horizontal
    return out


def random_pair(seed, shape=(24, 32)):
    rng = np.random.default_rng(seed)
    full = np.where(rng.random(shape) < 0.3, rng.uniform(2.0, 40.0, shape), 0.0).astype(np.float32)
    target = np.where(rng.random(shape) < 0.2, rng.uniform(2.0, 40.0, shape), 0.0).astype(np.float32)
    return target, full


@pytest.mark.parametrize("h,w", [(1, 1), (3, 3), (4, 2), (2, 6)])
def test_covered_targets_matches_brute_force(h, w):
    for seed in range(3):
        target, full = random_pair(seed)
        got = np.asarray(covered_targets(jnp.asarray(target), jnp.asarray(full), half_height_px=h, half_width_px=w))
        want = numpy_covered(target, full, h, w)
        assert want.sum() > 0 and (~want & (target > 0)).sum() > 0     # both outcomes occur
        np.testing.assert_array_equal(got, want)


def test_covered_targets_analytic_wall():
    """A far wall (20 m) and a near one (5 m, rows 8-20, columns 10-25), both sampled on
    scan lines every 4 rows. A far point inside the near wall's silhouette is covered; one
    just below its lower edge, one beside it, and a point only 0.5 m behind it are not."""
    H, W = 40, 40
    full = np.zeros((H, W), np.float32)
    full[::4, :] = 20.0
    full[8:21:4, 10:26] = 5.0
    target = np.zeros((H, W), np.float32)
    inside, below, beside, shallow = (14, 17), (22, 17), (14, 5), (14, 20)
    for y, x in (inside, below, beside):
        target[y, x] = 20.0
    target[shallow] = 5.5
    got = np.asarray(covered_targets(jnp.asarray(target), jnp.asarray(full), half_height_px=4))
    assert got[inside]
    assert not got[below] and not got[beside] and not got[shallow]
    assert got.sum() == 1


def test_covered_targets_jit_and_vmap():
    pairs = [random_pair(seed) for seed in range(3)]
    targets = jnp.asarray(np.stack([t for t, _ in pairs]))
    fulls = jnp.asarray(np.stack([f for _, f in pairs]))
    fn = lambda t, f: covered_targets(t, f, half_height_px=3, half_width_px=2)  # noqa: E731
    eager = [np.asarray(fn(t, f)) for t, f in zip(targets, fulls)]
    np.testing.assert_array_equal(np.asarray(jax.jit(fn)(targets[0], fulls[0])), eager[0])
    np.testing.assert_array_equal(np.asarray(jax.vmap(fn)(targets, fulls)), np.stack(eager))


def test_covered_targets_rejects_empty_window():
    with pytest.raises(ValueError, match="half_height_px"):
        covered_targets(jnp.zeros((4, 4)), jnp.zeros((4, 4)), half_height_px=0)


def test_scan_line_spacing_px():
    K = np.array([[700.0, 0, 600], [0, 721.5, 180], [0, 0, 1]])
    lidar = jaxdepth.LidarSpec(beams=64, fov_up_deg=2.0, fov_down_deg=-24.9)
    np.testing.assert_allclose(scan_line_spacing_px(K, lidar), 721.5 * np.radians(26.9) / 63, rtol=1e-12)


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_hidden_point_scores_uncovered_equal_metrics_at_kept_targets():
    """A near square (4 m) in front of a far plane (20 m); hidden far points behind the square
    are covered. "uncovered" scores equal depth_metrics at the targets covered_targets keeps,
    and "covered_pixels" counts the targets it drops."""
    from jaxdepth._src.geometry import project_to_image
    cams, K, T, points = square_before_plane(seed=1, far_points=1500, near_points=300, near_half_m=1.5)
    points = jnp.asarray(points)
    valid = np.ones(len(points), bool)
    hidden = np.zeros(len(points), bool)
    hidden[:300] = True
    lidar = jaxdepth.LidarSpec(beams=16)
    scores = jaxdepth.hidden_point_scores(points, valid, hidden, cams, lidar=lidar)
    h = int(np.ceil(scan_line_spacing_px(K, lidar)))
    gt, _ = project_to_image(points, jnp.asarray(hidden), jnp.asarray(K), jnp.asarray(T), height=48, width=64)
    full, _ = project_to_image(points, jnp.asarray(valid), jnp.asarray(K), jnp.asarray(T), height=48, width=64)
    covered = np.asarray(covered_targets(gt, full, half_height_px=h))
    assert int(scores["covered_pixels"][0]) == int(covered.sum()) > 0
    # the nearest fill: every pixel takes the depth of its city-block nearest input pixel (the public
    # stages on the input's z-buffer; no pipeline program of its own)
    sparse, _ = project_to_image(points, jnp.asarray(valid & ~hidden), jnp.asarray(K), jnp.asarray(T),
                                 height=48, width=64)
    seeds = jaxdepth.nearest_seed(sparse > 0, metric="l1")
    kept = jnp.where(jnp.asarray(covered), 0.0, gt)
    want = jaxdepth.depth_metrics(jaxdepth.gather_at_seed(sparse, seeds.du, seeds.dv), kept)
    for key in ("rmse", "mae"):
        np.testing.assert_allclose(float(scores["uncovered"]["nearest"][key][0]), float(want[key]), rtol=1e-5)
    # the covered targets are far-plane points behind the square
    gt_np = np.asarray(gt)
    assert np.all(np.abs(gt_np[covered] - 20.0) < 0.5)


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_hidden_point_scores_under_jit_needs_a_static_window():
    # the point count of the test above: the eager call reuses its compiled programs
    cams, K, T, points = square_before_plane(seed=2, far_points=1500, near_points=300, near_half_m=1.0)
    valid = np.ones(len(points), bool)
    hidden = np.arange(len(points)) % 5 == 0
    lidar = jaxdepth.LidarSpec(beams=16)
    with pytest.raises(ValueError, match="cover_half_height_px"):
        jax.jit(lambda c: jaxdepth.hidden_point_scores(points, valid, hidden, c, lidar=lidar))(cams)
    h = int(np.ceil(scan_line_spacing_px(K, lidar)))

    def compared(scores):
        """The covered targets (what the static window sizes) and the nearest fill's scores without them:
        under jit XLA drops the rest, so the traced program holds no SGM pipeline of its own (the test
        above checks the scores themselves)."""
        return scores["covered_pixels"], scores["uncovered"]["nearest"]["rmse"], scores["uncovered"]["nearest"]["mae"]

    traced = jax.jit(lambda p, v, hd, c: compared(jaxdepth.hidden_point_scores(p, v, hd, c, lidar=lidar,
                                                                               cover_half_height_px=h)))(
        points, valid, hidden, cams)
    eager = compared(jaxdepth.hidden_point_scores(points, valid, hidden, cams, lidar=lidar))
    np.testing.assert_array_equal(np.asarray(traced[0]), np.asarray(eager[0]))
    assert int(np.asarray(eager[0])[0]) > 0
    for got, want in zip(traced[1:], eager[1:]):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-6)


def test_euclidean_fill_is_the_depth_of_a_nearest_kept_pixel():
    """Brute force over every (pixel, kept pixel) pair: each pixel holds the depth of a kept pixel at the
    smallest Euclidean distance (exactly that pixel's where it is the only one); sparse pixels that are
    not kept are never used; jit == eager, C cameras at once."""
    rng = np.random.default_rng(7)
    shape = (2, 9, 13)
    sparse = np.where(rng.random(shape) < 0.25, rng.uniform(2.0, 40.0, shape), 0.0).astype(np.float32)
    keep = (sparse > 0) & (rng.random(shape) < 0.7)
    got = np.asarray(euclidean_fill(jnp.asarray(keep), jnp.asarray(sparse)))
    np.testing.assert_array_equal(np.asarray(euclidean_fill_jit(keep, sparse)), got)
    v, u = np.mgrid[0:shape[1], 0:shape[2]]
    for c in range(shape[0]):
        kv, ku = np.nonzero(keep[c])
        d2 = (v.reshape(-1, 1) - kv) ** 2 + (u.reshape(-1, 1) - ku) ** 2      # (pixels, kept) squared L2
        nearest = d2 == d2.min(axis=1, keepdims=True)
        values = sparse[c][kv, ku]
        assert np.all(np.any(nearest & (got[c].reshape(-1, 1) == values), axis=1))
        unique = nearest.sum(axis=1) == 1
        assert unique.mean() > 0.5
        np.testing.assert_array_equal(got[c].reshape(-1)[unique], values[nearest[unique].argmax(axis=1)])
