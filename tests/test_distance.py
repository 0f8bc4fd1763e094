"""Tests for jaxdepth._src.distance (step 3: nearest-seed distance transform).

Oracles: OpenCV's exact L1 distance transform, SciPy's exact Euclidean one
(both on ``~mask``, since they measure the distance to zero pixels), a
brute-force NumPy nearest seed with the documented raster-order tie rule, and
NumPy fancy indexing for gather_at_seed.  jit == eager, vmap == loop and no
retrace through tests/_harness.py.
"""

from __future__ import annotations

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.ndimage as ndi
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from jaxdepth._src.distance import NearestSeed, gather_at_seed, nearest_seed


METRICS = ("l1", "l2")
# One worker for the module: its tests share each (shape, metric) program (across two workers, two tests of
# one program once compiled it at the same time; docs/testing.md, "Compiled programs").
pytestmark = pytest.mark.xdist_group("distance")
EPS = float(np.finfo(np.float32).eps)


def _random_mask(shape, density, seed):
    return np.random.default_rng(seed).random(shape) < density


def _oracle_distance(mask: np.ndarray, metric: str) -> np.ndarray:
    if metric == "l1":
        return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L1, 3)
    return ndi.distance_transform_edt(~mask).astype(np.float32)


def _brute_force(mask: np.ndarray, metric: str):
    """Nearest seed by exhaustive search; ties: smallest seed row, then column. Every pixel against every seed,
    a block of pixel rows at a time in int32 (a full 130 x 67 mask: 76 M pairs; one int64 array of them took
    seconds of page faults)."""
    h, w = mask.shape
    sv, su = (a.astype(np.int32) for a in np.nonzero(mask))  # raster order: row-major
    bdv, bdu, d = (np.zeros((h, w), np.int32) for _ in range(3))
    rows = max(1, (1 << 20) // max(1, w * sv.size))
    for r0 in range(0, h, rows):
        v, u = np.indices((min(rows, h - r0), w), np.int32)
        dv = sv[None, None, :] - (v + r0)[..., None]
        du = su[None, None, :] - u[..., None]
        d2 = np.abs(dv) + np.abs(du) if metric == "l1" else dv * dv + du * du
        best = np.argmin(d2, axis=-1)[..., None]  # first minimum = raster-order tie rule
        for out, a in ((bdv, dv), (bdu, du), (d, d2)):
            out[r0:r0 + rows] = np.take_along_axis(a, best, -1)[..., 0]
    dist = d.astype(np.float64) if metric == "l1" else np.sqrt(d.astype(np.float64))
    return dist.astype(np.float32), bdu, bdv


def _check_result(res: NearestSeed, mask: np.ndarray, metric: str) -> None:
    """Distances equal the oracle and (v + dv, u + du) is a seed at that distance."""
    h, w = mask.shape
    for name in ("distance", "du", "dv"):
        assert getattr(res, name).shape == (h, w), name
    assert res.distance.dtype == jnp.float32
    assert res.du.dtype == jnp.int32 and res.dv.dtype == jnp.int32
    assert res.has_seed.shape == () and res.has_seed.dtype == jnp.bool_
    dist = np.asarray(res.distance)
    du = np.asarray(res.du)
    dv = np.asarray(res.dv)
    if not mask.any():
        assert not bool(res.has_seed)
        assert np.all(np.isposinf(dist))
        assert np.all(du == 0) and np.all(dv == 0)
        return
    assert bool(res.has_seed)
    assert not np.isnan(dist).any()
    ref = _oracle_distance(mask, metric)
    if metric == "l1":
        np.testing.assert_array_equal(dist, ref)
    else:
        np.testing.assert_allclose(dist, ref, rtol=4 * EPS, atol=0)
    v, u = np.indices((h, w))
    tv, tu = v + dv, u + du
    assert tv.min() >= 0 and tv.max() < h and tu.min() >= 0 and tu.max() < w
    assert mask[tv, tu].all(), "the returned seed is not a seed"
    if metric == "l1":
        np.testing.assert_array_equal(dist, (np.abs(du) + np.abs(dv)).astype(np.float32))
    else:
        exact = np.sqrt((du.astype(np.float64) ** 2 + dv.astype(np.float64) ** 2))
        np.testing.assert_allclose(dist, exact.astype(np.float32), rtol=EPS, atol=0)


# Few distinct shapes: every (shape, metric) pair compiles once and is reused across tests
# ((16, 21): the stage table's nearest_seed rows).
SHAPES = [(1, 1), (1, 17), (23, 1), (7, 9), (16, 21), (131, 67)]
DENSITIES = [0.0, 0.005, 0.04, 0.3, 1.0]


@pytest.mark.parametrize("metric", METRICS)
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("density", DENSITIES)
def test_matches_oracle(metric, shape, density):
    mask = _random_mask(shape, density, seed=hash((shape, density)) % 2**32)
    _check_result(nearest_seed(jnp.asarray(mask), metric=metric), mask, metric)


@pytest.mark.parametrize("metric", METRICS)
def test_kitti_sized_lidar_density(metric):
    """~4 % random seeds on the KITTI crop size (352 x 1216)."""
    mask = _random_mask((352, 1216), 0.04, seed=7)
    _check_result(nearest_seed(jnp.asarray(mask), metric=metric), mask, metric)


@pytest.mark.parametrize("metric", METRICS)
def test_kitti_velodyne_mask(metric, kitti):
    """The real KITTI sparse input: seeds only in the lower rows, long gaps above."""
    mask = kitti.sparse[2] > 0
    _check_result(nearest_seed(jnp.asarray(mask), metric=metric), mask, metric)


@pytest.mark.parametrize("metric", METRICS)
def test_empty_full_single(metric):
    empty = np.zeros((7, 9), bool)
    res = nearest_seed(jnp.asarray(empty), metric=metric)
    _check_result(res, empty, metric)

    full = np.ones((7, 9), bool)
    res = nearest_seed(jnp.asarray(full), metric=metric)
    assert np.all(np.asarray(res.distance) == 0)
    assert np.all(np.asarray(res.du) == 0) and np.all(np.asarray(res.dv) == 0)

    single = np.zeros((7, 9), bool)
    single[4, 2] = True
    res = nearest_seed(jnp.asarray(single), metric=metric)
    v, u = np.indices(single.shape)
    np.testing.assert_array_equal(np.asarray(res.du), 2 - u)
    np.testing.assert_array_equal(np.asarray(res.dv), 4 - v)
    d2 = (2 - u) ** 2 + (4 - v) ** 2
    expected = np.abs(2 - u) + np.abs(4 - v) if metric == "l1" else np.sqrt(d2)
    np.testing.assert_allclose(np.asarray(res.distance), expected.astype(np.float32), rtol=EPS)


@pytest.mark.parametrize("metric", METRICS)
@pytest.mark.parametrize("shape,density,seed", [((7, 9), 0.1, 0), ((7, 9), 0.3, 1),
                                                ((1, 17), 0.1, 2), ((23, 1), 0.1, 3),
                                                ((16, 21), 0.03, 4)])
def test_tie_rule_against_brute_force(metric, shape, density, seed):
    """Exact labels: the first nearest seed in raster order (row, then column)."""
    mask = _random_mask(shape, density, seed)
    mask[seed % shape[0], (3 * seed) % shape[1]] = True
    res = nearest_seed(jnp.asarray(mask), metric=metric)
    dist, du, dv = _brute_force(mask, metric)
    np.testing.assert_allclose(np.asarray(res.distance), dist, rtol=EPS, atol=0)
    np.testing.assert_array_equal(np.asarray(res.du), du)
    np.testing.assert_array_equal(np.asarray(res.dv), dv)


@pytest.mark.parametrize("metric", METRICS)
def test_tie_rule_symmetric_seeds(metric):
    """Two seeds at equal distance left/right and above/below: the upper, then left one."""
    mask = np.zeros((7, 9), bool)
    mask[2, 1] = mask[2, 5] = True  # pixel (2, 3) is 2 px from both
    res = nearest_seed(jnp.asarray(mask), metric=metric)
    assert (int(res.du[2, 3]), int(res.dv[2, 3])) == (-2, 0)
    mask = np.zeros((7, 9), bool)
    mask[1, 2] = mask[5, 2] = True  # pixel (3, 2) is 2 px from both
    res = nearest_seed(jnp.asarray(mask), metric=metric)
    assert (int(res.du[3, 2]), int(res.dv[3, 2])) == (0, -2)


@pytest.mark.parametrize("cost,shape,density,seed", [(2, (7, 9), 0.1, 5), (3, (16, 21), 0.03, 6),
                                                      (3, (23, 1), 0.1, 7), (4, (1, 17), 0.1, 8)])
def test_horizontal_cost_against_brute_force(cost, shape, density, seed):
    """``horizontal_cost`` c: the seed minimising c |du| + |dv|, ties in raster order (exhaustive NumPy search)."""
    mask = _random_mask(shape, density, seed)
    mask[seed % shape[0], (3 * seed) % shape[1]] = True
    res = nearest_seed(jnp.asarray(mask), metric="l1", horizontal_cost=cost)
    sv, su = np.nonzero(mask)
    v, u = np.indices(shape)
    dv, du = sv[None, None, :] - v[..., None], su[None, None, :] - u[..., None]
    weighted = cost * np.abs(du) + np.abs(dv)
    best = np.argmin(weighted, axis=-1)[..., None]
    np.testing.assert_array_equal(np.asarray(res.distance), np.take_along_axis(weighted, best, -1)[..., 0])
    np.testing.assert_array_equal(np.asarray(res.du), np.take_along_axis(du, best, -1)[..., 0])
    np.testing.assert_array_equal(np.asarray(res.dv), np.take_along_axis(dv, best, -1)[..., 0])
    with pytest.raises(ValueError, match=r"'horizontal_cost' expected an integer >= 1"):
        nearest_seed(jnp.asarray(mask), metric="l2", horizontal_cost=cost)


def _oracle_or_inf(mask, *, metric):
    """The OpenCV / SciPy distance; +inf everywhere without seeds (they return large finite values)."""
    mask = np.asarray(mask)
    return _oracle_distance(mask, metric) if mask.any() else np.full(mask.shape, np.inf, np.float32)


# OpenCV / SciPy oracle, jit == eager, vmap == loop, no retrace: rows nearest_seed-l1 / -l2 of tests/stage_table.py.


# Small shapes, the tests' above: no new programs.
_HYP_SHAPES = [(1, 1), (1, 17), (23, 1), (7, 9)]


@settings(deadline=None, max_examples=30)
@given(data=st.data(), metric=st.sampled_from(METRICS))
def test_property_matches_brute_force(data, metric):
    shape = data.draw(st.sampled_from(_HYP_SHAPES))
    mask = data.draw(hnp.arrays(np.bool_, shape))
    res = nearest_seed(jnp.asarray(mask), metric=metric)
    _check_result(res, mask, metric)
    if mask.any():
        dist, du, dv = _brute_force(mask, metric)
        np.testing.assert_allclose(np.asarray(res.distance), dist, rtol=EPS, atol=0)
        np.testing.assert_array_equal(np.asarray(res.du), du)
        np.testing.assert_array_equal(np.asarray(res.dv), dv)


def test_validation_errors():
    with pytest.raises(ValueError, match=r"field 'metric' expected one of \('l1', 'l2'\), got 'linf'"):
        nearest_seed(jnp.zeros((3, 3), bool), metric="linf")
    with pytest.raises(ValueError, match=r"'seed_mask' expected shape \(H, W\), got shape \(3,\)"):
        nearest_seed(jnp.zeros((3,), bool))
    with pytest.raises(ValueError, match=r"field 'seed_mask' expected dtype bool, got float32"):
        nearest_seed(jnp.zeros((3, 3), jnp.float32))
    with pytest.raises(ValueError, match=r"too large for metric 'l2'"):
        jax.eval_shape(lambda m: nearest_seed(m, metric="l2"),
                       jax.ShapeDtypeStruct((40000, 2), jnp.bool_))
    with pytest.raises(ValueError, match=r"too large for metric 'l1'"):
        jax.eval_shape(nearest_seed, jax.ShapeDtypeStruct((70000, 70000), jnp.bool_))
    with pytest.raises(TypeError):
        nearest_seed(jnp.zeros((3, 3), bool), "l1")  # metric is keyword-only


def test_l2_wide_stack_layout():
    """A tall image whose stack entries need two int32 arrays (8193 rows: 14 row bits)."""
    from jaxdepth._src.distance import _stack_layout

    assert _stack_layout(8193, 5)[0] == 2 and _stack_layout(352, 1216)[0] == 1
    mask = _random_mask((8193, 5), 0.01, seed=12)
    mask[:3000] = False  # a long seedless stretch
    _check_result(nearest_seed(jnp.asarray(mask), metric="l2"), mask, "l2")


def _both_column_passes(mask: np.ndarray):
    """l2 column pass results of the linked-stack pass and of the frozen buffer-stack pass."""
    from jaxdepth._src.distance import _l2_column_pass, _row_pass
    from oracles.distance_buffer_stack import _l2_column_pass as _buffer_stack_pass

    h, w = mask.shape
    row_key_t = _row_pass(jnp.asarray(mask))
    new = jax.jit(_l2_column_pass, static_argnums=1)(row_key_t, h + w)
    old = jax.jit(_buffer_stack_pass, static_argnums=1)(row_key_t, h + w)
    return new, old


@pytest.mark.parametrize("shape,densities", [((1, 1), (1.0,)), ((1, 40), (0.1,)), ((40, 1), (0.1,)),
                                             ((131, 67), (0.0, 1.0, 0.01, 0.2)), ((8193, 5), (0.01,))])
def test_l2_linked_equals_buffer_stack(shape, densities):
    """The linked stack makes the same decisions as the (H + 1) * W buffer stack (8193 rows: the
    two-int32 entry layout). Several masks of one shape: one program per shape."""
    for i, density in enumerate(densities):
        mask = _random_mask(shape, density, seed=shape[0] * 1000 + shape[1] + i)
        new, old = _both_column_passes(mask)
        assert bool(new[3]) == bool(old[3]) == bool(mask.any())
        if mask.any():
            for a, b in zip(new[:3], old[:3]):
                np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_l2_linked_equals_buffer_stack_kitti(kitti):
    """Bit-identical seed rows, g and right flags on the real KITTI mask (and its transpose)."""
    mask = kitti.sparse[2] > 0
    for m in (mask, np.ascontiguousarray(mask[::-1])):
        new, old = _both_column_passes(m)
        for a, b in zip(new, old):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("metric", METRICS)
def test_kitti_tie_rule_sampled_brute_force(metric, kitti):
    """Real KITTI mask: du, dv equal an exhaustive search (raster-order tie rule) on sampled pixels.

    The samples cover the seedless top rows, the borders and random pixels.
    """
    mask = kitti.sparse[2] > 0
    res = nearest_seed(jnp.asarray(mask), metric=metric)
    h, w = mask.shape
    rng = np.random.default_rng(5)
    pv = np.concatenate([rng.integers(0, h, 600), np.zeros(100, int), np.full(100, h - 1), rng.integers(0, 100, 200)])
    pu = np.concatenate([rng.integers(0, w, 600), rng.integers(0, w, 200), rng.integers(0, w, 200)])
    pv = np.concatenate([pv, rng.integers(0, h, 50), rng.integers(0, h, 50)])
    pu = np.concatenate([pu, np.zeros(50, int), np.full(50, w - 1)])
    sv, su = (a.astype(np.int32) for a in np.nonzero(mask))  # raster order
    dv = sv[None, :] - pv[:, None].astype(np.int32)  # (1100, ~19k) int32: ~80 MB per array
    du = su[None, :] - pu[:, None].astype(np.int32)
    d = np.abs(dv) + np.abs(du) if metric == "l1" else dv * dv + du * du
    best = np.argmin(d, axis=1)  # first minimum = smallest seed row, then column
    np.testing.assert_array_equal(np.asarray(res.dv)[pv, pu], dv[np.arange(len(pv)), best])
    np.testing.assert_array_equal(np.asarray(res.du)[pv, pu], du[np.arange(len(pv)), best])


def test_l2_vmap_keeps_row_loops_unbatched():
    """Under vmap the l2 build loop shares its bounds across the batch (a batched loop
    counter would turn every row read and write into gathers and scatters, ~5x slower),
    its rows are written by ``put_row`` and its pops read by ``take_last`` (no scatter, no
    (member, index) pairs), and nested vmap == loop."""
    from jaxdepth._src.xla_tuning import forced, shared_loop_bounds

    with forced("cpu"):
        first, stop = jax.vmap(shared_loop_bounds)(jnp.array([3, 1, 5]), jnp.array([7, 9, 2]))
        np.testing.assert_array_equal(np.asarray(first), [1, 1, 1])
        np.testing.assert_array_equal(np.asarray(stop), [9, 9, 9])
        assert shared_loop_bounds(jnp.int32(3), jnp.int32(7)) == (3, 7)
    with forced("plain"):  # the plain path keeps each member's own bounds
        first, stop = jax.vmap(shared_loop_bounds)(jnp.array([3, 1, 5]), jnp.array([7, 9, 2]))
        np.testing.assert_array_equal(np.asarray(first), [3, 1, 5])
        np.testing.assert_array_equal(np.asarray(stop), [7, 9, 2])
    masks = np.stack([_random_mask((16, 21), d, seed=20 + i) for i, d in enumerate([0.0, 0.04, 0.1, 0.3])])
    masks[1, :5] = False  # different first seeded rows per member
    masks[2, 12:] = False
    fn = jax.vmap(lambda m: nearest_seed(m, metric="l2"))
    with forced("cpu"):
        jaxpr = str(jax.make_jaxpr(fn)(jnp.asarray(masks)))
        assert "scatter" not in jaxpr and "operand_batching_dims=(0" not in jaxpr, jaxpr
    nested = jax.vmap(fn)(jnp.asarray(masks.reshape(2, 2, 16, 21)))
    for i, mask in enumerate(masks):
        single = nearest_seed(jnp.asarray(mask), metric="l2")
        for name, a, b in zip(NearestSeed._fields, nested, single):
            np.testing.assert_array_equal(np.asarray(a).reshape((4,) + a.shape[2:])[i], np.asarray(b),
                                          err_msg=name)


def test_l2_single_seed_anywhere():
    """One seed: every pixel points at it (first/last row and column, interior)."""
    h, w = 7, 9   # a shape of the tests above: their program
    v, u = np.indices((h, w))
    for sv, su in [(0, 0), (h - 1, w - 1), (0, w - 1), (4, 5)]:
        mask = np.zeros((h, w), bool)
        mask[sv, su] = True
        res = nearest_seed(jnp.asarray(mask), metric="l2")
        np.testing.assert_array_equal(np.asarray(res.du), su - u)
        np.testing.assert_array_equal(np.asarray(res.dv), sv - v)


def test_large_shapes_trace():
    """4096 x 4096 fits both metrics' integer budgets (trace only, no run)."""
    spec = jax.ShapeDtypeStruct((4096, 4096), jnp.bool_)
    for metric in METRICS:
        out = jax.eval_shape(lambda m, metric=metric: nearest_seed(m, metric=metric), spec)
        assert out.distance.shape == (4096, 4096) and out.du.dtype == jnp.int32


# --- gather_at_seed -------------------------------------------------------------------------


def _random_offsets(shape, seed):
    h, w = shape
    rng = np.random.default_rng(seed)
    v, u = np.indices(shape)
    tv = rng.integers(0, h, shape)
    tu = rng.integers(0, w, shape)
    return (tu - u).astype(np.int32), (tv - v).astype(np.int32)


@pytest.mark.parametrize("field_shape", [(7, 9), (2, 7, 9), (1, 7, 9)])   # the stage table's gather rows' shapes
@pytest.mark.parametrize("dtype", [np.float32, np.int32])
def test_gather_matches_numpy(field_shape, dtype):
    rng = np.random.default_rng(3)
    field = (rng.random(field_shape) * 100).astype(dtype)
    du, dv = _random_offsets(field_shape[-2:], 5)
    out = gather_at_seed(jnp.asarray(field), jnp.asarray(du), jnp.asarray(dv))
    v, u = np.indices(field_shape[-2:])
    expected = field[..., v + dv, u + du]
    assert out.shape == field.shape and out.dtype == field.dtype
    np.testing.assert_array_equal(np.asarray(out), expected)


def test_gather_with_nearest_seed_keeps_seed_values():
    mask = _random_mask((131, 67), 0.05, seed=9)   # a shape of the oracle tests: their nearest_seed program
    depth = np.where(mask, np.random.default_rng(1).uniform(1, 80, mask.shape), 0).astype(np.float32)
    res = nearest_seed(jnp.asarray(mask))
    out = np.asarray(gather_at_seed(jnp.asarray(depth), res.du, res.dv))
    np.testing.assert_array_equal(out[mask], depth[mask])
    assert np.all(out > 0)


# NumPy fancy-indexing oracle, jit == eager, vmap == loop: rows gather_at_seed-* of tests/stage_table.py.


def test_gather_validation():
    with pytest.raises(ValueError, match=r"field expected shape \(H, W\) or \(C, H, W\)"):
        gather_at_seed(jnp.zeros((5,)), jnp.zeros((5,), jnp.int32), jnp.zeros((5,), jnp.int32))
    with pytest.raises(ValueError, match=r"du expected shape \(4, 5\), got \(5, 4\)"):
        gather_at_seed(jnp.zeros((4, 5)), jnp.zeros((5, 4), jnp.int32), jnp.zeros((4, 5), jnp.int32))


@pytest.mark.parametrize("shape", [(16, 21), (7, 9), (2, 1), (130, 67)])
def test_l1_paired_row_keys_against_brute_force(shape, monkeypatch):
    """The L1 column pass reading the row keys as two int16 rows an int32 word (``xla_tuning.key_rows``: on
    images of >= 2**20 pixels; here at every size): the brute force's du, dv (tie rule) with random, empty and
    full masks, even and odd heights (odd: the int16 rows), jit == eager, vmap == loop. Fresh ``jit`` programs:
    not the module's cached ones."""
    from jaxdepth._src import xla_tuning

    monkeypatch.setattr(xla_tuning, "_PAIRED_MIN_PIXELS", 1)
    masks = np.stack([_random_mask(shape, d, seed=40 + i) for i, d in enumerate([0.0, 0.05, 0.3, 1.0])])
    with xla_tuning.forced("cpu"):
        fn = jax.jit(lambda m: tuple(nearest_seed.__wrapped__(m, metric="l1")))
        batched = jax.jit(jax.vmap(lambda m: tuple(nearest_seed.__wrapped__(m, metric="l1"))))(jnp.asarray(masks))
        for i, mask in enumerate(masks):
            res = NearestSeed(*fn(jnp.asarray(mask)))
            _check_result(res, mask, "l1")
            if mask.any():
                _, bdu, bdv = _brute_force(mask, "l1")
                np.testing.assert_array_equal(np.asarray(res.du), bdu)
                np.testing.assert_array_equal(np.asarray(res.dv), bdv)
            for name, a, b in zip(NearestSeed._fields, batched, res):
                np.testing.assert_array_equal(np.asarray(a)[i], np.asarray(b), err_msg=name)
        if shape == (16, 21):
            with jax.disable_jit():
                eager = nearest_seed.__wrapped__(jnp.asarray(masks[1]), metric="l1")
            for name, a, b in zip(NearestSeed._fields, eager, fn(jnp.asarray(masks[1]))):
                np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)


