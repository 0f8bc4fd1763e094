"""A rig camera's depth does not depend on the rig's other cameras.

Cameras of several sizes share one padded canvas (the largest height and width). Inside its
own window each camera's result must equal the single-camera call at its own size, with the
same K and pose: Step 2's window bounds (H / L, W L / N), the column bracket's H / L, the
blur's border and the above-scan window are the camera's own, and the padding is never read.
Oracle: :func:`jaxdepth.complete_points_stages` (one LiDAR) and
:func:`jaxdepth.complete_sources` of a one-camera rig (several sources), at each camera's own
size (the mask and seeds bit for bit, depths to float32 rounding), on the street scene and on
``edge_rig`` (points on rounding edges of three turned cameras: the scene where a batched and an
unbatched float32 product put points into other pixels, issue 37). Plus jit == eager of the
mixed-size rig, and the cameras grouped by size (one vmap per size on a canvas of that size) against
the same program with every camera on the padded canvas (``RigCameras.sizes=None``): bit for bit
inside each window, every field 0 (False) beyond it. And the one-source tail's column bracket against the NumPy
bracket of tests/helpers.py.
"""

from __future__ import annotations

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import dataclasses

from jaxdepth import complete_points_stages, complete_rig_stages, outlier_keep_mask, project_to_image, stack_cameras
from jaxdepth._src.above_scan import background_above_scan, capped_above_scan
from jaxdepth._src.hypotheses import column_hypotheses
from jaxdepth._src.smoothing import gaussian_blur
from jaxdepth._src.rig import size_groups, vmap_by_size
from jaxdepth._src.sources import complete_sources_stages, make_sources

from _harness import assert_close, assert_tree_close, check_stage
from scenes import SMALL_LIDAR, edge_size_rig, mixed_size_rig, small_camera

LIDAR = SMALL_LIDAR
FIELDS = ("sparse_depth", "inlier_mask", "seed_depth", "du", "dv", "residual", "depth_raw", "depth")
EXACT = ("sparse_depth", "inlier_mask", "seed_depth", "du", "dv")


@pytest.fixture(scope="module")
def mixed_rig():
    """(points, valid, cameras): two landscape 24 x 40 cameras and one portrait 40 x 24 (canvas 40 x 40)."""
    return mixed_size_rig()


@pytest.fixture(scope="module")
def edge_rig():
    """(points, valid, cameras): ``mixed_rig``'s points seen by three 24 x 40 cameras turned by odd angles
    (one vmapped group), every point the middle camera sees moved onto a rounding edge of its pixel grid
    (``scenes.edge_size_rig``). A batched product of three or more cameras' rotations rounds apart from
    the unbatched one (XLA:CPU picks another kernel; two cameras, as in ``mixed_rig``, round alike), so a
    projection computed with plain float32 products puts points into other pixels here (issue 37;
    tests/test_projection_rounding.py)."""
    return edge_size_rig()


def _assert_own_size(rig, i, cam, single):
    """Camera ``i`` of the rig's stages, on its window, equals ``single``; depth 0 beyond it.

    Bit for bit: the z-buffer, Step 2's mask and Step 3's seeds (depth and offsets). The float
    fields computed from them (residual, depth) within 16 eps x max(|x|, 1): the vmapped body is
    fused differently from the single call (1 ulp seen on the residual; same-size rigs too,
    tests/test_rig.py), while a camera's size read from the canvas moves depths by centimetres
    to metres (the blur's border, Step 2's window).
    """
    h, w = cam.height, cam.width
    for name in FIELDS:
        got = np.asarray(getattr(rig, name)[i])[:h, :w]
        want = np.asarray(getattr(single, name))
        msg = f"camera {i} ({h} x {w}) field {name}"
        if name in EXACT:
            np.testing.assert_array_equal(got, want, err_msg=msg)
        else:
            assert_close(got, want, ulps=16, err_msg=msg)
    depth = np.asarray(rig.depth[i])
    assert not depth[h:].any() and not depth[:, w:].any()


