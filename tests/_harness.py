"""One check for one stage function, in the style of dm_pix's tests.

:func:`check_stage` runs a function on a few inputs of one shape and checks:

1. **oracle**: the output equals an independent reference (a callable: OpenCV,
   SciPy, brute-force NumPy or an analytic answer);
2. **jit == eager**: ``jax.jit`` of the function equals the function run op by
   op under ``jax.disable_jit()`` (the library's own ``jit`` is disabled too);
   the one op-by-op run: a plain call outside ``jit`` would be a second one
   (``jax.numpy``'s own small jits compiled besides the primitives) that sees
   nothing the eager run does not (Python on concrete values);
3. **vmap == loop**: ``jax.vmap`` over the stacked inputs equals a Python loop
   of the per-input calls (a plain function's vmap runs inside ``jax.jit``: one compiled
   program, as a library jit's vmap is, not every batched primitive compiled op by op);
4. **no retrace**: a new input of the same shape (and a fresh, equal copy of
   every static option) reuses the compiled function. This catches static
   options that hash by identity, inputs whose dtype or weak type drifts, and
   Python control flow on traced values. A plain Python function is wrapped in
   ``jax.jit`` and its traces counted by a counter inside the wrapper. A
   function that already is a ``jax.jit`` object is called as it is (its
   program is the one the property tests and the session's compilation cache
   already hold: no second compile of the same stage), and its traces are
   counted through ``jax.monitoring``'s public trace-duration event.

Tolerances are multiples of the output dtype's machine epsilon:
``|actual - expected| <= ulps * eps * scale`` with ``scale`` the expected
magnitude (``max(|expected|, 1)`` per element unless given). Integer and bool
outputs must match exactly. NaN is never close to anything, not even NaN;
infinities must match exactly.
"""

from __future__ import annotations

import contextlib
import copy
import functools
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np


def assert_close(actual, expected, *, ulps: float, scale=None, err_msg: str = "") -> None:
    """Elementwise ``|actual - expected| <= ulps * eps(dtype) * scale``; NaN always fails.

    Args:
      actual: array (its dtype sets eps; integer / bool dtypes compare exactly).
      expected: array of the same shape.
      ulps: how many eps the difference may reach (derived in the caller: e.g.
        the number of rounded float operations between the two results).
      scale: scalar or array broadcastable to the shape; default
        ``max(|expected|, 1)`` per element.
    """
    actual = np.asarray(actual)
    expected = np.asarray(expected)
    assert actual.shape == expected.shape, f"{err_msg}: shape {actual.shape} != {expected.shape}"
    if not np.issubdtype(actual.dtype, np.inexact):
        np.testing.assert_array_equal(actual, expected, err_msg=err_msg)
        return
    a = actual.astype(np.float64)
    e = np.asarray(expected, np.float64)
    nan = np.isnan(a) | np.isnan(e)
    assert not nan.any(), f"{err_msg}: NaN at {np.argwhere(nan)[:5].tolist()} (NaN is never close)"
    inf = np.isinf(a) | np.isinf(e)
    assert np.array_equal(a[inf], e[inf]), f"{err_msg}: infinities differ"
    eps = float(np.finfo(actual.dtype).eps)
    if scale is None:
        scale = np.maximum(np.abs(np.where(inf, 0.0, e)), 1.0)
    tol = ulps * eps * np.broadcast_to(np.asarray(scale, np.float64), a.shape)
    diff = np.abs(np.where(inf, 0.0, a) - np.where(inf, 0.0, e))
    bad = diff > tol
    if bad.any():
        i = tuple(np.argwhere(bad)[0])
        raise AssertionError(f"{err_msg}: {int(bad.sum())} of {bad.size} elements differ by more than "
                             f"{ulps} eps x scale; first at {i}: {a[i]!r} vs {e[i]!r} (tolerance {tol[i]:.3g})")


def assert_tree_close(actual, expected, *, ulps: float, scale=None, err_msg: str = "",
                      check_dtype: bool = True) -> None:
    """:func:`assert_close` on every leaf of two pytrees of the same structure (and dtypes)."""
    a_leaves, a_def = jax.tree.flatten(actual)
    e_leaves, e_def = jax.tree.flatten(expected)
    assert a_def == e_def, f"{err_msg}: structure {a_def} != {e_def}"
    for k, (a, e) in enumerate(zip(a_leaves, e_leaves)):
        if check_dtype:
            assert np.asarray(a).dtype == np.asarray(e).dtype, f"{err_msg} leaf {k}: dtype {a.dtype} != {e.dtype}"
        assert_close(a, e, ulps=ulps, scale=scale, err_msg=f"{err_msg} leaf {k}")


#: jax.monitoring event recorded once per top-level jit trace (jax._src.dispatch.JAXPR_TRACE_EVENT).
_TRACE_EVENT = "/jax/core/compile/jaxpr_trace_duration"
_top_level_traces = [0]


def _count_trace(event: str, duration_secs: float, **kwargs) -> None:
    if event == _TRACE_EVENT:
        _top_level_traces[0] += 1


jax.monitoring.register_event_duration_secs_listener(_count_trace)


