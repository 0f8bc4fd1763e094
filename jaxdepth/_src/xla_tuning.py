"""Every XLA:CPU tuning trick of jaxdepth, with its reason, and the switch that turns them off.

The stages of the pipeline are written plainly and call the helpers here where XLA:CPU needs
steering; each call site says in one line why. On other backends (and with
``JAXDEPTH_XLA_TUNING=plain``) the helpers reduce to the plain computation. The choice is made
at trace time: :func:`enabled` is True when the mode is ``"cpu"``, or ``"auto"`` (the default)
and ``jax.default_backend() == "cpu"``. The mode comes from :func:`set_mode` if called, else the
environment variable ``JAXDEPTH_XLA_TUNING`` (``auto`` / ``cpu`` / ``plain``).

Why the tricks (measured with jax 0.10.2 on XLA:CPU; figures in benchmarks/results):

* **Stage fences** (:func:`stage`, :func:`fence`). XLA fuses a producer into every consumer.
  When a heavy elementwise chain feeds shifted slices, gathers or several outputs, each
  consumer re-runs the whole chain per element it reads, far slower than reading a buffer.
  ``lax.optimization_barrier`` is removed before fusion on CPU, so :func:`stage` runs the
  producer inside a ``lax.cond`` whose predicate always holds but is not provable at compile
  time (an int32 from the data compared with INT32_MIN): a conditional's operands and results
  are real buffers. The producer runs inside the branch, so nothing is copied. Under ``vmap``
  the predicate is reduced to a scalar (``custom_vmap``), so the conditional is not turned
  into a select that would run both branches; a ``custom_jvp`` differentiates ``fn``
  directly, so gradients flow as if the fence were not there. Plain: ``fn(*args)``. The stages
  reading the depth take their token from it with :func:`stage_token` (its first value's bits).
* **Channel packing** (:func:`pack_pair`, :func:`take_pair`). Two float32 channels gathered
  at the same indices travel as one complex64 array: half the gathered elements of two
  float32 gathers, and XLA fuses a complex gather into its consumer where it would not fuse a
  gather of a stacked (2, ...) array. Plain: the channels stay separate arrays. (Inside the
  normal fits, the pixel binning and the geodesic passes complex64 is the data layout of the
  stage itself and stays in both modes.) Not Step 3's seed gather: there the packing fused into
  the gathers, whose complex64 results were written out; four float32 gathers, each fused into
  its consumers, cost less (``pipeline._gather_seeds``; plain: one gather of the stacked channels).
* **Flat gathers under vmap** (:func:`take_last`). JAX batches a gather whose operand and index are
  both batched as a gather with a batching dimension, which XLA:CPU expands into an int32
  (B, ..., 2) array of (member, index) pairs written out before the gather; one flat 1-D gather
  from the flattened batch (member ``b`` at ``b N + index``) computes its index inside the gather's
  fusion (the seed gathers of the rigs' tails, ``pipeline._at_seed_index``: with the seed search's one
  flat index image, the nuScenes tail 0.84-0.90x; docs/speed.md, "The seed search's one flat index and
  the seed depth's read"). Its indices are not wrapped (all in bounds): JAX's negative-index wrap is a
  compare, an add and a select per element inside the gathers' fusions (the KITTI frame 0.97x CPU without
  it). Plain: the batched gather, wrapped.
* **Scheduling dependence** (:func:`after`). A value made to depend on a result that is
  always the same but not provably so at compile time is scheduled after that result: the
  column bracket's inputs would otherwise be scheduled before the seed search, stay live
  across its loops, and XLA:CPU copies loop state that aliases live buffers. Plain: the value.
* **Shared loop bounds** (:func:`shared_loop_bounds`). A loop whose bounds are batched
  (``vmap``) gets a batched counter, which turns every row read and row write in its body into
  gathers and scatters; a ``custom_vmap`` gives the batch the widest bounds instead (callers
  make extra rows harmless). Plain: the bounds themselves.
* **Row updates under vmap** (:func:`put_row`). JAX batches a loop's ``dynamic_update_slice`` of a row
  (a batched buffer, the loop's unbatched row counter) as a scatter, which XLA:CPU runs as an update
  guarded by an in-bounds select that reads the buffer's old row every step (and ~5 more small kernels a
  step); a ``custom_vmap`` writes the batch's rows with one ``dynamic_update_slice`` (the rigs' seed search
  and column bracket loops under the size groups' ``vmap``: the Argoverse 2 tail 0.97-0.98x, the nuScenes
  tail 0.95-0.99x, docs/speed.md "The loops' row writes under vmap"; the L2 column pass's rows with
  ``take_last`` for its pops: its seed search under ``vmap`` 0.87x, docs/speed.md "The seed search's loops, the
  capped tail's gather and the L2 pass under vmap"). Plain: ``lax.dynamic_update_index_in_dim``.
* **Wrap padding as one gather** (:func:`wrap_pad`). XLA:CPU compiles each slice feeding a
  concatenate as a kernel of its own; a ``take`` with static indices becomes one pad-like kernel.
  Plain: slices and concatenates (:func:`wrap_pad_slices`).
* **Copy insertion by region analysis** (:data:`COMPILER_OPTIONS`, given by :func:`entry_jit` to the
  ``jax.jit`` of the single-frame entry points, of the rig / sources programs and of the KITTI jobs' batch
  programs, ``jaxdepth.batch.runner``). XLA:CPU keeps loop
  state in place only where its copy insertion proves no live value aliases it, and copies the rest
  every loop step (loop counters, carried rows) or once per loop (whole images); the region analysis
  proves more of it: on the KITTI frame 15 fewer copies (10 of them loop counters, copied every step,
  two (H, W) int32 images), the same bytes, about 0.9x the frame's CPU; on the rigs' depth programs
  about 0.95x, their projection 0.86x (docs/speed.md, "The rig's tail against one camera"); the KITTI job's
  batch program 0.96-1.00x (docs/speed.md, "Step 2's dense passes and the KITTI job's programs"). A compile
  option, not an ``XLA_FLAGS`` setting: only the programs it is given see it, and backends other than
  XLA:CPU do not read it, so it holds in both modes.
* **Column reductions in a row loop** (:func:`first_row_and_count`). XLA:CPU reduces an (H, W) array over
  H > 32 rows by reduce-windows that read it from a buffer, so their producer (a select, a convert of a
  mask) is written out whole first; one loop over the rows reads each row once and writes nothing
  image-sized (the capped plane's top scan line and point count; with its window rows fenced, the Argoverse 2
  tail under ``capped`` 0.70x main's CPU, docs/speed.md "The capped plane on the Argoverse 2 job"). Plain: a
  min and a sum.
* **Small dots as products and sums** (:func:`small_matmul`). XLA:CPU hands a 3-vector by 3 x 3 dot to
  YNNPACK, ~9 ms for the Argoverse 2 sweep's (2, 65536, 3) rotations against 0.1 ms elementwise; the fenced
  products summed in order are its bits (docs/speed.md, "The rig's projection: small dots"). Plain: the dot.
* **Fills of their own** (:func:`scatter_onto_fill`). XLA merges equal fills into one buffer and copies it
  for each scatter into it (the rigs' six channels a camera); each fill in its own conditional is written
  once, where its scatter writes. Plain: the fill and the scatter.
* **A bool mask's columns as bits** (:func:`mask_columns`, :func:`mask_column`). XLA:CPU transposes a
  bool array element by element, ~1.5 ns a byte (the distance transform's row pass reads the seed mask's
  columns: the Argoverse 2 landscape group's (6, 1550, 2048) mask 26-30 ms a sweep, rigtail12's list); packed
  as 32 columns' bits in a uint32 (one reduce fusion reading the mask in order), the transpose moves 1/32 of
  the elements and a loop step takes its column's bit (the distance transform alone 0.82x on that group, the
  Argoverse 2 tail stage 0.95x; docs/speed.md, "The distance transform's transposes"). Plain: the transposed
  mask and its rows.
* **Row keys as int32 pairs** (:func:`key_rows`, :func:`key_row`). The row pass's int16 keys, transposed for
  the L1 column pass, go as two rows' keys in one int32 word (a bitcast, then a transpose of half the
  elements) on images of >= 2**20 pixels with an even height: the distance transform alone 0.83-0.90x on the
  Argoverse 2 portrait group (1, 2048, 1550), 0.91-0.95x on the nuScenes group (6, 900, 1600), 0.98-1.03x on
  the landscape group (6, 1550, 2048); not on the KITTI frame (0.92-1.10x across runs), which keeps its int16
  transpose (docs/speed.md, "The distance transform's int16 row keys as int32 pairs"). Plain: the transposed keys.
* **Bool reductions** (:func:`any_true`). A long ``any`` compiles to a large kernel; an int32
  maximum of the same mask is a small one. Plain: ``jnp.any``.

:func:`cond_all` is not backend tuning: it chooses a cheaper branch
that gives the same result, and keeps that choice a conditional under ``vmap`` on every
backend (a batched ``lax.cond`` runs both branches). It is here because it shares the
``custom_vmap`` steering of :func:`stage`.

Both modes give the same results: bit for bit where only materialisation, scheduling or
gather layout differ (tests/test_xla_tuning.py runs ``complete``, ``complete_points`` and
``complete_rig`` both ways).
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
from jax import custom_batching, lax

#: XLA flags the test suite compiles under (tests/conftest.py adds them to ``XLA_FLAGS`` before JAX
#: starts its backend; CLI, notebook and Ray subprocesses inherit them). Not a product setting: the
#: library never sets them. At XLA:CPU's backend optimisation level 0 the 32 x 48 pipeline compiles in
#: 5.0 s of CPU against 9.0-9.3 s (the KITTI crop: 6.7 s against 11.4 s, which then runs in 0.29 s
#: instead of 0.06 s), with outputs that differ from the production compile in the last bits. So the
#: tests that compare against bytes or figures recorded at production flags run in a subprocess at
#: those (``@pytest.mark.production_flags``), and ``tests/test_output_fingerprint.py`` recomputes part
#: of benchmarks/results/output_fingerprint.json at them (docs/testing.md, "Compile flags").
#: ``--xla_cpu_use_fusion_emitters=false`` on top would halve the compile again (2.3-2.7 s) but runs
#: out of memory (over 20 GB, std::bad_alloc) compiling the pipeline with every non-default option.
SUITE_XLA_FLAGS = "--xla_backend_optimization_level=0"

#: XLA compile options of the single-frame entry points (:func:`entry_jit`); see the module docstring.
COMPILER_OPTIONS = {"xla_cpu_copy_insertion_use_region_analysis": True}

MODES = ("auto", "cpu", "plain")
_ENV = "JAXDEPTH_XLA_TUNING"
_forced: str | None = None
_INT32_MIN = jnp.iinfo(jnp.int32).min
_INT32_MAX = jnp.iinfo(jnp.int32).max
_PIB = "promise_in_bounds"


def mode() -> str:
    """The tuning mode in force: :func:`set_mode`'s, else ``$JAXDEPTH_XLA_TUNING``, else ``"auto"``."""
    value = _forced if _forced is not None else os.environ.get(_ENV, "auto").strip().lower() or "auto"
    if value not in MODES:
        raise ValueError(f"{_ENV}: expected one of {MODES}, got {value!r}")
    return value