@pytest.mark.slow  # whole pipeline programs of their own: the 40 x 40 rig and each camera size
@pytest.mark.xdist_group("rig_mixed_sizes")  # the mixed rig's program is tests/test_rig.py's too: one worker
@pytest.mark.parametrize("scene", ["mixed_rig", "edge_rig"])
def test_rig_camera_equals_its_own_single_camera_call(scene, request):
    points, valid, cams = request.getfixturevalue(scene)
    cameras = stack_cameras(cams)
    rig = complete_rig_stages(points, valid, cameras, lidar=LIDAR)
    assert rig.depth.shape == (3, cameras.height, cameras.width) == (3, 40 if scene == "mixed_rig" else 24, 40)
    for i, cam in enumerate(cams):
        single = complete_points_stages(points, valid, cam, lidar=LIDAR)
        assert int(np.asarray(single.inlier_mask).sum()) > 20      # a real scene in every camera
        _assert_own_size(rig, i, cam, single)


def _two_sweeps(points, valid, *, second_valid):
    """Sources of two sweeps of ``LIDAR``: the points at the origin (sweep 0) and the same points 0.3 m
    further along x (sweep 1), valid where ``second_valid``. One static layout, so the tests below share
    one several-sources program per camera set."""
    shift = np.eye(4, dtype=np.float32)
    shift[0, 3] = 0.3
    return make_sources(np.stack([points, points + shift[:3, 3]]), np.stack([valid, second_valid]),
                        np.stack([np.eye(4, dtype=np.float32), shift]), lidars=(LIDAR, LIDAR), sweep=(0, 1))


@pytest.mark.slow  # the several-sources rig's program (the single calls are those of the test above)
@pytest.mark.xdist_group("rig_mixed_sizes")  # the edge rig's one-source program is tests/test_sources.py's too
@pytest.mark.parametrize("scene", ["mixed_rig", "edge_rig"])
def test_sources_rig_camera_equals_its_own_single_camera_call(scene, request):
    points, valid, cams = request.getfixturevalue(scene)
    # Edge rig: one source at the points' origin, which complete_sources runs through complete_rig's program
    # (docs/multi_source.md). Mixed rig: with an earlier sweep that has no valid point (it removes and adds
    # nothing), the several-sources program (Step 2 per source, each pixel's own origin, the free-space path's
    # projection) of test_sources_grouped_by_size_equals_one_canvas, not one of its own.
    if scene == "mixed_rig":
        sources = _two_sweeps(points, valid, second_valid=np.zeros_like(valid))
    else:
        sources = make_sources(points[None], valid[None], np.eye(4, dtype=np.float32)[None], lidars=(LIDAR,))
    rig = complete_sources_stages(sources, stack_cameras(cams))
    for i, cam in enumerate(cams):
        _assert_own_size(rig, i, cam, complete_points_stages(points, valid, cam, lidar=LIDAR))


@pytest.mark.slow  # the rig's program, and the pipeline op by op
def test_mixed_rig_jit_equals_eager(mixed_rig):
    points, valid, cams = mixed_rig
    cameras = stack_cameras(cams)
    fast = complete_rig_stages(points, valid, cameras, lidar=LIDAR)
    with jax.disable_jit():
        eager = complete_rig_stages(points, valid, cameras, lidar=LIDAR)
    np.testing.assert_array_equal(np.asarray(fast.inlier_mask), np.asarray(eager.inlier_mask))
    assert_tree_close(fast.depth, eager.depth, ulps=8, err_msg="jit != eager")


def _assert_grouped_equals_one_canvas(grouped, one_canvas, cams, *, ulps=0):
    """Every field of ``grouped`` equals ``one_canvas`` bit for bit in each camera's window (``ulps``: the float
    fields but :data:`EXACT`'s within that many eps x max(|x|, 1)), 0 beyond it."""
    for name in grouped._fields:
        for i, cam in enumerate(cams):
            got, want = np.array(getattr(grouped, name)[i]), np.asarray(getattr(one_canvas, name)[i])
            assert got.shape == want.shape == got.shape[:-2] + (40, 40)
            window = (Ellipsis, slice(cam.height), slice(cam.width))
            if ulps and name in FIELDS and name not in EXACT:
                assert_close(got[window], want[window], ulps=ulps, err_msg=f"camera {i} field {name}")
            else:
                np.testing.assert_array_equal(got[window], want[window], err_msg=f"camera {i} field {name}")
            got[window] = 0
            assert not got.any(), f"camera {i} field {name}: not 0 beyond the window"


