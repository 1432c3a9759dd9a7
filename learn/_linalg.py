"""Small dense linear algebra in plain ``jax.numpy`` (no LAPACK calls).

The structured networks of Figs. 2-3 produce a lower-triangular Cholesky factor ``L`` of the
mass matrix M(q) = L Lᵀ (or of M⁻¹(q) for the Hamiltonian network) directly, so solving
M x = b needs two triangular solves and no factorisation (eq. 6).

Everything here is written for one matrix of a small, static size n (n <= ~12) as unrolled
loops of vector operations: jaxlib's batched LAPACK calls (``cho_factor``, ``linalg.solve``,
``inv``) deadlocked at random on the development machine (jaxlib 0.10.2), and the unrolled
forms were also the fastest under ``vmap`` at these sizes. Nothing here uses scatter
(``.at[].set``) or gather: the factor is assembled by one product with a constant 0/1
selection matrix, whose transpose is a product too, so gradients stay scatter-free.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "mv",
    "mtv",
    "n_offdiag",
    "lower_from_parts",
    "parts_from_lower",
    "parts_of_lower",
    "solve_lower",
    "solve_lower_transpose",
    "cho_solve",
    "cho_inverse",
    "cholesky",
]


def mv(A, x):
    """A x for one small matrix A (r, c) and vector x (c,), as a fused multiply-and-sum.

    Under ``vmap`` a batch of tiny ``dot``s runs slowly on CPU; an elementwise product and a
    reduction fuse with their neighbours instead.
    """
    return jnp.sum(A * x[..., None, :], axis=-1)


def mtv(A, x):
    """Aᵀ x for one small matrix A (r, c) and vector x (r,), as a fused multiply-and-sum."""
    return jnp.sum(A * x[:, None], axis=0)


def n_offdiag(n: int) -> int:
    """Number of strictly-lower entries of an n x n matrix, (n² - n) / 2."""
    return n * (n - 1) // 2


@functools.cache
def _selection(n: int) -> np.ndarray:
    """0/1 matrix S (n², k) with vec(L) = S @ concat(diag, off), k = (n² + n)/2, row-major vec."""
    k = n + n_offdiag(n)
    S = np.zeros((n * n, k))
    S[np.arange(n) * (n + 1), np.arange(n)] = 1.0
    rows, cols = np.tril_indices(n, -1)
    S[rows * n + cols, n + np.arange(len(rows))] = 1.0
    return S


def lower_from_parts(diag, off):
    """Assemble a lower-triangular matrix from its diagonal and strictly-lower entries (Fig. 2).

    ``diag`` has shape (n,); ``off`` has shape ((n² - n)/2,) and lists the strictly-lower
    entries row by row, ``[l10, l20, l21, l30, ...]``, the order of the paper's Fig. 2 and of
    ``numpy.tril_indices(n, -1)``. One product with a constant 0/1 selection matrix: no
    scatter, and its transpose (the gradient) is one product too, no scatter-add.
    """
    n = diag.shape[-1]
    if off.shape[-1] != n_offdiag(n):
        raise ValueError(f"off must have {n_offdiag(n)} entries for n = {n}, got shape {off.shape}")
    S = jnp.asarray(_selection(n), diag.dtype)
    return (S @ jnp.concatenate([diag, off])).reshape(n, n)


def parts_of_lower(G):
    """(diag, strictly-lower entries row by row) of any n x n matrix G, by one product.

    The transpose of :func:`lower_from_parts`: the upper triangle of G is ignored. Used to pull
    a cotangent on L back onto the network outputs.
    """
    n = G.shape[0]
    v = jnp.asarray(_selection(n), G.dtype).T @ G.reshape(n * n)
    return v[:n], v[n:]


def parts_from_lower(L):
    """Inverse of :func:`lower_from_parts`: ``(diag, off)`` of a lower-triangular matrix."""
    n = L.shape[0]
    rows, cols = np.tril_indices(n, -1)
    return jnp.diagonal(L), L[rows, cols]


def solve_lower(L, b, inv_diag=None):
    """Solve L x = b by forward substitution; L (n, n) lower triangular, b (n,) or (n, k).

    ``inv_diag``: optional precomputed 1 / diag(L).
    """
    n = L.shape[0]
    inv_diag = 1.0 / jnp.diagonal(L) if inv_diag is None else inv_diag
    r = b
    xs = []
    for i in range(n):
        xi = r[i] * inv_diag[i]
        xs.append(xi)
        if i < n - 1:
            # remove column i's contribution from the remaining rows (row i itself becomes 0)
            if b.ndim == 1:
                r = r - L[:, i] * xi
            else:
                r = r - L[:, i : i + 1] * xi[None, :]
    return jnp.stack(xs)


def solve_lower_transpose(L, b, inv_diag=None):
    """Solve Lᵀ x = b by back substitution; L (n, n) lower triangular, b (n,) or (n, k).

    ``inv_diag``: optional precomputed 1 / diag(L).
    """
    n = L.shape[0]
    inv_diag = 1.0 / jnp.diagonal(L) if inv_diag is None else inv_diag
    r = b
    xs = [None] * n
    for i in reversed(range(n)):
        xi = r[i] * inv_diag[i]
        xs[i] = xi
        if i > 0:
            # column i of Lᵀ is row i of L (entries below row i of Lᵀ are zero)
            if b.ndim == 1:
                r = r - L[i, :] * xi
            else:
                r = r - L[i, :, None] * xi[None, :]
    return jnp.stack(xs)


def _cho_solve_substitution(L, b):
    inv_diag = 1.0 / jnp.diagonal(L)
    return solve_lower_transpose(L, solve_lower(L, b, inv_diag), inv_diag)


def cho_solve(L, b):
    """Solve (L Lᵀ) x = b with two triangular solves; never forms an inverse.

    Wrapped in ``lax.custom_linear_solve`` with the symmetric operator x -> L (Lᵀ x): derivatives
    (forward and reverse, any order) are taken implicitly, dx = (L Lᵀ)⁻¹ (db - d(L Lᵀ) x), so
    the substitution loops are never differentiated through; a reverse pass costs one more
    pair of triangular solves. Only the lower triangle of L is read.
    """
    L = jnp.tril(L)

    def matvec(x):
        if x.ndim == 1:
            return mv(L, mtv(L, x))
        return L @ (L.T @ x)

    return jax.lax.custom_linear_solve(
        matvec,
        b,
        solve=lambda _, rhs: _cho_solve_substitution(L, rhs),
        symmetric=True,
    )


def cho_inverse(L):
    """(L Lᵀ)⁻¹ by two triangular solves against the identity (for reporting, not for solving)."""
    n = L.shape[0]
    X = cho_solve(L, jnp.eye(n, dtype=L.dtype))
    return 0.5 * (X + X.T)


def cholesky(A):
    """Lower Cholesky factor of a symmetric positive-definite A (n, n), plain jnp, column by column.

    Only the lower triangle of A is read. Used by the Hessian reference of eq. 6 and by tests that
    inject analytic mass matrices; the learned models never factorise (their networks output L).
    """
    n = A.shape[0]
    idx = jnp.arange(n)
    cols = []
    for j in range(n):
        if j == 0:
            a = A[:, 0]
        else:
            Lprev = jnp.stack(cols, axis=1)  # (n, j)
            a = A[:, j] - Lprev @ Lprev[j]
        d = jnp.sqrt(a[j])
        col = jnp.where(idx > j, a / d, 0.0)
        col = jnp.where(idx == j, d, col)
        cols.append(col)
    return jnp.stack(cols, axis=1)