def enabled() -> bool:
    """Whether the XLA:CPU tricks apply to what is traced now (see the module docstring)."""
    chosen = mode()
    return chosen == "cpu" or (chosen == "auto" and jax.default_backend() == "cpu")


def set_mode(value: str | None) -> None:
    """Forces ``"cpu"`` (tricks on), ``"plain"`` (off) or ``"auto"``; None returns to the environment.

    Clears JAX's caches when the choice changes, so jitted functions are traced again.
    """
    global _forced
    if value is not None and value not in MODES:
        raise ValueError(f"set_mode: field 'value' expected one of {MODES} or None, got {value!r}")
    before = enabled()
    _forced = value
    if enabled() != before:
        jax.clear_caches()


@contextlib.contextmanager
def forced(value: str):
    """``with forced("plain"): ...`` traces the block in that mode, then restores the previous one."""
    previous = _forced
    set_mode(value)
    try:
        yield
    finally:
        set_mode(previous)


def _steered(scalar, operands, *, single, batched, reduce, tangent_fn=None):
    """``single(scalar, operands)`` as a ``custom_vmap`` whose batch rule keeps one scalar.

    Under ``vmap`` a batched ``scalar`` is reduced with ``reduce`` (so a
    conditional stays a conditional instead of a select of both branches),
    unbatched operands are broadcast leaf by leaf, and ``batched(scalar,
    operands)`` computes the whole batch. With ``tangent_fn``, JVPs are
    ``jax.jvp(tangent_fn(scalar), (operands,), (operand_tangents,))``.
    """

    @custom_batching.custom_vmap
    def run(scalar, operands):
        return single(scalar, operands)

    @run.def_vmap
    def run_vmap(axis_size, in_batched, scalar, operands):
        scalar_batched, ops_batched = in_batched
        if scalar_batched:
            scalar = reduce(scalar)
        operands = jax.tree.map(lambda a, b: a if b else jnp.broadcast_to(a, (axis_size,) + a.shape),
                                tuple(operands), tuple(ops_batched))
        out = batched(scalar, operands)
        return out, jax.tree.map(lambda _: True, out)

    if tangent_fn is None:
        return run(scalar, operands)

    @jax.custom_jvp
    def differentiable(scalar, operands):
        return run(scalar, operands)

    @differentiable.defjvp
    def differentiable_jvp(primals, tangents):
        scalar, operands = primals
        return jax.jvp(tangent_fn(scalar), (operands,), (tangents[1],))

    return differentiable(scalar, operands)


