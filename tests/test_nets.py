"""learn._nets: MLP linearisation, Cholesky fields (Figs. 2-3), potential and input fields."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from softpinn.errors import UserError
from softpinn.learn._nets import (
    MLP,
    CholeskyField,
    ConstantCholesky,
    ConstantMatrix,
    MatrixField,
    ScalarField,
    ZeroMatrix,
    softplus,
)


@pytest.mark.parametrize("activation", ["softplus", "tanh", "silu", "sigmoid"])
def test_mlp_linearize_and_transpose_match_autodiff(getkey, activation):
    mlp = MLP(3, 5, 8, 2, activation, key=getkey())
    x, v, g = (jax.random.normal(getkey(), (k,)) for k in (3, 3, 5))

    @jax.jit
    def both(x, v, g):
        y, yd, slopes = mlp.linearize(x, v)
        return (y, yd, mlp.transpose(slopes, g)), (
            *jax.jvp(mlp, (x,), (v,)),
            jax.vjp(mlp, x)[1](g)[0],
        )

    got, ref = both(x, v, g)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-13)


def test_softplus_is_accurate_and_differentiable():
    x = jnp.array([-40.0, -3.0, 0.0, 2.5, 40.0])
    np.testing.assert_allclose(softplus(x), np.logaddexp(np.asarray(x), 0.0), rtol=1e-15)
    np.testing.assert_allclose(jax.vmap(jax.grad(softplus))(x), jax.nn.sigmoid(x), rtol=1e-15)
    d2 = jax.vmap(jax.grad(jax.grad(softplus)))(x)
    s = jax.nn.sigmoid(x)
    np.testing.assert_allclose(d2, s * (1 - s), rtol=1e-12, atol=1e-30)


@pytest.mark.parametrize("n", [1, 3, 6])
def test_cholesky_field_is_symmetric_positive_definite(getkey, n):
    eps = 1e-3
    field = CholeskyField(n, 16, 2, "softplus", eps, key=getkey())
    qs = 3.0 * jax.random.normal(getkey(), (20, n))
    L, M = jax.jit(jax.vmap(lambda q: (field.factor(q), field(q))))(qs)
    M = np.asarray(M)
    assert np.all(np.triu(np.asarray(L), 1) == 0.0)
    assert np.all(np.diagonal(L, axis1=1, axis2=2) >= eps)
    np.testing.assert_array_equal(M, np.swapaxes(M, 1, 2))
    assert np.all(np.linalg.eigvalsh(M) > 0.0)
    # layout of Fig. 2: first n outputs -> diagonal (softplus + eps), the rest row by row
    out = field.mlp(qs[0])
    np.testing.assert_allclose(np.diagonal(L[0]), np.logaddexp(np.asarray(out[:n]), 0) + eps)
    np.testing.assert_allclose(np.asarray(L[0])[np.tril_indices(n, -1)], out[n:])


def test_cholesky_field_derivatives_match_autodiff(getkey):
    n = 4
    field = CholeskyField(n, 16, 2, "tanh", 1e-3, key=getkey())
    q, v = jax.random.normal(getkey(), (n,)), jax.random.normal(getkey(), (n,))

    @jax.jit
    def both(q, v):
        L, Ldot, g = field.factor_derivatives(q, v)
        _, none, g2 = field.factor_derivatives(q, v, tangent=False)
        assert none is None
        ref = jax.jvp(field.factor, (q,), (v,)) + (jax.grad(lambda q: 0.5 * v @ field(q) @ v)(q),)
        return (L, Ldot, g, g2, field.matvec(q, v)), ref + (ref[2], field(q) @ v)

    got, ref = both(q, v)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_damping_field_with_zero_eps_is_positive_semidefinite(getkey):
    field = CholeskyField(3, 8, 1, "relu", 0.0, key=getkey())
    D = np.asarray(jax.jit(jax.vmap(field))(jax.random.normal(getkey(), (10, 3))))
    assert np.all(np.linalg.eigvalsh(D) >= -1e-14)


def test_constant_fields_ignore_q(getkey):
    c = ConstantCholesky(3, 0.0, key=getkey())
    a = ConstantMatrix(3, 2, key=getkey())
    q1, q2 = jnp.zeros(3), jnp.ones(3)
    np.testing.assert_array_equal(c(q1), c(q2))
    np.testing.assert_array_equal(a(q1), a(q2))
    assert a(q1).shape == (3, 2)
    assert np.all(np.linalg.eigvalsh(np.asarray(c(q1))) > 0.0)


def test_scalar_and_matrix_fields_shapes_and_dtypes(getkey):
    V = ScalarField(3, 8, 2, "softplus", key=getkey(), dtype="float32")
    A = MatrixField(3, 3, 2, 8, 1, "tanh", key=getkey())
    q = jnp.ones(3)
    assert V(q.astype(jnp.float32)).shape == () and V.mlp.weights[0].dtype == jnp.float32
    assert A(q).shape == (3, 2) and A(q).dtype == jnp.float64
    Z = ZeroMatrix((3, 0))
    assert Z(q).shape == (3, 0) and Z(q).dtype == jnp.float64


def test_unknown_activation_is_a_user_error(getkey):
    with pytest.raises(UserError, match="activation must be one of"):
        MLP(2, 2, 4, 1, "swish", key=getkey())
