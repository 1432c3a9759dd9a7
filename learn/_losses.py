"""Training losses (eqs. 8-10) and batched helpers.

* :func:`pair_loss` / :func:`pair_errors`: one RK4 step per pair with the pair's own dt, then
  ‖q₁ - q̂₁‖² + λ ‖v₁ - v̂₁‖², with v = q̇ (eq. 8, Lagrangian and velocity data) or v = p
  (eq. 9, Hamiltonian and momentum data); the loss is the mean over the batch.
* :func:`accel_loss`: eq. 10, no integration: ‖ẋ₀ - f(x₀, u₀)‖². For a Lagrangian model
  ẋ = (q̇, q̈) and the first half is q̇ itself, so this is exactly ‖q̈ - q̂̈‖²; for the
  Hamiltonian and the black box it also fits q̇ (resp. the whole derivative).
* :func:`rollout_loss`: the mean of the same per-sample error over h consecutive steps
  simulated from the first state of each window (multiple shooting); with
  :func:`rollout_loss_and_range` also the fraction of windows whose rollout leaves the training
  data's range or is not finite (issue 43: reported, never a silent number).
* :func:`label_loss`: static-equilibrium labels G(q*) = A(q*) u* (and the force f* there),
  added to any of the above in training when ``TrainConfig.equilibrium_weight`` or
  ``force_weight`` > 0.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from softpinn.errors import UserError
from softpinn.learn._data import difference_accelerations
from softpinn.learn._integrate import rollout, step
from softpinn.learn._linalg import cho_solve
from softpinn.learn._models import _apply, _potential_grad

__all__ = [
    "Pairs",
    "Windows",
    "state_error",
    "pair_predictions",
    "pair_errors",
    "pair_loss",
    "accel_errors",
    "accel_loss",
    "rollout_predictions",
    "rollout_errors",
    "rollout_loss",
    "outside_range",
    "rollout_loss_and_range",
    "batch_vector_field",
    "Equilibria",
    "equilibrium_forces",
    "equilibria_of",
    "label_loss",
]


class Pairs(NamedTuple):
    """A batch of B consecutive-sample pairs of one trajectory each (never across two)."""

    x0: jax.Array  # (B, 2n) state at t_k: (q, q̇) or (q, p)
    u0: jax.Array  # (B, m) input at t_k
    u1: jax.Array  # (B, m) input at t_{k+1} (used by input_hold="linear")
    dt: jax.Array  # (B,) t_{k+1} - t_k
    x1: jax.Array  # (B, 2n) state at t_{k+1}
    xdot0: jax.Array | None = None  # (B, 2n) derivative at t_k, for eq. 10


class Windows(NamedTuple):
    """A batch of B windows of h + 1 consecutive samples of one trajectory each."""

    x: jax.Array  # (B, h + 1, 2n)
    u: jax.Array  # (B, h + 1, m)
    t: jax.Array  # (B, h + 1)


def state_error(x_true, x_pred, n: int, weight=1.0):
    """‖q - q̂‖² + λ ‖v - v̂‖² over the last axis, v the second half of the state (eqs. 8, 9)."""
    d = x_true - x_pred
    dq, dv = d[..., :n], d[..., n:]
    return jnp.sum(dq * dq, axis=-1) + weight * jnp.sum(dv * dv, axis=-1)


def _check_pairs(model, pairs):
    n2 = 2 * model.config.n
    B = pairs.x0.shape[0]
    shapes = {
        "x0": (B, n2),
        "u0": (B, model.config.m),
        "u1": (B, model.config.m),
        "dt": (B,),
        "x1": (B, n2),
    }
    for name, shape in shapes.items():
        got = getattr(pairs, name).shape
        if got != shape:
            raise UserError(f"pairs.{name} must have shape {shape}, got {got}")


def batch_vector_field(model, x, u):
    """ẋ for a batch: x (B, 2n), u (B, m) -> (B, 2n)."""
    return jax.vmap(model.vector_field)(x, u)


def pair_predictions(model, pairs: Pairs, *, substeps=1, input_hold="constant"):
    """x̂₁ for every pair: one RK4 step (or ``substeps``) over each pair's own dt, (B, 2n)."""
    _check_pairs(model, pairs)
    one = lambda x0, u0, u1, dt: step(
        model, x0, u0, u1, dt, substeps=substeps, input_hold=input_hold
    )
    return jax.vmap(one)(pairs.x0, pairs.u0, pairs.u1, pairs.dt)