@contextlib.contextmanager
def compiled_programs():
    """The names of the pipeline programs (``jit(..._program)``) XLA compiles inside the block, as
    ``jax.monitoring``'s backend-compile events report them (a program the session's caches serve is none)."""
    names = []

    def on_compile(event: str, duration_secs: float, **kwargs) -> None:
        if event == "/jax/core/compile/backend_compile_duration" and "_program" in str(kwargs.get("fun_name")):
            names.append(kwargs.get("fun_name"))

    jax.monitoring.register_event_duration_secs_listener(on_compile)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(on_compile)


def _is_jitted(fn) -> bool:
    """True for a ``jax.jit`` object (it has ``lower`` and ``trace``), not for a plain function."""
    return callable(getattr(fn, "lower", None)) and callable(getattr(fn, "trace", None))


def _stack(inputs: Sequence[tuple], in_axes) -> tuple:
    axes = in_axes if isinstance(in_axes, (tuple, list)) else (in_axes,) * len(inputs[0])
    stacked = []
    for k, axis in enumerate(axes):
        if axis is None:
            stacked.append(inputs[0][k])
        else:
            stacked.append(jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs], axis),
                                        *[args[k] for args in inputs]))
    return tuple(stacked)


def check_stage(fn: Callable, inputs: Sequence[tuple], *, static: dict | None = None,
                oracle: Callable | None = None, select: Callable = lambda out: out,
                oracle_ulps: float = 4, oracle_scale=None, ulps: float = 4, scale=None,
                in_axes: Any = 0, vmap: bool = True, eager_inputs: int | None = None) -> list:
    """Oracle, jit == eager, vmap == loop and no retrace for ``fn`` on ``inputs``.

    Args:
      fn: the stage, called ``fn(*args, **static)``; returns a pytree of arrays.
      inputs: two or more argument tuples of identical shapes and dtypes (the
        vmap check stacks them; the retrace check needs a second input).
      static: keyword options (hashable); passed as static arguments to the jit.
      oracle: ``oracle(*args, **static)`` -> the reference for ``select(output)``.
      select: picks what the oracle is compared with (e.g. distances, not indices).
      oracle_ulps, oracle_scale: tolerance against the oracle (see :func:`assert_close`).
      ulps, scale: tolerance of jit vs eager and vmap vs loop (the same maths, differently fused).
      in_axes: vmap axes per argument; ``None`` shares the first input's argument.
      vmap: False skips vmap == loop (for functions documented as unbatchable).
      eager_inputs: run the eager comparison on the first this many inputs only (default all);
        op-by-op runs of a whole pipeline take seconds per input.

    Returns:
      The per-input (loop) outputs, one per input, for further checks by the caller.
    """
    assert len(inputs) >= 2, "check_stage needs two inputs of one shape (the retrace check)"
    static = dict(static or {})
    traces = []
    library_jit = _is_jitted(fn)
    if library_jit:
        jitted = fn  # the stage's own compiled program; traces counted by jax.monitoring
    else:
        def counted(*args, **kwargs):
            traces.append(1)
            return fn(*args, **kwargs)

        jitted = jax.jit(counted, static_argnames=tuple(static))
    plain = []
    for n, host_args in enumerate(inputs):
        args = jax.tree.map(jnp.asarray, host_args)  # the oracle gets the host (NumPy) arrays
        if library_jit:
            before = _top_level_traces[0]
            # a fresh copy of every static option: equal values must hit the cache
            out = fast = fn(*args, **copy.deepcopy(static))
            jax.block_until_ready(out)
            if n > 0:
                traces.extend([1] * (_top_level_traces[0] - before))
        else:
            # no plain call outside jit: a second op-by-op run beside the eager one below, checking nothing
            # more and compiling its own programs (docs/testing.md); the oracle and the loop take the jit's
            out = fast = jitted(*args, **copy.deepcopy(static))
        plain.append(jax.tree.map(np.asarray, out))
        if eager_inputs is None or n < eager_inputs:
            with jax.disable_jit():
                eager = fn(*args, **static)
            assert_tree_close(fast, eager, ulps=ulps, scale=scale, err_msg=f"input {n}: jit != eager")
        if oracle is not None:
            assert_tree_close(jax.tree.map(np.asarray, select(out)), oracle(*host_args, **static),
                              ulps=oracle_ulps, scale=oracle_scale, err_msg=f"input {n}: oracle",
                              check_dtype=False)
    expected = 0 if library_jit else 1  # a library jit may have been traced before (by another test)
    assert len(traces) == expected, f"retraced: {len(traces) - expected} new traces for {len(inputs)} inputs of one shape"
    if vmap:
        stacked = jax.tree.map(jnp.asarray, _stack(inputs, in_axes))
        batched_fn = jax.vmap(functools.partial(fn, **static), in_axes=in_axes)
        if not library_jit:  # a library jit's vmap already is one program (a jit around it would compile a second)
            batched_fn = jax.jit(batched_fn)
        batched = batched_fn(*stacked)
        for n, out in enumerate(plain):
            assert_tree_close(jax.tree.map(lambda x: np.asarray(x)[n], batched), out, ulps=ulps, scale=scale,
                              err_msg=f"input {n}: vmap != loop")
    return plain