def stage(fn, args, token):
    """``fn(*args)`` computed in its own conditional: its outputs are real buffers
    that consumers read instead of re-running ``fn``.

    Args:
      fn: function of arrays returning a tuple (or any pytree) of arrays.
      args: tuple of arrays (the conditional's operands).
      token: int32 scalar derived from the data; ``token >= INT32_MIN`` always
        holds, so ``fn`` always runs. Any data-dependent scalar works (e.g.
        ``mask[0, 0].astype(jnp.int32)``); the depth's stages use :func:`stage_token`.

    Returns:
      ``fn(*args)``, bit-identical to calling it directly (which is what it does when the
      tricks are off).
    """
    if not enabled():
        return fn(*args)

    def single(tok, operands):
        # The false branch returns zeros of fn's output shapes. lax.cond traces the true
        # branch first, so its outputs give those shapes without tracing fn a second time
        # (eval_shape only if another JAX traced the branches in the other order).
        traced = []

        def run(ops):
            out = fn(*ops)
            traced.append(jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), out))
            return out

        def zeros(ops):
            shapes = traced[-1] if traced else jax.eval_shape(fn, *ops)
            return jax.tree.map(lambda t: jnp.zeros(t.shape, t.dtype), shapes)

        return jax.lax.cond(tok >= jnp.iinfo(jnp.int32).min, run, zeros, operands)

    # The batched token is reduced to one predicate for the batch, which keeps the conditional.
    return _steered(jnp.asarray(token, jnp.int32), tuple(args), single=single, reduce=jnp.min,
                    batched=lambda tok, ops: stage(jax.vmap(fn), ops, tok),
                    tangent_fn=lambda _: (lambda ops: fn(*ops)))


