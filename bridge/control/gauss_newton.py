"""The Gauss-Newton SQP's CasADi Functions (see :mod:`.mpc`): for the inputs U over the
horizon, the cost, its gradient and the Gauss-Newton Hessian wy Jᵀ J + wu I + wdu Δᵀ Δ (single
shooting, condensed; J = ∂y/∂u chained from each stage's ∂x⁺/∂x, ∂x⁺/∂u), the cost alone (the
line search), the predicted outputs and one step of the model; with ``sensitivities`` "frozen"
or "lifted" also the exact step (an iteration the approximate one could not make), and with
"lifted" the step linearised about the last plan's predicted states. Built once per
controller; :class:`.mpc.MPC` compiles and calls them."""

from __future__ import annotations

import casadi as ca
import numpy as np

from softpinn.bridge.control.config import MPCConfig
from softpinn.bridge.control.models import PredictionModel
from softpinn.bridge.control.rk4 import _field_functions, _frozen_sensitivities, _stage_functions

__all__ = ["sqp_functions"]


def _difference_matrix(m: int, N: int) -> np.ndarray:
    """Δ with (Δ U)_k = u_k - u_{k-1} (k >= 1) and (Δ U)_0 = u_0 (u_prev enters separately)."""
    D = np.eye(N * m)
    for k in range(1, N):
        D[k * m:(k + 1) * m, (k - 1) * m:k * m] = -np.eye(m)
    return D