def pair_errors(model, pairs: Pairs, *, weight=1.0, substeps=1, input_hold="constant"):
    """Per-pair loss ‖q₁ - q̂₁‖² + λ ‖v₁ - v̂₁‖² (eq. 8 or 9), shape (B,)."""
    x1_hat = pair_predictions(model, pairs, substeps=substeps, input_hold=input_hold)
    return state_error(jnp.asarray(pairs.x1, x1_hat.dtype), x1_hat, model.config.n, weight)


def pair_loss(model, pairs: Pairs, *, weight=1.0, substeps=1, input_hold="constant"):
    """Eq. 8 (velocity state) / eq. 9 (momentum state): mean of :func:`pair_errors`."""
    return jnp.mean(
        pair_errors(model, pairs, weight=weight, substeps=substeps, input_hold=input_hold)
    )


#: Where eq. 10 compares: "acceleration" (‖q̈ - q̂̈‖²) or "force" (‖M̂(q) (q̈ - q̂̈)‖², the
#: residual M̂ q̈ + Ĉ q̇ + D̂ q̇ + Ĝ - A u of eq. 4 with the labels' q̈; velocity-state physics
#: models with a known A).
ACCEL_SPACES = ("acceleration", "force")


def _mass_times(model, q, v):
    """M̂(q) v: L Lᵀ v for a Lagrangian network (M = L Lᵀ), a Cholesky solve for a Hamiltonian
    one (M⁻¹ = L Lᵀ)."""
    L = model.mass.factor(q)
    if model.config.kind == "hamiltonian":
        return cho_solve(L, v)
    return L @ (L.T @ v)


def accel_errors(model, pairs: Pairs, space: str = "acceleration", weights=None):
    """Per-sample ‖ẋ₀ - f(x₀, u₀)‖² (eq. 10), shape (B,); needs ``pairs.xdot0``. ``space``
    "force": ‖W M̂(q₀) (q̈₀ - q̂̈₀)‖² instead, the force balance of eq. 4 with the labels' q̈,
    which is linear in the networks' M̂, D̂, Ĝ (the q̇ half of a velocity state is exact); W =
    diag(``weights``) (n,), or I (see :func:`force_weights`)."""
    if pairs.xdot0 is None:
        raise UserError("the acceleration loss (eq. 10) needs pairs.xdot0 (the dataset's qdd)")
    _check_pairs(model, pairs)
    if pairs.xdot0.shape != pairs.x0.shape:
        raise UserError(f"pairs.xdot0 must have shape {pairs.x0.shape}, got {pairs.xdot0.shape}")
    f = batch_vector_field(model, pairs.x0, pairs.u0)
    d = jnp.asarray(pairs.xdot0, f.dtype) - f
    if space == "force":
        n = model.config.n
        d = jax.vmap(lambda q, v: _mass_times(model, q, v))(
            jnp.asarray(pairs.x0[:, :n], f.dtype), d[:, n:])
        if weights is not None:
            d = d * jnp.asarray(weights, f.dtype)[None, :]
    elif space != "acceleration":
        raise UserError(f"space: expected one of {list(ACCEL_SPACES)}, got {space!r}")
    return jnp.sum(d * d, axis=-1)


def accel_loss(model, pairs: Pairs, space: str = "acceleration", weights=None):
    """Eq. 10: mean over the batch of ‖ẋ₀ - f(x₀, u₀)‖² (= ‖q̈ - q̂̈‖² for Lagrangian models),
    or of its force-space form (:func:`accel_errors`)."""
    return jnp.mean(accel_errors(model, pairs, space, weights))


