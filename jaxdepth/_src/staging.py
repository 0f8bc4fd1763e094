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

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import custom_batching


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
        ``mask[0, 0].astype(jnp.int32)``).

    Returns:
      ``fn(*args)``, bit-identical to calling it directly.
    """

    def single(tok, operands):
        shapes = jax.eval_shape(fn, *operands)
        return jax.lax.cond(tok >= jnp.iinfo(jnp.int32).min, lambda ops: fn(*ops),
                            lambda ops: jax.tree.map(lambda t: jnp.zeros(t.shape, t.dtype), shapes), operands)

    # The batched token is reduced to one predicate for the batch, which keeps the conditional.
    return _steered(jnp.asarray(token, jnp.int32), tuple(args), single=single, reduce=jnp.min,
                    batched=lambda tok, ops: stage(jax.vmap(fn), ops, tok),
                    tangent_fn=lambda _: (lambda ops: fn(*ops)))


def fence(*arrays, token=None):
    """Materialises ``arrays`` (identity): consumers read buffers, producers run once.

    ``token`` defaults to the first element of the first array (as int32).
    Returns a tuple of the arrays.
    """
    if token is None:
        first = jnp.ravel(arrays[0])[0]
        if jnp.iscomplexobj(first):
            first = jnp.real(first)
        token = first.astype(jnp.int32)  # any int32 value will do
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
    return _steered(jnp.asarray(pred, bool), tuple(operands), reduce=jnp.all,
                    single=lambda p, ops: jax.lax.cond(p, true_fn, false_fn, *ops),
                    batched=lambda p, ops: cond_all(p, jax.vmap(true_fn), jax.vmap(false_fn), *ops),
                    tangent_fn=lambda p: (lambda ops: jax.lax.cond(p, true_fn, false_fn, *ops)))


def switch_widest(index, branches, *operands):
    """``lax.switch(index, branches, *operands)`` that stays a switch under ``vmap``.

    A batched ``index`` is reduced with ``max``: the whole batch takes the
    branch of its largest index. Use it only for branches that are valid for
    any index at least the true one (e.g. wider windows that give the same
    result with more work), so the choice never changes the output.
    Operands may be pytrees (tuples of arrays).
    """
    return _steered(index, tuple(operands), reduce=jnp.max,
                    single=lambda i, ops: jax.lax.switch(i, branches, *ops),
                    batched=lambda i, ops: switch_widest(i, [jax.vmap(fn) for fn in branches], *ops))
