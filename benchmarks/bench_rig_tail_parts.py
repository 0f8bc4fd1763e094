"""The rig's Steps 3-4 sub-stage by sub-stage: process CPU of each part jitted apart (issue 38, the rigs' tail).

One process (host memory kept, ``keep_freed_memory``, as the jobs), interleaved rounds, process CPU per real
pixel, every program compiled with the library's compile options (``xla_tuning.COMPILER_OPTIONS``). The tail
``pipeline._complete_tail`` (default ``SGMConfig``: unguided L1 seed, column bracket, no blend) cut at its
sub-stages, each part a program of its own on the real inputs (the previous part's outputs):

- ``seed``: Step 3's distance transform (``nearest_seed`` of the Step 2 mask): ``du``, ``dv``;
- ``gather``: the seed depth and normals read at each pixel's seed (``_gather_seeds``, complex64 pairs);
- ``residual``: the plane residual and the clipped ``depth_raw`` (``plane_residual``);
- ``bracket``: the column bracket (``column_hypotheses``: the neighbour search and the clip);
- ``cap``: the capped plane above the top scan line and its clip (``capped_above_scan``; the input as is when the
  case's ``above_scan`` is ``plane``);
- ``blur``: Step 4's Gaussian blur (``gaussian_blur``, the window form with ``image_size``);
- ``final``: the measured depth kept, the clips and the window cleared (``clear_outside_window``);
- ``whole``: the tail in one program (``_complete_tail`` then ``clear_outside_window``, ``depth`` out).

Cases: ``vmap6``, the parts under ``vmap`` over the Argoverse 2 sweep's six 1550 x 2048 landscape cameras (the rig's
size group, window form) and ``one``, a single 1550 x 2048 camera (the first, no window, the single-camera path);
beside them ``rig``, the Argoverse 2 tail stage program (``sources_stage_tail``: seven cameras, two size groups,
the canvas). The parts' chain must give the whole's ``depth`` bit for bit (checked). The sum of the parts against
the whole is what fusion between the sub-stages saves (or costs).

``--gather-forms``: instead, the whole tail programs (``vmap6``, ``one``, the Argoverse 2 and the nuScenes tail stage
programs) compiled twice from this library in one process, with its seed gather (``pipeline._gather_seeds``: four
float32 gathers) and with the form before branch rigtail8 (``_pairs_gather`` here: two complex64 pairs), outputs
compared byte for byte, interleaved rounds, per-round ratios library / pairs.

``--dt-forms``: the same whole tail programs, and the distance transform alone (``vmap6``, ``one``), compiled from this
library with its ``nearest_seed`` and with the form before branch rigdt (``_previous_nearest_seed`` here, set as
``pipeline.nearest_seed``: the mask and the row keys built by full-image fusions, each followed by XLA:CPU's
transposing copy, instead of inside the passes' first loops), outputs compared byte for byte, per-round ratios
library / previous.

``--bracket-forms``: the same, with the column bracket alone (``vmap6``, ``one``; ``depth_raw`` the sparse depth), the
library's ``hypotheses._column_keys`` against the keys built inside its loop (``_loop_column_keys`` here, tried on
branch rigtail10: no key images built before the loop, but two fresh fills written by it).

``--put-forms``: the same, with the column bracket alone and the distance transform alone, the library's row update
of the loops (``xla_tuning.put_row``, one ``dynamic_update_slice`` under ``vmap``) against JAX's batching of it
(``_scatter_put_row`` here, set as ``distance.put_row`` and ``hypotheses.put_row``: a scatter, which XLA:CPU runs
as an update guarded by an in-bounds select).

``--l2``: every program with ``SGMConfig(distance_metric="l2")``. ``--l2-forms`` (implies ``--l2``): the whole tails and the
distance transform alone, the library's L2 column pass (rows written by ``xla_tuning.put_row``, pops read by
``xla_tuning.take_last``) against the form before branch rigtail11 (``_previous_l2_column_pass`` here: JAX's batching of
the row writes, a scatter, and of the pops' gathers, (camera, index) pairs).

Forms tried on branch rigtail11 and not kept (each against the library, outputs compared): ``--offset-forms``, the
capped tail's seed gather at ``du``, ``dv`` as a flat gather (``_flat_gather_at_seed``, set as
``pipeline.gather_at_seed``; it moves the capped plane's rounding); ``--strided-forms row|column|both``, the seed
search's first loops reading strided columns of the untransposed source (``_strided_passes``: no transposing copies);
``--unroll-forms K``, the sweeps' ``fori_loop`` unrolled K times (``_unrolled_sweep``); ``--rows-forms K [--rows-write
stack|rows]``, K rows a loop step (``_block_sweep``).

    python -m benchmarks.bench_rig_tail_parts [--rounds 7] [--capped] [--l2]
        [--gather-forms | --dt-forms | --depth-forms | --bracket-forms | --put-forms | --l2-forms | --offset-forms
         | --strided-forms WHICH | --unroll-forms K | --rows-forms K] [--json PATH]
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from benchmarks.bench_rig_tail_split import interleaved_cpu

PARTS = ("seed", "gather", "residual", "bracket", "cap", "blur", "final")


def _parts(config, beams: int) -> dict:
    """``{part: per-camera function}`` (module docs); every one takes ``size`` (None: no window) last."""
    import jax.numpy as jnp

    from jaxdepth._src import pipeline
    from jaxdepth._src.above_scan import capped_above_scan
    from jaxdepth._src.distance import gather_at_seed
    from jaxdepth._src.hypotheses import column_hypotheses
    from jaxdepth._src.distance import seed_index, seed_offsets
    from jaxdepth._src.pipeline import _at_seed_index, _gather_seeds
    from jaxdepth._src.residual import plane_residual
    from jaxdepth._src.smoothing import gaussian_blur
    assert config.guidance_weight == 0 and config.column_bracket and not config.blend_hypotheses
    assert config.above_scan in ("auto", "plane", "capped") and config.keep_measured_depth

    def seed(keep, size):
        s = pipeline.nearest_seed(keep, metric=config.distance_metric, horizontal_cost=config.seed_horizontal_cost)
        return seed_index(s.du, s.dv), s.has_seed

    def gather(sparse, normals, keep, seed_at, has_seed, size):
        if config.above_scan == "capped":      # the library's capped form: gathers at (v + dv, u + du)
            du, dv = seed_offsets(seed_at)
            return _gather_seeds(sparse, keep, normals, functools.partial(gather_at_seed, du=du, dv=dv), has_seed)
        return _gather_seeds(sparse, keep, normals, _at_seed_index(seed_at), has_seed)

    def residual(seed_depth, seed_normal, seed_at, K, size):
        du, dv = seed_offsets(seed_at)
        res = plane_residual(seed_depth, seed_normal, du, dv, K, min_abs_denom=config.min_abs_denom,
                             max_residual_ratio=config.max_residual_ratio)
        return jnp.where(seed_depth > 0, jnp.clip(seed_depth + res, config.min_depth_m, config.max_depth_m), 0.0)

    def bracket(depth_raw, sparse, keep, normals, K, size):
        return column_hypotheses(depth_raw, jnp.where(keep, sparse, 0.0), jnp.zeros_like(depth_raw), normals, K,
                                 window_px=sparse.shape[0] / beams, blend=False, materialise=True,
                                 min_abs_denom=config.min_abs_denom, max_residual_ratio=config.max_residual_ratio,
                                 image_size=size, image_gap=None if size is None else size[0] // beams)

    def cap(depth_raw, seed_depth, seed_normal, seed_at, sparse, keep, K, size):
        if config.above_scan != "capped":       # the tail's "auto" is "plane" (the jobs resolve it before)
            return depth_raw
        du, dv = seed_offsets(seed_at)
        rows = (sparse.shape[0] if size is None else size[0]) / beams
        out = capped_above_scan(depth_raw, seed_depth, seed_normal, du, dv, keep, sparse > 0, K, beams=beams,
                                rows_px=rows, max_half_width_px=config.outlier_max_half_width_px,
                                min_abs_denom=config.min_abs_denom, max_residual_ratio=config.max_residual_ratio,
                                image_size=size)
        return jnp.where(seed_depth > 0, jnp.clip(out, config.min_depth_m, config.max_depth_m), 0.0)

    def blur(depth_raw, size):
        return gaussian_blur(depth_raw, sigma_px=config.smoothing_sigma_px, radius_px=config.smoothing_radius_px,
                             image_size=size)

    def final(depth, sparse, keep, seed_depth, size):
        depth = jnp.where(seed_depth > 0, jnp.clip(jnp.where(keep, sparse, depth), config.min_depth_m,
                                                   config.max_depth_m), 0.0)
        if size is None:
            return depth
        h, w = depth.shape
        inside = (jnp.arange(h)[:, None] < size[0]) & (jnp.arange(w)[None, :] < size[1])
        return jnp.where(inside, depth, 0.0)

    return dict(seed=seed, gather=gather, residual=residual, bracket=bracket, cap=cap, blur=blur, final=final)


def _cases(capped: bool = False, l2: bool = False) -> tuple:
    """``(cases, rig)``: ``{case: {part: (jitted, arg builder)}, ...}`` and the rig program (module docs); ``capped``:
    every program with ``SGMConfig(above_scan="capped")``, the Argoverse 2 job's resolved ``"auto"``."""
    import dataclasses

    import jax
    import jax.numpy as jnp

    from benchmarks.bench_rig_tail_split import av2_landscape_group
    from jaxdepth._src.pipeline import _complete_tail, clear_outside_window
    g = av2_landscape_group()
    config, beams, sizes, view, keep, K, T = (g[k] for k in ("config", "beams", "sizes", "view", "keep", "K", "T"))
    if capped or l2:
        config = dataclasses.replace(config, **_config_change(capped, l2))
        g["statics"] = {**g["statics"], "config": config}
    parts = _parts(config, beams)

    def whole(sparse, normals, points, keep, K, T, size):
        out = _complete_tail(sparse, normals, points, K, T, beams=beams, config=config, keep=keep, image_size=size)
        return (out if size is None else clear_outside_window(out, size)).depth

    inputs = {"vmap6": dict(sparse=view.sparse_depth, normals=view.normals_cam, points=view.points_cam, keep=keep,
                            K=K, T=T, size=jnp.broadcast_to(jnp.asarray([1550, 2048], jnp.int32), (6, 2))),
              "one": dict(sparse=view.sparse_depth[0], normals=tuple(n[0] for n in view.normals_cam),
                          points=tuple(p[0] for p in view.points_cam), keep=keep[0], K=K[0], T=T[0], size=None)}
    rig = (jax.jit(lambda *a: functools.partial(g["stage"], **g["statics"])(*a).depth), g["tail_args"],
           float(sum(h * w for h, w in sizes)))
    return inputs, parts, whole, rig


