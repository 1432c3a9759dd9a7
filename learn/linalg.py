"""Small dense linear algebra in plain ``jax.numpy`` (no LAPACK calls).

The structured networks of Figs. 2-3 produce a lower-triangular Cholesky factor ``L`` of the
mass matrix M(q) = L Lᵀ (or of M⁻¹(q) for the Hamiltonian network) directly, so solving
M x = b needs two triangular solves and no factorisation (eq. 6).

Everything here is written for one matrix of a small, static size n (n <= ~12) as unrolled
loops of vector operations: jaxlib's batched LAPACK calls (``cho_factor``, ``linalg.solve``,
``inv``) deadlocked at random on the development machine (jaxlib 0.10.2), and the unrolled
forms were also the fastest under ``vmap`` at these sizes. Nothing here uses scatter
(``.at[].set``): the factor is assembled from slices and concatenations, whose transposes are
slices and pads, so gradients stay scatter-free too.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

__all__ = [
    "n_offdiag",
    "lower_from_parts",
    "parts_from_lower",
    "solve_lower",
    "solve_lower_transpose",
    "cho_solve",
    "cho_inverse",
    "cholesky",
]


def n_offdiag(n: int) -> int:
    """Number of strictly-lower entries of an n x n matrix, (n² - n) / 2."""
    return n * (n - 1) // 2


def lower_from_parts(diag, off):
    """Assemble a lower-triangular matrix from its diagonal and strictly-lower entries (Fig. 2).

    ``diag`` has shape (n,); ``off`` has shape ((n² - n)/2,) and lists the strictly-lower
    entries row by row, ``[l10, l20, l21, l30, ...]``, the order of the paper's Fig. 2 and of
    ``numpy.tril_indices(n, -1)``. Built from slices and concatenations only (no scatter).
    """
    n = diag.shape[-1]
    if off.shape[-1] != n_offdiag(n):
        raise ValueError(f"off must have {n_offdiag(n)} entries for n = {n}, got shape {off.shape}")
    rows = []
    for i in range(n):
        start = i * (i - 1) // 2
        parts = [off[start : start + i], diag[i : i + 1]]
        if i < n - 1:
            parts.append(jnp.zeros((n - 1 - i,), diag.dtype))
        rows.append(jnp.concatenate(parts))
    return jnp.stack(rows)


def parts_from_lower(L):
    """Inverse of :func:`lower_from_parts`: ``(diag, off)`` of a lower-triangular matrix."""
    n = L.shape[0]
    rows, cols = np.tril_indices(n, -1)
    return jnp.diagonal(L), L[rows, cols]


def solve_lower(L, b):
    """Solve L x = b by forward substitution; L (n, n) lower triangular, b (n,) or (n, k)."""
    n = L.shape[0]
    r = b
    xs = []
    for i in range(n):
        xi = r[i] / L[i, i]
        xs.append(xi)
        if i < n - 1:
            # remove column i's contribution from the remaining rows (row i itself becomes 0)
            col = L[:, i] if b.ndim == 1 else L[:, i : i + 1]
            r = r - col * xi
    return jnp.stack(xs)


def solve_lower_transpose(L, b):
    """Solve Lᵀ x = b by back substitution; L (n, n) lower triangular, b (n,) or (n, k)."""
    n = L.shape[0]
    r = b
    xs = [None] * n
    for i in reversed(range(n)):
        xi = r[i] / L[i, i]
        xs[i] = xi
        if i > 0:
            # column i of Lᵀ is row i of L (entries below row i of Lᵀ are zero)
            row = L[i, :] if b.ndim == 1 else L[i, :, None]
            r = r - row * xi
    return jnp.stack(xs)


def cho_solve(L, b):
    """Solve (L Lᵀ) x = b with two triangular solves; never forms an inverse."""
    return solve_lower_transpose(L, solve_lower(L, b))


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
