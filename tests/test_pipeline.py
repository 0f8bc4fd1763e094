"""The whole SGM pipeline: analytic scenes, invariants, real KITTI accuracy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth import SGMConfig, complete, complete_points_stages, complete_stages, depth_metrics
from jaxdepth._src import synthetic
from jaxdepth._src.distance import gather_at_seed, nearest_seed

from scenes import NON_DEFAULT, POINTS_CONFIG, SMALL_LIDAR, lidar_to_camera, small_camera, tiny_frame


def plane_frame(camera, planes):
    scene = synthetic.scene_arrays(planes=np.asarray(planes, np.float32))
    points, valid = synthetic.lidar_sweep(scene, lidar=SMALL_LIDAR)
    dense = synthetic.render_depth(camera, scene)
    return np.asarray(points), np.asarray(valid), np.asarray(dense)


@pytest.mark.parametrize("planes", [
    [[0.0, 0.0, 1.0, -1.73]],  # flat ground 1.73 m below the LiDAR
    [[0.05, 0.0, 1.0, -1.73]],  # ground pitched by ~3 degrees
    [[-np.cos(0.5), -np.sin(0.5), 0.0, -12.0]],  # a wall 12 m ahead, yawed by ~29 degrees
])
@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
@pytest.mark.xdist_group("pipeline_planar")  # both planes take one program: compiled once, on one worker
def test_planar_scene_completes_nearly_exactly(planes):
    """On the 96 x 160 camera with POINTS_CONFIG (the program of the test below); scored on
    ``depth_raw``, before the smoothing."""
    camera = small_camera(lidar_to_camera())
    points, valid, dense = plane_frame(camera, planes)
    stages = complete_points_stages(points, valid, camera, lidar=SMALL_LIDAR, config=POINTS_CONFIG)
    depth = np.asarray(stages.depth_raw)
    seeds = np.asarray(stages.inlier_mask)
    assert seeds.sum() > 200
    # score where the nearest seed is close and the true surface exists, away from the borders
    near = (np.abs(np.asarray(stages.du)) + np.abs(np.asarray(stages.dv)) <= 4) & (dense > 0) & (dense < 30)
    near[:4], near[-4:], near[:, :4], near[:, -4:] = False, False, False, False
    rel = np.abs(depth[near] - dense[near]) / dense[near]
    nearest_rel = np.abs(np.asarray(stages.seed_depth)[near] - dense[near]) / dense[near]
    # Seeds sit on rounded pixel centres, so a seed's depth belongs to a point up to half a pixel
    # away: on the ground that is a relative error of up to 0.5 / (v - cy). The residual is exact
    # for exact seeds (tests/test_residual.py); here we ask for sub-percent accuracy.
    assert np.median(rel) < 1e-2, np.median(rel)
    # never worse than the nearest seed; on the ground, where depth changes fast along v between
    # beams, the residual removes most of the nearest-seed error
    assert np.mean(rel) < np.mean(nearest_rel)
    if planes[0][2] != 0:
        assert np.mean(rel) < 0.5 * np.mean(nearest_rel)


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_seeds_keep_depth_and_outputs_are_finite_and_clipped():
    frame = synthetic.make_street_scene(3, lidar=SMALL_LIDAR, cameras=[small_camera(lidar_to_camera())])
    config = POINTS_CONFIG
    stages = complete_points_stages(frame.points, frame.valid, frame.cameras[0], lidar=SMALL_LIDAR, config=config)
    for name, value in stages._asdict().items():
        assert np.all(np.isfinite(np.asarray(value))), name
    depth = np.asarray(stages.depth)
    keep = np.asarray(stages.inlier_mask)
    sparse = np.asarray(stages.sparse_depth)
    np.testing.assert_array_equal(depth[keep], np.clip(sparse[keep], config.min_depth_m, config.max_depth_m))
    assert depth.min() >= config.min_depth_m and depth.max() <= config.max_depth_m
    assert sparse.max() > config.max_depth_m and np.any(depth == config.max_depth_m)  # the clip is exercised
    # every kept seed is its own nearest seed
    assert np.all(np.asarray(stages.du)[keep] == 0) and np.all(np.asarray(stages.dv)[keep] == 0)
    # the seed depth is the kept depth at (v + dv, u + du) (NumPy's indexing), and the seeds are Step 2's
    v, u = np.indices(sparse.shape)
    du, dv = np.asarray(stages.du), np.asarray(stages.dv)
    np.testing.assert_array_equal(np.asarray(stages.seed_depth), np.where(keep, sparse, 0)[v + dv, u + du])
    seeds = nearest_seed(stages.inlier_mask)
    np.testing.assert_array_equal(du, np.asarray(seeds.du))
    np.testing.assert_array_equal(dv, np.asarray(seeds.dv))


def test_no_kept_pixel_gives_no_seed_depth_where_the_depth_is_not_empty():
    """The seed depth is read unmasked at each seed (a seed is a kept pixel): with no kept pixel at all, every
    pixel is its own "seed" and the depth there, not kept, must not leak in."""
    from jaxdepth._src.pipeline import _complete_tail
    sparse, K, T = tiny_frame(3)
    assert np.any(sparse > 0)
    normals = jnp.zeros((3,) + sparse.shape, jnp.float32).at[2].set(-1.0)
    # one program for both masks (called plainly, every primitive of the tail compiles on its own)
    tail = jax.jit(lambda sparse, normals, K, T, keep: _complete_tail(
        sparse, normals, None, K, T, beams=SMALL_LIDAR.beams, config=POINTS_CONFIG, keep=keep))
    for keep in (np.zeros(sparse.shape, bool), sparse > 0):
        stages = tail(jnp.asarray(sparse), normals, jnp.asarray(K), jnp.asarray(T), jnp.asarray(keep))
        if keep.any():
            assert np.all(np.asarray(stages.seed_depth) > 0)
        else:
            assert np.all(np.asarray(stages.seed_depth) == 0) and np.all(np.asarray(stages.depth) == 0)


@pytest.mark.slow  # a pipeline program of its own (docs/testing.md)
def test_seed_horizontal_cost_takes_the_weighted_seed():
    """SGMConfig.seed_horizontal_cost: Step 3's offsets are nearest_seed's with that horizontal cost on the
    Step 2 mask (the brute-force-checked transform of tests/test_distance.py), and they differ from city block."""
    frame = synthetic.make_street_scene(3, lidar=SMALL_LIDAR, cameras=[small_camera(lidar_to_camera())])
    config = POINTS_CONFIG.replace(seed_horizontal_cost=3)
    stages = complete_points_stages(frame.points, frame.valid, frame.cameras[0], lidar=SMALL_LIDAR, config=config)
    seeds = nearest_seed(stages.inlier_mask, horizontal_cost=3)
    np.testing.assert_array_equal(np.asarray(stages.du), np.asarray(seeds.du))
    np.testing.assert_array_equal(np.asarray(stages.dv), np.asarray(seeds.dv))
    city = nearest_seed(stages.inlier_mask)
    assert np.any(np.asarray(city.du) != np.asarray(seeds.du))


# jit == eager, vmap == loop and no retrace of complete_points, complete and complete_stages (against the
# plain composition of the stage functions) are rows of tests/stage_table.py.


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_complete_stages_traces_once_whichever_keywords(monkeypatch):
    """The library's own jit: a new frame and K, and ``config`` passed or left at its default,
    reuse one trace (counted by a wrapper around a function the traced body calls). The jit's
    in-memory cache is emptied first, so the first call traces again; the 32 x 48 program is the
    stage table's (its compilation is read back from the session's compilation cache)."""
    from jaxdepth._src import pipeline
    traces = []
    real = pipeline.pixel_normals_slots

    def counted(*args, **kwargs):
        traces.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(pipeline, "pixel_normals_slots", counted)
    (d0, K0, T), (d1, K1, _) = [tiny_frame(s) for s in (6, 7)]
    pipeline._complete_stages.clear_cache()
    complete_stages(d0, K0, T, lidar=SMALL_LIDAR).depth.block_until_ready()
    complete_stages(d1, K1, T, config=SGMConfig(), lidar=SMALL_LIDAR).depth.block_until_ready()
    assert len(traces) == 1


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_scaling_the_scene_scales_the_depth():
    """Metres in, metres out: scaling depths and the LiDAR offset by s scales the output by s. Without the
    outlier removal, whose epsilon scales with the scene too (test_outliers.test_scale_invariance): with
    scenes.NON_DEFAULT (no removal, l2 seeds, blended hypotheses, no smoothing, background above the scan),
    test_speed_equivalence's program; s = 1/2 keeps both runs inside the default clip range."""
    depth, K, T = tiny_frame(5)
    s = 0.5
    T2 = T.copy()
    T2[:3, 3] *= s
    config = NON_DEFAULT
    assert depth.max() < config.max_depth_m and depth[depth > 0].min() * s > config.min_depth_m
    a = np.asarray(complete_stages(depth, K, T, lidar=SMALL_LIDAR, config=config).depth)
    b = np.asarray(complete_stages(depth * s, K, T2, lidar=SMALL_LIDAR, config=config).depth)
    np.testing.assert_allclose(b, s * a, rtol=1e-4, atol=1e-4)


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_empty_input_gives_empty_output():
    _, K, T = tiny_frame(3)
    out = np.asarray(complete(np.zeros((32, 48), np.float32), K, T, lidar=SMALL_LIDAR))
    assert np.all(out == 0)