def _config_change(capped: bool, l2: bool) -> dict:
    """``SGMConfig`` fields of ``--capped`` and ``--l2``."""
    return {**({"above_scan": "capped"} if capped else {}), **({"distance_metric": "l2"} if l2 else {})}


def _previous_l2_column_pass(row_key_t, far):
    """``distance._l2_column_pass`` before branch rigtail11: its row writes by ``lax.dynamic_update_index_in_dim`` (a
    scatter under ``vmap``) and its pops' gathers by JAX's batching (``(camera, index)`` pairs), not ``put_row`` and
    ``take_last`` (the library's function traced with those two swapped back)."""
    from jax import lax

    from jaxdepth._src import distance
    saved = distance.put_row, distance.take_last
    distance.put_row = lambda buf, row, i, wrap: lax.dynamic_update_index_in_dim(buf, row, i, 0)
    distance.take_last = lambda values, index: values.at[..., index].get(mode="promise_in_bounds")
    try:
        return _LIBRARY_L2[0](row_key_t, far)
    finally:
        distance.put_row, distance.take_last = saved


_LIBRARY_L2 = []


def _pairs_gather(sparse_depth, keep, normals, at, has_seed):
    """The seed gather before branch rigtail8: two complex64 pairs (``xla_tuning.pack_pair``), XLA:CPU mode."""
    import jax.numpy as jnp

    from jaxdepth._src.xla_tuning import pack_pair, unpack_pair
    seed_field = jnp.where(keep, sparse_depth, 0.0)
    xy, zd = pack_pair(normals[0], normals[1]), pack_pair(normals[2], seed_field)
    (nx, ny), (nz, depth) = unpack_pair(at(xy)), unpack_pair(at(zd))
    return depth, jnp.stack([nx, ny, nz])