def stage_token(x: jax.Array) -> jax.Array:
    """The int32 scalar token of :func:`stage` / :func:`fence` taken from an array: the bits of its first value.

    Args:
      x: any array of float32 (or a type that converts to float32 exactly), at least one element; usually
        the depth image, so that the fences of every stage reading it share one token.

    Returns:
      int32 scalar: ``x``'s first value, as float32, reinterpreted (``bitcast_convert_type``), not converted.

    Why data: the token must come from the inputs, so that XLA cannot fold the fence's predicate and inline
    the conditional (which would fuse the stages again). Why one value's bits: a bitcast costs no
    instruction and every bit pattern is a valid int32 (a NaN or an infinite depth too, where a float to
    int conversion is not defined), and the same expression of the same array gives the same scalar, which
    XLA computes once: the fences of Step 1, Step 2's prefilter and the tail share one predicate kernel
    instead of one per token (the KITTI listed program 203 -> 199 kernels when they first shared it).
    """
    return jax.lax.bitcast_convert_type(jnp.ravel(x)[0].astype(jnp.float32), jnp.int32)


def fence(*arrays, token=None):
    """Materialises ``arrays`` (identity): consumers read buffers, producers run once.

    ``token`` defaults to the first element of the first array (as int32).
    Returns a tuple of the arrays (the arrays themselves when the tricks are off).
    """
    if not enabled():
        return tuple(arrays)
    if token is None:
        first = jnp.ravel(arrays[0])[0]
        if jnp.iscomplexobj(first):
            first = jnp.real(first)
        token = first.astype(jnp.int32)  # any int32 value will do
    return stage(lambda *a: a, arrays, token)


def small_matmul(lhs: jax.Array, rhs: jax.Array) -> jax.Array:
    """``jnp.matmul(lhs, rhs)`` of float32 ``(..., N, K) @ (..., K, M)`` with a small K (3-vectors by 3 x 3
    matrices), as products and sums.

    XLA:CPU hands such a dot to YNNPACK, which takes ~9 ms for (2, 65536, 3) @ (2, 3, 3) (0.1 ms
    elementwise). Its result is each product rounded to float32, summed in order (k = 0, 1, ...),
    no FMA: the products here are fenced (:func:`fence`), so XLA cannot fuse a multiply into the
    add, and the sums run in that order: the dot's bits (``tests/test_xla_tuning.py``). Plain: the
    dot itself.
    """
    if not enabled():
        return jnp.matmul(lhs, rhs)
    products = fence(*(lhs[..., :, k, None] * rhs[..., None, k, :] for k in range(lhs.shape[-1])))
    return functools.reduce(jnp.add, products)


