"""The XLA:CPU tuning switch (jaxdepth._src.xla_tuning): both paths give the same completion.

On CPU, ``complete``, ``complete_points`` and ``complete_rig`` are traced once with the tricks on
(stage fences, complex64 gathers, the scheduling dependence, shared loop bounds) and once plain;
the oracle is the other path. Small frames take every code path a KITTI frame takes (both branches
of the image-plane normals, the column window, vmap over cameras, guided seeds); one KITTI-size
run (slow) keeps the real density and candidate counts. The maths is the same, but XLA fuses the float stages differently
(a fence is a fusion boundary), which moves float32 rounding:

* bit for bit: the sparse depth, the inlier mask, the seeds (du, dv) and the seed depth;
* within float32 rounding: normals (measured <= 1.8e-7, 1.5 ulps of 1), the residual (<= 6e-6 m),
  ``depth_raw`` (the residual's 1e-5 m: 8e-6 m on the KITTI frame, 5 ulps of a near pixel on the
  thinned small frame) and ``depth`` (<= 2 ulps measured, 4 allowed);
* image-guided seeds: the geodesic distances round differently, so near-tie seeds flip (70 of
  466k pixels on the KITTI frame); checked as a share of pixels.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest

import jaxdepth
from jaxdepth._src import synthetic, xla_tuning
from jaxdepth._src.config import SGMConfig

from scenes import (GUIDED, POINTS_CONFIG, SMALL_LIDAR, small_camera, stereo_street, thinned_for_listed_normals,
                    tiny_frame)


def _both(run):
    """``run()`` traced with the tricks on, then plain (caches cleared between)."""
    out = {}
    for mode in ("cpu", "plain"):
        with xla_tuning.forced(mode):
            assert xla_tuning.enabled() == (mode == "cpu")
            out[mode] = {k: np.asarray(v) for k, v in run()._asdict().items() if v is not None}
    return out["cpu"], out["plain"]


EXACT = ("sparse_depth", "inlier_mask", "seed_depth", "du", "dv")


def _assert_same(tuned, plain):
    assert tuned.keys() == plain.keys()
    for name in EXACT:
        np.testing.assert_array_equal(tuned[name], plain[name], err_msg=name)
    np.testing.assert_allclose(tuned["normals"], plain["normals"], rtol=0, atol=2.5e-7, err_msg="normals")
    np.testing.assert_allclose(tuned["residual"], plain["residual"], rtol=0, atol=1e-5, err_msg="residual")
    # depth_raw is clip(seed_depth + residual) with seed_depth exact: it inherits the residual's bound plus
    # the sum's own rounding, one ulp of the result (on the thinned 96 x 160 frame 7.6e-6 m is 5 ulps of a
    # near pixel; on the KITTI frame one ulp of a 95.8 m pixel is 7.6e-6 m); depth keeps <= 4 ulps
    bound = 1e-5 + np.spacing(np.abs(plain["depth_raw"]))
    worst = np.abs(tuned["depth_raw"].astype(np.float64) - plain["depth_raw"]) - bound
    assert worst.max() <= 0, ("depth_raw", worst.max(), np.unravel_index(worst.argmax(), worst.shape))
    np.testing.assert_array_max_ulp(tuned["depth"], plain["depth"], maxulp=4)


def _assert_same_but_near_ties(tuned, plain, *, share: float):
    """Guided: seeds may differ at near ties; elsewhere the unguided tolerances hold."""
    for name in EXACT[:2]:
        np.testing.assert_array_equal(tuned[name], plain[name], err_msg=name)
    flipped = (tuned["du"] != plain["du"]) | (tuned["dv"] != plain["dv"])
    assert flipped.mean() < share, flipped.mean()
    differs = np.abs(tuned["depth"].astype(np.float64) - plain["depth"]) > 1e-4
    assert differs.mean() < 10 * share, differs.mean()


def test_mode_comes_from_the_environment_and_set_mode(monkeypatch):
    monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "plain")
    assert xla_tuning.mode() == "plain" and not xla_tuning.enabled()
    monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "auto")
    import jax
    assert xla_tuning.enabled() == (jax.default_backend() == "cpu")
    with xla_tuning.forced("cpu"):
        monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "plain")
        assert xla_tuning.enabled()  # set_mode wins over the environment
    assert not xla_tuning.enabled()
    monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "fast")
    with pytest.raises(ValueError, match="JAXDEPTH_XLA_TUNING"):
        xla_tuning.mode()
    with pytest.raises(ValueError, match="'value'"):
        xla_tuning.set_mode("fast")


def test_helpers_reduce_to_the_plain_computation():
    import jax
    import jax.numpy as jnp
    a, b = jnp.arange(6.0), -jnp.arange(6.0)
    index = jnp.array([5, 0, 2])
    for mode in ("cpu", "plain"):
        with xla_tuning.forced(mode):
            packed = xla_tuning.pack_pair(a, b)
            assert isinstance(packed, tuple) == (mode == "plain")
            got = xla_tuning.take_pair(packed, index)
            np.testing.assert_array_equal(got[0], a[index])
            np.testing.assert_array_equal(got[1], b[index])
            np.testing.assert_array_equal(xla_tuning.after(a, jnp.int32([7])), a)
            first, stop = xla_tuning.shared_loop_bounds(jnp.int32(2), jnp.int32(5))
            assert (int(first), int(stop)) == (2, 5)
            for mask in (jnp.zeros((3, 40), bool), jnp.zeros((3, 40), bool).at[2, 39].set(True), jnp.ones(5, bool),
                         jnp.zeros((0,), bool)):
                assert bool(xla_tuning.any_true(mask)) == bool(np.any(np.asarray(mask)))
            rng = np.random.default_rng(3)     # first True row per column (H where none) and count: NumPy's
            mask, valid = rng.random((2, 3, 37, 29)) < np.array([0.05, 0.3])[:, None, None, None]
            mask[0] = False
            first, count = jax.vmap(xla_tuning.first_row_and_count)(jnp.asarray(mask), jnp.asarray(valid))
            np.testing.assert_array_equal(first, np.where(mask.any(1), mask.argmax(1), 37))
            np.testing.assert_array_equal(count, valid.sum((1, 2)))
            values, at = rng.random((4, 3, 35)).astype(np.float32), rng.integers(0, 35, (4, 5, 7))
            for v_axis in (0, None):        # values[..., index] under vmap: NumPy's indexing, member by member
                got = jax.vmap(xla_tuning.take_last, in_axes=(v_axis, 0))(values if v_axis == 0 else values[0], at)
                want = np.stack([(values[b] if v_axis == 0 else values[0])[:, at[b]] for b in range(4)])
                np.testing.assert_array_equal(got, want)
            np.testing.assert_array_equal(xla_tuning.take_last(values[1], at[2]), values[1][:, at[2]])
            # tuned: a gather from the flattened batch, no batching dimension (which XLA:CPU expands to pairs)
            jaxpr = str(jax.make_jaxpr(jax.vmap(xla_tuning.take_last))(values, at))
            assert ("operand_batching_dims=(0,)" in jaxpr) == (mode == "plain"), jaxpr
            # tuned: the indices (all in bounds) are not wrapped, no compare with 0 before the gather
            single = str(jax.make_jaxpr(xla_tuning.take_last)(values[1], at[2]))
            assert (" lt " in jaxpr, " lt " in single) == ((mode == "plain"),) * 2, (jaxpr, single)
            buf, rows, i = rng.integers(-9, 9, (4, 6, 5)), rng.integers(-9, 9, (4, 5)), jnp.int32(4)
            for (b_axis, r_axis), wrap in itertools.product(((0, 0), (0, None), (None, 0)), (False, True)):
                # row i replaced, member by member: NumPy's (wrap: the single-camera form's index wrap, the same rows)
                got = jax.vmap(functools.partial(xla_tuning.put_row, wrap=wrap), in_axes=(b_axis, r_axis, None))(
                    buf if b_axis == 0 else buf[0], rows if r_axis == 0 else rows[0], i)
                want = np.stack([buf[b if b_axis == 0 else 0] for b in range(4)])
                want[:, 4] = rows if r_axis == 0 else rows[0]
                np.testing.assert_array_equal(got, want)
            for wrap in (False, True):      # unbatched: NumPy's
                want = buf[0].copy()
                want[4] = rows[0]
                np.testing.assert_array_equal(xla_tuning.put_row(buf[0], rows[0], i, wrap=wrap), want)
            got = jax.jit(jax.vmap(xla_tuning.put_row))(buf, rows, jnp.int32([0, 5, 2, 1]))   # a row per member
            np.testing.assert_array_equal(got, [np.vstack([b[:k], r[None], b[k + 1:]]) for b, r, k in
                                                zip(buf, rows, [0, 5, 2, 1])])
            # tuned: one dynamic_update_slice of the batch, no scatter (which XLA:CPU guards by a select)
            jaxpr = str(jax.make_jaxpr(jax.vmap(xla_tuning.put_row, in_axes=(0, 0, None)))(buf, rows, i))
            assert ("scatter" in jaxpr) == (mode == "plain"), jaxpr
            for w in (1, 31, 32, 33, 67):    # a mask's columns (tuned: 32 to a uint32): NumPy's column u, member by member
                masks = rng.random((2, 5, w)) < 0.4
                columns = jax.vmap(xla_tuning.mask_columns)(jnp.asarray(masks))
                assert columns.shape == ((2, w, 5) if mode == "plain" else (2, -(-w // 32), 5))
                for u in range(w):
                    got = jax.vmap(xla_tuning.mask_column, in_axes=(0, None))(columns, jnp.int32(u))
                    np.testing.assert_array_equal(got, masks[:, :, u])
                np.testing.assert_array_equal(xla_tuning.mask_column(xla_tuning.mask_columns(jnp.asarray(masks[1])),
                                                                     w - 1), masks[1, :, w - 1])  # an int (eager loops)
            # the row keys' rows (tuned: two int16 rows a word on images of >= 2**20 pixels with an even height):
            # NumPy's row v, widened, member by member and for an int (eager loops)
            for h, dtype, big in ((8, jnp.int16, True), (7, jnp.int16, True), (8, jnp.int32, True), (8, jnp.int16, False)):
                keys_t = rng.integers(0, 2**15 if dtype == jnp.int16 else 2**31, (3, 5, h)).astype(dtype)
                cut = 1 if big else 2**20
                with pytest.MonkeyPatch.context() as patch:
                    patch.setattr(xla_tuning, "_PAIRED_MIN_PIXELS", cut)
                    rows = jax.vmap(xla_tuning.key_rows)(jnp.asarray(keys_t))
                    paired = mode == "cpu" and big and h % 2 == 0 and dtype == jnp.int16
                    assert rows.shape == ((3, h // 2, 5) if paired else (3, h, 5))
                    assert rows.dtype == (jnp.int32 if paired else dtype)
                    for v in range(h):
                        got = jax.vmap(functools.partial(xla_tuning.key_row, h=h), in_axes=(0, None))(rows, jnp.int32(v))
                        assert got.dtype == jnp.int32
                        np.testing.assert_array_equal(got, keys_t[:, :, v])
                        np.testing.assert_array_equal(xla_tuning.key_row(rows[2], v, h), keys_t[2, :, v])
            big = jax.eval_shape(xla_tuning.key_rows, jax.ShapeDtypeStruct((2048, 1550), jnp.int16))
            assert (big.shape, big.dtype) == (((775, 2048), jnp.int32) if mode == "cpu" else ((1550, 2048), jnp.int16))
            kitti = jax.eval_shape(xla_tuning.key_rows, jax.ShapeDtypeStruct((1216, 352), jnp.int16))
            assert (kitti.shape, kitti.dtype) == ((352, 1216), jnp.int16)    # the KITTI frame keeps its int16 rows


def test_small_matmul_is_the_dots_bits_and_scatter_onto_fill_the_scatter():
    """``small_matmul`` == ``jnp.matmul`` bit for bit at this process's flags in both modes (3-vectors of
    mixed scales, one and two groups, vmapped as the sources' frames use it); ``scatter_onto_fill`` ==
    the fill-then-scatter it replaces (dropped slots past the canvas), vmapped too."""
    import jax
    import jax.numpy as jnp
    rng = np.random.default_rng(11)
    for g, p in ((1, 300), (2, 4099)):
        lhs = (rng.standard_normal((g, p, 3)) * rng.choice([1e-3, 1.0, 40.0], (g, p, 1))).astype(np.float32)
        rhs = rng.standard_normal((g, 3, 3)).astype(np.float32)
        want = np.asarray(jax.jit(jnp.matmul)(lhs, rhs))
        slot = rng.integers(0, 60, p).astype(np.int32)        # 50.. past a 50-slot canvas: dropped
        vals = rng.standard_normal((g, p)).astype(np.float32)
        want_img = jax.jit(jax.vmap(lambda v: jnp.full((50,), -2.0).at[slot].set(v, mode="drop")))(vals)
        for mode in ("cpu", "plain"):
            with xla_tuning.forced(mode):
                got = jax.jit(xla_tuning.small_matmul)(lhs, rhs)
                np.testing.assert_array_equal(np.asarray(got).view(np.int32), want.view(np.int32))
                got = jax.jit(jax.vmap(xla_tuning.small_matmul))(lhs, rhs)
                np.testing.assert_array_equal(np.asarray(got).view(np.int32), want.view(np.int32))
                img = jax.jit(jax.vmap(lambda v: xla_tuning.scatter_onto_fill(50, -2.0, slot, v)))(vals)
                np.testing.assert_array_equal(img, want_img)


def test_stage_token_is_the_first_values_bits_and_the_only_one_written():
    """stage_token: the int32 bits of the first value as float32 (NumPy's view; NaN, infinities, -0.0,
    subnormals and other dtypes too), jit == eager, vmap == loop, a fence token in both modes; and no module
    of jaxdepth writes the token out by hand (the stages' fences share one expression, so one predicate)."""
    import pathlib
    import re

    import jax
    import jax.numpy as jnp
    firsts = [np.nan, np.inf, -np.inf, -0.0, 1e-45, -3.5, 95.8, 0.0]
    for first in firsts:
        x = np.full((3, 5), 7.25, np.float32)
        x[0, 0] = first
        want = int(x.reshape(-1)[:1].view(np.int32)[0])
        assert int(xla_tuning.stage_token(x)) == want
        assert int(jax.jit(xla_tuning.stage_token)(x)) == want
        assert int(xla_tuning.stage_token(x[None])) == want and int(xla_tuning.stage_token(x[0])) == want
    stack = np.random.default_rng(0).uniform(-5, 5, (len(firsts), 4, 6)).astype(np.float32)
    stack[:, 0, 0] = firsts
    np.testing.assert_array_equal(jax.vmap(xla_tuning.stage_token)(stack),
                                  [int(xla_tuning.stage_token(s)) for s in stack])
    for other in (np.float64(2.5), np.int32(3), np.float16(-1.5)):       # converted to float32 first
        assert int(xla_tuning.stage_token(np.asarray([other]))) == int(np.float32(other).view(np.int32))
    for mode in ("cpu", "plain"):
        with xla_tuning.forced(mode):
            x = jnp.asarray(stack[0])
            out = xla_tuning.stage(lambda a: (a * 2.0,), (x,), xla_tuning.stage_token(x))[0]
            np.testing.assert_array_equal(out, stack[0] * 2.0)
    package = pathlib.Path(jaxdepth.__file__).parent
    by_hand = re.compile(r"bitcast_convert_type\(\s*(jnp\.ravel\([^)]*\)\[0\]|\w+\[0, 0\])")
    written = [str(f.relative_to(package)) for f in package.rglob("*.py")
               if f.name != "xla_tuning.py" and by_hand.search(f.read_text())]
    assert written == []


def test_entry_jit_compiles_with_the_options_at_the_top_level_only():
    """entry_jit: a top-level call compiles with COMPILER_OPTIONS (fewer copies in an in-place loop than
    the plain jit's program); JAX rejects the options on a nested jit, so a call inside jit / vmap takes
    the plain jit (also nested with constant arguments only); every way returns the plain jit's bytes."""
    import jax
    import jax.numpy as jnp

    def sweep(x, *, scale: int):    # an in-place loop: what the options' copy insertion is about
        body = lambda i, b: b.at[i].set(jnp.minimum(b[i], b[i - 1] + scale))
        return jax.lax.fori_loop(1, x.shape[0], body, x)

    fn = xla_tuning.entry_jit(sweep, static_argnames=("scale",))
    plain = jax.jit(sweep, static_argnames=("scale",))
    nested = jax.jit(sweep, static_argnames=("scale",), compiler_options=xla_tuning.COMPILER_OPTIONS)
    with pytest.raises(ValueError, match="compiler_options"):      # why the nested path exists
        jax.jit(lambda y: nested(y, scale=2))(jnp.zeros(3))
    x = jnp.asarray(np.random.default_rng(0).integers(0, 50, (40, 7)), jnp.int32)
    copies = lambda f: f.lower(x, scale=2).compile().as_text().count(" copy(")
    assert copies(fn) < copies(plain)
    want = np.asarray(plain(x, scale=2))
    np.testing.assert_array_equal(want[1:], np.minimum(want[1:], want[:-1] + 2))   # the recurrence holds
    for got in (fn(x, scale=2), jax.jit(lambda y: fn(y, scale=2))(x), jax.vmap(lambda y: fn(y, scale=2))(x[None])[0],
                jax.jit(lambda: fn(np.asarray(x), scale=2))()):       # nested, a constant argument
        np.testing.assert_array_equal(np.asarray(got), want)
    fn.clear_cache()


@pytest.mark.parametrize("config, rig", [(POINTS_CONFIG, False), (SGMConfig(distance_metric="l2", blend_hypotheses=True), True)],
                         ids=["default-points", "l2_blend-rig"])
@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_complete_points_and_rig_agree_on_the_synthetic_scene(config, rig):
    """complete_points (range image, point normals) with the default options (POINTS_CONFIG: the output
    clip at 60 m) on the street through the 96 x 160 camera (tuned: test_pipeline's planar program),
    and complete_rig (the points pipeline under vmap over cameras: batched stage tokens, shared loop
    bounds, the widest outlier window) with the l2 seeds and blended hypotheses, on the small stereo
    street."""
    if rig:
        frame, cams = stereo_street()
        run = lambda: jaxdepth.complete_rig_stages(frame.points, frame.valid, jaxdepth.stack_cameras(cams),
                                                   config=config, lidar=SMALL_LIDAR)
    else:
        frame = synthetic.make_street_scene(1, lidar=SMALL_LIDAR, cameras=[small_camera()])
        run = lambda: jaxdepth.complete_points_stages(frame.points, frame.valid, frame.cameras[0], config=config,
                                                      lidar=SMALL_LIDAR)
    _assert_same(*_both(run))


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_complete_agrees_on_small_frames_both_normal_branches_and_guided():
    """complete (image-plane normals from a sparse depth image), unguided on both branches of the
    image-plane normals, and image-guided (geodesic seeds: near ties may flip, as on KITTI). The
    32 x 48 street frame of the stage table (tuned: its programs) as projected (more points than the
    image-plane normals' n_pix / 16 slots: the dense branch) and thinned to about 1 point in 16 (their
    listed branch, the one a KITTI frame takes: compacted pixels on a window of range-image columns);
    guided with test_geodesic's configuration and the camera's uint8 rendering (its program)."""
    sparse, K, T, image = tiny_frame(0, images=True)
    thin = thinned_for_listed_normals(sparse, keep=1 / 16, min_points=20)
    for depth in (sparse, thin):
        _assert_same(*_both(lambda: jaxdepth.complete_stages(depth, K, T, lidar=SMALL_LIDAR)))
    _assert_same_but_near_ties(*_both(lambda: jaxdepth.complete_stages(
        thin, K, T, image=image, config=GUIDED, lidar=SMALL_LIDAR)), share=5e-3)


@pytest.mark.slow
@pytest.mark.shared_data
def test_complete_agrees_on_the_kitti_frame(kitti):
    """The one KITTI-size run: a real frame's density, window and outlier candidate counts (many
    chunks of the exact test, wide outlier windows). The benchmark crop (the tuned program is
    test_pipeline's and test_speed_equivalence's)."""
    sparse, K, T = kitti.sparse[2], kitti.K[2], kitti.T_cam_lidar[2]
    _assert_same(*_both(lambda: jaxdepth.complete_stages(sparse, K, T)))