def _flat_gather_at_seed(field, du, dv):
    """``distance.gather_at_seed`` as a flat gather (tried on branch rigtail11 for the capped tail, not kept): under a
    rig's ``vmap`` one 1-D gather per channel at the flat index computed in its fusion (``xla_tuning.take_last``),
    no (camera, index) pairs; the same values, but the capped plane's float32 rounding moves (docs/speed.md)."""
    from jaxdepth._src.distance import seed_index
    from jaxdepth._src.xla_tuning import take_last
    h, w = field.shape[-2:]
    return take_last(field.reshape(field.shape[:-2] + (h * w,)), seed_index(du, dv))


def _strided_passes(row: bool, column: bool):
    """``(distance._row_pass, distance._l1_column_pass)`` whose first loops read their source by strided columns of
    the untransposed array (tried on branch rigtail11, not kept): ``row``, the row pass's forward loop reads column i
    of the (H, W) mask (no bool transposing copy); ``column``, the column pass's forward loop reads column i of the
    (W, H) row keys (no int16 transposing copy). The same values."""
    import jax.numpy as jnp
    from jax import lax

    from jaxdepth._src import distance
    from jaxdepth._src.xla_tuning import put_row

    def sweep_read(buf, init, step, read):
        def body(i, state):
            carry, buf = state
            carry = step(i, read(i), carry)
            return carry, put_row(buf, carry, i)
        return lax.fori_loop(0, buf.shape[0], body, (init, buf))[1]

    def column(a, i):
        return lax.dynamic_slice_in_dim(a, i, 1, axis=1)[:, 0]

    library_row, library_column = distance._row_pass, distance._l1_column_pass

    def row_pass(seed_mask):
        h, w = seed_mask.shape
        far = h + w
        dtype = jnp.int16 if 2 * (far + w) + 1 <= distance._INT16_MAX else jnp.int32
        init = jnp.full((h,), 2 * far, dtype)
        no_seed = jnp.asarray(2 * (far + w) + 1, dtype)
        buf = sweep_read(jnp.zeros((w, h), dtype), init,
                         lambda i, r, carry: jnp.minimum(jnp.where(r, jnp.zeros((), dtype), no_seed), carry + 2),
                         lambda i: column(seed_mask, i))
        return distance._sweep(buf, init, lambda i, r, carry: jnp.minimum(r, (carry + 2) | 1), reverse=True)

    def column_pass(row_key_t, far, horizontal_cost=1):
        assert horizontal_cost == 1
        w, h = row_key_t.shape
        cb = distance._bits(h) + 1
        step = 1 << cb
        init = jnp.full((w,), far << cb, jnp.int32)

        def forward(i, hk, carry):
            hk = hk.astype(jnp.int32)
            return jnp.minimum((jnp.minimum(hk >> 1, far) << cb) | (i << 1) | (hk & 1), carry + step)

        key = sweep_read(jnp.zeros((h, w), jnp.int32), init, forward, lambda i: column(row_key_t, i))
        key = distance._sweep(key, init, lambda i, r, carry: jnp.minimum(r, carry + step), reverse=True)
        return key, cb

    return (row_pass if row else library_row), (column_pass if column else library_column)