def sqp_functions(mod: PredictionModel, cfg: MPCConfig, u_ref: np.ndarray
                  ) -> dict[str, ca.Function]:
    """The SQP's Functions of the prediction model ``mod`` under ``cfg`` (``cfg.substeps`` as
    the controller raised them), with ``u_ref`` the input reference (m values): ``gn``,
    ``cost``, ``predict``, ``step`` and, with approximate sensitivities, ``gn_exact`` (and
    ``gn_lifted``)."""
    n, m, N = mod.n, mod.m, cfg.horizon
    nx, ny = mod.nx, mod.output.size1_out(0)  # (q, q̇) and any actuator lag states
    frozen = cfg.sensitivities in ("frozen", "lifted")
    # one (f, ∂f) pair for every Function below: the C holds the Jacobian once (issue 46)
    fields = _field_functions(mod.field, mod.jacobian)
    stage, roll = _stage_functions(mod.field, cfg.dt, cfg.substeps, frozen=frozen,
                                   functions=fields)
    xs = ca.SX.sym("x", nx)
    ys = mod.output(xs[:n])
    out = ca.Function("mpc_output", [xs], [ys, ca.jacobian(ys, xs)])

    x0, U = ca.MX.sym("x0", nx), ca.MX.sym("U", m, N)
    dx = ca.MX.sym("d", nx)  # the state disturbance added at every step (offset_free)
    R, up = ca.MX.sym("R", ny, N), ca.MX.sym("u_prev", m)
    sy = np.sqrt(cfg.weight_y)
    D = _difference_matrix(m, N)
    uref = np.tile(u_ref, N)
    Uv = ca.vec(U)
    e_prev = ca.vertcat(up, ca.MX(m * (N - 1), 1))
    du = ca.mtimes(ca.DM(D), Uv) - e_prev
    cost_u = 0.5 * cfg.weight_u * ca.sumsqr(Uv - uref) + 0.5 * cfg.weight_du * ca.sumsqr(du)
    grad_u = cfg.weight_u * (Uv - uref) + cfg.weight_du * ca.mtimes(ca.DM(D.T), du)
    hess_u = cfg.weight_u * np.eye(N * m) + cfg.weight_du * D.T @ D

    def gn_outputs(stages):
        """f, g = Jᵀ r + ..., H = Jᵀ J + ... from the predicted states x_{k+1} and each
        stage's sensitivities (Ak, Bk): S = ∂x_{k+1}/∂(u_0 ... u_k), chained stage by
        stage."""
        S, res, rows = None, [], []
        for k, (x, Ak, Bk) in enumerate(stages):
            S = Bk if S is None else ca.horzcat(ca.mtimes(Ak, S), Bk)
            y, Ck = out(x)
            res.append(sy * (y - R[:, k]))
            row = sy * ca.mtimes(Ck, S)
            if k < N - 1:
                row = ca.horzcat(row, ca.MX(ny, (N - 1 - k) * m))
            rows.append(row)
        r, J = ca.vertcat(*res), ca.vertcat(*rows)
        return [0.5 * ca.sumsqr(r) + cost_u, ca.mtimes(J.T, r) + grad_u,
                ca.mtimes(J.T, J) + hess_u]

    def gauss_newton(name, stage):
        """The Gauss-Newton Function of a rollout through ``stage``."""
        x, stages = x0, []
        for k in range(N):
            x, Ak, Bk = stage(x, U[:, k])
            x = x + dx
            stages.append((x, Ak, Bk))
        return ca.Function(name, [x0, U, R, up, dx], gn_outputs(stages),
                           ["x0", "U", "R", "u_prev", "d"], ["f", "g", "H"])

    gn = gauss_newton("mpc_gn", stage)
    # the cost alone (line search), and the predicted outputs (for plots and checks)
    x, res, ys_all, xs_all = x0, [], [], [x0]
    for k in range(N):
        x = roll(x, U[:, k]) + dx
        y, _ = out(x)
        ys_all.append(y)
        xs_all.append(x)
        res.append(sy * (y - R[:, k]))
    fc = 0.5 * ca.sumsqr(ca.vertcat(*res)) + cost_u
    cost = ca.Function("mpc_cost", [x0, U, R, up, dx], [fc, ca.horzcat(*xs_all)],
                       ["x0", "U", "R", "u_prev", "d"], ["f", "X"])
    predict = ca.Function("mpc_predict", [x0, U, dx], [ca.horzcat(*ys_all)],
                          ["x0", "U", "d"], ["Y"])
    u0 = ca.MX.sym("u0", m)
    step = ca.Function("mpc_step", [x0, u0], [roll(x0, u0)], ["x0", "u0"], ["x1"])
    fns = {"gn": gn, "cost": cost, "predict": predict, "step": step}
    if frozen:  # the exact step, for an iteration the frozen one could not make
        fns["gn_exact"] = gauss_newton("mpc_gn_exact",
                                       _stage_functions(mod.field, cfg.dt, cfg.substeps,
                                                        functions=fields)[0])
    if cfg.sensitivities == "lifted":
        # the Gauss-Newton step about the last plan's predicted states, shifted by one
        # step: no rollout, the states corrected to first order for the new measurement
        # (δ₀ = x0 − xb₀) and the change of the disturbance estimate (dd):
        # x_{k+1} ≈ xb_{k+1} + δ_{k+1}, δ_{k+1} = A_k δ_k + dd
        fj = fields[0]
        h = cfg.dt / cfg.substeps
        Xb, dd = ca.MX.sym("Xb", nx, N), ca.MX.sym("dd", nx)
        delta, stages = x0 - Xb[:, 0], []
        d_base = dx - dd  # the disturbance the base states were predicted with
        for k in range(N):
            xa = Xb[:, k]
            # the model's own step from xa (the last one rolled, as the base would have)
            own = Xb[:, k + 1] - d_base if k < N - 1 else roll(xa, U[:, k])
            xb = own + d_base
            Ak, Bk = _frozen_sensitivities(fj, 0.5 * (xa + own), U[:, k], h, cfg.substeps)
            delta = ca.mtimes(Ak, delta) + dd
            stages.append((xb + delta, Ak, Bk))
        fns["gn_lifted"] = ca.Function(
            "mpc_gn_lifted", [x0, Xb, U, R, up, dx, dd], gn_outputs(stages),
            ["x0", "Xb", "U", "R", "u_prev", "d", "dd"], ["f", "g", "H"])
    return fns
