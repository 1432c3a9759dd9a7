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

import enum
import inspect
import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import UserError
from .matrices import (
    BLOCKS,
    MATRICES,
    WEIGHTINGS,
    MatrixStack,
    as_stack,
    block_weights,
    check_pair,
    check_q,
    common_blocks,
    stacked_blocks,
    subset,
)

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
]

#: Names accepted by :func:`fit_transform`.
TRANSFORMS = ("pointwise", "joint", "alpha", "constant", "smooth", "direct")
BASES = ("polynomial", "rbf")


class Status(enum.StrEnum):
    """Outcome of a fit (like diffrax' ``RESULTS``): success or why the values are doubtful."""

    SUCCESS = "success"
    SINGULAR = "singular"  # a learned mass matrix is singular at some q: P is NaN there
    RANK_DEFICIENT = "rank_deficient"  # the least-squares system lacks full rank: minimum-norm P
    UNDERDETERMINED = "underdetermined"  # fewer equations than unknowns


# --------------------------------------------------------------------------------------------
# Result


@dataclass(frozen=True, eq=False)
class TransformResult:
    """One fitted transform with its residuals (values, residuals, status, message).

    Attributes:
        name: the transform (one of :data:`TRANSFORMS`).
        P: (N, n, n), the transform at each q, with ``P X^ ~= X`` for every matrix X.
        residuals: per matrix, the relative residual ``||P X^ - X||_F / ||X||_F`` at each q
            (N,); NaN where the true matrix is zero and the residual is not.
        residual: per matrix, the same over all q: ``sqrt(sum ||P X^ - X||^2 / sum ||X||^2)``.
        residual_total: root mean square of ``residual`` over the matrices.
        scale: (N,), the best ``c`` with ``P ~= c I`` (``trace(P) / n``); ``alpha = 1 / c``.
        distance: (N,), ``||P - c I||_F / ||P||_F``: 0 when P is a multiple of I.
        scale_all, distance_all: the same over all q (one c).
        status, message: :class:`Status` and a one-line explanation.
        params: transform-specific values (``alpha``, ``weights``, ``blocks``, ``rank``,
            ``coefficients``, ``train``, ``residual_train``, ``residual_heldout``...).
        model: for ``alpha``, ``constant`` and ``smooth``, a function giving P at new q (M, n).
    """

    name: str
    P: np.ndarray
    residuals: Mapping[str, np.ndarray]
    residual: Mapping[str, float]
    residual_total: float
    scale: np.ndarray
    distance: np.ndarray
    scale_all: float
    distance_all: float
    status: Status
    message: str
    params: Mapping[str, Any] = field(default_factory=dict)
    model: Callable[[np.ndarray], np.ndarray] | None = None

    @property
    def alpha(self) -> float:
        """``learned ~= alpha * true`` for the multiple of I nearest to P over all q."""
        return 1.0 / self.scale_all if self.scale_all != 0 else math.inf

    def transformed(self, learned: MatrixStack | Mapping[str, Any], key: str) -> np.ndarray:
        """``P X^`` for matrix ``key`` of the learned stack (G as (N, n))."""
        learned = as_stack(learned, "learned")
        out = self.P @ learned.block(key)
        return out[:, :, 0] if key == "G" else out

    def to_dict(self) -> dict[str, Any]:
        """Every number as JSON-ready lists (NaN and inf become None)."""
        return to_jsonable(
            {
                "name": self.name,
                "status": str(self.status),
                "message": self.message,
                "P": self.P,
                "residuals": dict(self.residuals),
                "residual": dict(self.residual),
                "residual_total": self.residual_total,
                "scale": self.scale,
                "distance": self.distance,
                "scale_all": self.scale_all,
                "distance_all": self.distance_all,
                "alpha": self.alpha,
                "params": dict(self.params),
            }
        )


def to_jsonable(x: Any) -> Any:
    """Arrays to nested lists, numpy scalars to Python, NaN and inf to None, enums to str."""
    if isinstance(x, Mapping):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, np.ndarray):
        return to_jsonable(x.tolist())
    if isinstance(x, list | tuple):
        return [to_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, enum.Enum):
        return str(x.value)
    return x