def _unrolled_sweep(k: int):
    """``distance._sweep`` with ``lax.fori_loop(..., unroll=k)`` (tried on branch rigtail11, not kept)."""
    from jaxdepth._src import distance
    return functools.partial(distance._sweep, unroll=k)


def _block_sweep(k: int, write: str):
    """``distance._sweep`` with ``k`` rows a loop step (tried on branch rigtail11, not kept): one ``k``-row block read;
    written as one block (``write="stack"``: the carries stacked, one ``dynamic_update_slice``, under ``vmap`` of the
    batch) or row by row (``"rows"``: ``k`` ``put_row`` calls a step). The same values."""
    import jax.numpy as jnp
    from jax import custom_batching, lax

    from jaxdepth._src.xla_tuning import put_row

    @custom_batching.custom_vmap
    def put_rows(buf, rows, i):
        return lax.dynamic_update_slice_in_dim(buf, rows, i, 0)

    @put_rows.def_vmap
    def _put_rows_vmap(axis_size, in_batched, buf, rows, i):
        assert not in_batched[2]
        buf, rows = (x if b else jnp.broadcast_to(x, (axis_size,) + x.shape) for x, b in zip((buf, rows), in_batched))
        return lax.dynamic_update_slice_in_dim(buf, rows, i, 1), True

    def sweep(buf, init, step, *, reverse=False, source=None):
        n = buf.shape[0]
        m, r = divmod(n, k)

        def block(start, rows, carry, buf, size):
            out = [None] * size
            for t in (range(size - 1, -1, -1) if reverse else range(size)):
                carry = out[t] = step(start + t, rows[t], carry)
                if write == "rows":
                    buf = put_row(buf, carry, start + t)
            return carry, (buf if write == "rows" else put_rows(buf, jnp.stack(out), start))

        def body(j, state):
            carry, buf = state
            start = (n - (j + 1) * k) if reverse else (j * k)
            return block(start, lax.dynamic_slice_in_dim(buf if source is None else source, start, k, 0), carry, buf,
                         k)

        carry, buf = lax.fori_loop(0, m, body, (init, buf))
        if r:
            start = 0 if reverse else m * k
            rows = lax.slice_in_dim(buf if source is None else source, start, start + r, axis=0)
            carry, buf = block(jnp.int32(start), rows, carry, buf, r)
        return buf

    return sweep


def _masked_gather(sparse_depth, keep, normals, at, has_seed):
    """The seed gather before branch rigtail9 (XLA:CPU mode): the depth read through the mask,
    ``where(keep, sparse_depth, 0)`` at the seed (two reads there), ``has_seed`` unused."""
    import jax.numpy as jnp
    seed_field = jnp.where(keep, sparse_depth, 0.0)
    nx, ny, nz, depth = (at(channel) for channel in (*normals, seed_field))
    return depth, jnp.stack([nx, ny, nz])


