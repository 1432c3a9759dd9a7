"""learn._linalg: scatter-free Cholesky assembly and plain-jnp triangular solves vs numpy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from softpinn.learn._linalg import (
    cho_inverse,
    cho_solve,
    cholesky,
    lower_from_parts,
    n_offdiag,
    parts_from_lower,
    solve_lower,
    solve_lower_transpose,
)

SIZES = [1, 2, 6, 12]


def _random_lower(rng, n):
    L = np.tril(rng.normal(size=(n, n)), -1)
    L[np.diag_indices(n)] = rng.uniform(0.5, 2.0, n)
    return L


@pytest.mark.parametrize("n", SIZES)
def test_lower_from_parts_places_entries_like_fig2(n):
    rng = np.random.default_rng(n)
    diag, off = rng.normal(size=n), rng.normal(size=n_offdiag(n))
    L = np.asarray(lower_from_parts(jnp.asarray(diag), jnp.asarray(off)))
    expected = np.zeros((n, n))
    expected[np.diag_indices(n)] = diag
    expected[np.tril_indices(n, -1)] = off  # row by row: l10, l20, l21, ...
    np.testing.assert_array_equal(L, expected)
    d2, o2 = parts_from_lower(jnp.asarray(L))
    np.testing.assert_array_equal(d2, diag)
    np.testing.assert_array_equal(o2, off)


def test_lower_from_parts_order_and_size_check():
    L = lower_from_parts(jnp.array([1.0, 2.0, 3.0]), jnp.array([10.0, 20.0, 21.0]))
    assert L[1, 0] == 10.0 and L[2, 0] == 20.0 and L[2, 1] == 21.0
    with pytest.raises(ValueError, match="off must have 3 entries"):
        lower_from_parts(jnp.ones(3), jnp.ones(2))


def test_construction_and_its_gradient_use_no_scatter():
    n = 12

    def f(v):
        L = lower_from_parts(v[:n], v[n:])
        return jnp.sum(L @ L.T)

    v = jnp.ones(n + n_offdiag(n))
    for fn, arg in ((f, v), (jax.grad(f), v), (jax.vmap(jax.grad(f)), v[None])):
        text = str(jax.make_jaxpr(fn)(arg))
        assert "scatter" not in text and "gather" not in text


@pytest.mark.parametrize("n", SIZES)
def test_triangular_solves_match_numpy(n):
    rng = np.random.default_rng(100 + n)
    L = _random_lower(rng, n)
    L_upper_garbage = L + np.triu(rng.normal(size=(n, n)), 1)  # only the lower triangle is read
    solves = jax.jit(lambda L, b: (solve_lower(L, b), solve_lower_transpose(L, b), cho_solve(L, b)))
    for b in (rng.normal(size=n), rng.normal(size=(n, 3))):
        x, y, z = (np.asarray(a) for a in solves(jnp.asarray(L_upper_garbage), jnp.asarray(b)))
        np.testing.assert_allclose(x, np.linalg.solve(L, b), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(y, np.linalg.solve(L.T, b), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(z, np.linalg.solve(L @ L.T, b), rtol=1e-10, atol=1e-10)
    Minv = np.asarray(jax.jit(cho_inverse)(jnp.asarray(L)))
    np.testing.assert_allclose(Minv, np.linalg.inv(L @ L.T), rtol=1e-10, atol=1e-10)
    np.testing.assert_array_equal(Minv, Minv.T)


@pytest.mark.parametrize("n", SIZES)
def test_cholesky_matches_numpy(n):
    rng = np.random.default_rng(200 + n)
    B = rng.normal(size=(n, n))
    A = B @ B.T + n * np.eye(n)
    L = np.asarray(jax.jit(cholesky)(jnp.asarray(A)))
    np.testing.assert_allclose(L, np.linalg.cholesky(A), rtol=1e-12, atol=1e-12)
    assert np.all(np.triu(L, 1) == 0.0)


def test_solves_vmap_and_differentiate():
    rng = np.random.default_rng(7)
    n, B = 4, 5
    Ls = np.stack([_random_lower(rng, n) for _ in range(B)])
    bs = rng.normal(size=(B, n))
    x = np.asarray(jax.jit(jax.vmap(cho_solve))(jnp.asarray(Ls), jnp.asarray(bs)))
    for k in range(B):
        np.testing.assert_allclose(x[k], np.linalg.solve(Ls[k] @ Ls[k].T, bs[k]), rtol=1e-10)
    # first and second derivatives of a solve (implicit, custom_linear_solve) against
    # central finite differences, in forward and in reverse mode
    L0, b0 = jnp.asarray(Ls[0]), jnp.asarray(bs[0])
    P = jnp.asarray(np.tril(rng.normal(size=(n, n))))

    def f(s):
        return jnp.sum(cho_solve(L0 + s * P, b0 * (1.0 + s)) ** 2)

    h = 1e-4
    d1 = jax.jit(jax.grad(f))
    d2 = jax.jit(jax.jacfwd(jax.grad(f)))
    fd1 = (f(h) - f(-h)) / (2 * h)
    fd2 = (d1(h) - d1(-h)) / (2 * h)
    np.testing.assert_allclose(d1(0.0), fd1, rtol=1e-6)
    np.testing.assert_allclose(d2(0.0), fd2, rtol=1e-5)