def test_bad_shapes_raise_clear_errors():
    with pytest.raises(ValueError, match="sparse_depth"):
        complete(np.zeros((2, 3, 4), np.float32), np.eye(3))
    with pytest.raises(ValueError, match="'K'"):
        complete(np.zeros((30, 40), np.float32), np.eye(4))


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_synthetic_street_sgm_beats_nearest():
    """The full-size synthetic street and its LiDAR (a program of its own: on the small scenes' 96 x 160
    camera and 32-beam LiDAR the nearest fill has the lower MAE, measured)."""
    frame = synthetic.make_street_scene(0)
    camera = frame.cameras[0]
    stages = complete_points_stages(frame.points, frame.valid, camera, lidar=frame.lidar)
    gt = np.asarray(frame.dense_depth[0])
    sgm = depth_metrics(stages.depth, gt)
    nearest = depth_metrics(stages.seed_depth, gt)
    assert float(sgm["rmse"]) < float(nearest["rmse"])
    assert float(sgm["mae"]) < float(nearest["mae"])


@pytest.fixture(scope="module")
def kitti_frames(kitti):
    """camera -> (sparse, truth, K, T_cam_lidar) of the shared KITTI frame."""
    return {cam: (kitti.sparse[cam], kitti.truth[cam], kitti.K[cam], kitti.T_cam_lidar[cam]) for cam in (2, 3)}