def _previous_nearest_seed(seed_mask, *, metric, horizontal_cost):
    """``distance.nearest_seed`` (``"l1"``) before branch rigdt, here for ``pipeline``: the mask to int16 and the row
    keys to int32 by full-image fusions before the loops (each followed by XLA:CPU's transposing copy)."""
    import jax.numpy as jnp

    from jaxdepth._src.distance import _INT16_MAX, NearestSeed, _bits, _sweep
    assert metric == "l1"
    h, w = seed_mask.shape
    far, c = seed_mask.shape[0] + seed_mask.shape[1], horizontal_cost
    dtype = jnp.int16 if 2 * (far + w) + 1 <= _INT16_MAX else jnp.int32
    init = jnp.full((h,), 2 * far, dtype)
    buf = jnp.where(seed_mask.T, jnp.zeros((), dtype), jnp.asarray(2 * (far + w) + 1, dtype))
    buf = _sweep(buf, init, lambda i, row, carry: jnp.minimum(row, carry + 2))
    row_key_t = _sweep(buf, init, lambda i, row, carry: jnp.minimum(row, (carry + 2) | 1), reverse=True)
    cb = _bits(h) + 1
    step = 1 << cb
    hk = row_key_t.T.astype(jnp.int32)
    rows = jnp.arange(h, dtype=jnp.int32)[:, None]
    key = (jnp.minimum(c * (hk >> 1), c * far) << cb) | (rows << 1) | (hk & 1)
    init = jnp.full((w,), (c * far) << cb, jnp.int32)
    key = _sweep(key, init, lambda i, row, carry: jnp.minimum(row, carry + step))
    key = _sweep(key, init, lambda i, row, carry: jnp.minimum(row, carry + step), reverse=True)
    has_seed = key[0, 0] < ((c * far) << cb)
    dist = key >> cb
    dv = ((key >> 1) & ((1 << (cb - 1)) - 1)) - rows
    abs_du = (dist - jnp.abs(dv)) // c
    du = jnp.where((key & 1) == 1, abs_du, -abs_du)
    return NearestSeed(distance=jnp.where(has_seed, dist.astype(jnp.float32), jnp.inf),
                       du=jnp.where(has_seed, du, 0), dv=jnp.where(has_seed, dv, 0), has_seed=has_seed)


def _loop_column_keys(kept_depth, *, max_gap, height=None):
    """``hypotheses._column_keys`` with each row's keys built inside the running-max loop from the row of ``kept_depth``
    it reads (tried on branch rigtail10, not kept): the two key images are then fresh fills the loop writes."""
    import jax.numpy as jnp
    from jax import lax

    from jaxdepth._src.hypotheses import _depth_bits
    from jaxdepth._src.xla_tuning import put_row
    h, w = kept_depth.shape
    depth_bits, scale, top = _depth_bits(h if height is None else height)
    last = h - 1 if height is None else jnp.asarray(height, jnp.int32) - 1

    def key(order, row):
        level = jnp.clip(jnp.round(row * scale), 1, top).astype(jnp.int32)
        return jnp.where(row > 0, (order << depth_bits) | level, -1)

    def step(i, state):
        c_fwd, c_bwd, fwd, bwd = state
        j = h - 1 - i
        get = functools.partial(lax.dynamic_index_in_dim, kept_depth, axis=0, keepdims=False,
                                allow_negative_indices=False)
        c_fwd = jnp.maximum(c_fwd, key(i, get(i)))
        c_bwd = jnp.maximum(c_bwd, key(last - j, get(j)))
        return c_fwd, c_bwd, put_row(fwd, c_fwd, i), put_row(bwd, c_bwd, j)

    init = jnp.full((w,), -1, jnp.int32)
    _, _, up, down = lax.fori_loop(0, h, step, (init, init, jnp.full((h, w), -1, jnp.int32),
                                                jnp.full((h, w), -2, jnp.int32)))
    rows = jnp.arange(h, dtype=jnp.int32)[:, None]
    g = int(max_gap)
    up = jnp.where(rows - (up >> depth_bits) <= g, up, -1)
    down = jnp.where(last - (down >> depth_bits) - rows <= g, down, -1)
    return up, down, depth_bits, scale, top, last


def _scatter_put_row(buf, row, i):
    """``xla_tuning.put_row`` before branch rigtail10: JAX's batching of the row update (a scatter under ``vmap``)."""
    from jax import lax
    return lax.dynamic_update_index_in_dim(buf, row, i, 0, allow_negative_indices=False)


