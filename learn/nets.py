"""Sub-networks of the physics-inspired models (Section III-A, Figs. 2-5).

Every field maps one configuration vector q (n,) to one physical quantity:

* :class:`CholeskyField` (Fig. 2 / Fig. 3): a positive-definite (``eps > 0``) or positive
  semi-definite (``eps = 0``) matrix field U(q) = L(q) L(q)ᵀ. An MLP outputs (n² + n)/2 numbers;
  the first n, through softplus and + eps, are the diagonal of L, the rest its strictly-lower
  entries ``[l10, l20, l21, ...]``. Used for M(q), M⁻¹(q) (Hamiltonian) and D(q).
* :class:`ConstantCholesky`: the same, but a learned constant (constant damping).
* :class:`ScalarField` (Fig. 4): the potential V(q).
* :class:`MatrixField` (Fig. 5): the input matrix A(q) in R^{n x m}; :class:`ConstantMatrix`
  is its learned-constant version, :class:`ZeroMatrix` a fixed zero (m = 0, or no damping).

The models only rely on this small protocol, so tests can inject analytic fields:

* mass-like fields: ``factor(q) -> L`` (lower triangular, positive diagonal) and
  ``__call__(q) -> L Lᵀ``;
* damping and input fields: ``__call__(q) -> (n, n)`` or ``(n, m)`` matrix;
* potential: ``__call__(q) -> scalar``.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .errors import UserError
from .linalg import lower_from_parts, n_offdiag

__all__ = [
    "ACTIVATIONS",
    "activation_fn",
    "make_mlp",
    "CholeskyField",
    "ConstantCholesky",
    "ScalarField",
    "MatrixField",
    "ConstantMatrix",
    "ZeroMatrix",
]

ACTIVATIONS: dict[str, Callable] = {
    "softplus": jax.nn.softplus,
    "tanh": jnp.tanh,
    "relu": jax.nn.relu,
    "silu": jax.nn.silu,
    "gelu": jax.nn.gelu,
    "elu": jax.nn.elu,
    "sigmoid": jax.nn.sigmoid,
}


def activation_fn(name: str) -> Callable:
    """The activation function called ``name`` (one of :data:`ACTIVATIONS`)."""
    try:
        return ACTIVATIONS[name]
    except KeyError:
        raise UserError(f"activation must be one of {sorted(ACTIVATIONS)}, got {name!r}") from None


def make_mlp(in_size, out_size, width: int, depth: int, activation: str, *, key, dtype):
    """An ``eqx.nn.MLP``: ``depth`` hidden layers of ``width`` units, parameters in ``dtype``."""
    return eqx.nn.MLP(
        in_size=in_size,
        out_size=out_size,
        width_size=width,
        depth=depth,
        activation=activation_fn(activation),
        key=key,
        dtype=jnp.dtype(dtype),
    )


class CholeskyField(eqx.Module):
    """U(q) = L(q) L(q)ᵀ with L lower triangular, diag(L) = softplus(.) + eps (Figs. 2, 3).

    ``eps > 0`` makes U positive definite (mass matrix M or its inverse); ``eps = 0`` gives the
    positive semi-definite damping matrix D (softplus keeps the diagonal non-negative).
    """

    mlp: eqx.nn.MLP
    n: int = eqx.field(static=True)
    eps: float = eqx.field(static=True)

    def __init__(self, n, width, depth, activation, eps, *, key, dtype="float64"):
        self.n = int(n)
        self.eps = float(eps)
        self.mlp = make_mlp(n, n + n_offdiag(n), width, depth, activation, key=key, dtype=dtype)

    def factor(self, q):
        """The lower-triangular factor L(q), shape (n, n)."""
        out = self.mlp(q)
        n = self.n
        return lower_from_parts(jax.nn.softplus(out[:n]) + self.eps, out[n:])

    def __call__(self, q):
        L = self.factor(q)
        return L @ L.T


class ConstantCholesky(eqx.Module):
    """A learned constant U = L Lᵀ, diag(L) = softplus(.) + eps; ``q`` is ignored."""

    raw: jax.Array
    n: int = eqx.field(static=True)
    eps: float = eqx.field(static=True)

    def __init__(self, n, eps, *, key, dtype="float64", scale=0.1):
        self.n = int(n)
        self.eps = float(eps)
        self.raw = scale * jax.random.normal(key, (n + n_offdiag(n),), jnp.dtype(dtype))

    def factor(self, q):
        del q
        n = self.n
        return lower_from_parts(jax.nn.softplus(self.raw[:n]) + self.eps, self.raw[n:])

    def __call__(self, q):
        L = self.factor(q)
        return L @ L.T


class ScalarField(eqx.Module):
    """A scalar field of q, e.g. the potential energy V(q) (Fig. 4)."""

    mlp: eqx.nn.MLP

    def __init__(self, n, width, depth, activation, *, key, dtype="float64"):
        self.mlp = make_mlp(n, "scalar", width, depth, activation, key=key, dtype=dtype)

    def __call__(self, q):
        return self.mlp(q)


class MatrixField(eqx.Module):
    """A matrix field A(q) in R^{rows x cols}: an MLP with rows*cols outputs, reshaped (Fig. 5)."""

    mlp: eqx.nn.MLP
    shape: tuple[int, int] = eqx.field(static=True)

    def __init__(self, n, rows, cols, width, depth, activation, *, key, dtype="float64"):
        self.shape = (int(rows), int(cols))
        self.mlp = make_mlp(n, rows * cols, width, depth, activation, key=key, dtype=dtype)

    def __call__(self, q):
        return self.mlp(q).reshape(self.shape)


class ConstantMatrix(eqx.Module):
    """A learned constant matrix; ``q`` is ignored."""

    value: jax.Array

    def __init__(self, rows, cols, *, key, dtype="float64", scale=None):
        scale = 1.0 / np.sqrt(max(cols, 1)) if scale is None else scale
        self.value = scale * jax.random.normal(key, (rows, cols), jnp.dtype(dtype))

    def __call__(self, q):
        del q
        return self.value


class ZeroMatrix(eqx.Module):
    """A fixed zero matrix of a given shape (no damping; A for unactuated systems, m = 0)."""

    shape: tuple[int, int] = eqx.field(static=True)

    def __call__(self, q):
        return jnp.zeros(self.shape, q.dtype)