def test_l1_large_image_paired_rows_sampled_brute_force():
    """A 1024 x 1024 mask (>= 2**20 pixels, even height: the row keys go as int32 pairs with the CPU tricks on,
    the Argoverse 2 and nuScenes cameras' path): OpenCV's distances, every du, dv a seed at that distance, and an
    exhaustive search (tie rule) on sampled pixels, borders included."""
    from jaxdepth._src import xla_tuning

    mask = _random_mask((1024, 1024), 0.002, seed=77)
    mask[:40] = False                    # seedless top rows, as a LiDAR image has
    with xla_tuning.forced("cpu"):
        res = NearestSeed(*jax.jit(lambda m: tuple(nearest_seed.__wrapped__(m, metric="l1")))(jnp.asarray(mask)))
    _check_result(res, mask, "l1")
    rng = np.random.default_rng(6)
    pv = np.concatenate([rng.integers(0, 1024, 400), np.zeros(50, int), np.full(50, 1023), rng.integers(0, 1024, 100)])
    pu = np.concatenate([rng.integers(0, 1024, 500), np.zeros(50, int), np.full(50, 1023)])
    sv, su = (a.astype(np.int32) for a in np.nonzero(mask))  # raster order
    dv = sv[None, :] - pv[:, None].astype(np.int32)
    du = su[None, :] - pu[:, None].astype(np.int32)
    best = np.argmin(np.abs(dv) + np.abs(du), axis=1)  # first minimum = smallest seed row, then column
    np.testing.assert_array_equal(np.asarray(res.dv)[pv, pu], dv[np.arange(len(pv)), best])
    np.testing.assert_array_equal(np.asarray(res.du)[pv, pu], du[np.arange(len(pv)), best])
