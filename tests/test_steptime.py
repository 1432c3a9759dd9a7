"""The per-step work count of learn._steptime (XLA's FLOP count of a compiled program)."""

import jax
import jax.numpy as jnp
import pytest

from softpinn.learn._steptime import step_gflop


def test_step_gflop_counts_a_matrix_product():
    """A product of (64, 32) and (32, 128) matrices is 2·64·32·128 floating-point operations."""
    a, b = jnp.ones((64, 32)), jnp.ones((32, 128))
    compiled = jax.jit(jnp.matmul).lower(a, b).compile()
    assert step_gflop(compiled) == pytest.approx(2 * 64 * 32 * 128 / 1e9, rel=0.01)


def test_step_gflop_is_none_without_a_count():
    class NoCount:
        def cost_analysis(self):
            raise NotImplementedError

    assert step_gflop(NoCount()) is None
    assert step_gflop(type("Empty", (), {"cost_analysis": lambda self: [{}]})()) is None
