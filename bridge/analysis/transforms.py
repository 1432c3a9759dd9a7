"""Matrix equivalence: how learned dynamics matrices relate to the true ones.

A Lagrangian network learns one of many equivalent models: if ``P(q)`` is invertible, the
equations of motion ``M q'' + C q' + G + D q' = A u`` (eqs. 4-6) are unchanged when every term is
multiplied by ``P(q)^-1`` on the left. Section IV-A reports ``M(q) = P(q) M^(q)`` and
``D(q) = P(q) D^(q)`` for Task 4 (Table I), and Tables V, VI a scalar ``alpha`` with
``learned ~= alpha * true`` (so ``P = I / alpha``). A Hamiltonian network (eq. 7) learns the
physical solution itself (Tables II, VII, IX): there ``P`` should be the identity.

This module fits such transforms on pure arrays, true and learned matrices stacked over a batch
of configurations ``q`` (``M``, ``M_inv``, ``D``: (N, n, n); ``G``: (N, n); ``A``: (N, n, m)):

=============  =====================================================================
``pointwise``  ``P(q) = M(q) M^(q)^-1`` at each q (by a linear solve)
``joint``      least-squares ``P(q)`` of ``P [M^ D^ A^ G^] ~= [M D A G]`` at each q
``alpha``      one scalar over all q, closed form: ``learned ~= alpha * true``
``constant``   one constant matrix ``P`` over all q (linear least squares)
``smooth``     ``P(q) = sum_j phi_j(q) C_j`` on a polynomial or RBF basis of q, fitted on
               part of the q and scored on the held-out rest (optionally with ridge)
``direct``     no transform (``P = I``): the comparison for Hamiltonian models
=============  =====================================================================

Every fit returns a :class:`TransformResult` (values, residuals, status, message, like
optimistix' least-squares solutions and diffrax' ``RESULTS``): ``P`` at each q, the relative
residual ``||P X^ - X||_F / ||X||_F`` of every matrix per q and over all q, and how close ``P`` is
to a multiple of the identity. numpy only.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable

import numpy as np

from softpinn.bridge.analysis.matrices import (
    BLOCKS,
    MATRICES,
    WEIGHTINGS,
    MatrixStack,
    as_stack,
    block_weights,
    check_q,
    common_blocks,
    stacked_blocks,
)
from softpinn.bridge.analysis.smooth_fit import Basis, fit_smooth, make_basis, split_train_heldout
from softpinn.bridge.analysis.transform_result import (
    BASES,
    TRANSFORMS,
    Status,
    TransformResult,
    _lstsq_rows,
    _prepare,
    _residuals,
    _result,
    to_jsonable,
)
from softpinn.errors import UserError

__all__ = [
    "BASES",
    "BLOCKS",
    "MATRICES",
    "TRANSFORMS",
    "WEIGHTINGS",
    "Basis",
    "MatrixStack",
    "Status",
    "TransformResult",
    "as_stack",
    "block_weights",
    "check_q",
    "common_blocks",
    "compare_direct",
    "fit_alpha",
    "fit_constant",
    "fit_joint",
    "fit_pointwise",
    "fit_smooth",
    "fit_transform",
    "make_basis",
    "split_train_heldout",
    "to_jsonable",
]

# --------------------------------------------------------------------------------------------
# The transforms


def fit_pointwise(true, learned, q=None, *, blocks=None, cond_max: float = 1e14) -> TransformResult:
    """``P(q) = M(q) M^(q)^-1`` at each q (Section IV-A), by solving ``M^(q)^T P^T = M^T``.

    The residuals of the other matrices tell whether this P also maps D^, G^, A^ (Table I).
    Where ``cond(M^) > cond_max``, P is NaN and the status is ``singular``.
    """
    true, learned, _, blocks = _prepare(true, learned, q, blocks)
    M = true.mass()
    if learned.M is not None:
        Mh = learned.M
        cond = np.linalg.cond(Mh)
        bad = ~(cond < cond_max)
        safe = np.where(bad[:, None, None], np.eye(true.n), Mh)
        P = np.swapaxes(np.linalg.solve(np.swapaxes(safe, 1, 2), np.swapaxes(M, 1, 2)), 1, 2)
    else:  # Hamiltonian: M^-1 learned directly, no solve needed
        Mh_inv = learned.M_inv
        cond = np.linalg.cond(Mh_inv)
        bad = ~(cond < cond_max)
        P = M @ Mh_inv
    P = np.where(bad[:, None, None], np.nan, P)
    if np.any(bad):
        status, msg = (
            Status.SINGULAR,
            (
                f"learned mass matrix singular (cond > {cond_max:.0e}) at {int(bad.sum())} of "
                f"{true.N} q; P is NaN there"
            ),
        )
    else:
        status, msg = Status.SUCCESS, "P(q) = M(q) M^(q)^-1 at every q"
    params = {"blocks": list(blocks), "cond_learned_M": cond}
    return _result("pointwise", P, true, learned, blocks, status, msg, params)


def fit_joint(
    true, learned, q=None, *, blocks=None, weighting="frobenius", rcond=None
) -> TransformResult:
    """Least-squares ``P(q)`` of ``P [M^ D^ A^ G^] ~= [M D A G]`` at each q, each block
    weighted (:func:`block_weights`). Minimum-norm solution where the learned blocks do not
    have rank n (status ``rank_deficient``)."""
    true, learned, _, blocks = _prepare(true, learned, q, blocks)
    w = block_weights(true, learned, blocks, weighting)
    Xh, X = stacked_blocks(learned, blocks, w), stacked_blocks(true, blocks, w)
    P, rank, cond = _lstsq_rows(Xh, X, rcond)
    deficient = rank < true.n
    if np.any(deficient):
        status, msg = (
            Status.RANK_DEFICIENT,
            (
                f"learned blocks have rank < n = {true.n} at {int(deficient.sum())}/{true.N} q; "
                "minimum-norm P there"
            ),
        )
    else:
        status, msg = Status.SUCCESS, f"joint least squares over {'+'.join(blocks)} at every q"
    params = {"blocks": list(blocks), "weights": w, "rank": rank, "cond": cond}
    return _result("joint", P, true, learned, blocks, status, msg, params)


def fit_alpha(true, learned, q=None, *, blocks=None, weighting="frobenius") -> TransformResult:
    """One scalar for all q (Tables V, VI): ``alpha = <X^, X>_w / <X, X>_w`` minimises
    ``sum_k w_k^2 ||X^_k - alpha X_k||^2``, so ``learned ~= alpha * true`` and ``P = I / alpha``.

    ``params`` also holds ``alpha_per_matrix`` (each matrix alone) and ``alpha_per_q``
    (Table VI gives one alpha per row).
    """
    true, learned, _, blocks = _prepare(true, learned, q, blocks)
    w = block_weights(true, learned, blocks, weighting)
    Xh, X = stacked_blocks(learned, blocks, w), stacked_blocks(true, blocks, w)
    num, den = float(np.sum(Xh * X)), float(np.sum(X * X))
    if den == 0.0 or num == 0.0:
        raise UserError(
            f"alpha: undefined, the {'true' if den == 0 else 'learned'} matrices "
            f"{'+'.join(blocks)} are zero"
        )
    alpha = num / den
    with np.errstate(divide="ignore", invalid="ignore"):
        per_q = np.sum(Xh * X, axis=(1, 2)) / np.sum(X * X, axis=(1, 2))
    per_matrix = {}
    for k in blocks:
        a, b = learned.block(k), true.block(k)
        d = float(np.sum(b * b))
        per_matrix[k] = float(np.sum(a * b)) / d if d > 0 else math.nan
    n = true.n

    def model(qq, _c=1.0 / alpha, _n=n):
        qq = np.atleast_2d(np.asarray(qq, dtype=np.float64))
        return np.broadcast_to(_c * np.eye(_n), (qq.shape[0], _n, _n)).copy()

    P = np.broadcast_to(np.eye(n) / alpha, (true.N, n, n)).copy()
    params = {
        "alpha": alpha,
        "alpha_per_matrix": per_matrix,
        "alpha_per_q": per_q,
        "blocks": list(blocks),
        "weights": w,
    }
    msg = f"learned ~= {alpha:.6g} * true over {'+'.join(blocks)} and all {true.N} q"
    return _result("alpha", P, true, learned, blocks, Status.SUCCESS, msg, params, model)


def fit_constant(
    true, learned, q=None, *, blocks=None, weighting="frobenius", rcond=None
) -> TransformResult:
    """One constant ``P`` for all q: least squares of ``P [X^(q_1) ... X^(q_N)] ~=
    [X(q_1) ... X(q_N)]`` over the weighted blocks."""
    true, learned, _, blocks = _prepare(true, learned, q, blocks)
    w = block_weights(true, learned, blocks, weighting)
    n = true.n
    Xh = np.concatenate(list(stacked_blocks(learned, blocks, w)), axis=1)[None]  # (1, n, N K)
    X = np.concatenate(list(stacked_blocks(true, blocks, w)), axis=1)[None]
    P1, rank, cond = _lstsq_rows(Xh, X, rcond)
    P1 = P1[0]
    status, msg = Status.SUCCESS, f"one constant P over {'+'.join(blocks)} and all {true.N} q"
    if rank[0] < n:
        status, msg = Status.RANK_DEFICIENT, f"stacked learned blocks have rank {rank[0]} < n = {n}"

    def model(qq, _P=P1):
        qq = np.atleast_2d(np.asarray(qq, dtype=np.float64))
        return np.broadcast_to(_P, (qq.shape[0], *_P.shape)).copy()

    P = np.broadcast_to(P1, (true.N, n, n)).copy()
    params = {"blocks": list(blocks), "weights": w, "rank": int(rank[0]), "cond": float(cond[0])}
    return _result("constant", P, true, learned, blocks, status, msg, params, model)




def compare_direct(true, learned, q=None, *, blocks=None) -> TransformResult:
    """No transform (P = I): direct relative errors of M^-1, D, A, G, the comparison for
    Hamiltonian models (Tables II, VII, IX). ``M`` may be requested in ``blocks`` too;
    ``params["residual_M"]`` holds it in any case."""
    true, learned, _, _ = _prepare(true, learned, q, None)
    allowed = ("M_inv", *BLOCKS)
    if blocks is None:
        blocks = tuple(
            k
            for k in allowed
            if k != "M" and true.has(k) and learned.has(k) and true.block(k).shape[2] > 0
        )
    else:
        blocks = (blocks,) if isinstance(blocks, str) else tuple(blocks)
        for k in blocks:
            if k not in allowed:
                raise UserError(f"blocks: unknown matrix {k!r}; expected some of {list(allowed)}")
            for side in (true, learned):
                if not side.has(k):
                    raise UserError(
                        f"blocks: {k} requested but {side.name} has {list(side.present)}"
                    )
    P = np.broadcast_to(np.eye(true.n), (true.N, true.n, true.n)).copy()
    msg = "no transform: learned compared with true as they are"
    res = _result("direct", P, true, learned, blocks, Status.SUCCESS, msg, {})
    mres, mtot = _residuals(P, true, learned, ("M",))
    params = {"blocks": list(blocks), "residuals_M": mres["M"], "residual_M": mtot["M"]}
    return TransformResult(**{**res.__dict__, "params": params})


_FITS: dict[str, Callable[..., TransformResult]] = {
    "pointwise": fit_pointwise,
    "joint": fit_joint,
    "alpha": fit_alpha,
    "constant": fit_constant,
    "smooth": fit_smooth,
    "direct": compare_direct,
}


def fit_transform(name: str, true, learned, q=None, **options) -> TransformResult:
    """Run the transform ``name`` (one of :data:`TRANSFORMS`) with its keyword options."""
    if name not in _FITS:
        raise UserError(f"transform: unknown {name!r}; expected one of {list(TRANSFORMS)}")
    fit = _FITS[name]
    allowed = [p for p in inspect.signature(fit).parameters if p not in ("true", "learned", "q")]
    for key in options:
        if key not in allowed:
            raise UserError(
                f"transform {name!r}: unknown option {key!r}; expected some of {allowed}"
            )
    return fit(true, learned, q, **options)

