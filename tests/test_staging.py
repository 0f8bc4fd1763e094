"""Stage fences and batch-aware conditionals: identities, and what they do under vmap."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.xla_tuning import cond_all, fence, stage


def test_fence_and_stage_are_identities_under_jit_and_vmap():
    x = jnp.arange(12.0).reshape(3, 4)
    f = jax.jit(lambda a: fence(a * 2.0, a + 1.0))
    np.testing.assert_array_equal(f(x)[0], x * 2.0)
    np.testing.assert_array_equal(f(x)[1], x + 1.0)
    g = jax.vmap(lambda a: stage(lambda b: (jnp.sin(b),), (a,), jnp.int32(0))[0])
    np.testing.assert_array_equal(g(x), jnp.sin(x))
    grad = jax.grad(lambda a: fence(a * a)[0].sum())(x)
    np.testing.assert_allclose(grad, 2 * x)


def test_cond_all_takes_the_fast_branch_only_when_every_member_may():
    fast = lambda a: (a * 2.0, jnp.int32(1))
    slow = lambda a: (a + a, jnp.int32(0))
    xs = jnp.arange(6.0).reshape(3, 2)
    out, which = jax.vmap(lambda p, a: cond_all(p, fast, slow, a))(jnp.array([True, True, True]), xs)
    np.testing.assert_array_equal(which, [1, 1, 1])
    out, which = jax.vmap(lambda p, a: cond_all(p, fast, slow, a))(jnp.array([True, False, True]), xs)
    np.testing.assert_array_equal(which, [0, 0, 0])
    np.testing.assert_array_equal(out, xs * 2.0)


def test_cond_all_broadcasts_unbatched_pytree_operands():
    """An unbatched tuple operand next to a batched one (a vmap over a parameter only)."""
    fast = lambda pair, s: pair[0] * s + pair[1]
    slow = lambda pair, s: pair[0] * s + pair[1] + 0.0
    pair = (jnp.arange(3.0), jnp.ones(3))
    scales = jnp.array([1.0, 2.0, 3.0, 4.0])
    got = jax.vmap(lambda s: cond_all(s > 2.0, fast, slow, pair, s))(scales)
    want = jnp.stack([pair[0] * s + pair[1] for s in scales])
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
