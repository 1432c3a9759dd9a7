"""How much a data set says about the mass matrix: velocity data (eq. 10 on q̈) against momentum
data (eq. 10 on q̇ = M⁻¹ p), with the true model at the data's own samples.

Perturb the true M(q) to M + ε E_ij, E_ij the symmetric unit direction (i, j) scaled by
sqrt(M_ii M_jj) (a relative change of that entry). To first order in ε the targets of eq. 10
move by

    velocity data:  δq̈ = -M⁻¹ E q̈        momentum data:  δq̇ = -M⁻¹ E q̇

(q̈ = M⁻¹ f at a fixed force f; q̇ = M⁻¹ p at a fixed p; a constant E leaves C unchanged). Each
coordinate's change is divided by the rms of its label over the samples, so both losses are
compared in their own units, and the rows (samples x coordinates) by sqrt(N): a singular value
of the sensitivity matrix is the rms change of the labels per unit relative change of M along
its singular direction, the smallest the weakest.

Velocity data see M only through the force balance (eq. 4): a change of M that a change of a
constant D and of G(q) (polynomials of q up to ``g_degree``) explains as well leaves no trace
in q̈. :func:`mass_identifiability` projects those out and reports what is left per entry
(``fraction_left``) and as singular values. Momentum data need no such step: q̇ = M⁻¹ p holds M
alone. ``benchmarks/identifiability.py`` runs it on a data file.
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np

__all__ = ["mass_sensitivities", "force_columns", "mass_identifiability"]


def _pairs(n: int):
    return [(i, j) for i in range(n) for j in range(i, n)]


def _symmetric_columns(Minv, v, scale):
    """-M⁻¹ E_ij v for every (i, j) of :func:`_pairs`, E_ij the symmetric unit direction times
    ``scale[:, i, j]`` (or the constant ``scale``): s (M⁻¹[:, i] v_j + M⁻¹[:, j] v_i), once for
    i = j; each (N, n)."""
    cols = []
    for i, j in _pairs(Minv.shape[1]):
        s = scale[:, i, j, None] if np.ndim(scale) else scale
        col = Minv[:, :, i] * v[:, j, None]
        if i != j:
            col = col + Minv[:, :, j] * v[:, i, None]
        cols.append(-s * col)
    return cols


def _relative(M):
    """sqrt(M_ii M_jj): an entry's change relative to the diagonal around it, (N, n, n)."""
    d = np.sqrt(np.diagonal(M, axis1=1, axis2=2))
    return d[:, :, None] * d[:, None, :]


def mass_sensitivities(M, vectors, scale=1.0, *, Minv=None):
    """(N·n, n(n+1)/2) matrix: column (i, j) holds -M⁻¹ E_ij v at every sample (E_ij scaled by
    sqrt(M_ii M_jj)), each coordinate divided by ``scale``, the rows by sqrt(N); and the (i, j)
    pairs. M: (N, n, n), vectors: (N, n) (q̈ for velocity data, q̇ for momentum data);
    ``Minv``: M⁻¹ if the caller has it."""
    M = np.asarray(M, float)
    Minv = np.linalg.inv(M) if Minv is None else Minv
    cols = _symmetric_columns(Minv, np.asarray(vectors, float), _relative(M))
    J = np.stack([(c / scale).ravel() for c in cols], 1)
    return J / np.sqrt(len(M)), _pairs(M.shape[1])


def force_columns(M, q, qd, scale=1.0, g_degree: int = 3, *, Minv=None):
    """What a constant D and a polynomial G(q) do to q̈ = M⁻¹(... - D q̇ - G): the columns
    -M⁻¹ δD q̇ (δD symmetric) and -M⁻¹ δG(q) (δG's coordinates monomials of the standardised q
    up to ``g_degree``), scaled like :func:`mass_sensitivities`, each of unit norm."""
    M = np.asarray(M, float)
    q = np.asarray(q, float)
    n = M.shape[1]
    Minv = np.linalg.inv(M) if Minv is None else Minv
    cols = _symmetric_columns(Minv, np.asarray(qd, float), 1.0)
    std = q.std(0)
    z = (q - q.mean(0)) / np.where(std > 0, std, 1.0)
    monomials = [np.ones(len(q))]
    for d in range(1, g_degree + 1):
        for c in combinations_with_replacement(range(n), d):
            monomials.append(np.prod(z[:, list(c)], axis=1))
    for mono in monomials:
        for i in range(n):
            cols.append(-Minv[:, :, i] * mono[:, None])
    J = np.stack([(c / scale).ravel() for c in cols], 1)
    norms = np.linalg.norm(J, axis=0, keepdims=True)
    return J / np.where(norms > 0, norms, 1.0)


def mass_identifiability(M, q, qd, qdd, *, g_degree: int = 3, names=None) -> dict:
    """The singular values of the mass sensitivities on momentum data (q̇ = M⁻¹ p), on
    velocity data (q̈) and on velocity data after the best compensating change of D and G
    (:func:`force_columns`), the fraction of each entry's effect left after it, and the
    weakest combination's largest entries. M: (N, n, n) true mass matrices at the samples q,
    qd, qdd (N, n)."""
    qd = np.asarray(qd, float)
    qdd = np.asarray(qdd, float)
    n = qd.shape[1]
    names = list(names) if names is not None else [f"q{i}" for i in range(n)]
    scale_v = np.sqrt(np.mean(qdd**2, axis=0))
    scale_p = np.sqrt(np.mean(qd**2, axis=0))
    M = np.asarray(M, float)
    Minv = np.linalg.inv(M)
    Jv, pairs = mass_sensitivities(M, qdd, scale_v, Minv=Minv)
    Jp, _ = mass_sensitivities(M, qd, scale_p, Minv=Minv)
    JN = force_columns(M, q, qd, scale_v, g_degree, Minv=Minv) / np.sqrt(len(qd))
    coef, *_ = np.linalg.lstsq(JN, Jv, rcond=None)
    left = Jv - JN @ coef
    _, s_left, V = np.linalg.svd(left, full_matrices=False)
    labels = [f"{names[i]}-{names[j]}" for i, j in pairs]
    weakest = np.argsort(-np.abs(V[-1]))[:4]
    norms = np.linalg.norm(Jv, axis=0)
    return {
        "singular_values": {
            "momentum": np.linalg.svd(Jp, compute_uv=False).tolist(),
            "velocity": np.linalg.svd(Jv, compute_uv=False).tolist(),
            "velocity_after_D_G": s_left.tolist(),
        },
        "fraction_left": {lab: float(a / b) if b > 0 else 0.0 for lab, a, b in
                          zip(labels, np.linalg.norm(left, axis=0), norms, strict=True)},
        "weakest_after_D_G": {labels[k]: round(float(V[-1, k]), 3) for k in weakest},
        "g_degree": g_degree, "force_columns": JN.shape[1], "samples": len(qd),
    }
