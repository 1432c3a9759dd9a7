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

import functools
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from softpinn.errors import UserError
from softpinn.learn._linalg import lower_from_parts, mtv, mv, n_offdiag, parts_of_lower

__all__ = [
    "ACTIVATIONS",
    "activation_fn",
    "softplus",
    "softplus_inverse",
    "make_mlp",
    "MLP",
    "first_layers",
    "first_layers_transpose",
    "CholeskyField",
    "ConstantCholesky",
    "ScalarField",
    "MatrixField",
    "ConstantMatrix",
    "ZeroMatrix",
]


#: Terms of the series of atanh that :func:`_log1p_unit` sums, per dtype: t ≤ 1/3, so the
#: k-th term is below 9⁻ᵏ/(2k + 1): 17 terms reach 1e-17 (float64), 8 reach 1e-9 (float32).
_LOG1P_TERMS = {"float64": 17, "float32": 8, "float16": 5, "bfloat16": 4}


def _log1p_unit(e):
    """log(1 + e) for e in [0, 1], as log1p to the dtype's precision, by 2 atanh(e / (2 + e))
    summed as a polynomial (Horner) in t² ≤ 1/9.

    XLA's CPU log1p is not vectorised: in float64 it cost 12 ns per element, 5x this series,
    and softplus runs on every hidden unit of every sub-network at every RK4 stage (1.9 M
    times per training step of an n = 6 Lagrangian network on 1,024 pairs). Measured against
    numpy's log1p over 1.7 M normal samples: relative error 6e-16 (float64), 3e-7 (float32).
    """
    terms = _LOG1P_TERMS.get(jnp.dtype(e.dtype).name, 17)
    t = e / (2.0 + e)
    s = t * t
    acc = jnp.full_like(s, 1.0 / (2 * terms - 1))
    for k in range(terms - 2, -1, -1):
        acc = acc * s + 1.0 / (2 * k + 1)
    return 2.0 * t * acc


@jax.custom_jvp
def softplus(x):
    """log(1 + eˣ) = max(x, 0) + log1p(e^-|x|), the log1p by :func:`_log1p_unit`; its derivative
    is the logistic σ(x)."""
    return jnp.maximum(x, 0) + _log1p_unit(jnp.exp(-jnp.abs(x)))


@softplus.defjvp
def _softplus_jvp(primals, tangents):
    (x,), (t,) = primals, tangents
    return softplus(x), jax.nn.sigmoid(x) * t


def softplus_inverse(y: float) -> float:
    """The x with softplus(x) = y > 0, as a Python float (a bias that puts a softplus output at
    ``y``): x = log(eʸ - 1) = y + log(1 - e⁻ʸ), the second form for large y."""
    return y + math.log(-math.expm1(-y))


def _value_and_slope(name, z):
    """(σ(z), σ'(z)) elementwise, explicit for the common activations."""
    if name == "softplus":
        return softplus(z), jax.nn.sigmoid(z)
    if name == "tanh":
        a = jnp.tanh(z)
        return a, 1.0 - a * a
    if name == "sigmoid":
        a = jax.nn.sigmoid(z)
        return a, a * (1.0 - a)
    return jax.jvp(ACTIVATIONS[name], (z,), (jnp.ones_like(z),))