@pytest.fixture(scope="module")
def kitti_sgm_metrics(kitti_frames):
    """camera -> depth_metrics of the default SGM on the shared KITTI frame (run once for the tests below)."""
    return {cam: depth_metrics(complete_stages(sparse, K, T).depth, gt)
            for cam, (sparse, gt, K, T) in kitti_frames.items()}


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
@pytest.mark.production_flags  # the figures of accuracy_rigs.json, recorded at the production flags
@pytest.mark.xdist_group("pipeline_kitti")  # one worker runs the module's KITTI completion once
def test_kitti_sgm_clearly_beats_nearest_fill(kitti_frames, kitti_sgm_metrics):
    """Issue 3: SGM must clearly beat a nearest-neighbour fill on the real frame (both cameras)."""
    sgm, nearest = [], []
    for cam, (sparse, gt, K, T) in kitti_frames.items():
        # the city-block nearest fill of every measured pixel, from the public stage functions
        seeds = nearest_seed(jnp.asarray(sparse > 0), metric="l1")
        sgm.append(kitti_sgm_metrics[cam])
        nearest.append(depth_metrics(gather_at_seed(jnp.asarray(sparse), seeds.du, seeds.dv), gt))
    mean = lambda rows, k: float(np.mean([float(r[k]) for r in rows]))
    assert mean(sgm, "rmse") < 0.85 * mean(nearest, "rmse")
    assert mean(sgm, "mae") < 0.80 * mean(nearest, "mae")
    # and it matches the published method (the paper's own code: ~954 / 250 mm here; we measure
    # 936.9 / 246.7 with the default config: benchmarks/results/accuracy_rigs.json, the README's
    # accuracy table), with a margin of about 1 % for float32 / XLA version differences
    assert mean(sgm, "rmse") < 946 and mean(sgm, "mae") < 249


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
@pytest.mark.xdist_group("pipeline_kitti")  # one worker runs the module's KITTI completion once
def test_kitti_sgm_beats_ip_basic(kitti_frames, kitti_sgm_metrics):
    from jaxdepth import complete_with
    sgm, ipb = [], []
    for cam, (sparse, gt, K, T) in kitti_frames.items():
        sgm.append(kitti_sgm_metrics[cam])
        ipb.append(depth_metrics(complete_with(sparse, K, T, method="ip-basic",
                                               config=SGMConfig(outlier_removal=False)), gt))
    mean = lambda rows, k: float(np.mean([float(r[k]) for r in rows]))
    assert mean(sgm, "rmse") < mean(ipb, "rmse") and mean(sgm, "mae") < mean(ipb, "mae")


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_listed_normals_give_the_same_stages_whichever_branch():
    """Step 1 kept listed (``pixel_normals_slots``, the frame's program): the tail's conditional gives the same
    Stages bytes whether it reads the slot image and table (the frame fits) or the dense fallback's normals,
    and those of ``pixel_normals``' (3, H, W) image passed as it is (the form the rigs' tail takes). Every
    fourth row and column of a tiny frame: 63 pixels with depth, under the listed path's 96 slots."""
    from jaxdepth._src import pipeline
    from jaxdepth._src.pixel_normals import pixel_normals, pixel_normals_slots
    sparse, K, T = tiny_frame(6)
    grid = np.zeros(sparse.shape, bool)
    grid[::4, ::4] = True
    sparse = np.where(grid, sparse, 0.0).astype(np.float32)
    config = SGMConfig()
    opts = dict(lidar=SMALL_LIDAR, smoothing=config.normal_smoothing, fill_max_gap=config.range_fill_max_gap)

    def stages(form):
        def run(d, K, T):
            d = jnp.where(d > 0, d, 0.0)
            listed = pixel_normals_slots(d, K, T, **opts)
            normals = {"image": lambda: pixel_normals(d, K, T, **opts), "listed": lambda: listed,
                       "fallback": lambda: listed._replace(fits=jnp.bool_(False))}[form]()
            return pipeline._complete_tail(d, normals, None, K, T, beams=SMALL_LIDAR.beams, config=config), listed.fits
        out, fits = jax.jit(run)(sparse, K, T)
        return [np.asarray(a) for a in out], bool(fits)

    (image, _), (listed, fits), (fallback, _) = (stages(f) for f in ("image", "listed", "fallback"))
    assert fits  # the listed branch ran
    for field, a, b, c in zip(pipeline.Stages._fields, image, listed, fallback):
        assert a.tobytes() == b.tobytes() == c.tobytes(), field


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_every_pixel_seed_has_depth_exactly_when_the_search_found_one():
    """The single-camera tail masks by the seed search's scalar ``has_seed`` in place of ``seed_depth > 0`` at
    each pixel (kitti14's ``scalar_mask``). The invariant it rests on, on its own: with any kept pixel, every
    pixel's seed depth is finite and positive; with none, every pixel's is 0 and so is the depth. A tiny frame
    with NaN, infinite, negative and -0 values planted, an empty one and one with no positive value; outlier
    removal on and off."""
    sparse, K, T = tiny_frame(6)
    dirty = sparse.copy()
    dirty[0, :3] = np.nan, np.inf, -2.0
    dirty[-1, -3:] = -np.inf, -0.0, np.nan
    for config in (SGMConfig(), SGMConfig(outlier_removal=False)):
        for d in (dirty, np.zeros_like(sparse), np.where(np.isfinite(dirty), -np.abs(dirty), np.nan)):
            stages = complete_stages(d, K, T, config=config, lidar=SMALL_LIDAR)
            found = bool(np.asarray(stages.inlier_mask).any())
            assert found == bool((np.isfinite(d) & (d > 0)).any())
            seed_depth = np.asarray(stages.seed_depth)
            assert np.array_equal(seed_depth > 0, np.full(d.shape, found))
            assert np.all(np.isfinite(seed_depth))
            assert found or not np.asarray(stages.depth).any()
