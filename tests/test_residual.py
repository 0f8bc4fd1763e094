"""Residual (Step 4a): exact on analytic planes, a float64 NumPy oracle, finite values and
gradients; jit, vmap and retrace via tests/_harness.py."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth._src.residual import plane_residual

#: Value tests call the stage through one jit (called plainly, each shape compiles every primitive op by op);
#: jit == eager, vmap == loop and no retrace are the stage table's plane_residual row.
_plane_residual = jax.jit(plane_residual, static_argnames=("min_abs_denom", "max_residual_ratio"))


K = np.array([[500.0, 0.0, 63.5], [0.0, 480.0, 40.2], [0.0, 0.0, 1.0]], np.float32)
H, W = 80, 128


def plane_depth(n, d, K, h, w):
    """Depth of the plane n . X = d seen through K at every pixel centre."""
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)])
    return d / np.tensordot(n, rays, axes=1)


@pytest.mark.parametrize("normal", [(0.0, 0.0, -1.0), (0.3, -0.2, -0.9), (-0.5, 0.4, -0.7), (0.0, -0.95, -0.3)])
def test_plane_completes_exactly(normal):
    n = np.asarray(normal, np.float64)
    n /= np.linalg.norm(n)
    depth = plane_depth(n, -10.0, K, H, W)  # n . X = -10 with n facing the camera
    assert np.all(depth > 0)
    rng = np.random.default_rng(0)
    du = rng.integers(-6, 7, size=(H, W))
    dv = rng.integers(-6, 7, size=(H, W))
    v, u = np.mgrid[0:H, 0:W]
    su = np.clip(u + du, 0, W - 1)
    sv = np.clip(v + dv, 0, H - 1)
    du, dv = su - u, sv - v
    seed_depth = depth[sv, su]
    seed_normal = np.broadcast_to(n[:, None, None], (3, H, W))
    dz = _plane_residual(jnp.float32(seed_depth), jnp.float32(seed_normal), jnp.int32(du), jnp.int32(dv),
                         K, min_abs_denom=1e-6, max_residual_ratio=10.0)
    completed = seed_depth + np.asarray(dz, np.float64)
    np.testing.assert_allclose(completed, depth, rtol=2e-5)
    if abs(n[0]) + abs(n[1]) > 0:  # tilted: the residual is a real correction, seeds alone are wrong
        assert np.abs(seed_depth - depth).max() > 0.05
    else:  # fronto-parallel: every residual is zero
        np.testing.assert_allclose(np.asarray(dz), 0.0, atol=1e-5)


def test_guards_keep_values_and_gradients_finite():
    seed_depth = jnp.full((4, 5), 10.0)
    grazing = jnp.zeros((3, 4, 5)).at[0].set(1.0)  # n = x axis: denominator ~ (u-pu)/fu can vanish
    du = jnp.ones((4, 5), jnp.int32)
    dv = jnp.zeros((4, 5), jnp.int32)
    Kg = jnp.array([[100.0, 0, 2.0], [0, 100.0, 2.0], [0, 0, 1]])

    def total(depth):
        return plane_residual(depth, grazing, du, dv, Kg).sum()

    value = jax.jit(total)(seed_depth)
    grad = jax.jit(jax.grad(total))(seed_depth)   # compiled once (op by op: every primitive of the backward pass)
    assert np.isfinite(value) and np.all(np.isfinite(grad))
    zero_normal = _plane_residual(seed_depth, jnp.zeros((3, 4, 5)), du, dv, Kg)
    assert np.all(zero_normal == 0)
    no_seed = _plane_residual(jnp.zeros((4, 5)), grazing, du, dv, Kg)
    assert np.all(no_seed == 0)


def test_residual_clipped_to_ratio():
    n = jnp.zeros((3, 4, 5)).at[0].set(0.99).at[2].set(-0.14)
    dz = _plane_residual(jnp.full((4, 5), 10.0), n, jnp.full((4, 5), 50, jnp.int32), jnp.zeros((4, 5), jnp.int32),
                         jnp.array([[100.0, 0, 2.0], [0, 100.0, 2.0], [0, 0, 1]]), max_residual_ratio=0.25)
    assert float(jnp.abs(dz).max()) <= 2.5 + 1e-6


def numpy_residual(seed_depth, seed_normal, du, dv, K, *, min_abs_denom, max_residual_ratio):
    """The paper's Delta z, float64, written from the formula (zero-skew pinhole)."""
    z, n = np.asarray(seed_depth, np.float64), np.asarray(seed_normal, np.float64)
    K = np.asarray(K, np.float64)
    v, u = np.indices(z.shape, dtype=np.float64)
    numer = z * (du * n[0] / K[0, 0] + dv * n[1] / K[1, 1])
    denom = (u - K[0, 2]) / K[0, 0] * n[0] + (v - K[1, 2]) / K[1, 1] * n[1] + n[2]
    ok = (np.abs(denom) > min_abs_denom) & (z > 0)
    dz = np.where(ok, numer / np.where(ok, denom, 1.0), 0.0)
    return np.clip(dz, -max_residual_ratio * z, max_residual_ratio * z)


# The NumPy oracle above, jit == eager, vmap == loop, no retrace: row plane_residual of tests/stage_table.py.
