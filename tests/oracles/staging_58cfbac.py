"""FROZEN ORACLE: jaxdepth/_src/staging.py at commit 58cfbac (used by ``normals_58cfbac``), verbatim
except this header. Do not edit.
"""
# flake8: noqa
# ruff: noqa

from __future__ import annotations

"""Stage fences: make XLA:CPU materialise an intermediate instead of re-running it.

XLA fuses a producer into every consumer. When a heavy elementwise chain feeds
shifted slices, gathers or several outputs, each consumer re-runs the whole
chain per element it reads (measured 5-20x slower than reading a buffer).
``lax.optimization_barrier`` is removed before fusion on CPU, so :func:`stage`
runs the producer inside a ``lax.cond`` whose predicate always holds but is not
provable at compile time (an int32 from the data compared with INT32_MIN): a
conditional's operands and results are real buffers. The producer runs inside
the branch, so nothing is copied.

Under ``vmap`` the predicate is reduced to a scalar (``custom_vmap``), so the
conditional is not turned into a select that would run both branches; a
``custom_jvp`` differentiates ``fn`` directly, so gradients flow as if the
fence were not there.
"""


import jax
import jax.numpy as jnp
from jax import custom_batching


def stage(fn, args, token):
    """``fn(*args)`` computed in its own conditional: its outputs are real buffers
    that consumers read instead of re-running ``fn``.

    Args:
      fn: function of arrays returning a tuple (or any pytree) of arrays.
      args: tuple of arrays (the conditional's operands).
      token: int32 scalar derived from the data; ``token >= INT32_MIN`` always
        holds, so ``fn`` always runs. Any data-dependent scalar works (e.g.
        ``mask[0, 0].astype(jnp.int32)``).

    Returns:
      ``fn(*args)``, bit-identical to calling it directly.
    """
    args = tuple(args)

    @custom_batching.custom_vmap
    def run(operands, tok):
        shapes = jax.eval_shape(fn, *operands)
        return jax.lax.cond(tok >= jnp.iinfo(jnp.int32).min, lambda ops: fn(*ops),
                            lambda ops: jax.tree.map(lambda t: jnp.zeros(t.shape, t.dtype), shapes), operands)

    @run.def_vmap
    def run_vmap(axis_size, in_batched, operands, tok):
        ops_batched, tok_batched = in_batched
        if tok_batched:
            tok = jnp.min(tok)  # one predicate for the batch keeps the conditional
        operands = tuple(a if b else jnp.broadcast_to(a, (axis_size,) + a.shape)
                         for a, b in zip(operands, ops_batched))
        out = stage(jax.vmap(fn), operands, tok)
        return out, jax.tree.map(lambda _: True, out)

    @jax.custom_jvp
    def staged(operands, tok):
        return run(operands, tok)

    @staged.defjvp
    def staged_jvp(primals, tangents):
        operands, _ = primals
        return jax.jvp(fn, operands, tangents[0])

    return staged(args, jnp.asarray(token, jnp.int32))


def fence(*arrays, token=None):
    """Materialises ``arrays`` (identity): consumers read buffers, producers run once.

    ``token`` defaults to the first element of the first array (as int32).
    Returns a tuple of the arrays.
    """
    if token is None:
        token = jnp.ravel(arrays[0])[0].astype(jnp.int32)  # any int32 value will do
    return stage(lambda *a: a, arrays, token)


def cond_all(pred, true_fn, false_fn, *operands):
    """``lax.cond(pred, true_fn, false_fn, *operands)`` that stays a conditional under ``vmap``.

    ``lax.cond`` with a batched predicate becomes a select that runs both
    branches. Here a batched predicate is reduced with ``all``: the batch
    takes ``true_fn`` only when every member would, else ``false_fn``. Use it
    only where both branches compute the same result (``true_fn`` being a fast
    path valid under ``pred``), so the choice never changes the output.
    Differentiable (the JVP follows ``lax.cond`` per member).
    """

    @custom_batching.custom_vmap
    def run(pred, operands):
        return jax.lax.cond(pred, true_fn, false_fn, *operands)

    @run.def_vmap
    def run_vmap(axis_size, in_batched, pred, operands):
        pred_batched, ops_batched = in_batched
        if pred_batched:
            pred = jnp.all(pred)
        operands = tuple(a if b else jnp.broadcast_to(a, (axis_size,) + a.shape)
                         for a, b in zip(operands, ops_batched))
        out = cond_all(pred, jax.vmap(true_fn), jax.vmap(false_fn), *operands)
        return out, jax.tree.map(lambda _: True, out)

    @jax.custom_jvp
    def chosen(pred, operands):
        return run(pred, operands)

    @chosen.defjvp
    def chosen_jvp(primals, tangents):
        pred, operands = primals
        return jax.jvp(lambda ops: jax.lax.cond(pred, true_fn, false_fn, *ops), (operands,), (tangents[1],))

    return chosen(jnp.asarray(pred, bool), tuple(operands))