def _residuals(P: np.ndarray, true: MatrixStack, learned: MatrixStack, blocks):
    """Relative residuals per q and over all q; q where P is NaN (undefined) are left out of
    the aggregate."""
    per_q, total = {}, {}
    defined = np.all(np.isfinite(P), axis=(1, 2))
    for k in blocks:
        X = true.block(k)
        err = np.linalg.norm(P @ learned.block(k) - X, axis=(1, 2))
        den = np.linalg.norm(X, axis=(1, 2))
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(den > 0, err / np.where(den > 0, den, 1.0), np.nan)
        rel = np.where((den == 0) & (err == 0), 0.0, rel)
        per_q[k] = rel
        num = float(np.sqrt(np.sum(err[defined] ** 2)))
        d = float(np.sqrt(np.sum(den[defined] ** 2)))
        if not defined.any():
            total[k] = math.nan
        else:
            total[k] = num / d if d > 0 else (0.0 if num == 0 else math.inf)
    return per_q, total


def _identity_distance(P: np.ndarray):
    n = P.shape[-1]
    eye = np.eye(n)
    scale = np.trace(P, axis1=1, axis2=2) / n
    normP = np.linalg.norm(P, axis=(1, 2))
    err = np.linalg.norm(P - scale[:, None, None] * eye, axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.where(normP > 0, err / np.where(normP > 0, normP, 1.0), 0.0)
    finite = np.all(np.isfinite(P), axis=(1, 2))
    if not np.any(finite):
        return scale, dist, math.nan, math.nan
    Pf = P[finite]
    scale_all = float(np.mean(scale[finite]))
    tot = float(np.linalg.norm(Pf))
    dist_all = float(np.linalg.norm(Pf - scale_all * eye)) / tot if tot > 0 else 0.0
    return scale, dist, scale_all, dist_all


def _result(name, P, true, learned, blocks, status, message, params, model=None):
    residuals, residual = _residuals(P, true, learned, blocks)
    vals = [v for v in residual.values()]
    total = float(np.sqrt(np.mean(np.square(vals)))) if vals else math.nan
    scale, dist, scale_all, dist_all = _identity_distance(P)
    return TransformResult(
        name=name,
        P=P,
        residuals=residuals,
        residual=residual,
        residual_total=total,
        scale=scale,
        distance=dist,
        scale_all=scale_all,
        distance_all=dist_all,
        status=Status(status),
        message=message,
        params=params,
        model=model,
    )


def _prepare(true, learned, q, blocks):
    true = as_stack(true, "true")
    learned = as_stack(learned, "learned")
    check_pair(true, learned)
    qa = None if q is None else check_q(q, true.N, true.n)
    return true, learned, qa, common_blocks(true, learned, blocks)


# --------------------------------------------------------------------------------------------
# Least squares


def _lstsq_rows(Xh: np.ndarray, X: np.ndarray, rcond: float | None):
    """Batched minimum-norm least squares of ``P Xh ~= X`` by SVD; Xh, X: (B, n, K).

    Returns P (B, n, n), the rank of each Xh and its condition number.
    """
    U, S, Vt = np.linalg.svd(Xh, full_matrices=False)  # U (B,n,r) S (B,r) Vt (B,r,K)
    if rcond is None:
        rcond = max(Xh.shape[1], Xh.shape[2]) * np.finfo(np.float64).eps
    smax = S[:, :1]
    keep = S > rcond * smax
    inv = np.where(keep, 1.0 / np.where(keep, S, 1.0), 0.0)
    P = (X @ np.swapaxes(Vt, 1, 2)) * inv[:, None, :] @ np.swapaxes(U, 1, 2)
    rank = keep.sum(axis=1)
    with np.errstate(divide="ignore"):
        cond = np.where(S[:, -1] > 0, S[:, 0] / np.where(S[:, -1] > 0, S[:, -1], 1.0), np.inf)
    return P, rank, cond


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


# --------------------------------------------------------------------------------------------
# Smooth P(q)


@dataclass(frozen=True, eq=False)
class Basis:
    """Feature map ``phi(q)`` for a smooth P(q) = sum_j phi_j(q) C_j.

    ``polynomial``: all monomials of total degree <= ``degree`` in the scaled coordinates
    ``z = (q - center) / half_range`` of the training q. ``rbf``: a constant plus Gaussians
    ``exp(-|z - c|^2 / (2 width^2))`` at ``centers``.
    """

    kind: str
    center: np.ndarray
    half_range: np.ndarray
    exponents: np.ndarray | None = None  # (J, n) for polynomial
    centers: np.ndarray | None = None  # (J - 1, n) for rbf, in z
    width: float = 1.0

    @property
    def size(self) -> int:
        return len(self.exponents) if self.kind == "polynomial" else 1 + len(self.centers)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """Features (N, J) at q (N, n)."""
        z = (np.atleast_2d(q) - self.center) / self.half_range
        if self.kind == "polynomial":
            return np.prod(z[:, None, :] ** self.exponents[None, :, :], axis=2)
        d2 = np.sum((z[:, None, :] - self.centers[None]) ** 2, axis=2)
        return np.concatenate([np.ones((len(z), 1)), np.exp(-d2 / (2 * self.width**2))], axis=1)


def make_basis(q_train: np.ndarray, kind="polynomial", *, degree=2, n_centers=20, seed=0) -> Basis:
    """A :class:`Basis` scaled to the training q (see there)."""
    if kind not in BASES:
        raise UserError(f"basis: expected one of {list(BASES)}, got {kind!r}")
    lo, hi = q_train.min(axis=0), q_train.max(axis=0)
    center = (lo + hi) / 2
    half = np.where(hi > lo, (hi - lo) / 2, 1.0)
    n = q_train.shape[1]
    if kind == "polynomial":
        if int(degree) != degree or degree < 0:
            raise UserError(f"degree: expected an integer >= 0, got {degree!r}")
        exps = []
        for d in range(int(degree) + 1):
            for combo in itertools.combinations_with_replacement(range(n), d):
                e = np.zeros(n, dtype=np.int64)
                for i in combo:
                    e[i] += 1
                exps.append(e)
        return Basis("polynomial", center, half, exponents=np.array(exps))
    if int(n_centers) != n_centers or n_centers < 1:
        raise UserError(f"n_centers: expected an integer >= 1, got {n_centers!r}")
    z = (q_train - center) / half
    k = min(int(n_centers), len(z))
    # farthest-point sampling from a seeded start: spread-out, deterministic centres
    rng = np.random.default_rng(seed)
    idx = [int(rng.integers(len(z)))]
    d = np.sum((z - z[idx[0]]) ** 2, axis=1)
    for _ in range(k - 1):
        idx.append(int(np.argmax(d)))
        d = np.minimum(d, np.sum((z - z[idx[-1]]) ** 2, axis=1))
    centers = z[idx]
    if k > 1:
        pd = np.sqrt(np.sum((centers[:, None] - centers[None]) ** 2, axis=2))
        width = float(np.median(pd[np.triu_indices(k, 1)]))
    else:
        width = 1.0
    return Basis("rbf", center, half, centers=centers, width=width if width > 0 else 1.0)


def split_train_heldout(N: int, heldout: float, seed: int) -> np.ndarray:
    """Boolean training mask: a seeded random ``heldout`` fraction of the N q is held out
    (at least one on each side when N >= 2)."""
    if not (0.0 <= heldout < 1.0):
        raise UserError(f"heldout: expected a fraction in [0, 1), got {heldout!r}")
    n_out = int(round(heldout * N))
    if heldout > 0 and N >= 2:
        n_out = min(max(n_out, 1), N - 1)
    mask = np.ones(N, dtype=bool)
    mask[np.random.default_rng(seed).permutation(N)[:n_out]] = False
    return mask


def fit_smooth(
    true,
    learned,
    q,
    *,
    blocks=None,
    weighting="frobenius",
    basis="polynomial",
    degree=2,
    n_centers=20,
    ridge=0.0,
    heldout=0.25,
    train=None,
    seed=0,
    rcond=None,
) -> TransformResult:
    """A smooth ``P(q) = sum_j phi_j(q) C_j`` fitted jointly on ``P(q) [M^ D^ A^ G^] ~=
    [M D A G]`` at the training q (linear least squares in the coefficients C_j, with an
    optional ridge penalty ``ridge * sum_j ||C_j||_F^2`` on the weighted equations) and scored
    at every q. ``train`` (boolean mask, N) overrides the seeded random ``heldout`` split.

    ``params`` holds ``train`` (mask), ``residual_train`` and ``residual_heldout`` (per matrix,
    over those q), ``coefficients`` (J, n, n) and the ``basis``; ``model(q)`` gives P at new q.
    """
    if q is None:
        raise UserError("smooth: q is required (the fit is a function of q)")
    true, learned, qa, blocks = _prepare(true, learned, q, blocks)
    N, n = true.N, true.n
    if train is None:
        mask = split_train_heldout(N, heldout, seed)
    else:
        mask = np.asarray(train, dtype=bool)
        if mask.shape != (N,):
            raise UserError(f"train: expected a boolean mask of shape ({N},), got {mask.shape}")
        if not mask.any():
            raise UserError("train: no q selected for training")
    if not (math.isfinite(ridge) and ridge >= 0):
        raise UserError(f"ridge: expected a number >= 0, got {ridge!r}")
    phi_map = make_basis(qa[mask], basis, degree=degree, n_centers=n_centers, seed=seed)
    J = phi_map.size
    tr_true = subset(true, mask)
    tr_learned = subset(learned, mask)
    w = block_weights(tr_true, tr_learned, blocks, weighting)
    Xh = stacked_blocks(tr_learned, blocks, w)  # (Nt, n, K)
    X = stacked_blocks(tr_true, blocks, w)
    phi = phi_map(qa[mask])  # (Nt, J)
    Nt, _, K = Xh.shape
    # unknown C = [C_1 ... C_J] (n, J n); equation C F = X with F = [phi_j(q) Xh(q)]_j stacked
    F = (phi[:, :, None, None] * Xh[:, None]).reshape(Nt, J * n, K)
    F = np.moveaxis(F, 0, 1).reshape(J * n, Nt * K)
    T = np.moveaxis(X, 0, 1).reshape(n, Nt * K)
    if ridge > 0:
        F = np.concatenate([F, math.sqrt(ridge) * np.eye(J * n)], axis=1)
        T = np.concatenate([T, np.zeros((n, J * n))], axis=1)
    Ct, _, rank, sv = np.linalg.lstsq(F.T, T.T, rcond=rcond)
    C = Ct.T.reshape(n, J, n).transpose(1, 0, 2)  # (J, n, n)

    def model(qq, _C=C, _phi=phi_map):
        return np.einsum("nj,jab->nab", _phi(np.atleast_2d(np.asarray(qq, float))), _C)

    P = model(qa)
    res = _result("smooth", P, true, learned, blocks, Status.SUCCESS, "", {}, model)
    out = ~mask
    sub = {}
    for label, m in (("train", mask), ("heldout", out)):
        if m.any():
            _, sub[label] = _residuals(P[m], subset(true, m), subset(learned, m), blocks)
        else:
            sub[label] = {k: math.nan for k in blocks}
    status = Status.SUCCESS
    unknowns, equations = J * n, Nt * K
    msg = (
        f"{basis} basis ({J} functions) fitted on {int(mask.sum())} q, held out {int(out.sum())};"
        f" held-out residual {_fmt_max(sub['heldout'])}"
    )
    if ridge == 0 and equations < unknowns:
        status = Status.UNDERDETERMINED
        msg = f"{equations} equations per row for {unknowns} unknowns: add q or ridge; " + msg
    elif rank < unknowns and ridge == 0:
        status = Status.RANK_DEFICIENT
        msg = f"design matrix rank {rank} < {unknowns} unknowns: minimum-norm fit; " + msg
    params = {
        "blocks": list(blocks),
        "weights": w,
        "basis": basis,
        "degree": degree if basis == "polynomial" else None,
        "n_functions": J,
        "ridge": ridge,
        "train": mask,
        "rank": int(rank),
        "residual_train": sub["train"],
        "residual_heldout": sub["heldout"],
        "coefficients": C,
        "seed": seed,
    }
    return TransformResult(**{**res.__dict__, "status": status, "message": msg, "params": params})


def _fmt_max(d: Mapping[str, float]) -> str:
    vals = [v for v in d.values() if math.isfinite(v)]
    return f"max {max(vals):.3g}" if vals else "n/a"


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