def _forms(inputs, whole, rig, options, forms: dict, alone=None, *, wholes: bool = True,
           config_change: dict | None = None) -> dict:
    """``{case/form: (executable, args, real pixels)}``: each whole tail (and, given ``alone = (label, part, names)``,
    ``part`` alone on the inputs ``names`` as ``case_label``) traced with every form's module attributes set
    (``forms[form] = {(module, name): value}``)."""
    import jax

    from benchmarks.bench_stage_programs import _case_inputs
    import dataclasses
    stages, args, statics, _, one_args = _case_inputs("nuscenes")
    if config_change:       # the tail's config only (Steps 1-2 as the case's)
        statics = list(statics)
        statics[2] = {**statics[2], "config": dataclasses.replace(statics[2]["config"], **config_change)}
    views = jax.jit(functools.partial(stages[0], **statics[0]))(*args[0])
    keeps = jax.jit(functools.partial(stages[1], **statics[1]))(*args[1](views))
    sizes = np.asarray(one_args[-1].image_size).tolist()
    nuscenes = (jax.jit(lambda *a: functools.partial(stages[2], **statics[2])(*a).depth), args[2]((views, keeps)),
                float(sum(h * w for h, w in sizes)))
    runs = {}
    for form, patch in forms.items():
        saved = {key: getattr(*key) for key in patch}
        for (module, name), value in patch.items():
            setattr(module, name, value)         # read when the programs are traced (below)
        jax.clear_caches()                       # nearest_seed is a jit of its own: trace it again
        try:
            for case, x in inputs.items():
                px = 1550 * 2048.0 * (6 if case == "vmap6" else 1)
                a = (x["sparse"], x["normals"], x["points"], x["keep"], x["K"], x["T"], x["size"])
                fn = jax.vmap(whole) if case == "vmap6" else (lambda *b: whole(*b[:-1], None))
                if wholes:
                    runs[f"{case}/{form}"] = (jax.jit(fn).lower(*a).compile(options), a, px)
                if alone is not None:
                    label, part, names = alone
                    b = tuple(x[n] for n in names)
                    runs[f"{case}_{label}/{form}"] = (_compile(lambda *c: part(*c, None), b, case == "vmap6",
                                                               options), b, px)
            for case, (fn, a, px) in (("av2_rig", rig), ("nuscenes_rig", nuscenes)) if wholes else ():
                runs[f"{case}/{form}"] = (jax.jit(fn).lower(*a).compile(options), a, px)
        finally:
            for (module, name), value in saved.items():
                setattr(module, name, value)
            jax.clear_caches()
    return runs


