"""The MPC's prediction: RK4 steps of a model's field (input held) and their sensitivities.

:func:`rk4_map` is the step itself; :func:`_stage_functions` gives one control step with its
∂x⁺/∂x, ∂x⁺/∂u, exact (RK4's variational equations) or frozen (one Jacobian per step, RK4's
sensitivities of that linearisation in closed form, :func:`_frozen_sensitivities`); the
controller that uses them is :mod:`.mpc`. :func:`stiff_substeps`: how many sub-steps a stiff
model needs.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from softpinn.bridge.control.actuation import settled
from softpinn.bridge.control.config import MPCConfig
from softpinn.bridge.control.models import PredictionModel
from softpinn.errors import UserError

__all__ = ["rk4_map", "stiff_substeps"]


def _sym(fn: ca.Function):
    """The symbol type to call ``fn`` with: MX for an MX Function (a black box rebuilt from its
    weights keeps its dense matrix products), SX otherwise."""
    return ca.MX if fn.is_a("MXFunction") else ca.SX


def rk4_map(field: ca.Function, dt: float, substeps: int) -> ca.Function:
    """F(x, u) -> x after ``substeps`` RK4 steps of dt / substeps, input held (SX, or MX for
    an MX field)."""
    sym = _sym(field)
    x = sym.sym("x", field.size1_in(0))
    u = sym.sym("u", field.size1_in(1))
    h = dt / substeps
    y = x
    for _ in range(substeps):
        k1 = field(y, u)
        k2 = field(y + 0.5 * h * k1, u)
        k3 = field(y + 0.5 * h * k2, u)
        k4 = field(y + h * k3, u)
        y = y + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
    return ca.Function("F", [x, u], [y], ["x", "u"], ["x_next"])


def _field_functions(field: ca.Function, jacobian: ca.Function | None = None):
    """``(f, ∂f/∂(x, u))`` and ``f`` of the field as Functions of (x, u); ``jacobian``: the
    first, given by the model (:attr:`.models.PredictionModel.jacobian`)."""
    nx, m = field.size1_in(0), field.size1_in(1)
    sym = _sym(field)
    xs, us = sym.sym("x", nx), sym.sym("u", m)
    f = field(xs, us)
    if jacobian is not None:
        return jacobian, ca.Function("mpc_field", [xs, us], [f])
    z = ca.vertcat(xs, us)
    # MX (a network's dense layers): forward mode in all directions at once keeps each layer one
    # matrix product; ``jacobian`` would multiply dense diagonal matrices (twice the time)
    J = ca.jtimes(f, z, ca.DM.eye(nx + m)) if sym is ca.MX else ca.jacobian(f, z)
    return (ca.Function("mpc_field_jac", [xs, us], [f, J]),
            ca.Function("mpc_field", [xs, us], [f]))


def _frozen_sensitivities(fj: ca.Function, point, u, h: float, substeps: int):
    """(∂x⁺/∂x, ∂x⁺/∂u) of ``substeps`` RK4 steps of length h for the field linearised at
    ``point`` (its Jacobian from ``fj``, held over the step), in closed form."""
    nx = fj.size1_in(0)
    _, Jxu = fj(point, u)
    Z, I = h * Jxu[:, :nx], ca.DM.eye(nx)
    Q = I + ca.mtimes(Z, I / 2.0 + ca.mtimes(Z, I / 6.0 + Z / 24.0))
    P = I + ca.mtimes(Z, Q)  # I + Z + Z²/2 + Z³/6 + Z⁴/24
    A, Ssum = I, ca.MX(nx, nx)
    for _ in range(substeps):
        Ssum = Ssum + A
        A = ca.mtimes(P, A)
    return A, ca.mtimes(Ssum, ca.mtimes(h * Q, Jxu[:, nx:]))


def _stage_functions(field: ca.Function, dt: float, substeps: int, frozen: bool = False,
                     functions=None):
    """``stage(x, u) -> (x⁺, ∂x⁺/∂x, ∂x⁺/∂u)`` and ``roll(x, u) -> x⁺`` for the RK4 map.

    ``frozen=False``: the sensitivities follow RK4's variational equations from the field's
    own Jacobians (one SX Function ``(f, ∂f/∂x, ∂f/∂u)``, called four times per sub-step),
    which the generated C holds once: several times smaller than differentiating the unrolled
    RK4 expression. They are exact.

    ``frozen=True``: one Jacobian per control step, at its midpoint ((x + x⁺) / 2, u), held
    over the step: the sensitivities are those RK4 gives the linearised field
    ẋ ≈ Jx x + Ju u, in closed form, ∂x⁺/∂x = P(h Jx)^s and
    ∂x⁺/∂u = (I + P + ... + P^{s-1}) h Q(h Jx) Ju, with P(Z) = I + Z + Z²/2 + Z³/6 + Z⁴/24
    and Q(Z) = I + Z/2 + Z²/6 + Z³/24 (one RK4 step of a linear system), for s sub-steps of
    length h. The state x⁺ itself is the full RK4 step, so the predicted plan, the cost and
    its residuals are exact; only the Gauss-Newton gradient and Hessian are approximate, to
    O(h²) (the midpoint; the start's Jacobian was O(h) and lost task 5's steps): an
    inexact-Jacobian SQP, whose iterations :class:`MPC` redoes with the exact sensitivities
    where they give no step. It costs one Jacobian
    instead of 4 s per step: most of a solve for a network's field.

    ``functions``: the field's ``(fj, fs)`` of :func:`_field_functions` to call, so that the
    Functions of one controller share them: the generated C holds each once (issue 46: built
    per call, the frozen controller's C held the Jacobian twice and the lifted one's three
    times, 582 k lines each for a 3-segment arm)."""
    nx, m = field.size1_in(0), field.size1_in(1)
    fj, fs = _field_functions(field) if functions is None else functions
    x, u = ca.MX.sym("x", nx), ca.MX.sym("u", m)
    h = dt / substeps

    def rk4(y):
        r1 = fs(y, u)
        r2 = fs(y + 0.5 * h * r1, u)
        r3 = fs(y + 0.5 * h * r2, u)
        r4 = fs(y + h * r3, u)
        return y + (h / 6.0) * (r1 + 2.0 * (r2 + r3) + r4)

    y_roll = x
    for _ in range(substeps):
        y_roll = rk4(y_roll)
    roll = ca.Function("mpc_roll", [x, u], [y_roll])
    if frozen:
        A, B = _frozen_sensitivities(fj, 0.5 * (x + y_roll), u, h, substeps)
        stage = ca.Function("mpc_stage", [x, u], [y_roll, A, B])
        return stage, roll
    y, S = x, ca.DM(np.hstack([np.eye(nx), np.zeros((nx, m))]))

    def slope(point, sens):
        k, J = fj(point, u)
        return k, ca.mtimes(J[:, :nx], sens) + ca.horzcat(ca.MX(nx, nx), J[:, nx:])

    for _ in range(substeps):
        k1, d1 = slope(y, S)
        k2, d2 = slope(y + 0.5 * h * k1, S + 0.5 * h * d1)
        k3, d3 = slope(y + 0.5 * h * k2, S + 0.5 * h * d2)
        k4, d4 = slope(y + h * k3, S + h * d3)
        y = y + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
        S = S + (h / 6.0) * (d1 + 2.0 * (d2 + d3) + d4)
    stage = ca.Function("mpc_stage", [x, u], [y, S[:, :nx], S[:, nx:]])
    return stage, roll


def stiff_substeps(model: PredictionModel, config: MPCConfig, operating_point) -> int:
    """``config.substeps``, raised until h ρ <= ``config.stiffness`` for the spectral radius ρ
    of ∂f/∂x at the operating point (at most 64 sub-steps)."""
    if operating_point is None or config.stiffness == 0:
        return config.substeps
    q, qd, u = (np.asarray(v, float).ravel() for v in operating_point)
    x0 = np.concatenate([np.asarray(model.to_state(q, qd), float).ravel(),
                         settled(model.actuator, model.m, u)])
    sym = _sym(model.field)
    xs, us = sym.sym("x", model.nx), sym.sym("u", model.m)
    jac = ca.Function("stiffness", [xs, us], [ca.jacobian(model.field(xs, us), xs)])
    J = np.asarray(jac(x0, u))
    if not np.all(np.isfinite(J)):
        raise UserError(f"prediction model {model.name}: its Jacobian at the operating point "
                        "is not finite")
    rho = float(np.max(np.abs(np.linalg.eigvals(J))))
    need = int(np.ceil(config.dt * rho / config.stiffness))
    return int(min(max(config.substeps, need), 64))