@pytest.mark.slow  # the rig's program with every camera on the canvas (the grouped one is the tests' above)
# Bit for bit at the production codegen. At the suite's level 0 the grouped form's last kernel (its masks from the
# seed search's scalar, no window but the blur's: branch nusc14) rounds the blur 1 ulp apart at ~10 % of the pixels.
@pytest.mark.production_flags
def test_rig_grouped_by_size_equals_one_canvas(mixed_rig):
    points, valid, cams = mixed_rig
    cameras = stack_cameras(cams)
    assert cameras.sizes == ((24, 40), (40, 24), (24, 40))
    one_canvas = dataclasses.replace(cameras, sizes=None)
    _assert_grouped_equals_one_canvas(complete_rig_stages(points, valid, cameras, lidar=LIDAR),
                                      complete_rig_stages(points, valid, one_canvas, lidar=LIDAR), cams)


@pytest.mark.slow  # a rig program of its own (one camera sees no point)
def test_rig_groups_masks_from_the_seed_search_scalar(mixed_rig):
    # The one-source rig's size groups take the one camera's forms (no window but the blur's; the depth's masks
    # from the seed search's "any seed" scalar): a camera with every point behind it has depth 0 everywhere,
    # and in every camera "the pixel's seed has depth" is "the camera kept a pixel" (NumPy), at every pixel.
    points, valid, cams = mixed_rig
    away = np.array(cams[0].T_cam_lidar, np.float32)
    away[2, 3] -= 1e4       # every point 10 km behind the camera
    cams = [cams[0], dataclasses.replace(cams[0], T_cam_lidar=jnp.asarray(away)), cams[1]]
    cameras = stack_cameras(cams)
    rig = complete_rig_stages(points, valid, cameras, lidar=LIDAR)
    one_canvas = complete_rig_stages(points, valid, dataclasses.replace(cameras, sizes=None), lidar=LIDAR)
    kept = [bool(np.asarray(rig.inlier_mask[i]).any()) for i in range(3)]
    assert kept == [True, False, True]
    assert not np.asarray(rig.depth[1]).any() and not np.asarray(rig.depth_raw[1]).any()
    for i, cam in enumerate(cams):
        window = (slice(cam.height), slice(cam.width))
        seed_depth = np.asarray(rig.seed_depth[i])[window]
        np.testing.assert_array_equal(seed_depth > 0, np.full(seed_depth.shape, kept[i]), err_msg=f"camera {i}")
        assert_close(np.asarray(rig.depth[i])[window], np.asarray(one_canvas.depth[i])[window], ulps=4,
                     err_msg=f"camera {i}")
        np.testing.assert_array_equal(np.asarray(rig.depth_raw[i])[window], np.asarray(one_canvas.depth_raw[i])[window])


def _two_lidars(points, valid):
    """Sources of one sweep of two LiDARs (as Argoverse 2's): the even points from the origin, the odd ones from
    a LiDAR 0.11 m lower (Step 2's exact test once for every camera, ``rig.keep_by_size``'s shared path)."""
    lower = np.eye(4, dtype=np.float32)
    lower[2, 3] = -0.11
    even = (np.arange(valid.shape[0]) % 2 == 0)
    return make_sources(np.stack([points, points]), np.stack([valid & even, valid & ~even]),
                        np.stack([np.eye(4, dtype=np.float32), lower]), lidars=(LIDAR, LIDAR), sweep=(0, 0))


