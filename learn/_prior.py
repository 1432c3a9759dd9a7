"""A linear prior inside the networks (issue 43): the linear second-order model as a fixed part
of every model kind, with the networks learning the correction on it.

On arms that move close to linearly in their recorded range (the Cosserat and experiment
stand-ins, RESULTS.md), a freshly initialised network spends its budget relearning what the
fit M q̈ + D q̇ + K q = B u + c already knows, and ends near or behind it. With the prior, a
model starts as that fit (by least squares on q̈, or by its rollout error where that rolls out
better on the validation trajectories: :func:`resolve_prior`) and its sub-networks add what is
not linear:

* Lagrangian (eq. 6) and Hamiltonian (eq. 7) networks: the prior enters as a generalised force
      F₀(q, q̇, u) = B₀ u + c₀ - K₀ q - D₀ q̇
  on the right-hand side, M q̈ = A u - Ṁ q̇ + ½ ∂(q̇ᵀ M q̇)/∂q - ∂V/∂q - D q̇ + F₀ (and
  ṗ = -∂H/∂q - D q̇ + A u + F₀), with K₀, D₀, B₀, c₀ the fit's in its normalised form M = I
  (the scale of M is not identifiable from motion, :mod:`learn._baselines`). At the start
  M = I exactly, V and A are zero and D nearly (:func:`quiet_start`): the model is the linear
  fit; the learned matrices a report shows are the totals (G = ∂V/∂q + K₀ q - c₀, D + D₀, A + B₀).
* Black box: ẋ = (q̇, F₀(q, q̇, u)) + MLP([x, u]), the MLP's last layer starting at zero.

The prior is fixed (a static field, like a known input matrix): the optimizer moves only the
networks. It travels in :class:`learn._model_config.ModelConfig` as JSON text (``prior``), so
a run's ``config.json`` rebuilds its model alone and the exporter writes the same force.
"""

from __future__ import annotations

import json
import math
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from softpinn.errors import UserError
from softpinn.learn._baselines import checked_array, fit_linear_second_order
from softpinn.learn._nets import (
    CholeskyField,
    ConstantCholesky,
    ConstantMatrix,
    MatrixField,
    ScalarField,
    softplus_inverse,
)
from softpinn.learn._output_error import fit_linear_rollout, window_error

__all__ = ["LinearPrior", "PRIOR_SETTINGS", "parse_prior", "prior_text", "quiet_start",
           "resolve_prior", "zero_last"]

#: ``TrainConfig.prior``: none, the linear fit, or auto (linear on imported recordings).
PRIOR_SETTINGS = ("none", "linear", "auto")
_KEYS = ("K", "D", "B", "c")


def _matrix(d: dict, key: str, shape: tuple[int, ...]) -> tuple:
    a = checked_array(d, key, shape, "prior")
    return tuple(a.tolist()) if a.ndim == 1 else tuple(tuple(r) for r in a.tolist())


def parse_prior(text: str, n: int, m: int) -> dict[str, tuple]:
    """``prior`` text checked against n, m: ``{"K", "D", "B", "c"}`` as tuples of floats."""
    try:
        d = json.loads(text)
    except (TypeError, ValueError) as err:
        raise UserError(f"prior must be JSON text, got {str(text)[:40]!r} ({err})") from None
    if not isinstance(d, dict) or d.get("kind") != "linear":
        raise UserError("prior: expected {'kind': 'linear', 'K', 'D', 'B', 'c'}")
    shapes = {"K": (n, n), "D": (n, n), "B": (n, m), "c": (n,)}
    return {k: _matrix(d, k, shapes[k]) for k in _KEYS}


def prior_text(fit) -> str:
    """Canonical ``prior`` text of a :class:`learn._baselines.LinearSecondOrder` fit (or of a
    dict with K, D, B, c): compact JSON with sorted keys, so equal fits give equal configs."""
    mats = fit.matrices() if hasattr(fit, "matrices") else fit
    d = {"kind": "linear", **{k: np.asarray(mats[k], dtype=np.float64).tolist() for k in _KEYS}}
    for k in _KEYS:
        if not np.all(np.isfinite(np.asarray(d[k], dtype=np.float64))):
            raise UserError(f"prior: the linear fit's {k} holds NaN or inf")
    return json.dumps(d, sort_keys=True, separators=(",", ":"), allow_nan=False)


def resolve_prior(setting: str, data, train_ids, val_ids=(), *,
                  input_hold: str = "constant") -> tuple[str | None, str | None]:
    """(``ModelConfig.prior`` text or None, a one-line note) for ``TrainConfig.prior``:
    "linear" fits M q̈ + D q̇ + K q = B u + c on the training trajectories of ``data`` (a
    :class:`learn._data.Dataset` whose inputs are what reaches the arm, i.e. after the run's
    actuator), "auto" does so on imported recordings only, "none" does not.

    Two fits: least squares on the data's q̈ and the rollout fit that starts from it
    (:mod:`learn._output_error`, on data with one sample step). The prior is the one with the
    lower rollout error on the validation trajectories ``val_ids`` (on the training ones where
    there are none): on noisy recordings the rollout fit (smoothed q̈ mislead least squares), on
    clean ones whichever generalises better."""
    if setting not in PRIOR_SETTINGS:
        raise UserError(f"prior: expected one of {list(PRIOR_SETTINGS)}, got {setting!r}")
    if setting == "none" or (setting == "auto" and data.meta.get("source") != "import"):
        return None, None
    fits = [fit_linear_second_order(data, train_ids)]
    try:
        fits.append(fit_linear_rollout(data, train_ids, input_hold=input_hold))
    except UserError:  # several sample steps: the least-squares fit alone
        pass
    why = "--prior linear" if setting == "linear" else "auto: imported recordings"
    trained = (f"{len(train_ids)} training trajector"
               f"{'y' if len(train_ids) == 1 else 'ies'}")
    if len(fits) == 1:
        fit = fits[0]
        note = (f"prior: the linear model fitted by least squares on q̈ on {trained} (q̈ "
                f"residual rms {fit.info['accel_rms']:.3g}; the samples are not at one step, "
                f"so no rollout fit); the networks learn the correction ({why})")
        return prior_text(fit), note
    judge = list(val_ids) if len(val_ids) else list(train_ids)
    horizon = fits[1].info["horizon"]
    scores = [window_error(f, data, judge, horizon=horizon, input_hold=input_hold)
              for f in fits]
    fit = fits[1] if scores[1] <= scores[0] or not math.isfinite(scores[0]) else fits[0]
    how = "by least squares on q̈" if fit.kind == "linear2" else "by its rollout error"
    where = "validation" if len(val_ids) else "training"
    note = (f"prior: the linear model fitted {how} on {trained} ({horizon:g} s rollout error "
            f"on the {where} trajectories: least squares {scores[0]:.3g}, rollout fit "
            f"{scores[1]:.3g}); the networks learn the correction ({why})")
    return prior_text(fit), note