def _compile(fn, args, batched: bool, options):
    import jax
    if batched:
        fn = jax.vmap(fn)
    return jax.jit(fn).lower(*args).compile(options)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--gather-forms", action="store_true", help="the seed gather's two forms (module docs)")
    parser.add_argument("--dt-forms", action="store_true", help="the distance transform's two forms (module docs)")
    parser.add_argument("--bracket-forms", action="store_true", help="the column bracket's two forms (module docs)")
    parser.add_argument("--put-forms", action="store_true", help="the loops' two row updates (module docs)")
    parser.add_argument("--unroll-forms", type=int, default=0, metavar="K",
                        help="the seed search's sweeps with K loop bodies per iteration against the library's")
    parser.add_argument("--rows-forms", type=int, default=0, metavar="K",
                        help="the seed search's sweeps with K-row blocks per loop step against the library's")
    parser.add_argument("--rows-write", choices=("stack", "rows"), default="stack",
                        help="--rows-forms: a block written as one (stack) or row by row (rows)")
    parser.add_argument("--strided-forms", choices=("row", "column", "both"), default=None,
                        help="the seed search's first loops reading strided columns, no transposing copy (module docs)")
    parser.add_argument("--offset-forms", action="store_true",
                        help="the capped tail's seed gather at du, dv: the library's pairs against a flat gather (module docs)")
    parser.add_argument("--depth-forms", action="store_true", help="the seed depth's two reads (module docs)")
    parser.add_argument("--l2", action="store_true", help='SGMConfig(distance_metric="l2")')
    parser.add_argument("--l2-forms", action="store_true",
                        help="the L2 column pass's row writes and pops: put_row / take_last against before (module docs)")
    parser.add_argument("--capped", action="store_true", help='SGMConfig(above_scan="capped"), the AV2 job\'s tail')
    parser.add_argument("--json", default=None, help="default results/rig_tail_parts.json (--gather-forms: "
                                                        "rig_tail_gather_forms.json, --dt-forms: rig_tail_dt_forms.json)")
    args, t0 = parser.parse_args(argv), time.time()
    args.json = args.json or str(RESULTS / ("rig_tail_gather_forms.json" if args.gather_forms else
                                            "rig_tail_dt_forms.json" if args.dt_forms else
                                            "rig_tail_depth_forms.json" if args.depth_forms else
                                            "rig_tail_bracket_forms.json" if args.bracket_forms else
                                            "rig_tail_put_forms.json" if args.put_forms else
                                            "rig_tail_unroll_forms.json" if args.unroll_forms else
                                            "rig_tail_rows_forms.json" if args.rows_forms else
                                            "rig_tail_offset_forms.json" if args.offset_forms else
                                            "rig_tail_strided_forms.json" if args.strided_forms else
                                            "rig_tail_l2_forms.json" if args.l2_forms else
                                            "rig_tail_parts.json"))
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jaxdepth command (else page faults decide)

    from jaxdepth._src.xla_tuning import COMPILER_OPTIONS
    args.l2 = args.l2 or args.l2_forms
    inputs, parts, whole, rig = _cases(args.capped, args.l2)
    from jaxdepth._src import pipeline
    if args.gather_forms:
        forms = {"library": {}, "pairs": {(pipeline, "_gather_seeds"): _pairs_gather}}
        return _time_forms(_forms(inputs, whole, rig, COMPILER_OPTIONS, forms), args, t0, "the seed gather", "pairs")
    if args.offset_forms:
        forms = {"library": {}, "flat": {(pipeline, "gather_at_seed"): _flat_gather_at_seed}}
        return _time_forms(_forms(inputs, whole, rig, COMPILER_OPTIONS, forms), args, t0, "seed gather at du, dv",
                           "flat")
    if args.depth_forms:
        forms = {"library": {}, "masked": {(pipeline, "_gather_seeds"): _masked_gather}}
        return _time_forms(_forms(inputs, whole, rig, COMPILER_OPTIONS, forms), args, t0, "seed depth", "masked")
    if args.dt_forms:
        forms = {"library": {}, "previous": {(pipeline, "nearest_seed"): _previous_nearest_seed}}
        return _time_forms(_forms(inputs, whole, rig, COMPILER_OPTIONS, forms, ("seed", parts["seed"], ("keep",))),
                           args, t0, "the distance transform", "previous")
    if args.l2_forms:
        from jaxdepth._src import distance
        _LIBRARY_L2[:] = [distance._l2_column_pass]
        forms = {"library": {}, "previous": {(distance, "_l2_column_pass"): _previous_l2_column_pass}}
        runs = _forms(inputs, whole, rig, COMPILER_OPTIONS, forms, ("seed", parts["seed"], ("keep",)),
                      config_change=_config_change(args.capped, True))
        return _time_forms(runs, args, t0, "L2 column pass", "previous")
    if args.strided_forms:
        from jaxdepth._src import distance
        row_pass, column_pass = _strided_passes(args.strided_forms in ("row", "both"),
                                                args.strided_forms in ("column", "both"))
        other = f"strided_{args.strided_forms}"
        forms = {"library": {}, other: {(distance, "_row_pass"): row_pass, (distance, "_l1_column_pass"): column_pass}}
        return _time_forms(_forms(inputs, whole, rig, COMPILER_OPTIONS, forms, ("seed", parts["seed"], ("keep",))),
                           args, t0, "seed search's first loops", other)
    if args.unroll_forms or args.rows_forms:
        from jaxdepth._src import distance
        other = f"unroll{args.unroll_forms}" if args.unroll_forms else f"rows{args.rows_forms}"
        forms = {"library": {}, other: {(distance, "_sweep"): _unrolled_sweep(args.unroll_forms)} if args.unroll_forms
                 else {(distance, "_sweep"): _block_sweep(args.rows_forms, args.rows_write)}}
        return _time_forms(_forms(inputs, whole, rig, COMPILER_OPTIONS, forms, ("seed", parts["seed"], ("keep",))),
                           args, t0, "seed search's sweeps", other)
    if args.bracket_forms or args.put_forms:
        from jaxdepth._src import distance, hypotheses
        other = "loop_keys" if args.bracket_forms else "scatter"
        forms = {"library": {}, other: {(hypotheses, "_column_keys"): _loop_column_keys} if args.bracket_forms else
                 {(hypotheses, "put_row"): _scatter_put_row, (distance, "put_row"): _scatter_put_row}}
        alone = ("bracket", lambda s, k, n, K, size: parts["bracket"](s, s, k, n, K, size),
                 ("sparse", "keep", "normals", "K"))
        runs = _forms(inputs, whole, rig, COMPILER_OPTIONS, forms, alone)
        if args.put_forms:
            runs.update(_forms(inputs, whole, rig, COMPILER_OPTIONS, forms, ("seed", parts["seed"], ("keep",)),
                               wholes=False))
        return _time_forms(runs, args, t0, "row updates" if args.put_forms else "column bracket's keys", other)
    runs, same = {}, {}             # runs[name] = (executable, args, real pixels)
    for case, x in inputs.items():
        batched, px = case == "vmap6", 1550 * 2048.0 * (6 if case == "vmap6" else 1)
        size = x["size"]
        part_args = {"seed": (x["keep"], size)}
        chain = {}

        def run(name, a, batched=batched, case=case, px=px):
            fn = parts[name] if size is not None else (lambda *b, f=parts[name]: f(*b, None))
            a = a if size is not None else a[:-1]
            exe = _compile(fn, a, batched, COMPILER_OPTIONS)
            runs[f"{case}/{name}"] = (exe, a, px)
            return exe(*a)

        chain["seed_at"], has_seed = run("seed", part_args["seed"])
        chain["seed_depth"], chain["seed_normal"] = run(
            "gather", (x["sparse"], x["normals"], x["keep"], chain["seed_at"], has_seed, size))
        chain["depth_raw"] = run("residual", (chain["seed_depth"], chain["seed_normal"], chain["seed_at"], x["K"],
                                              size))
        chain["bracketed"] = run("bracket", (chain["depth_raw"], x["sparse"], x["keep"], x["normals"], x["K"], size))
        chain["capped"] = run("cap", (chain["bracketed"], chain["seed_depth"], chain["seed_normal"], chain["seed_at"],
                                      x["sparse"], x["keep"], x["K"], size))
        chain["blurred"] = run("blur", (chain["capped"], size))
        depth = run("final", (chain["blurred"], x["sparse"], x["keep"], chain["seed_depth"], size))
        whole_args = (x["sparse"], x["normals"], x["points"], x["keep"], x["K"], x["T"], size)
        fn = whole if size is not None else (lambda *b: whole(*b, None))
        wa = whole_args if size is not None else whole_args[:-1]
        exe = _compile(fn, wa, batched, COMPILER_OPTIONS)
        runs[f"{case}/whole"] = (exe, wa, px)
        same[case] = int(np.sum(np.asarray(exe(*wa)) != np.asarray(depth)))
    runs["rig/whole"] = (rig[0].lower(*rig[1]).compile(COMPILER_OPTIONS), rig[1], rig[2])
    print("depth values of the parts' chain differing from the whole:", same, flush=True)
    cpu = interleaved_cpu(runs, args.rounds)
    median = {k: statistics.median(v) for k, v in cpu.items()}
    summary = {}
    for case in inputs:
        total = [sum(cpu[f"{case}/{p}"][r] for p in PARTS) for r in range(args.rounds)]
        summary[case] = {"parts_sum_median": statistics.median(total), "whole_median": median[f"{case}/whole"],
                         "whole_over_parts_per_round_median": statistics.median(
                             [w / t for w, t in zip(cpu[f"{case}/whole"], total)]),
                         "share_of_parts_sum": {p: statistics.median([cpu[f"{case}/{p}"][r] / total[r]
                                                                      for r in range(args.rounds)]) for p in PARTS}}
    print("median CPU ns/px", {k: round(v, 2) for k, v in median.items()}, flush=True)
    print("summary", summary, flush=True)
    doc = {"what": "the rig's tail sub-stage by sub-stage (module docs), process CPU ns per real pixel, "
                   "interleaved rounds", "load_average": os.getloadavg(), "cpu_ns_px": cpu, "cpu_ns_px_median": median,
           "summary": summary, "chain_depth_values_differing_from_whole": same}
    write_results(args.json, doc, None, t0)
    return 0


