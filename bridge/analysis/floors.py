"""The integration floor: the one-step loss of the *true* model stepped as the networks are.

Every model is trained on eq. 8 (eq. 9 for momentum data): one RK4 step (or ``substeps`` of
them) from x_k with the input held constant or interpolated linearly, compared with the
recorded x_{k+1}. The true equations of motion stepped the same way do not reach zero: RK4's
truncation error and the input's variation within a step remain. That loss is a floor under
what any network can reach without learning the integrator's error as physics. A learned
model's test loss near its floor says: refine the step (``substeps``, ``input_hold``), not
the network. ``softpinn reproduce`` reports the floor of every model beside its test loss.
"""

from __future__ import annotations

import numpy as np

__all__ = ["drift_baseline", "integration_floor", "true_vector_field"]


def true_vector_field(true_model, state: str):
    """f(x, u) -> ẋ for batches x (B, 2n), u (B, m) of the true model in ``state`` form:
    "velocity" x = (q, q̇) (eq. 4) or "momentum" x = (q, p) (eq. 7)."""
    n, m = true_model.n, true_model.m

    def velocity(x, u):
        qdd = true_model.qdd(x[:, :n], x[:, n:], u if m else None)
        return np.concatenate([x[:, n:], qdd], axis=1)

    def momentum(x, u):
        qdot, pdot = true_model.hamiltonian(x[:, :n], x[:, n:], u if m else None)
        return np.concatenate([qdot, pdot], axis=1)

    if state not in ("velocity", "momentum"):
        raise ValueError(f"state must be 'velocity' or 'momentum', got {state!r}")
    return velocity if state == "velocity" else momentum


def integration_floor(
    true_model,
    pairs,
    *,
    state: str,
    substeps: int = 1,
    input_hold: str = "constant",
    weight: float = 1.0,
) -> np.ndarray:
    """Per-pair one-step errors (eqs. 8-9) of the true model on ``pairs``.

    ``pairs``: a :class:`learn._data.PairData` (x0, u0, u1, dt, x1) in the given ``state`` form.
    The step mirrors :func:`learn._integrate.step`: ``substeps`` RK4 steps of dt / substeps,
    the input u0 throughout ("constant") or u0 + (u1 - u0) s / dt ("linear").
    """
    if not (isinstance(substeps, int) and substeps >= 1):
        raise ValueError(f"substeps must be an integer >= 1, got {substeps!r}")
    if input_hold not in ("constant", "linear"):
        raise ValueError(f"input_hold must be 'constant' or 'linear', got {input_hold!r}")
    f = true_vector_field(true_model, state)
    n = true_model.n
    x0, u0, u1, dt, x1 = (np.asarray(a, float) for a in pairs[:5])
    dt = dt.reshape(-1, 1)
    h = dt / substeps

    def u_at(s):  # s: fraction of the whole step
        return u0 if input_hold == "constant" else u0 + (u1 - u0) * s

    x = x0
    with np.errstate(over="ignore", invalid="ignore"):  # a blow-up is reported as inf
        for j in range(substeps):
            s0, s1 = j / substeps, (j + 1) / substeps
            um = u_at(0.5 * (s0 + s1))
            k1 = f(x, u_at(s0))
            k2 = f(x + 0.5 * h * k1, um)
            k3 = f(x + 0.5 * h * k2, um)
            k4 = f(x + h * k3, u_at(s1))
            x = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        d = x1 - x
        err = np.sum(d[:, :n] ** 2, axis=1) + weight * np.sum(d[:, n:] ** 2, axis=1)
    return np.where(np.isfinite(err), err, np.inf)


def drift_baseline(pairs, qd0, *, state: str, weight: float = 1.0) -> np.ndarray:
    """Per-pair one-step errors (eqs. 8-9) of a model that learned no forces: q moves on with
    the recorded velocity q̇₀, the velocity (or momentum) stays as it was. In the velocity form
    that is RK4 with q̈ = 0. A learned model near this baseline has learned almost nothing
    about the accelerations, whatever its loss looks like in absolute terms.
    """
    if state not in ("velocity", "momentum"):
        raise ValueError(f"state must be 'velocity' or 'momentum', got {state!r}")
    x0, x1, dt = (np.asarray(a, float) for a in (pairs[0], pairs[4], pairs[3]))
    n = x0.shape[1] // 2
    qd0 = np.asarray(qd0, float)
    if qd0.shape != (len(x0), n):
        raise ValueError(f"qd0 must have shape {(len(x0), n)}, got {qd0.shape}")
    dq = x1[:, :n] - (x0[:, :n] + dt.reshape(-1, 1) * qd0)
    dv = x1[:, n:] - x0[:, n:]
    return np.sum(dq**2, axis=1) + weight * np.sum(dv**2, axis=1)
