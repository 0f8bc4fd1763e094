"""Tests for jaxdepth._src.geodesic (image-guided nearest seed, GeoS raster passes).

Oracles: a multi-source Dijkstra (heapq) in float64 NumPy on the same
4-connected step costs; per-seed single-source Dijkstra for the chosen seed; a
Dijkstra on the layered graph (pixel, run index) for the exact meaning of a
given number of sweeps; OpenCV's exact L1 transform and ``nearest_seed`` for
``color_weight = 0``.  Plus jit == eager and vmap == loop.
"""

from __future__ import annotations

import heapq

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth._src.distance import gather_at_seed, nearest_seed
from jaxdepth._src.geodesic import geodesic_seed, median_step_difference, step_costs

import scenes
from scenes import SMALL_LIDAR

RTOL = 2e-6  # float32 sums of up to a few hundred steps vs float64


def _edge_cost(img: np.ndarray, weight: float, a, b, floor: float = 0.0) -> float:
    diff = img[a].astype(np.float64) - img[b].astype(np.float64)
    return 1.0 + weight * max(float(np.sqrt(np.sum(diff * diff))) - floor, 0.0)


def _neighbours(h, w, v, u):
    for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        if 0 <= v + dv < h and 0 <= u + du < w:
            yield v + dv, u + du, dv == 0


def _dijkstra(sources, img, weight, runs=None, floor=0.0):
    """Multi-source Dijkstra on the 4-connected grid.

    With ``runs`` (an int), paths are limited to at most ``runs`` straight runs
    alternating horizontal / vertical, horizontal first (run 1 may be empty):
    the state is (pixel, run index r), r odd = horizontal, even = vertical.
    """
    h, w = img.shape[:2]
    img = img.reshape(h, w, -1)
    r_max = 1 if runs is None else runs
    dist = np.full((r_max + 1, h, w), np.inf)
    heap = []
    for v, u in sources:
        dist[1, v, u] = 0.0
        heap.append((0.0, 1, v, u))
    heapq.heapify(heap)
    while heap:
        d, r, v, u = heapq.heappop(heap)
        if d > dist[r, v, u]:
            continue
        for nv, nu, horizontal in _neighbours(h, w, v, u):
            if runs is None:
                nr = 1
            else:
                nr = r if (r % 2 == 1) == horizontal else r + 1
                if nr > r_max:
                    continue
            nd = d + _edge_cost(img, weight, (v, u), (nv, nu), floor)
            if nd < dist[nr, nv, nu]:
                dist[nr, nv, nu] = nd
                heapq.heappush(heap, (nd, nr, nv, nu))
    return dist[1:].min(axis=0)


