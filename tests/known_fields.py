"""Analytic fields that follow the sub-network protocol of ``learn._nets``, for building
physics models with known matrices in tests (a network is replaced by a Python function)."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx

from softpinn.learn._linalg import cholesky


class Field(eqx.Module):
    """A known field q -> value (potential, damping or input matrix)."""

    fn: Callable = eqx.field(static=True)

    def __call__(self, q):
        return self.fn(q)


class MassField(eqx.Module):
    """A known SPD matrix field; factor() by the plain-jnp Cholesky."""

    fn: Callable = eqx.field(static=True)

    def factor(self, q):
        return cholesky(self.fn(q))

    def __call__(self, q):
        return self.fn(q)
