"""The sub-networks of :mod:`softpinn.learn._nets` rebuilt as CasADi SX expressions.

Each function takes the numeric parameters of one trained field (numpy arrays) and an SX column
vector and returns the same quantity the JAX field computes, with the same activations and the
same Cholesky construction (Figs. 2-5):

* :func:`mlp`: W_d σ(... σ(W_0 x + b_0) ...) + b_d;
* :func:`lower_factor`: diag(L) = softplus(.) + eps, the strictly-lower entries row by row
  ``[l10, l20, l21, l30, ...]`` (the order of ``numpy.tril_indices(n, -1)``, Fig. 2);
* :func:`field_expression`: a mass-like field's factor L(q), the potential V(q), a damping
  matrix D(q) = L Lᵀ and an input matrix A(q) (row-major reshape, as ``jnp.reshape``).

Nothing is evaluated numerically: the expressions are exact symbolic copies, so their
derivatives (``casadi.jacobian``, ``jtimes``) are the networks' own derivatives.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from softpinn.bridge.exact.serialize import casadi_function
from softpinn.errors import UserError

__all__ = [
    "ACTIVATIONS",
    "activation",
    "softplus",
    "mlp",
    "lower_factor",
    "solve_lower",
    "solve_lower_transpose",
    "cho_solve",
    "lower_inverse",
    "field_expression",
]


def softplus(z):
    """log(1 + eᶻ) as :func:`softpinn.learn._nets.softplus` writes it: max(z, 0) + log1p(e^-|z|)."""
    return ca.fmax(z, 0) + ca.log1p(ca.exp(-ca.fabs(z)))


def _sigmoid(z):
    return 1.0 / (1.0 + ca.exp(-z))


def _gelu(z):
    # jax.nn.gelu's default (approximate=True): the tanh form
    return 0.5 * z * (1.0 + ca.tanh(math.sqrt(2.0 / math.pi) * (z + 0.044715 * z**3)))


def _elu(z):
    # jax.nn.elu: where(z > 0, z, expm1(min(z, 0))): the inner min keeps e^z finite
    return ca.if_else(z > 0, z, ca.expm1(ca.fmin(z, 0)))


ACTIVATIONS = {
    "softplus": softplus,
    "tanh": ca.tanh,
    "relu": lambda z: ca.fmax(z, 0),
    "silu": lambda z: z * _sigmoid(z),
    "gelu": _gelu,
    "elu": _elu,
    "sigmoid": _sigmoid,
}


def activation(name: str):
    """The CasADi form of the activation ``name`` (the names of ``learn._nets.ACTIVATIONS``)."""
    try:
        return ACTIVATIONS[name]
    except KeyError:
        raise UserError(
            f"activation must be one of {sorted(ACTIVATIONS)} to export, got {name!r}"
        ) from None


def mlp(params: dict, x):
    """The MLP of ``learn._nets.MLP`` at the SX column ``x``.

    ``params``: ``{"weights": [W_0, ..., W_d], "biases": [...], "activation": name}`` with
    W_i of shape (fan_out, fan_in).
    """
    act = activation(params["activation"])
    h = x
    weights, biases = params["weights"], params["biases"]
    for W, b in zip(weights[:-1], biases[:-1], strict=True):
        h = act(ca.mtimes(ca.DM(W), h) + ca.DM(b))
    return ca.mtimes(ca.DM(weights[-1]), h) + ca.DM(biases[-1])


def lower_factor(out, n: int, eps: float):
    """Lower-triangular L from the (n² + n)/2 raw outputs ``out`` (Fig. 2): diag softplus + eps."""
    L = ca.SX(n, n)
    for i in range(n):
        L[i, i] = softplus(out[i]) + eps
    rows, cols = np.tril_indices(n, -1)
    for k, (r, c) in enumerate(zip(rows, cols, strict=True)):
        L[int(r), int(c)] = out[n + k]
    return L


def solve_lower(L, b):
    """x with L x = b by forward substitution (L lower triangular, b a column or a matrix)."""
    n = L.shape[0]
    rows = []
    for i in range(n):
        r = b[i, :]
        for j in range(i):
            r = r - L[i, j] * rows[j]
        rows.append(r / L[i, i])
    return ca.vertcat(*rows)


def solve_lower_transpose(L, b):
    """x with Lᵀ x = b by back substitution."""
    n = L.shape[0]
    rows = [None] * n
    for i in reversed(range(n)):
        r = b[i, :]
        for j in range(i + 1, n):
            r = r - L[j, i] * rows[j]
        rows[i] = r / L[i, i]
    return ca.vertcat(*rows)


def cho_solve(L, b):
    """x with (L Lᵀ) x = b: two triangular solves, never an inverse (eq. 6's M⁻¹)."""
    return solve_lower_transpose(L, solve_lower(L, b))


def lower_inverse(L):
    """(L Lᵀ)⁻¹ = L⁻ᵀ L⁻¹, symmetric by construction (for reporting M or M⁻¹)."""
    Linv = solve_lower(L, ca.SX.eye(L.shape[0]))
    return ca.mtimes(Linv.T, Linv)


def field_expression(field: dict, q):
    """The SX value of one exported field (see :func:`softpinn.bridge.export.params.field_params`).

    ``kind``: "cholesky" -> L(q) (the factor, not L Lᵀ), "constant-cholesky" -> L, "scalar" ->
    V(q), "matrix" -> A(q) (rows x cols, row-major as ``jnp.reshape``), "constant" -> the
    stored matrix, "known" -> the known A(q) (constant or program), "zero" -> zeros of ``shape``.
    """
    kind = field["kind"]
    if kind == "cholesky":
        return lower_factor(mlp(field["mlp"], q), field["n"], field["eps"])
    if kind == "constant-cholesky":
        return lower_factor(ca.SX(ca.DM(field["raw"])), field["n"], field["eps"])
    if kind == "scalar":
        return mlp(field["mlp"], q)[0]
    if kind == "matrix":
        rows, cols = field["shape"]
        out = mlp(field["mlp"], q)
        return ca.vertcat(*[ca.horzcat(*[out[i * cols + j] for j in range(cols)])
                            for i in range(rows)]) if rows and cols else ca.SX(rows, cols)
    if kind == "constant":
        return ca.SX(ca.DM(np.asarray(field["value"], float)))
    if kind == "known":  # a known A(q): a constant, or the exact A(q) rebuilt from its program
        if "value" in field:
            return ca.SX(ca.DM(np.asarray(field["value"], float)))

        return casadi_function(field["program"])(q)
    if kind == "zero":
        return ca.SX(*field["shape"])
    raise AssertionError(kind)