def scatter_onto_fill(size: int, fill, slot: jax.Array, values: jax.Array) -> jax.Array:
    """``jnp.full((size,), fill, values.dtype).at[slot].set(values, mode="drop")`` on a canvas of its own.

    XLA merges equal fills (one constant broadcast) into one buffer, which each scatter into it then
    copies before writing (the rigs' six float32 channels of a camera: one fill read by six copies);
    inside its own conditional (:func:`stage`, token ``slot[0]``) each fill has the scatter as its only
    reader and is written where the scatter writes. Plain: the scatter.
    """
    def run(slot, values):
        return jnp.full((size,), fill, values.dtype).at[slot].set(values, mode="drop")

    return stage(run, (slot, values), slot[0]) if enabled() else run(slot, values)


def cond_all(pred, true_fn, false_fn, *operands):
    """``lax.cond(pred, true_fn, false_fn, *operands)`` that stays a conditional under ``vmap``.

    ``lax.cond`` with a batched predicate becomes a select that runs both
    branches. Here a batched predicate is reduced with ``all``: the batch
    takes ``true_fn`` only when every member would, else ``false_fn``. Use it
    only where both branches compute the same result (``true_fn`` being a fast
    path valid under ``pred``), so the choice never changes the output.
    Differentiable (the JVP follows ``lax.cond`` per member).
    """
    return _steered(jnp.asarray(pred, bool), tuple(operands), reduce=jnp.all,
                    single=lambda p, ops: jax.lax.cond(p, true_fn, false_fn, *ops),
                    batched=lambda p, ops: cond_all(p, jax.vmap(true_fn), jax.vmap(false_fn), *ops),
                    tangent_fn=lambda p: (lambda ops: jax.lax.cond(p, true_fn, false_fn, *ops)))


def pack_pair(a: jax.Array, b: jax.Array):
    """Two float32 channels of one shape, to be gathered together: complex64 ``a + i b`` (tricks
    on) or the pair ``(a, b)``. Read back with :func:`take_pair` or :func:`unpack_pair`."""
    return jax.lax.complex(a, b) if enabled() else (a, b)


def unpack_pair(packed) -> tuple[jax.Array, jax.Array]:
    """The two float32 channels of :func:`pack_pair` (or of any complex64 array)."""
    if isinstance(packed, tuple):
        return packed
    return jnp.real(packed), jnp.imag(packed)