@pytest.mark.slow  # the several-sources program with every camera on the canvas
@pytest.mark.xdist_group("rig_mixed_sizes")  # its two-sweep program is the mixed rig's several-sources test's
@pytest.mark.parametrize("layout", ["two_sweeps", "two_lidars"])
def test_sources_grouped_by_size_equals_one_canvas(mixed_rig, layout):
    points, valid, cams = mixed_rig
    # Two sources of two sweeps (the second the first moved by 0.3 m): the free-space and occlusion
    # verdicts (once per sweep, outside the camera groups) reach every group. Two LiDARs of one sweep: Step 2's
    # one exact-test loop. The groups run without the window (branch rigtail14), the canvas with it.
    # Two LiDARs at the suite's level 0: the portrait group's depth_raw rounds 1 ulp apart from the canvas's at 2-6 %
    # of its pixels (the base's window form too: the vmapped group of one camera fused apart), so the float fields to
    # 16 ulps; the Argoverse 2 job's PNGs at the production flags are the bytes' check (docs/speed.md).
    sources = _two_sweeps(points, valid, second_valid=valid) if layout == "two_sweeps" else _two_lidars(points, valid)
    cameras = stack_cameras(cams)
    grouped = complete_sources_stages(sources, cameras)
    _assert_grouped_equals_one_canvas(grouped, complete_sources_stages(sources, dataclasses.replace(cameras, sizes=None)),
                                      cams, ulps=16 if layout == "two_lidars" else 0)
    # The several-sources keep (the top-line rule's too) lies within the view's finite positive depth, as one
    # source's: the seed search's scalar would give the depth's masks (not taken: docs/speed.md, rigtail14).
    kept, depth = np.asarray(grouped.inlier_mask), np.asarray(grouped.sparse_depth)
    assert kept.any() and not (kept & ~((depth > 0) & np.isfinite(depth))).any()


def test_size_groups_are_static_in_first_appearance_order():
    cams = [small_camera(h=h, w=w) for h, w in ((24, 40), (40, 24), (24, 40), (31, 33), (40, 24))]
    cameras = stack_cameras(cams)
    assert (cameras.height, cameras.width) == (40, 40)
    groups = size_groups(cameras)
    assert [size for size, _ in groups] == [(24, 40), (40, 24), (31, 33)]
    assert [idx.tolist() for _, idx in groups] == [[0, 2], [1, 4], [3]]
    one = size_groups(dataclasses.replace(cameras, sizes=None))
    assert len(one) == 1 and one[0][0] == (40, 40) and one[0][1].tolist() == [0, 1, 2, 3, 4]
    assert jax.tree_util.tree_structure(cameras) != jax.tree_util.tree_structure(
        dataclasses.replace(cameras, sizes=None))      # the sizes are static: part of a jit's key


@pytest.mark.parametrize("colour", [False, True])
def test_vmap_by_size_puts_each_camera_back_on_the_canvas(colour):
    """A per-camera function on each group's own (h, w) canvas: its output for camera ``i`` (NumPy
    oracle: built from K, the size and the image's top-left corner) lands at index ``i`` of the (C, H,
    W) canvas, zeros beyond; under jit == eager, and every camera's image cropped to its group."""
    sizes = ((24, 40), (40, 24), (24, 40), (31, 33))
    cameras = stack_cameras([small_camera(h=h, w=w, f=20.0 + i) for i, (h, w) in enumerate(sizes)])
    rng = np.random.default_rng(3)
    images = rng.uniform(0, 1, (4, 40, 40) + ((3,) if colour else ())).astype(np.float32)

    def per_camera(K, T, size, image, *, height, width):
        grey = image if image.ndim == 2 else image.sum(-1)
        assert grey.shape == (height, width)       # the group's canvas, static
        rows = jnp.arange(height, dtype=jnp.float32)[:, None]
        return {"value": K[0, 0] + 100 * rows + grey + T[0, 0] * size[1], "hit": grey > 0.5}

    def oracle(i, h, w):
        grey = images[i] if not colour else images[i].sum(-1)
        value = np.zeros((40, 40), np.float32)
        t00 = np.asarray(cameras.T_cam_lidar)[i, 0, 0]
        value[:h, :w] = np.float32(20.0 + i) + 100 * np.arange(h, dtype=np.float32)[:, None] + grey[:h, :w] + t00 * w
        hit = np.zeros((40, 40), bool)
        hit[:h, :w] = grey[:h, :w] > 0.5
        return value, hit

    run = jax.jit(lambda cams, ims: vmap_by_size(per_camera, cams, ims))
    for out in (run(cameras, images), vmap_by_size(per_camera, cameras, jnp.asarray(images))):
        for i, (h, w) in enumerate(sizes):
            value, hit = oracle(i, h, w)
            np.testing.assert_allclose(np.asarray(out["value"][i]), value, rtol=1e-6, err_msg=f"camera {i}")
            np.testing.assert_array_equal(np.asarray(out["hit"][i]), hit, err_msg=f"camera {i}")