ACTIVATIONS: dict[str, Callable] = {
    "softplus": softplus,
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
    """An :class:`MLP`: ``depth`` hidden layers of ``width`` units, parameters in ``dtype``."""
    return MLP(in_size, out_size, width, depth, activation, key=key, dtype=dtype)


@functools.partial(jax.jit, static_argnums=(1, 2))
def _init_mlp(key, sizes, dtype):
    """Weights and biases of an MLP, uniform in ±1/sqrt(fan_in).

    One random draw for all parameters, one compiled call per shape (initialisation is cheap to
    compile, which keeps tests and start-up fast), and it works under ``vmap`` over keys.
    """
    pairs = list(zip(sizes[:-1], sizes[1:], strict=True))
    total = sum(fo * fi + fo for fi, fo in pairs)
    u = jax.random.uniform(key, (total,), dtype, -1.0, 1.0)
    weights, biases, start = [], [], 0
    for fan_in, fan_out in pairs:
        lim = float(1.0 / np.sqrt(fan_in))  # a Python float stays weakly typed
        weights.append(lim * u[start : start + fan_out * fan_in].reshape(fan_out, fan_in))
        start += fan_out * fan_in
        biases.append(lim * u[start : start + fan_out])
        start += fan_out
    return tuple(weights), tuple(biases)


class MLP(eqx.Module):
    """A plain feed-forward network x -> W_d σ(... σ(W_0 x + b_0) ...) + b_d.

    Besides the forward pass it offers :meth:`linearize` (value, Jacobian-vector product and
    the activation slopes, in one pass) and :meth:`transpose` (vector-Jacobian product from those
    slopes), so the structured models can get J v and Jᵀ g from ONE forward pass with shared
    σ'(z). Initialisation as ``eqx.nn.Linear`` (uniform in ±1/sqrt(fan_in)).
    """

    weights: tuple[jax.Array, ...]
    biases: tuple[jax.Array, ...]
    activation: str = eqx.field(static=True)

    def __init__(self, in_size, out_size, width, depth, activation, *, key, dtype="float64"):
        activation_fn(activation)  # validate the name
        sizes = (int(in_size),) + (int(width),) * int(depth) + (int(out_size),)
        self.weights, self.biases = _init_mlp(key, sizes, jnp.dtype(dtype).name)
        self.activation = activation

    @property
    def out_size(self) -> int:
        return self.weights[-1].shape[0]

    def __call__(self, x):
        act = ACTIVATIONS[self.activation]
        h = x
        for W, b in zip(self.weights[:-1], self.biases[:-1], strict=True):
            h = act(W @ h + b)
        return self.weights[-1] @ h + self.biases[-1]

    def linearize(self, x, v=None, *, first=None):
        """(y, J v, slopes): output, its derivative along v (None: skipped), and σ'(z) per layer.

        ``first``: optional ``(W₀x + b₀, W₀v)`` (the second None when v is), the first layer's
        products computed elsewhere, e.g. by :func:`first_layers` for several networks that
        read the same x at once; x and v are then not read.
        """
        if first is None:
            W, b = self.weights[0], self.biases[0]
            z = W @ x + b
            zd = None if v is None else W @ v
        else:
            z, zd = first
        if len(self.weights) == 1:
            return z, zd, ()
        h, hd, slopes = None, None, []
        for i, (W, b) in enumerate(zip(self.weights[:-1], self.biases[:-1], strict=True)):
            if i > 0:
                z = W @ h + b
                zd = None if hd is None else W @ hd
            h, s = _value_and_slope(self.activation, z)
            slopes.append(s)
            if zd is not None:
                hd = s * zd
        y = self.weights[-1] @ h + self.biases[-1]
        yd = None if hd is None else self.weights[-1] @ hd
        return y, yd, tuple(slopes)

    def transpose_to_first(self, slopes, g):
        """The cotangent c on the first layer's product W₀x + b₀ of the output cotangent g, at
        the point :meth:`linearize` was called with: Jᵀ g = W₀ᵀ c."""
        if len(self.weights) == 1:
            return g
        g = self.weights[-1].T @ g
        for W, s in zip(reversed(self.weights[1:-1]), reversed(slopes[1:]), strict=True):
            g = W.T @ (s * g)
        return slopes[0] * g

    def transpose(self, slopes, g):
        """Jᵀ g at the point :meth:`linearize` was called with (reverse pass from its slopes)."""
        return self.weights[0].T @ self.transpose_to_first(slopes, g)


def first_layers(mlps, x):
    """[W₀x + b₀ of each MLP in ``mlps``], all read from the same x, by ONE product with their
    first layers' weights stacked (what the fused pass of :class:`learn._models.LagrangianNet`
    uses for M, V, D and A: one matrix product instead of four small ones)."""
    W = jnp.concatenate([m.weights[0] for m in mlps], axis=0)
    b = jnp.concatenate([m.biases[0] for m in mlps], axis=0)
    z = W @ x + b
    out, start = [], 0
    for m in mlps:
        rows = m.weights[0].shape[0]
        out.append(z[start : start + rows])
        start += rows
    return out


def first_layers_transpose(mlps, cotangents):
    """Σᵢ W₀ᵢᵀ cᵢ for the cotangents cᵢ on the first layers' products of ``mlps`` (see
    :meth:`MLP.transpose_to_first`), by ONE product with their stacked first-layer weights."""
    W = jnp.concatenate([m.weights[0] for m in mlps], axis=0)
    return W.T @ jnp.concatenate(cotangents)


class CholeskyField(eqx.Module):
    """U(q) = L(q) L(q)ᵀ with L lower triangular, diag(L) = softplus(.) + eps (Figs. 2, 3).

    ``eps > 0`` makes U positive definite (mass matrix M or its inverse); ``eps = 0`` gives the
    positive semi-definite damping matrix D (softplus keeps the diagonal non-negative).
    """

    mlp: MLP
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
        return lower_from_parts(softplus(out[:n]) + self.eps, out[n:])

    def factor_derivatives(self, q, v, *, tangent=True):
        """(L, L̇, g) at q from ONE forward pass of the network:

        L̇ = dL/dq · v (a Jacobian-vector product; None if ``tangent=False``) and
        g = ½ ∂‖L(q)ᵀ v‖²/∂q = Jᵀ (the lower part of v wᵀ), w = Lᵀ v (a vector-Jacobian product).
        ½ ‖Lᵀ v‖² = ½ vᵀ M v is the kinetic energy for M = L Lᵀ (eq. 6), or the Hamiltonian's
        kinetic term for M⁻¹ = L Lᵀ and v = p (eq. 7).
        """
        L, Ldot, c = self.factor_derivatives_first(q, v, tangent=tangent)
        return L, Ldot, self.mlp.weights[0].T @ c

    def factor_derivatives_first(self, q, v, *, tangent=True, first=None):
        """:meth:`factor_derivatives` up to the network's first layer: (L, L̇, c) with
        g = W₀ᵀ c. ``first``: the first layer's products ``(W₀q + b₀, W₀v)``, when computed
        together with other networks' (:func:`first_layers`); q is then not read."""
        n = self.n
        if first is None:
            out, out_dot, slopes = self.mlp.linearize(q, v if tangent else None)
        else:
            out, out_dot, slopes = self.mlp.linearize(None, first=first)
        d, sig = _value_and_slope("softplus", out[:n])
        L = lower_from_parts(d + self.eps, out[n:])
        Ldot = None
        if tangent:
            Ldot = lower_from_parts(sig * out_dot[:n], out_dot[n:])
        w = mtv(L, v)
        g_diag, g_off = parts_of_lower(jnp.outer(v, w))
        g_out = jnp.concatenate([sig * g_diag, g_off])
        return L, Ldot, self.mlp.transpose_to_first(slopes, g_out)

    def factor_from_first(self, z0):
        """The factor L from the first layer's product W₀q + b₀ (see :func:`first_layers`)."""
        out = self.mlp.linearize(None, first=(z0, None))[0]
        n = self.n
        return lower_from_parts(softplus(out[:n]) + self.eps, out[n:])

    def matvec(self, q, v):
        """U(q) v = L (Lᵀ v) without forming U."""
        L = self.factor(q)
        return mv(L, mtv(L, v))

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
        self.raw = float(scale) * jax.random.normal(key, (n + n_offdiag(n),), jnp.dtype(dtype))

    def factor(self, q):
        del q
        n = self.n
        return lower_from_parts(softplus(self.raw[:n]) + self.eps, self.raw[n:])

    def __call__(self, q):
        L = self.factor(q)
        return L @ L.T


class ScalarField(eqx.Module):
    """A scalar field of q, e.g. the potential energy V(q) (Fig. 4)."""

    mlp: MLP

    def __init__(self, n, width, depth, activation, *, key, dtype="float64"):
        self.mlp = make_mlp(n, 1, width, depth, activation, key=key, dtype=dtype)

    def __call__(self, q):
        return self.mlp(q)[0]


class MatrixField(eqx.Module):
    """A matrix field A(q) in R^{rows x cols}: an MLP with rows*cols outputs, reshaped (Fig. 5)."""

    mlp: MLP
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
        scale = float(1.0 / np.sqrt(max(cols, 1))) if scale is None else float(scale)
        self.value = scale * jax.random.normal(key, (rows, cols), jnp.dtype(dtype))

    def __call__(self, q):
        del q
        return self.value


class ZeroMatrix(eqx.Module):
    """A fixed zero matrix of a given shape (no damping; A for unactuated systems, m = 0)."""

    shape: tuple[int, int] = eqx.field(static=True)

    def __call__(self, q):
        return jnp.zeros(self.shape, q.dtype)