def force_weights(model, q, qdd) -> np.ndarray:
    """Weights of the force-space residual's coordinates from a trained model: mean(s) / s_i,
    s_i the rms over the samples of (M̂(q) q̈)_i, the model's inertial force (q (N, n), q̈ labels
    (N, n)). With them each coordinate's residual counts relative to its own force scale: in
    plain force space a light segment's small forces weigh little, and its block of M, whose
    inverse dominates M⁻¹, is fitted loosely (task 5: M⁻¹ 14 % off with M 1.3 %; 5.4 % with
    these weights, RESULTS.md)."""
    q = jnp.asarray(q)
    f = jax.vmap(lambda q, v: _mass_times(model, q, v))(q, jnp.asarray(qdd, q.dtype))
    s = np.sqrt(np.mean(np.asarray(f, dtype=float) ** 2, axis=0))
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise UserError("accel_weights: the model's inertial force M̂ q̈ is 0 or not finite in "
                        "some coordinate over these data; give the weights instead")
    return s.mean() / s


def data_force_weights(model, data, traj_ids, labels: str = "differences") -> tuple[float, ...]:
    """:func:`force_weights` over every sample of trajectories ``traj_ids`` of a
    :class:`learn._data.Dataset`, with q̈ labels as loss accel takes them (``labels``
    "recorded": the file's qdd; "differences": central differences of its q̇)."""
    rows = np.concatenate([data.indices(int(k)) for k in traj_ids])
    qdd = difference_accelerations(data) if labels == "differences" else data.qdd
    return tuple(float(w) for w in force_weights(model, data.q[rows], qdd[rows]))


def _check_horizon(model, x, horizon):
    if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1:
        raise UserError(f"horizon must be an integer >= 1, got {horizon!r}")
    if x.ndim != 3 or x.shape[1] < horizon + 1:
        raise UserError(
            f"windows.x must have shape (B, >= {horizon + 1}, {2 * model.config.n}), got {x.shape}"
        )


def rollout_predictions(model, windows: Windows, *, horizon: int, substeps=1,
                        input_hold="constant"):
    """x̂ (B, horizon + 1, 2n): each window simulated from its first state with its own inputs
    and times over its first ``horizon`` steps (any model kind: a Hamiltonian network on
    (q, q̇) is stepped through its momenta, :func:`learn._integrate.step`)."""
    x, u, t = windows
    _check_horizon(model, x, horizon)
    x, u, t = x[:, : horizon + 1], u[:, : horizon + 1], t[:, : horizon + 1]
    one = lambda xw, uw, tw: rollout(model, xw[0], uw, tw, substeps=substeps, input_hold=input_hold)
    return jax.vmap(one)(x, u, t)


def _window_errors(model, windows: Windows, xhat, horizon: int, weight):
    x = jnp.asarray(windows.x[:, : horizon + 1], xhat.dtype)
    err = state_error(x[:, 1:], xhat[:, 1:], model.config.n, weight)
    return jnp.mean(err, axis=1)


def rollout_errors(
    model, windows: Windows, *, horizon: int, weight=1.0, substeps=1, input_hold="constant"
):
    """Per-window mean over h steps of ‖q_k - q̂_k‖² + λ ‖v_k - v̂_k‖², shape (B,).

    Each window is simulated from its first state with its own inputs and times; only the first
    ``horizon + 1`` samples of each window are used.
    """
    xhat = rollout_predictions(model, windows, horizon=horizon, substeps=substeps,
                               input_hold=input_hold)
    return _window_errors(model, windows, xhat, horizon, weight)


def rollout_loss(
    model, windows: Windows, *, horizon: int, weight=1.0, substeps=1, input_hold="constant"
):
    """Multi-step loss: mean over windows and steps of the state error (eqs. 8/9 over h steps)."""
    return jnp.mean(
        rollout_errors(
            model,
            windows,
            horizon=horizon,
            weight=weight,
            substeps=substeps,
            input_hold=input_hold,
        )
    )


def outside_range(xhat, n: int, low, high):
    """Per window (B,): whether its rollout x̂ (B, h + 1, 2n) is not finite anywhere or its q̂
    leaves the box [low, high] (n,) anywhere (:func:`learn._objective.training_box`)."""
    q = xhat[..., :n]
    low, high = jnp.asarray(low)[None, None, :], jnp.asarray(high)[None, None, :]
    inside = jnp.all((q >= low) & (q <= high), axis=(1, 2))
    return ~(inside & jnp.all(jnp.isfinite(xhat), axis=(1, 2)))