def take_pair(packed, index: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Both channels of a flat (N,) :func:`pack_pair` (or complex64 array) at ``index`` (in bounds).

    Tricks on: one complex64 gather. Off: one float32 gather per channel (same values).
    """
    if enabled() and not isinstance(packed, tuple):
        return unpack_pair(packed.at[index].get(mode=_PIB))
    return tuple(channel.at[index].get(mode=_PIB) for channel in unpack_pair(packed))


def after(value: jax.Array, result: jax.Array) -> jax.Array:
    """``value``, scheduled after ``result`` (an int32 array) is computed (tricks on); else ``value``.

    The dependence is ``where(result[0, ...] > INT32_MIN, value, 0)``: always ``value``, but
    XLA cannot prove it.
    """
    if not enabled():
        return value
    return jnp.where(jnp.ravel(result)[0] > _INT32_MIN, value, jnp.zeros((), value.dtype))


def any_true(mask: jax.Array) -> jax.Array:
    """``jnp.any(mask)`` of a bool array (any shape), as an int32 max (tricks on); the same bool scalar.

    XLA:CPU splits a long bool reduction into a 32-wide ``reduce-window`` whose kernel is about
    200 kB of LLVM IR (on 26,752 entries: ~5 % of the KITTI program's code, ~0.4 s of its compile);
    the int32 maximum compiles to about 30 kB.
    """
    if not enabled():
        return jnp.any(mask)
    return jnp.max(mask.astype(jnp.int32), initial=0) > 0


def first_row_and_count(mask: jax.Array, valid: jax.Array) -> tuple:
    """``(first, n)``: each column's first True row of an (H, W) bool ``mask`` ((W,) int32, H where none) and
    the int32 count of the True pixels of an (H, W) bool ``valid``; one loop over the rows (tricks on)."""
    height, width = mask.shape
    if not enabled():
        rows = jnp.arange(height, dtype=jnp.int32)[:, None]
        return jnp.min(jnp.where(mask, rows, height), axis=0), jnp.sum(valid, dtype=jnp.int32)

    def row(v, carry):
        first, count = carry
        return jnp.minimum(first, jnp.where(mask[v], v, height)), count + valid[v].astype(jnp.int32)

    first, count = jax.lax.fori_loop(0, height, row, (jnp.full((width,), height, jnp.int32),
                                                       jnp.zeros((width,), jnp.int32)))
    return first, jnp.sum(count)


def wrap_pad(a: jax.Array, k: int, fill, *, seam=None) -> jax.Array:
    """(L, C) -> (L + 2k, C + 2k): columns wrap around 360 degrees, rows take ``fill`` (the range-image
    padding of :mod:`~jaxdepth._src.normals`).

    ``seam``: added to the left pad and subtracted from the right one (``2 pi`` unwraps azimuths
    across the seam). Tricks on: one ``take`` with static column indices (the seam through ``where``
    on the pad columns) and ``jnp.pad`` for the rows, which XLA:CPU compiles as one kernel per array;
    the plain form's two column slices (or the seam's adds) and concatenate were three (docs/speed.md,
    "The wrap padding as one kernel"). The same values. Only for arrays that are buffers (stage
    operands): a gather of computed values pulls their maths into its kernel, which at the test
    suite's compile flags gave other last bits (the smoothing's pads use :func:`wrap_pad_slices`).
    """
    if not enabled():
        return wrap_pad_slices(a, k, fill, seam=seam)
    cols = a.shape[1]
    a = a[:, np.concatenate([np.arange(cols - k, cols), np.arange(cols), np.arange(k)])]
    if seam is not None:
        j = np.arange(cols + 2 * k)
        a = jnp.where(j < k, a + seam, jnp.where(j >= cols + k, a - seam, a))
    return jnp.pad(a, ((k, k), (0, 0)), constant_values=fill)


def wrap_pad_slices(a: jax.Array, k: int, fill, *, seam=None) -> jax.Array:
    """:func:`wrap_pad`'s plain form: the last and first ``k`` columns as two slices, one concatenate
    (in both modes for computed arrays, see :func:`wrap_pad`)."""
    left, right = a[:, a.shape[1] - k:], a[:, :k]
    if seam is not None:
        left, right = left + seam, right - seam
    a = jnp.concatenate([left, a, right], axis=1)
    rows = jnp.full((k, a.shape[1]), fill, a.dtype)
    return jnp.concatenate([rows, a, rows], axis=0)


@custom_batching.custom_vmap
def _widest_bounds(first: jax.Array, stop: jax.Array):
    return first, stop


@_widest_bounds.def_vmap
def _widest_bounds_vmap(axis_size, in_batched, first, stop):
    del axis_size
    first_batched, stop_batched = in_batched
    first = jnp.min(first) if first_batched else first
    stop = jnp.max(stop) if stop_batched else stop
    return _widest_bounds(first, stop), (False, False)


def shared_loop_bounds(first: jax.Array, stop: jax.Array):
    """Loop bounds ``(first, stop)``; under ``vmap`` with the tricks on, ``(min first, max stop)``
    shared by the batch, so the loop counter stays a scalar. Use only for loops where the extra
    iterations are harmless."""
    if not enabled():
        return first, stop
    return _widest_bounds(first, stop)


@custom_batching.custom_vmap
def _take_last(values: jax.Array, index: jax.Array):
    return values.at[..., index].get(mode=_PIB, wrap_negative_indices=False)


@_take_last.def_vmap
def _take_last_vmap(axis_size, in_batched, values, index):
    values_batched, index_batched = in_batched
    values, index = jnp.asarray(values), jnp.asarray(index)
    if not index_batched:
        return _take_last(values, index), values_batched
    if not values_batched:
        values = jnp.broadcast_to(values, (axis_size,) + values.shape)
    rows, n = int(np.prod(values.shape[:-1])), values.shape[-1]      # batch x channels: one flat row each
    if rows * n > _INT32_MAX:                                         # past int32: the batched gather
        return jax.vmap(lambda v, i: v.at[..., i].get(mode=_PIB, wrap_negative_indices=False))(values, index), True
    row = jnp.arange(rows, dtype=jnp.int32).reshape(values.shape[:-1] + (1,) * (index.ndim - 1)) * n
    at = row + index.reshape(index.shape[:1] + (1,) * (values.ndim - 2) + index.shape[1:]).astype(jnp.int32)
    return values.reshape(-1).at[at].get(mode=_PIB, wrap_negative_indices=False), True


def take_last(values: jax.Array, index: jax.Array) -> jax.Array:
    """``values[..., index]``, every index in bounds: (..., N) values at an integer index array of any shape.

    Under ``vmap`` with the tricks on, a batched index reads the batch with one flat 1-D gather (member
    ``b``'s row at ``b N + index[b]``, int32; fused into its consumer), where JAX's batching rule gives
    XLA a gather of (member, index) pairs, which XLA:CPU writes out first as an int32 (B, ..., 2) array
    (the rig tail's seed gather: 152 MB per group of six 1550 x 2048 cameras). With the tricks on, the index is
    not wrapped (``wrap_negative_indices=False``: every index is in bounds, so no compare, add and select per
    element in the gathers' fusions; the KITTI frame 0.97x CPU, docs/speed.md "One frame now"). The same
    elements. Plain: ``values[..., index]``.
    """
    values, index = jnp.asarray(values), jnp.asarray(index)
    if not enabled():
        return values.at[..., index].get(mode=_PIB)
    return _take_last(values, index)


_COLUMN_BITS = 32


def mask_columns(mask: jax.Array) -> jax.Array:
    """A (H, W) bool mask laid out for a loop over its columns, read by :func:`mask_column`.

    With the tricks on, (ceil(W / 32), H) uint32: bit ``j`` of ``[k, v]`` is ``mask[v, 32 k + j]`` (columns past
    W False), so XLA:CPU's transposing copy moves one uint32 per 32 mask elements instead of every bool (the
    packing is one reduce fusion reading the mask in its own layout). Plain: ``mask.T``.
    """
    if not enabled():
        return mask.T
    h, w = mask.shape
    padded = -(-w // _COLUMN_BITS) * _COLUMN_BITS
    bits = jnp.pad(mask, ((0, 0), (0, padded - w))).reshape(h, padded // _COLUMN_BITS, _COLUMN_BITS)
    # A sum of distinct bits (one reduce fusion; an OR of 32 slices wrote the mask's uint32 convert out first).
    return jnp.sum(bits.astype(jnp.uint32) << jnp.arange(_COLUMN_BITS, dtype=jnp.uint32), axis=-1,
                   dtype=jnp.uint32).T


def mask_column(columns: jax.Array, u) -> jax.Array:
    """Column ``u`` (an int32 scalar or int, ``0 <= u < W``) of the mask of :func:`mask_columns`: (H,) bool."""
    if not enabled():
        return lax.dynamic_index_in_dim(columns, u, 0, keepdims=False, allow_negative_indices=False)
    u = jnp.asarray(u, jnp.int32)  # (a Python int when the loop runs eagerly)
    shift = _COLUMN_BITS.bit_length() - 1
    word = lax.dynamic_index_in_dim(columns, u >> shift, 0, keepdims=False, allow_negative_indices=False)
    return ((word >> (u & (_COLUMN_BITS - 1)).astype(jnp.uint32)) & 1) != 0


_PAIRED_MIN_PIXELS = 2**20
_EVEN_ROW_SHIFT = 0 if sys.byteorder == "little" else 16


def key_rows(keys_t: jax.Array) -> jax.Array:
    """The row pass's (W, H) keys (int16 or int32, each ``>= 0``) laid out for a loop over the rows, read by
    :func:`key_row`.

    With the tricks on, int16 keys, an even H and ``H W >= 2**20``: (H / 2, W) int32, word ``[j, u]`` holding
    ``keys_t[u, 2 j]`` and ``keys_t[u, 2 j + 1]`` (``lax.bitcast_convert_type`` of adjacent keys, then XLA:CPU's
    transposing copy of half the elements; at the KITTI frame's size the int16 transpose was as fast or faster).
    Else (plain, int32 keys, odd H, smaller images): ``keys_t.T``, (H, W).
    """
    w, h = keys_t.shape
    if not enabled() or keys_t.dtype != jnp.int16 or h % 2 or h * w < _PAIRED_MIN_PIXELS:
        return keys_t.T
    return lax.bitcast_convert_type(keys_t.reshape(w, h // 2, 2), jnp.int32).T


def key_row(rows: jax.Array, i, h: int) -> jax.Array:
    """Row ``i`` (an int32 scalar, ``0 <= i < h``) of the keys of :func:`key_rows` for an image of height ``h``:
    (W,) int32, the keys widened."""
    if rows.shape[0] == h:
        return lax.dynamic_index_in_dim(rows, i, 0, keepdims=False, allow_negative_indices=False).astype(jnp.int32)
    word = lax.dynamic_index_in_dim(rows, i >> 1, 0, keepdims=False, allow_negative_indices=False)
    # The half of the word that holds row i (the bitcast's element order is the host's byte order, XLA:CPU;
    # every key is >= 0 and below 2**15, so the mask gives it back exactly).
    return (word >> (_EVEN_ROW_SHIFT ^ ((i & 1) << 4))) & 0xFFFF


def _plain_put_row(buf: jax.Array, row: jax.Array, i: jax.Array):
    return lax.dynamic_update_index_in_dim(buf, row, i, 0, allow_negative_indices=False)


def _wrapping_put_row(buf: jax.Array, row: jax.Array, i: jax.Array):
    return lax.dynamic_update_index_in_dim(buf, row, i, 0)


def _batched_put_row(plain):
    """``plain`` as a ``custom_vmap`` whose batch rule writes the batch's rows with one ``dynamic_update_slice``."""
    put = custom_batching.custom_vmap(plain)

    @put.def_vmap
    def put_vmap(axis_size, in_batched, buf, row, i):
        buf_batched, row_batched, i_batched = in_batched
        if i_batched:                                   # a row per member: JAX's batching rule (a scatter)
            return jax.vmap(plain, in_axes=(0 if buf_batched else None, 0 if row_batched else None, 0))(
                buf, row, i), True
        if not buf_batched:
            buf = jnp.broadcast_to(buf, (axis_size,) + buf.shape)
        if not row_batched:
            row = jnp.broadcast_to(row, (axis_size,) + row.shape)
        return lax.dynamic_update_index_in_dim(buf, row, i, 1, allow_negative_indices=False), True

    return put


_put_row = _batched_put_row(_plain_put_row)
_put_row_wrapping = _batched_put_row(_wrapping_put_row)


def put_row(buf: jax.Array, row: jax.Array, i, *, wrap: bool = False) -> jax.Array:
    """``buf`` with row ``i`` (int32 scalar, in range: ``0 <= i < N``) replaced by ``row``: (N, ...) and (...) arrays.

    Under ``vmap`` with the tricks on and ``i`` unbatched (a loop's row counter), one
    ``dynamic_update_slice`` of the batched buffer at (0, i, 0, ...). JAX batches a
    ``dynamic_update_slice`` as a scatter, which XLA:CPU turns back into one guarded by an in-bounds
    select that reads the buffer's old row at every step (the rigs' row loops under the size groups'
    ``vmap``: the seed search's sweeps, the column bracket's running maxima). The same values: ``i`` is in
    range. Plain: ``lax.dynamic_update_index_in_dim``. Not for float buffers that are differentiated: reverse mode
    does not go through its ``custom_vmap`` outside ``vmap`` (jaxdepth writes integer keys with it).
    ``wrap`` (static): outside ``vmap``, ``lax``'s negative-index wrap kept (a compare and select of ``i``; the
    same values), so that a single-camera program stays the one it was where its reads wrap ``i`` too (XLA
    computes the wrapped index once for both; the L2 column pass).
    """
    plain, put = (_wrapping_put_row, _put_row_wrapping) if wrap else (_plain_put_row, _put_row)
    if not enabled():
        return plain(buf, row, i)
    return put(buf, row, jnp.asarray(i, jnp.int32))


def entry_jit(fun=None, **jit_kwargs):
    """``jax.jit(fun, **jit_kwargs)`` compiled with :data:`COMPILER_OPTIONS` when called at the top level.

    JAX takes compile options only for a program's outermost ``jit``: called with a tracer among its
    arguments (inside another ``jit``, ``vmap``, ``grad``), or inside another trace with constants only
    (JAX then refuses the options), the call goes to the plain ``jit``, whose program the caller's
    compiles. Same results either way (the options steer copy insertion only).
    Usable as ``@entry_jit`` or ``@functools.partial(entry_jit, static_argnames=...)``; ``lower`` and
    ``clear_cache`` are the top-level ``jit``'s (``clear_cache`` clears both); ``compiler_options`` is
    :data:`COMPILER_OPTIONS`, for callers that compile the function inside a ``jit`` of their own (the program
    cache's :class:`~jaxdepth.batch.program_cache.Program`, benchmarks).
    """
    if fun is None:
        return functools.partial(entry_jit, **jit_kwargs)
    plain = jax.jit(fun, **jit_kwargs)
    top = jax.jit(fun, compiler_options=COMPILER_OPTIONS, **jit_kwargs)
    static = frozenset(jit_kwargs.get("static_argnames", ()))    # hashable options: never tracers

    @functools.wraps(fun)
    def call(*args, **kwargs):
        dynamic = (args, [v for k, v in kwargs.items() if k not in static])
        if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(dynamic)):
            return plain(*args, **kwargs)
        try:
            return top(*args, **kwargs)
        except ValueError as error:      # nested without tracers among the arguments (closed-over constants)
            if "compiler_options" not in str(error):
                raise
            return plain(*args, **kwargs)

    def clear_cache():
        plain.clear_cache()
        top.clear_cache()

    call.lower, call.clear_cache, call.compiler_options = top.lower, clear_cache, COMPILER_OPTIONS
    return call
