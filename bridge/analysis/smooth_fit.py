"""A smooth transform P(q) fitted across configurations (polynomial or RBF basis) and checked
on held-out q: does one continuous P(q) relate the learned matrices to the true ones?"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from softpinn.bridge.analysis.matrices import (
    block_weights,
    stacked_blocks,
    subset,
)
from softpinn.bridge.analysis.transform_result import (
    BASES,
    Status,
    TransformResult,
    _fmt_max,
    _prepare,
    _residuals,
    _result,
)
from softpinn.errors import UserError

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