def _scene(seed, h=11, w=13, density=0.08, grey=False):
    rng = np.random.default_rng(seed)
    keep = rng.random((h, w)) < density
    keep.flat[rng.integers(h * w)] = True
    # Piecewise-constant colours plus noise: real edges, as in a photo.
    labels = (np.add.outer(np.arange(h) // 4, np.arange(w) // 5) + rng.integers(0, 3, (h, w)) // 2) % 3
    palette = rng.random((3, 3)).astype(np.float32)
    img = palette[labels] + 0.05 * rng.random((h, w, 3)).astype(np.float32)
    if grey:
        img = img.mean(axis=-1)
    return keep, img.astype(np.float32)


def _check_against_dijkstra(res, keep, img, weight):
    ref = _dijkstra(list(zip(*np.nonzero(keep))), img, weight)
    np.testing.assert_allclose(np.asarray(res.distance), ref, rtol=RTOL)
    # The chosen seed is a seed, and its own single-source distance is the minimum.
    h, w = keep.shape
    v, u = np.indices((h, w))
    sv = v + np.asarray(res.dv)
    su = u + np.asarray(res.du)
    assert keep[sv, su].all()
    per_seed = {}
    for s in set(zip(sv.ravel().tolist(), su.ravel().tolist())):
        per_seed[s] = _dijkstra([s], img, weight)
    from_chosen = np.array([[per_seed[(sv[i, j], su[i, j])][i, j] for j in range(w)] for i in range(h)])
    np.testing.assert_allclose(from_chosen, ref, rtol=RTOL)


@pytest.mark.parametrize("seed,weight,grey", [(0, 5.0, False), (1, 20.0, False), (2, 3.0, True), (3, 50.0, False)])
def test_matches_dijkstra_when_converged(seed, weight, grey):
    keep, img = _scene(seed, grey=grey)
    res = geodesic_seed(keep, img, color_weight=weight, sweeps=8)
    _check_against_dijkstra(res, keep, img, weight)


@pytest.mark.parametrize("sweeps", [1, 2, 3])
def test_sweeps_are_exact_over_alternating_runs(sweeps):
    """s sweeps = the shortest path with at most 2 s alternating runs (H first). (A grey 12 x 12 scene: the
    maze test's programs; each of the three limits still leaves paths the next one shortens.)"""
    keep, img = _scene(4, h=12, w=12, density=0.03, grey=True)
    weight = 30.0
    res = geodesic_seed(keep, img, color_weight=weight, sweeps=sweeps)
    ref = _dijkstra(list(zip(*np.nonzero(keep))), img, weight, runs=2 * sweeps)
    np.testing.assert_allclose(np.asarray(res.distance), ref, rtol=RTOL)


# --- the noise floor (SGMConfig.guidance_noise_floor) ---

def _sampled_steps(img, stride=4):
    """NumPy: the colour differences of every stride-th row and column of the steps, finite only."""
    img = img.reshape(img.shape[0], img.shape[1], -1).astype(np.float64)
    dh = np.sqrt(np.sum(np.square(img[:, 1:] - img[:, :-1]), axis=-1))
    dv = np.sqrt(np.sum(np.square(img[1:] - img[:-1]), axis=-1))
    sample = np.concatenate([dh[::stride, ::stride].ravel(), dv[::stride, ::stride].ravel()])
    return dh, dv, sample[np.isfinite(sample)]


#: One compiled program per shape (called plainly, each new shape compiles every primitive op by op); the
#: library runs both inside geodesic_seed's jit.
_median_step_difference = jax.jit(median_step_difference)
_step_costs = jax.jit(step_costs, static_argnames=("noise_floor",))


@pytest.mark.parametrize("shape,nan_rows", [((40, 57), ()), ((9, 30), (0, 4)), ((3, 3), ()), ((64, 33), (8, 9, 10))])
def test_median_step_difference_is_the_sampled_median(shape, nan_rows):
    img = np.random.default_rng(shape[0]).random(shape + (3,)).astype(np.float32)
    img[list(nan_rows)] = np.nan   # a rig canvas' padding: left out, not counted
    dh, dv, sample = _sampled_steps(img)
    got = float(_median_step_difference(*(jnp.asarray(d, jnp.float32) for d in (dh, dv))))
    lower_median = np.sort(sample)[(len(sample) - 1) // 2]
    assert abs(got - lower_median) <= sample.max() / 2**12 + 1e-6


def test_median_step_difference_without_finite_steps_is_zero():
    nan = jnp.full((4, 5), jnp.nan)
    assert float(_median_step_difference(nan, nan)) == 0.0


def test_step_costs_with_noise_floor_match_numpy():
    keep, img = _scene(8, h=20, w=23)
    dh, dv, sample = _sampled_steps(img)
    floor = 1.5 * np.sort(sample)[(len(sample) - 1) // 2]
    got_h, got_v = _step_costs(img, 7.0, noise_floor=1.5)
    tol = 7.0 * 1.5 * sample.max() / 2**12 + 1e-5   # the bisected median's resolution, times weight and floor
    np.testing.assert_allclose(got_h, 1.0 + 7.0 * np.maximum(dh - floor, 0.0), atol=tol)
    np.testing.assert_allclose(got_v, 1.0 + 7.0 * np.maximum(dv - floor, 0.0), atol=tol)
    assert float(np.min(got_h)) == 1.0 and float(np.min(got_v)) == 1.0  # half of the steps at least cost 1


@pytest.mark.xdist_group("geodesic_noise_floor")  # the cases share their programs: one worker compiles their shared program once
@pytest.mark.parametrize("seed,weight,grey", [(0, 20.0, False), (2, 10.0, True), (3, 50.0, False)])
def test_noise_floor_matches_dijkstra_when_converged(seed, weight, grey):
    keep, img = _scene(seed, grey=grey)  # the converged tests' scenes: the plain run below is their program
    _, _, sample = _sampled_steps(img)
    floor = np.sort(sample)[(len(sample) - 1) // 2]
    res = geodesic_seed(keep, img, color_weight=weight, sweeps=8, noise_floor=1.0)
    ref = _dijkstra(list(zip(*np.nonzero(keep))), img, weight, floor=floor)
    # The floor is bisected to max / 2**12: each step's cost may differ by weight times that.
    steps = np.abs(np.asarray(res.du)) + np.abs(np.asarray(res.dv))
    atol = weight * sample.max() / 2**12 * (4 * steps + 4) + 1e-4
    np.testing.assert_array_less(np.abs(np.asarray(res.distance) - ref), atol)
    v, u = np.indices(keep.shape)
    assert keep[v + np.asarray(res.dv), u + np.asarray(res.du)].all()
    # The floor changes the answer here: the plain cost picks other seeds or distances.
    plain = geodesic_seed(keep, img, color_weight=weight, sweeps=8)
    assert np.any(np.asarray(plain.distance) > np.asarray(res.distance) + 1e-3)


def test_noise_floor_zero_is_the_plain_cost():
    keep, img = _scene(5)
    a = geodesic_seed(keep, img, color_weight=9.0, sweeps=8)  # the converged tests' program
    b = geodesic_seed(keep, img, color_weight=9.0, sweeps=8, noise_floor=0.0)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_noise_floor_makes_a_uniform_texture_free():
    """A checkerboard: every step has the same colour difference, the median; with the floor all cost 1 (= L1)."""
    keep, _ = _scene(7, h=16, w=16)
    board = np.where(np.add.outer(np.arange(16), np.arange(16)) % 2 == 0, 0.3, 0.7).astype(np.float32)
    l1 = nearest_seed(keep, metric="l1")
    res = geodesic_seed(keep, board, color_weight=50.0, sweeps=2, noise_floor=1.0)
    np.testing.assert_allclose(res.distance, l1.distance, atol=50.0 * 0.4 / 2**12 * 32)
    plain = geodesic_seed(keep, board, color_weight=50.0, sweeps=2)
    np.testing.assert_allclose(plain.distance, 21.0 * np.asarray(l1.distance), rtol=1e-5)  # each step 1 + 50 x 0.4


def test_maze_needs_more_sweeps_and_distances_never_increase():
    # A seed inside a spiral-ish wall of high contrast: the cheap path winds.
    h, w = 12, 12
    img = np.zeros((h, w), np.float32)
    img[2, 2:10] = img[2:10, 9] = img[9, 2:10] = img[4:10, 2] = 1.0
    img[4, 2:7] = img[4:8, 7] = 1.0
    keep = np.zeros((h, w), bool)
    keep[6, 4] = True
    weight = 100.0
    exact = _dijkstra([(6, 4)], img, weight)
    previous = None
    converged_at = None
    for sweeps in range(1, 7):
        d = np.asarray(geodesic_seed(keep, img, color_weight=weight, sweeps=sweeps).distance)
        assert np.all(d >= exact * (1 - RTOL))
        if previous is not None:
            assert np.all(d <= previous)
        if converged_at is None and np.allclose(d, exact, rtol=RTOL):
            converged_at = sweeps
        previous = d
    assert converged_at is not None and converged_at > 1


@pytest.mark.parametrize("shape,density", [((7, 9), 0.1), ((16, 5), 0.02), ((1, 12), 0.2), ((10, 1), 0.3)])
def test_zero_weight_is_exact_l1(shape, density):
    rng = np.random.default_rng(sum(shape))
    keep = rng.random(shape) < density
    keep.flat[0] = True
    img = rng.random(shape + (3,)).astype(np.float32)
    res = geodesic_seed(keep, img, color_weight=0.0, sweeps=1)
    ref = cv2.distanceTransform((~keep).astype(np.uint8), cv2.DIST_L1, 3)
    np.testing.assert_array_equal(np.asarray(res.distance), ref)
    np.testing.assert_array_equal(res.distance, nearest_seed(keep, metric="l1").distance)
    # gather_at_seed works unchanged: the seed's own position is read back.
    v, u = np.indices(shape)
    got = gather_at_seed(jnp.asarray(v * shape[1] + u), res.du, res.dv)
    assert keep.reshape(-1)[np.asarray(got)].all()
    assert np.all(np.abs(res.du) + np.abs(res.dv) == ref)


def test_no_seed_and_all_seeds():
    img = np.random.default_rng(0).random((8, 9, 3)).astype(np.float32)  # 8 x 9 x 3, 2 sweeps: one program (below)
    empty = geodesic_seed(np.zeros((8, 9), bool), img, color_weight=2.0, sweeps=2)
    assert not bool(empty.has_seed) and np.all(np.isinf(empty.distance))
    assert not np.any(empty.du) and not np.any(empty.dv)
    full = geodesic_seed(np.ones((8, 9), bool), img, color_weight=2.0, sweeps=2)
    assert bool(full.has_seed) and not np.any(full.distance) and not np.any(full.du) and not np.any(full.dv)


def test_traced_weight_equals_static_weight():
    """jit == eager, vmap == loop and the Dijkstra oracle with a static weight: row geodesic_seed of
    tests/stage_table.py. Here: a traced weight gives the same bits."""
    keep, img = _scene(5, h=8, w=9)  # the vmap test's per-frame program
    jitted = geodesic_seed(keep, img, color_weight=7.0, sweeps=2)
    traced = jax.jit(lambda k, i, cw: geodesic_seed(k, i, color_weight=cw, sweeps=2))(keep, img, 7.0)
    for got, want in zip(traced, jitted):
        np.testing.assert_array_equal(got, want)


def test_vmap_equals_loop():
    scenes = [_scene(s, h=8, w=9) for s in range(3)]
    scenes[2] = (np.zeros_like(scenes[2][0]), scenes[2][1])  # one frame without seeds
    keeps = np.stack([k for k, _ in scenes])
    imgs = np.stack([i for _, i in scenes])
    weights = np.array([0.0, 4.0, 9.0], np.float32)
    batched = jax.vmap(lambda k, i, cw: geodesic_seed(k, i, color_weight=cw, sweeps=2))(keeps, imgs, weights)
    for b in range(3):
        one = geodesic_seed(keeps[b], imgs[b], color_weight=float(weights[b]), sweeps=2)
        for got, want in zip(batched, one):
            np.testing.assert_array_equal(got[b], want)


@pytest.mark.parametrize("keep,img,kwargs,match", [
    (np.zeros((4, 5), bool), np.zeros((4, 6, 3), np.float32), {}, r"'image' expected shape \(4, 5\)"),
    (np.zeros((4, 5), bool), np.zeros((4, 5, 4), np.float32), {}, "'image' expected shape"),
    (np.zeros((4, 5), bool), np.zeros((4, 5), np.uint16), {}, "'image' expected a floating dtype"),
    (np.zeros((4, 5), np.uint8), np.zeros((4, 5), np.float32), {}, "'keep' expected dtype bool"),
    (np.zeros((4, 5), bool), np.zeros((4, 5), np.float32), {"sweeps": 0}, "'sweeps' expected an integer >= 1"),
    (np.zeros((4, 5), bool), np.zeros((4, 5), np.float32), {"color_weight": -1.0}, "'color_weight' expected >= 0"),
])
def test_bad_input(keep, img, kwargs, match):
    options = {"color_weight": 1.0, "sweeps": 1} | kwargs
    with pytest.raises(ValueError, match=match):
        geodesic_seed(keep, img, **options)
    with pytest.raises(ValueError, match=match):
        jax.jit(lambda k, i: geodesic_seed(k, i, **options))(keep, img)


# --- the pipeline option (SGMConfig.guidance_weight / guidance_sweeps, image=) ---

#: The shared scenes' LiDAR (tests/scenes.py), whose 32 x 48 frames the pipeline tests below take.
LIDAR = SMALL_LIDAR

#: One guided configuration for the pipeline tests below (one compiled pipeline, test_xla_tuning's
#: too), with the noise floor on: weight 30, 2 sweeps, floor 1.
GUIDED = scenes.GUIDED


def _pipeline_frame():
    """Two shared tiny street frames (32 x 48, SMALL_LIDAR, two focal lengths, one T), random colours."""
    from jaxdepth._src.geometry import project_to_image
    from scenes import tiny_street_frames
    frames = []
    for points, valid, camera in tiny_street_frames((3, 4)):
        depth, _ = project_to_image(points, valid, camera.K, camera.T_cam_lidar, height=32, width=48)
        frames.append((np.asarray(depth), np.asarray(camera.K)))
    T = np.asarray(camera.T_cam_lidar)
    rng = np.random.default_rng(7)
    images = [rng.integers(0, 256, depth.shape + (3,), dtype=np.uint8) for depth, _ in frames]
    return frames, T, images


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_pipeline_without_guidance_ignores_the_image():
    from jaxdepth import complete_stages
    (frames, T, images) = _pipeline_frame()
    depth, K = frames[0]
    plain = complete_stages(depth, K, T, lidar=LIDAR)
    with_image = complete_stages(depth, K, T, lidar=LIDAR, image=images[0])
    for a, b in zip(plain, with_image):
        np.testing.assert_array_equal(a, b)


@pytest.mark.xdist_group("geodesic_guided_pipeline")  # one worker compiles their shared program once
@pytest.mark.slow  # the guided pipeline: two whole-pipeline programs of its own (per frame, vmapped)
def test_pipeline_guided_seeds_and_vmap():
    """Guided seeds are geodesic_seed of Step 2's inliers; uint8 scaling; vmap == loop."""
    from jaxdepth import complete, complete_stages
    (frames, T, images) = _pipeline_frame()
    config = GUIDED
    loop = []
    for (depth, K), image in zip(frames, images):
        stages = complete_stages(depth, K, T, lidar=LIDAR, config=config, image=image)
        want = geodesic_seed(np.asarray(stages.inlier_mask), image.astype(np.float32) / 255.0,
                             color_weight=30.0, sweeps=2, noise_floor=config.guidance_noise_floor)
        np.testing.assert_array_equal(stages.du, want.du)
        np.testing.assert_array_equal(stages.dv, want.dv)
        v, u = np.indices(depth.shape)
        kept = np.where(stages.inlier_mask, depth, 0.0)
        np.testing.assert_array_equal(stages.seed_depth, kept[v + np.asarray(want.dv), u + np.asarray(want.du)])
        loop.append(np.asarray(stages.depth))
    # uint8 is scaled to [0, 1]; a float image is taken as it is.
    from jaxdepth._src.images import guidance_image
    np.testing.assert_allclose(guidance_image(images[0], images[0].shape[:2], guided=True, where="t"),
                               images[0].astype(np.float32) / np.float32(255.0), rtol=1e-6)
    as_float = images[0].astype(np.float32) / 255.0
    assert guidance_image(as_float, as_float.shape[:2], guided=False, where="t") is None
    depths = np.stack([d for d, _ in frames])
    Ks = np.stack([K for _, K in frames])
    batched = jax.vmap(lambda d, K, im: complete(d, K, T, lidar=LIDAR, config=config, image=im))(depths, Ks, np.stack(images))
    # Same tolerance as test_pipeline's vmap test (batched XLA kernels round differently).
    np.testing.assert_allclose(batched, np.stack(loop), rtol=1e-5, atol=1e-4)


@pytest.mark.xdist_group("geodesic_bad_image")  # the cases render one frame: one worker compiles it once
@pytest.mark.parametrize("image,match", [
    (None, r"'image' expected an \(H, W\) or \(H, W, 3\) camera image because config.guidance_weight > 0, got None"),
    (np.zeros((10, 20, 3), np.uint8), r"'image' expected shape \(32, 48\) \(grey\) or \(32, 48, 3\).*got \(10, 20, 3\)"),
    (np.zeros((32, 48, 4), np.uint8), r"'image' expected shape .*got \(32, 48, 4\)"),
    (np.zeros((32, 48, 3), np.uint16), r"'image' expected dtype uint8 \(0-255\) or float in \[0, 1\], got uint16 "
                                        r"\(a 16-bit image"),
])
def test_pipeline_bad_image(image, match):
    from jaxdepth import SGMConfig, complete
    (frames, T, _) = _pipeline_frame()
    depth, K = frames[0]
    with pytest.raises(ValueError, match=match):
        complete(depth, K, T, lidar=LIDAR, config=SGMConfig(guidance_weight=1.0), image=image)


@pytest.mark.parametrize("field,value,match", [
    ("guidance_weight", -1.0, "field 'guidance_weight' expected >= 0"),
    ("guidance_sweeps", 0, "field 'guidance_sweeps' expected an integer >= 1"),
    ("guidance_sweeps", 1.5, "field 'guidance_sweeps' expected an integer >= 1"),
    ("guidance_noise_floor", -0.5, "field 'guidance_noise_floor' expected >= 0"),
])
def test_config_fields(field, value, match):
    from jaxdepth import SGMConfig
    with pytest.raises(ValueError, match=match):
        SGMConfig(**{field: value})


@pytest.mark.xdist_group("geodesic_guided_pipeline")  # one worker compiles their shared program once
@pytest.mark.slow  # the guided pipeline program of the test above
def test_pipeline_passes_the_noise_floor():
    from jaxdepth import complete_stages
    (frames, T, images) = _pipeline_frame()
    depth, K = frames[0]
    stages = complete_stages(depth, K, T, lidar=LIDAR, config=GUIDED, image=images[0])
    keep, image = np.asarray(stages.inlier_mask), images[0].astype(np.float32) / 255.0
    want = geodesic_seed(keep, image, color_weight=30.0, sweeps=2, noise_floor=1.0)
    np.testing.assert_array_equal(stages.du, want.du)
    np.testing.assert_array_equal(stages.dv, want.dv)
    plain = geodesic_seed(keep, image, color_weight=30.0, sweeps=2)
    assert np.any(np.asarray(plain.du) != np.asarray(want.du))  # the floor changed some seeds


@pytest.mark.slow  # the guided point-cloud pipeline: tests/test_rig_images.py's single-camera program
@pytest.mark.xdist_group("rig_images_guided")  # on that module's worker: the program is compiled once
def test_complete_points_guided():
    """The stereo street's first camera with test_rig_images' configuration and image (on which that
    module checks that the image changes the seeds): the single-camera guided program of its loop
    oracle, one program for both modules. The seeds are geodesic_seed's of Step 2's inliers; where the
    two pick different seeds (a near tie that the pipeline's fusion rounds the other way: 1 of 26,752
    pixels here), the pipeline's seed is a kept pixel at the same geodesic distance (geodesic_seed from
    that seed alone), within float32 rounding."""
    from jaxdepth import complete_points_stages
    from test_rig_images import GUIDED as config, _images
    frame, cams = scenes.stereo_street()
    points, valid, camera = frame.points, frame.valid, cams[0]
    image = _images(cams)[0]
    with pytest.raises(ValueError, match=r"complete_points: field 'image' expected .* got None"):
        complete_points_stages(points, valid, camera, lidar=LIDAR, config=config)
    stages = complete_points_stages(points, valid, camera, lidar=LIDAR, config=config, image=image)
    keep, du, dv = (np.asarray(a) for a in (stages.inlier_mask, stages.du, stages.dv))

    def seek(mask):
        return geodesic_seed(mask, image.astype(np.float32) / 255.0, color_weight=config.guidance_weight,
                             sweeps=config.guidance_sweeps, noise_floor=config.guidance_noise_floor)

    want = seek(keep)
    apart = np.argwhere((du != np.asarray(want.du)) | (dv != np.asarray(want.dv)))
    assert len(apart) <= keep.size // 1000, len(apart)
    for v, u in apart:
        sv, su = v + dv[v, u], u + du[v, u]
        assert keep[sv, su]
        alone = np.zeros_like(keep)
        alone[sv, su] = True
        assert float(seek(alone).distance[v, u]) == pytest.approx(float(want.distance[v, u]), rel=1e-5)


def test_non_finite_colours_still_give_real_seeds():
    keep, img = _scene(6, h=8, w=9)  # the vmap test's per-frame program
    img[3, :, 0] = np.nan
    img[:, 4, 1] = np.inf
    res = geodesic_seed(keep, img, color_weight=2.0, sweeps=2)
    v, u = np.indices(keep.shape)
    assert keep[v + np.asarray(res.dv), u + np.asarray(res.du)].all()
    assert np.all(np.isfinite(res.distance))