def _time_forms(runs: dict, args, t0, what: str, other: str) -> int:
    cases = sorted({name.split("/")[0] for name in runs})
    differ = {c: int(sum(np.sum(np.asarray(a) != np.asarray(b)) for a, b in zip(
        _leaves(runs[f"{c}/library"][0](*runs[f"{c}/library"][1])),
        _leaves(runs[f"{c}/{other}"][0](*runs[f"{c}/{other}"][1]))))) for c in cases}
    print("output values differing between the two forms:", differ, flush=True)
    cpu = interleaved_cpu(runs, args.rounds)
    ratio = {c: [a / b for a, b in zip(cpu[f"{c}/library"], cpu[f"{c}/{other}"])] for c in cases}
    median = {k: statistics.median(v) for k, v in cpu.items()}
    summary = {c: {f"library_over_{other}_per_round_median": statistics.median(ratio[c]),
                   "rounds_below_1": sum(r < 1 for r in ratio[c])} for c in cases}
    print("median CPU ns/px", {k: round(v, 2) for k, v in median.items()}, f"\nlibrary / {other}", summary, flush=True)
    doc = {"what": f"the whole tail (and parts) with the library's {what} against the {other} form (module docs), "
                   "process CPU ns per real pixel, interleaved rounds", "load_average": os.getloadavg(),
           "cpu_ns_px": cpu, "cpu_ns_px_median": median, f"library_over_{other}_per_round": ratio, "summary": summary,
           "output_values_differing": differ}
    write_results(args.json, doc, None, t0)
    return 0


def _leaves(out) -> list:
    import jax
    return [np.asarray(a) for a in jax.tree_util.tree_leaves(out)]


if __name__ == "__main__":
    raise SystemExit(main())