# ---- The stages one by one (no pipeline compiled): each with ``image_size`` on a 40 x 40 canvas
# whose padding holds garbage, against the stage's oracle on the camera's own (h, w) image; jit ==
# eager, vmap == loop (cameras of three sizes in one batch) and no retrace via check_stage.

CANVAS = 40
SIZES = ((24, 40), (40, 24), (31, 33))


def _inside(x, size):
    """``x`` (.., H, W) with 0 outside the top-left ``size`` window."""
    h, w = x.shape[-2:]
    keep = (jnp.arange(h)[:, None] < size[0]) & (jnp.arange(w)[None, :] < size[1])
    return jnp.where(keep, x, jnp.zeros((), x.dtype))


def _embed(x, size):
    """NumPy: the (h, w) ``x`` in the top-left corner of a zero canvas."""
    out = np.zeros(x.shape[:-2] + (CANVAS, CANVAS), x.dtype)
    out[..., :size[0], :size[1]] = x
    return out


def test_blur_mirrors_at_the_cameras_own_border():
    rng = np.random.default_rng(0)
    inputs = []
    for h, w in SIZES:
        canvas = rng.uniform(1e3, 2e3, (CANVAS, CANVAS)).astype(np.float32)    # garbage beyond the window
        canvas[:h, :w] = rng.uniform(1, 50, (h, w))
        inputs.append((canvas, np.array([h, w], np.int32)))

    def oracle(canvas, size):
        h, w = size
        return _embed(cv2.GaussianBlur(canvas[:h, :w], (7, 7), 1.4, borderType=cv2.BORDER_REFLECT_101), size)

    check_stage(lambda c, s: _inside(gaussian_blur(c, sigma_px=1.4, radius_px=3, image_size=s), s), inputs,
                oracle=oracle, oracle_ulps=8)


def test_outlier_window_bounds_are_the_cameras_own(mixed_rig):
    """Each camera's window of the canvas equals Algorithm 1 on the camera's own image (the footprint double
    loop of test_outliers, float64, the default caps; no second keep-mask program per camera size), and the
    canvas beyond it is False."""
    from test_outliers import _assert_matches_footprint, footprint_double_loop
    from jaxdepth._src.config import DEFAULT_CONFIG as D
    points, valid, cams = mixed_rig
    inputs, wants, removed = [], [], 0
    for cam in cams:
        sparse, _ = project_to_image(points, valid, cam.K, cam.T_cam_lidar, height=cam.height, width=cam.width)
        size = (cam.height, cam.width)
        inputs.append((_embed(np.asarray(sparse), size), np.asarray(cam.K), np.asarray(cam.T_cam_lidar),
                       np.array(size, np.int32)))
        wants.append(footprint_double_loop(np.asarray(sparse), np.asarray(cam.K), np.asarray(cam.T_cam_lidar),
                                           beams=LIDAR.beams, epsilon_m=D.epsilon_m,
                                           max_half_width_px=D.outlier_max_half_width_px,
                                           max_half_height_px=D.outlier_max_half_height_px))
        removed += int(((np.asarray(sparse) > 0) & ~wants[-1][0]).sum())
    assert removed > 0      # the scene has outliers to remove

    # The library's own program (stage_table._OneLibraryJit): a jit around the call would compile the keep
    # mask a second time. Beyond the window the canvas holds no depth, so the mask is False there already.
    from stage_table import _OneLibraryJit
    from jaxdepth._src import outliers
    keep_mask = _OneLibraryJit(lambda c, K, T, s: outlier_keep_mask(c, K, T, beams=LIDAR.beams, image_size=s),
                               outliers._keep_mask)
    outs = check_stage(keep_mask, inputs, eager_inputs=1)
    for out, (_, _, _, (h, w)), (want, unsure) in zip(outs, inputs, wants):
        _assert_matches_footprint(out[:h, :w], want, unsure)
        assert not out[h:].any() and not out[:, w:].any()