class LinearPrior(eqx.Module):
    """F₀(q, q̇, u) = B₀ u + c₀ - K₀ q - D₀ q̇, fixed (static data: no parameter to train)."""

    data: Any = eqx.field(static=True)
    shape: tuple[int, int] = eqx.field(static=True)

    def __init__(self, text: str, n: int, m: int):
        self.data = parse_prior(text, n, m)
        self.shape = (int(n), int(m))

    def arrays(self, dtype=jnp.float64) -> dict[str, jnp.ndarray]:
        n, m = self.shape
        return {"K": jnp.asarray(self.data["K"], dtype).reshape(n, n),
                "D": jnp.asarray(self.data["D"], dtype).reshape(n, n),
                "B": jnp.asarray(self.data["B"], dtype).reshape(n, m),
                "c": jnp.asarray(self.data["c"], dtype).reshape(n)}

    def to_data(self) -> dict[str, Any]:
        """JSON-ready ``{"kind": "linear", "K", "D", "B", "c"}`` (for the exporter)."""
        return {"kind": "linear", **{k: np.asarray(v).tolist() for k, v in self.data.items()}}

    def __call__(self, q, qd, u):
        a = self.arrays(q.dtype)
        return a["B"] @ u + a["c"] - a["K"] @ q - a["D"] @ qd

    def matrices(self, q) -> dict[str, jnp.ndarray]:
        """The prior's share of the learned matrices at q: G₀ = K₀ q - c₀, D₀, A₀ = B₀."""
        a = self.arrays(q.dtype)
        return {"G": a["K"] @ q - a["c"], "D": a["D"], "A": a["B"]}


def zero_last(mlp, *, bias=0.0):
    """The MLP with its last layer's weights zero and biases ``bias`` (a number or array)."""
    W, b = mlp.weights[-1], mlp.biases[-1]
    return eqx.tree_at(lambda f: (f.weights[-1], f.biases[-1]), mlp,
                       (jnp.zeros_like(W), jnp.broadcast_to(jnp.asarray(bias, b.dtype), b.shape)))


#: Bias of a quiet Cholesky damping network's diagonal: diag(L) = softplus(b) = 0.03, so D
#: starts at 9e-4 I. Not lower: D = L Lᵀ has no gradient at L = 0, and the damping network
#: would never leave a factor that starts there.
_QUIET_DIAG = softplus_inverse(0.03)


def quiet_start(parts: dict, n: int, eps: float) -> dict:
    """The sub-networks of a physics model (``_physics_parts``'s dict) set so that the model
    starts as its prior alone: M (or M⁻¹) = I exactly, ∂V/∂q = 0, D = 9e-4 I (see
    :data:`_QUIET_DIAG`) and A = 0. Only last layers are set; their inputs keep their random
    features, so gradients reach every weight from the first step."""
    out = dict(parts)
    mass = parts["mass"]
    if isinstance(mass, CholeskyField):
        b0 = softplus_inverse(1.0 - eps)  # diag(L) = softplus(b) + eps = 1
        bias = jnp.zeros_like(mass.mlp.biases[-1]).at[:n].set(b0)
        out["mass"] = eqx.tree_at(lambda f: f.mlp, mass, zero_last(mass.mlp, bias=bias))
    if isinstance(parts["potential"], ScalarField):
        pot = parts["potential"]
        out["potential"] = eqx.tree_at(lambda f: f.mlp, pot, zero_last(pot.mlp))
    damping = parts["damping"]
    if isinstance(damping, CholeskyField):
        bias = jnp.zeros_like(damping.mlp.biases[-1]).at[:n].set(_QUIET_DIAG)
        out["damping"] = eqx.tree_at(lambda f: f.mlp, damping,
                                     zero_last(damping.mlp, bias=bias))
    elif isinstance(damping, ConstantCholesky):
        raw = jnp.zeros_like(damping.raw).at[:n].set(_QUIET_DIAG)
        out["damping"] = eqx.tree_at(lambda f: f.raw, damping, raw)
    A = parts["input_map"]
    if isinstance(A, MatrixField):
        out["input_map"] = eqx.tree_at(lambda f: f.mlp, A, zero_last(A.mlp))
    elif isinstance(A, ConstantMatrix):
        out["input_map"] = eqx.tree_at(lambda f: f.value, A, jnp.zeros_like(A.value))
    return out
