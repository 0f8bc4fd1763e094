"""Step 2's exact test once for several size groups (``outlier_groups.exact_test_groups``) against each group's
own ``_keep_mask`` (the per-group form, vmapped as the rigs run it), bit for bit, and jit == eager."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth._src import compaction, outliers
from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.outlier_groups import exact_test_groups, shared_windows
from jaxdepth._src.rig import size_groups, stack_cameras
from jaxdepth._src.above_scan import resolved_config
from jaxdepth._src.sources import default_beams, make_sources, sources_program
from jaxdepth._src import synthetic

from scenes import SMALL_LIDAR, lidar_to_camera, small_camera


def _camera(rng, h, w, n_sources):
    """A sparse depth image with near and far layers (occlusions), its points, each pixel's source, K, origins."""
    K = np.array([[0.8 * w, 0.0, w / 2], [0.0, 0.8 * w, h / 2], [0, 0, 1]], np.float32)
    depth = np.where(rng.random((h, w)) < 0.25, rng.uniform(2.0, 30.0, (h, w)), 0.0).astype(np.float32)
    depth[h // 3:h // 2, w // 4:w // 2] = np.where(depth[h // 3:h // 2, w // 4:w // 2] > 0, 1.5, 0.0)
    v, u = np.mgrid[:h, :w].astype(np.float32) + rng.uniform(-0.4, 0.4, (2, h, w)).astype(np.float32)
    points = tuple(np.where(depth > 0, c, 0.0).astype(np.float32)
                   for c in ((u - K[0, 2]) * depth / K[0, 0], (v - K[1, 2]) * depth / K[1, 1], depth))
    source = rng.integers(0, n_sources, (h, w)).astype(np.int32)
    origins = rng.uniform(-0.6, 0.6, (n_sources, 3)).astype(np.float32)
    return depth, points, source, K, origins


def _group(rng, n, h, w, n_sources=2):
    cams = [_camera(rng, h, w, n_sources) for _ in range(n)]
    return tuple(jnp.asarray(np.stack(x)) if not isinstance(x[0], tuple) else
                 tuple(jnp.asarray(np.stack(c)) for c in zip(*x)) for x in zip(*cams))


def _group_masks(groups, sizes, *, beams, shared, test):
    """The masks of every group: one loop for all groups (``shared``) or each group's own ``_keep_mask``."""
    windows = dict(shared_windows(sizes, beams=beams, config=DEFAULT_CONFIG), test=test)

    def one(depth, points, source, K, origins, size):
        return outliers._keep_mask(depth, K, jnp.eye(4, dtype=jnp.float32), points, jnp.float32(1.0), beams=beams,
                                   half_width=windows["hw"], half_height=windows["hh"], test=test, origins=origins,
                                   image_size=size, pixel_source=source, defer=shared)

    out = []
    for (depth, points, source, K, origins), (h, w) in zip(groups, sizes):
        size = jnp.broadcast_to(jnp.asarray([h, w], jnp.int32), (depth.shape[0], 2))
        out.append(jax.vmap(one)(depth, points, source, K, origins, size))
    return exact_test_groups(tuple(out), sizes, **windows) if shared else out


def _masks(groups, sizes, *, beams, shared, test="footprint"):
    """:func:`_group_masks` in one jit (one compile, not one per primitive); under disable_jit: op by op."""
    return [np.asarray(m) for m in jax.jit(lambda g: _group_masks(g, sizes, beams=beams, shared=shared,
                                                                   test=test))(groups)]


@pytest.mark.parametrize("sizes, beams", [(((96, 128), (128, 96)), 2),    # tall windows: words down the columns
                                          (((64, 72), (60, 80)), 8)])     # short windows: words along the rows
def test_one_loop_for_all_groups_equals_each_groups_own(sizes, beams):
    # both condition-1 tests, the one loop and each group's own, in one program (one compile, where four
    # programs took 2.4 s of CPU each; one of them 7 s): the same masks as four jits (checked)
    rng = np.random.default_rng(7)
    groups = [_group(rng, n, h, w) for n, (h, w) in zip((3, 1), sizes)]
    every = jax.jit(lambda g: {(test, shared): _group_masks(g, sizes, beams=beams, shared=shared, test=test)
                               for test in ("footprint", "paper") for shared in (False, True)})(groups)
    for test in ("footprint", "paper"):
        want, got = ([np.asarray(m) for m in every[test, shared]] for shared in (False, True))
        for g, (a, b) in enumerate(zip(got, want)):
            assert a.shape == b.shape
            np.testing.assert_array_equal(a, b, err_msg=f"{test} group {g}")
        assert sum(int((~b & (np.asarray(groups[g][0]) > 0)).sum()) for g, b in enumerate(want)) > 0, test  # removed


@pytest.mark.slow  # op by op (~12 s CPU); the quick equality tests above run the same loop jitted
def test_one_loop_jit_equals_eager():
    sizes = ((96, 128), (128, 96))
    rng = np.random.default_rng(3)
    groups = [_group(rng, n, h, w) for n, (h, w) in zip((2, 1), sizes)]
    fast = _masks(groups, sizes, beams=2, shared=True)
    with jax.disable_jit():
        eager = _masks(groups, sizes, beams=2, shared=True)
    for a, b in zip(fast, eager):
        np.testing.assert_array_equal(a, b)


def test_shared_windows_only_where_every_group_agrees():
    assert shared_windows(((96, 128), (128, 96)), beams=2, config=DEFAULT_CONFIG)["down"]
    assert not shared_windows(((64, 72), (60, 80)), beams=8, config=DEFAULT_CONFIG)["down"]
    assert shared_windows(((96, 128),), beams=2, config=DEFAULT_CONFIG) is None           # one group
    assert shared_windows(((40, 24), (24, 40)), beams=8, config=DEFAULT_CONFIG) is None    # hh 4 against 2


@pytest.mark.slow  # two whole several-sources programs (grouped by size, and every camera on one canvas)
def test_sources_rig_of_two_sizes_with_one_loop_equals_one_canvas():
    # 40 x 48 and 48 x 40 cameras under a 32-beam LiDAR: the same window (|dv| <= 1, |du| <= 12), so the grouped
    # program runs one exact-test loop for all three cameras (rig.keep_by_size); on one 48 x 48 canvas (sizes
    # unknown) one group, each camera its own bounds: every field equal in each camera's window.
    cams = [small_camera(h=40, w=48, f=30.0), small_camera(lidar_to_camera((0.2, 0.0, 0.5)), h=48, w=40, f=30.0),
            small_camera(lidar_to_camera((-0.5, 0.1, 0.2)), h=40, w=48, f=34.0)]
    frame = synthetic.make_street_scene(3, lidar=SMALL_LIDAR, cameras=cams)
    sources = make_sources(np.asarray(frame.points)[None], np.asarray(frame.valid)[None],
                           np.eye(4, dtype=np.float32)[None], lidars=(SMALL_LIDAR,))
    cameras = stack_cameras(cams)
    sizes = tuple(size for size, _ in size_groups(cameras))
    assert shared_windows(sizes, beams=SMALL_LIDAR.beams, config=DEFAULT_CONFIG) is not None
    # sources_program itself: complete_sources_stages runs complete_rig's program for one source at the origin
    def several_sources(cams_):
        return sources_program(sources, cams_, None, config=resolved_config(DEFAULT_CONFIG, sources), free_space=True,
                               beams=default_beams(sources), occlusion=True)
    grouped = several_sources(cameras)
    one_canvas = several_sources(dataclasses.replace(cameras, sizes=None))
    assert int((np.asarray(grouped.sparse_depth) > 0).sum() - np.asarray(grouped.inlier_mask).sum()) > 0  # removed
    for name in grouped._fields:
        for i, cam in enumerate(cams):
            window = (Ellipsis, slice(cam.height), slice(cam.width))
            np.testing.assert_array_equal(np.asarray(getattr(grouped, name)[i])[window],
                                          np.asarray(getattr(one_canvas, name)[i])[window], err_msg=f"{i} {name}")


def test_word_locator_in_runs_past_float32_exact_range_equals_brute_force():
    # 4 runs of 140,000 words: 17.9 M bits, past float32's exact 2^24, so the prefix sums run per run (runs=4).
    rng = np.random.default_rng(5)
    words = np.where(rng.random(4 * 140_000) < 0.01, rng.integers(1, 2 ** 32, 4 * 140_000, dtype=np.uint64), 0)
    words = words.astype(np.uint32)
    bits = np.flatnonzero(np.unpackbits(words.view(np.uint8), bitorder="little"))
    slots = np.concatenate([[0, len(bits) - 1], rng.integers(0, len(bits), 2000)]).astype(np.int32)
    count, located = jax.jit(lambda w, s: (lambda c, f: (c, f(s)))(*compaction.word_locator(w, runs=4)))(
        jnp.asarray(words), jnp.asarray(slots))
    assert int(count) == len(bits)
    np.testing.assert_array_equal(np.asarray(located), bits[slots])