def test_column_bracket_uses_the_cameras_own_window():
    rng = np.random.default_rng(1)
    beams = 8                                   # h / L: 3 rows (h = 24), 5 (h = 40), 3 (h = 31); canvas 5
    K = np.array([[30, 0, 19.5], [0, 30, 12], [0, 0, 1]], np.float32)
    inputs = []
    for h, w in SIZES:
        kept = np.zeros((CANVAS, CANVAS), np.float32)
        rows = np.zeros(CANVAS, bool)
        rows[rng.choice(h, h // 3, replace=False)] = True
        kept[:h, :w] = np.where(rows[:h, None] & (rng.random((h, w)) < 0.7), rng.uniform(2, 40, (h, w)), 0.0)
        raw = rng.uniform(0.5, 60, (CANVAS, CANVAS)).astype(np.float32)
        dist = rng.integers(0, 8, (CANVAS, CANVAS)).astype(np.float32)
        normals = rng.normal(size=(3, CANVAS, CANVAS)).astype(np.float32)
        size = np.array([h, w], np.int32)
        inputs.append((raw, kept, dist, normals, size))

    def run(raw, kept, dist, normals, size):
        return _inside(column_hypotheses(raw, kept, dist, normals, K, window_px=CANVAS / beams, blend=True,
                                         image_size=size, image_gap=size[0] // beams), size)

    bracket = jax.jit(column_hypotheses, static_argnames=("window_px", "blend"))

    def oracle(raw, kept, dist, normals, size):
        h, w = size
        return _embed(np.asarray(bracket(raw[:h, :w], kept[:h, :w], dist[:h, :w], normals[:, :h, :w], K,
                                         window_px=h / beams, blend=True)), size)

    check_stage(run, inputs, oracle=oracle)


def test_above_scan_window_is_the_cameras_own():
    from test_above_scan import above_scan_inputs, numpy_above_scan
    rng = np.random.default_rng(2)
    inputs = []
    for n, (h, w) in enumerate(SIZES):
        depth_raw, seed_depth, keep, valid = above_scan_inputs(n, H=h, W=w, points=3 * w)
        garbage = lambda x: np.where(np.asarray(_embed(np.ones_like(x, bool), (h, w))), _embed(x, (h, w)),  # noqa: E731
                                     rng.uniform(70, 90, (CANVAS, CANVAS)).astype(np.float32))
        inputs.append((garbage(depth_raw), garbage(seed_depth), _embed(keep, (h, w)), _embed(valid, (h, w)),
                       np.array([h, w], np.int32)))

    def oracle(depth_raw, seed_depth, keep, valid, size):
        h, w = size
        return _embed(numpy_above_scan(depth_raw[:h, :w], seed_depth[:h, :w], keep[:h, :w], valid[:h, :w],
                                       beams=16, max_half_width_px=12), size)

    check_stage(lambda d, s, k, v, n: _inside(background_above_scan(d, s, k, v, beams=16, image_size=n), n), inputs,
                oracle=oracle, oracle_ulps=0)


def test_capped_above_scan_window_is_the_cameras_own():
    """On a canvas, with the camera's (h, w): inside the window the capped plane equals the float64 oracle of
    the (h, w) image alone with R = h / L (padding rows and columns hold garbage)."""
    from test_above_scan import capped_inputs, numpy_capped_above_scan
    rng = np.random.default_rng(3)
    inputs = []
    for n, (h, w) in enumerate(SIZES):
        d, s, nrm, du, dv, keep, valid, Kc = capped_inputs(n, H=h, W=w, points=3 * w)
        garbage = lambda x: np.where(np.asarray(_embed(np.ones_like(x, bool), (h, w))), _embed(x, (h, w)),  # noqa: E731
                                     rng.uniform(70, 90, (CANVAS, CANVAS)).astype(np.float32))
        inputs.append((garbage(d), garbage(s), np.stack([_embed(c, (h, w)) for c in nrm]),
                       _embed(du, (h, w)).astype(np.int32), _embed(dv, (h, w)).astype(np.int32),
                       _embed(keep, (h, w)), _embed(valid, (h, w)), Kc, np.array([h, w], np.int32)))

    def run(d, s, nrm, du, dv, keep, valid, K, size):
        return _inside(capped_above_scan(d, s, nrm, du, dv, keep, valid, K, beams=16, rows_px=size[0] / 16,
                                         image_size=size), size)

    def oracle(d, s, nrm, du, dv, keep, valid, K, size):
        h, w = size
        return _embed(numpy_capped_above_scan(d[:h, :w], s[:h, :w], nrm[:, :h, :w], du[:h, :w], dv[:h, :w],
                                              keep[:h, :w], valid[:h, :w], K, beams=16, rows_px=h / 16,
                                              max_half_width_px=12), size)

    check_stage(run, inputs, oracle=oracle, oracle_ulps=16, ulps=16)


@pytest.mark.slow  # one whole program of each pipeline beside its three stage programs (docs/testing.md)
@pytest.mark.xdist_group("rig_mixed_sizes")  # the stage programs are the tests' above
@pytest.mark.parametrize("pipeline", ["rig", "sources"])
def test_stage_programs_equal_the_one_program(pipeline, mixed_rig):
    """The pipeline as three jitted stage programs called one after another (``run_*_stages`` outside a jit)
    against the library's one program, the same stages traced into one ``jit`` (XLA then fuses across the
    stage boundaries): every field bit for bit, on the two-size rig; the two-sweep sources with free space and
    occlusion (each pixel's source and shadow cross the boundaries). (The jobs' depth-only programs: the next
    test, at the production flags.)"""
    from jaxdepth._src.rig import run_rig_stages
    from jaxdepth._src.sources import default_beams, run_sources_stages
    from jaxdepth._src.config import DEFAULT_CONFIG
    points, valid, cams = mixed_rig
    cameras = stack_cameras(cams)
    if pipeline == "rig":
        split = run_rig_stages(points, valid, cameras, config=DEFAULT_CONFIG, lidar=LIDAR)
        one = complete_rig_stages(points, valid, cameras, lidar=LIDAR)
    else:
        sources = _two_sweeps(points, valid, second_valid=valid)
        split = run_sources_stages(sources, cameras, config=DEFAULT_CONFIG, free_space=True,
                                   beams=default_beams(sources))
        one = complete_sources_stages(sources, cameras)
    assert int(np.asarray(split.inlier_mask).sum()) > 60
    for name in split._fields:
        np.testing.assert_array_equal(np.asarray(getattr(split, name)), np.asarray(getattr(one, name)), err_msg=name)


@pytest.mark.slow  # two whole programs of each pipeline, in a subprocess (docs/testing.md)
@pytest.mark.production_flags  # the depth-only program fuses the tail otherwise: at level 0 some depths move 1 ulp
@pytest.mark.parametrize("pipeline", ["rig", "sources"])
def test_depth_programs_equal_the_stages_programs_depth(pipeline, mixed_rig):
    """The depth-only programs (``rig_depth_program`` / ``sources_depth_program``: no other field written, none
    put onto the canvas), as ``complete_rig`` / ``complete_sources`` run them and with ``seen`` (``complete-rig``'s),
    against the ``Stages`` programs' ``depth`` bit for bit and their ``sparse_depth``'s pixel counts, on the
    two-size rig (the canvas) and the two-sweep sources with free space and occlusion."""
    from jaxdepth import complete_rig
    from jaxdepth._src.config import DEFAULT_CONFIG
    from jaxdepth._src.rig import rig_depth_program
    from jaxdepth._src.sources import complete_sources, default_beams, sources_depth_program
    points, valid, cams = mixed_rig
    cameras = stack_cameras(cams)
    if pipeline == "rig":
        want = complete_rig_stages(points, valid, cameras, lidar=LIDAR)
        got = complete_rig(points, valid, cameras, lidar=LIDAR)
        got_seen = rig_depth_program(points, valid, cameras, config=DEFAULT_CONFIG, lidar=LIDAR, seen=True)
    else:
        sources = _two_sweeps(points, valid, second_valid=valid)
        want = complete_sources_stages(sources, cameras)
        got = complete_sources(sources, cameras)
        got_seen = sources_depth_program(sources, cameras, config=DEFAULT_CONFIG, free_space=True,
                                         beams=default_beams(sources), seen=True)
    assert np.count_nonzero(np.asarray(want.depth)) > 1000
    assert np.asarray(got).tobytes() == np.asarray(want.depth).tobytes()
    assert np.asarray(got_seen[0]).tobytes() == np.asarray(want.depth).tobytes()
    np.testing.assert_array_equal(np.asarray(got_seen[1]), np.count_nonzero(np.asarray(want.sparse_depth), axis=(1, 2)))


@pytest.mark.slow  # the tail's program, op by op and vmapped (~15 s)
def test_one_source_tail_bracket_after_the_seed_index_equals_numpy():
    """The one-source rig's tail (three normal channels, ``whole_window``, the masks from the seed search's
    scalar): its bracket's input ordered after the seed search's own index buffer (nusc16) gives the plane
    depth clipped to the column bracket, against a composition of the public stages and the NumPy bracket;
    jit == eager, vmap == loop."""
    from helpers import numpy_column_hypotheses
    from jaxdepth import SGMConfig
    from jaxdepth._src.distance import gather_at_seed, nearest_seed
    from jaxdepth._src.pipeline import _complete_tail
    from jaxdepth._src.residual import plane_residual
    rng = np.random.default_rng(3)
    h, w, beams = 24, 40, 8
    config = SGMConfig(above_scan="plane")
    K = np.array([[30, 0, 19.5], [0, 30, 12], [0, 0, 1]], np.float32)
    T = np.eye(4, dtype=np.float32)
    inputs = []
    for _ in range(3):
        rows = np.zeros(h, bool)
        rows[rng.choice(h, h // 3, replace=False)] = True
        sparse = np.where(rows[:, None] & (rng.random((h, w)) < 0.6), rng.uniform(2, 40, (h, w)), 0.0)
        keep = (sparse > 0) & (rng.random((h, w)) < 0.9)
        normals = rng.normal(size=(3, h, w)).astype(np.float32)
        normals /= np.linalg.norm(normals, axis=0)
        inputs.append((sparse.astype(np.float32), keep, normals, K))

    def run(sparse, keep, normals, K):
        stages = _complete_tail(sparse, tuple(normals), None, K, T, beams=beams, config=config, keep=keep,
                                image_size=jnp.array([h, w], jnp.int32), keep_is_step2=True, whole_window=True)
        return stages.depth_raw

    def oracle(sparse, keep, normals, K):
        seeds = nearest_seed(jnp.asarray(keep))
        seed_depth = gather_at_seed(jnp.where(keep, sparse, 0.0), seeds.du, seeds.dv)
        residual = plane_residual(seed_depth, gather_at_seed(jnp.asarray(normals), seeds.du, seeds.dv), seeds.du,
                                  seeds.dv, K, min_abs_denom=config.min_abs_denom,
                                  max_residual_ratio=config.max_residual_ratio)
        plane = np.where(np.asarray(seed_depth) > 0, np.clip(np.asarray(seed_depth + residual), config.min_depth_m,
                                                              config.max_depth_m), 0.0)
        bracketed = numpy_column_hypotheses(plane, np.where(keep, sparse, 0.0), h // beams)
        clipped.append(np.mean(np.abs(bracketed - plane) > 1e-3))
        return bracketed.astype(np.float32)

    clipped = []
    # The bracket's neighbour depths are quantised to 256 m / 2**26 (< 4e-6 m at h = 24), the residual fused
    # otherwise than the oracle's (and op by op in the eager run): 4 ulps of 100 m (5e-5 m) at depths up to 60 m.
    check_stage(run, inputs, oracle=oracle, oracle_scale=100.0, scale=100.0)
    assert min(clipped) > 0.05, clipped      # the bracket moves the plane depth at a part of every input
