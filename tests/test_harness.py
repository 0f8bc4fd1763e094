"""The test harness itself must be able to fail: NaN, tolerance, retrace, jit != eager."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from _harness import assert_close, check_stage

EPS32 = float(np.finfo(np.float32).eps)


def test_assert_close_rejects_nan_even_against_nan():
    with pytest.raises(AssertionError, match="NaN"):
        assert_close(np.float32([1.0, np.nan]), np.float32([1.0, np.nan]), ulps=1e9)


def test_assert_close_tolerance_is_eps_times_scale():
    x = np.float32([100.0])
    assert_close(x + np.float32(4 * 100 * EPS32), x, ulps=5)
    with pytest.raises(AssertionError, match="differ"):
        assert_close(x + np.float32(8 * 100 * EPS32), x, ulps=5)
    with pytest.raises(AssertionError, match="infinities"):
        assert_close(np.float32([np.inf]), np.float32([-np.inf]), ulps=1)
    with pytest.raises(AssertionError):
        assert_close(np.int32([1, 2]), np.int32([1, 3]), ulps=1e9)


@dataclasses.dataclass(frozen=True, eq=False)
class _IdentityHashed:
    """An option object without value equality: every fresh copy is a new jit cache key."""
    factor: float = 2.0


def test_check_stage_catches_a_retrace_on_identity_hashed_options():
    f = lambda x, *, option: x * option.factor
    inputs = [(np.ones(3, np.float32),), (np.zeros(3, np.float32),)]
    with pytest.raises(AssertionError, match="retraced"):
        check_stage(f, inputs, static=dict(option=_IdentityHashed()))


def test_check_stage_catches_a_retrace_of_a_jitted_stage():
    """A stage that is itself a jax.jit object runs as it is; its retraces are counted through jax.monitoring."""
    inputs = [(np.ones(3, np.float32),), (np.zeros(3, np.float32),)]
    f = jax.jit(lambda x, *, option: x * option.factor, static_argnames="option")
    with pytest.raises(AssertionError, match="retraced"):
        check_stage(f, inputs, static=dict(option=_IdentityHashed()))
    g = jax.jit(lambda x: x * 2.0)
    drift = [(np.ones(3, np.float32),), (np.zeros(3, np.float64).astype(np.int32),)]  # dtype drift: a new trace
    with pytest.raises(AssertionError, match="retraced"):
        check_stage(g, drift)
    check_stage(jax.jit(lambda x, *, k: x * k, static_argnames="k"), inputs, static=dict(k=2.0), oracle=lambda x, k: 2 * x)


def test_check_stage_catches_jit_differing_from_eager_and_a_wrong_oracle():
    def f(x):  # a value that differs between tracing and eager execution
        return x + (0.0 if isinstance(x, jax.core.Tracer) else 1.0)
    inputs = [(np.ones(3, np.float32),), (np.zeros(3, np.float32),)]
    with pytest.raises(AssertionError, match=r"(plain call|eager) != jit|jit != eager"):
        check_stage(f, inputs)
    with pytest.raises(AssertionError, match="oracle"):
        check_stage(jnp.sin, inputs, oracle=lambda x: np.cos(x))
    check_stage(jnp.sin, inputs, oracle=lambda x: np.sin(x.astype(np.float64)), oracle_ulps=1)


@pytest.mark.xdist_group("harness_group_check")
def test_xdist_groups_are_honoured(request):
    """Under ``--dist loadgroup`` pytest-xdist tags each grouped test's node id with its group and
    schedules a group on one worker. When it cannot tag them (pytest 9.2 with pytest-xdist 3.8), the
    groups are silently ignored: Ray clusters and module-scoped jobs then start on both workers, and
    shared programs compile twice. pyproject.toml pins pytest below 9.2."""
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("not run by a pytest-xdist worker with --dist loadgroup")
    assert request.node.nodeid.endswith("@harness_group_check"), request.node.nodeid