def rollout_loss_and_range(model, windows: Windows, box, *, horizon: int, weight=1.0,
                           substeps=1, input_hold="constant"):
    """(:func:`rollout_loss`, the fraction of the windows whose rollout leaves ``box`` = (low,
    high) or is not finite): the loss of a training step and what it says about range, from one
    simulation."""
    xhat = rollout_predictions(model, windows, horizon=horizon, substeps=substeps,
                               input_hold=input_hold)
    loss = jnp.mean(_window_errors(model, windows, xhat, horizon, weight))
    out = outside_range(xhat, model.config.n, box[0], box[1])
    return loss, jnp.mean(out.astype(xhat.dtype))


# ------------------------------------------------------------------- equilibrium labels


class Equilibria(NamedTuple):
    """Static-equilibrium labels (Section VI-B, "additional labels"): at rest under the constant
    input u*, eq. 4 gives G(q*) = A(q*) u* = f*, the generalized force there."""

    q: jax.Array  # (K, n)
    u: jax.Array  # (K, m)
    force: jax.Array  # (K, n)
    force_scale: jax.Array  # () mean |f*|^2 over the labels (1 where all f* are 0)


def equilibrium_forces(model, eq: Equilibria):
    """The model's G(q*) (K, n) and A(q*) u* (K, n) at the labelled equilibria."""
    if not hasattr(model, "potential") or not hasattr(model, "input_map"):
        raise UserError(f"equilibrium labels weigh G and A of a physics model; a "
                        f"{model.config.kind} model has none")
    dt = model.dtype
    q, u = jnp.asarray(eq.q, dt), jnp.asarray(eq.u, dt)
    G = jax.vmap(lambda qq: _potential_grad(model.potential, qq))(q)
    Au = jax.vmap(lambda qq, uu: _apply(model.input_map, qq, uu))(q, u)
    return G, Au


def label_loss(model, eq: Equilibria, *, equilibrium_weight=0.0, force_weight=0.0):
    """The label terms added to the training loss, dimensionless:

    * balance (``equilibrium_weight``): mean_k |G(q*_k) - A(q*_k) u*_k|² divided by
      mean_k (|G|² + |A u*|²) / 2 of the model itself. Relative, so that it is unchanged when
      the network scales M, D, G and A together by one α, which leaves every trajectory the
      same and which the labels cannot see either (a term in absolute units would pull every
      force towards 0 along that direction); it is 0 exactly when the learned potential and
      input forces balance at every labelled equilibrium, 2 when they are orthogonal.
    * force (``force_weight``): (mean |G - f*|² + mean |A u* - f*|²) / (2 mean |f*|²), with the
      measured generalized force f* (``eq_force``): it pins that scale (and G and A u at q*).
    """
    G, Au = equilibrium_forces(model, eq)
    sq = lambda a: jnp.sum(a * a, axis=-1)
    total = jnp.zeros((), G.dtype)
    if equilibrium_weight:
        norm = 0.5 * jnp.mean(sq(G) + sq(Au)) + jnp.finfo(G.dtype).tiny
        total = total + equilibrium_weight * jnp.mean(sq(G - Au)) / norm
    if force_weight:
        f = jnp.asarray(eq.force, G.dtype)
        scale = jnp.asarray(eq.force_scale, G.dtype)
        total = total + force_weight * (jnp.mean(sq(G - f)) + jnp.mean(sq(Au - f))) / (2 * scale)
    return total


def equilibria_of(data, dtype=None) -> Equilibria:
    """The labels of a :class:`learn._data.Dataset` holding equilibria (``eq_q`` ...)."""
    if getattr(data, "eq_q", None) is None or data.equilibria == 0:
        raise UserError(f"dataset file {data.path} holds no static equilibria (eq_q, eq_u, "
                        "eq_force): simulate it with --equilibria K")
    scale = float(np.mean(np.sum(data.eq_force ** 2, axis=1)))
    a = lambda x: jnp.asarray(x, dtype)
    return Equilibria(a(data.eq_q), a(data.eq_u), a(data.eq_force), a(scale if scale > 0 else 1.0))
