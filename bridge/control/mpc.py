"""Nonlinear model-predictive control in CasADi: Gauss-Newton SQP from generated C, or IPOPT.

The problem over a horizon of N steps of length dt, for the prediction model's state x:

    min  Σ_k ½ wy ‖y(x_{k+1}) - r_{k+1}‖² + ½ wu ‖u_k - u_ref‖² + ½ wdu ‖u_k - u_{k-1}‖²
    s.t. x_0 = x̂ (measured), x_{k+1} = RK4(field, x_k, u_k, dt) (input held over the step),
         u_min <= u_k <= u_max,

with u_{-1} the input applied at the last step. Two solvers:

* ``"sqp"`` (default): Gauss-Newton sequential quadratic programming on the inputs alone
  (single shooting, condensed). One call of a compiled Function returns the cost, its gradient
  and the Gauss-Newton Hessian wy Jᵀ J + wu I + wdu Δᵀ Δ, where J = ∂y/∂u is chained from
  each stage's exact ∂x⁺/∂x, ∂x⁺/∂u (RK4's variational equations from the field's Jacobian:
  one small C function called four times per sub-step; or, ``sensitivities="frozen"``, one
  Jacobian per stage and RK4's sensitivities of that linearisation in closed form, and
  ``"lifted"`` about the last plan's states, without a rollout); the box-constrained QP is
  solved by a Cholesky solve when no bound is active, else by a dense QP solver shipped with
  CasADi (``qpsol``: daqp, qpoases, osqp, ...). A backtracking line search on the cost keeps
  each step a descent. The Functions (:mod:`.gauss_newton`) are compiled through the project's
  code cache (:func:`softpinn.symbolic.compile_functions`), so a model compiles once per
  machine; without a C compiler they run in CasADi's virtual machine.
* ``"ipopt"``: the same problem in multiple shooting with exact Hessians, solved by IPOPT
  (``casadi.nlpsol``) in CasADi's virtual machine, warm-started from the shifted previous
  solution and multipliers: the reference the SQP is checked against, tens of times slower on
  task 4 (docs/control.md; ``codegen`` does not apply).

Both warm-start from the previous plan shifted by one step.

A model with an actuator (issue 43 item 2, :mod:`.actuation`) plans the commands: its state
carries the actuator's lag states, which the controller tracks from the commands it sent (exact
for a command held over the step), and with a dead time of D steps it first rolls the model
over the D commands already sent and plans from the state they lead to, against the
reference D steps later (the earlier outputs no command of this plan can change).
"""

from __future__ import annotations

import dataclasses
import time

import casadi as ca
import numpy as np

from softpinn.bridge.control.actuation import delay_steps, lagged_inputs, settled
from softpinn.bridge.control.blas import one_blas_thread
from softpinn.bridge.control.config import QP_SOLVERS, SENSITIVITIES, SOLVERS, MPCConfig
from softpinn.bridge.control.failures import cause
from softpinn.bridge.control.gauss_newton import sqp_functions
from softpinn.bridge.control.models import PredictionModel
from softpinn.bridge.control.rk4 import _sym, rk4_map, stiff_substeps
from softpinn.errors import UserError
from softpinn.symbolic import DEFAULT_FLAGS, CompilerTimeout, compile_functions

__all__ = ["MPCConfig", "MPC", "rk4_map", "SOLVERS", "QP_SOLVERS", "SENSITIVITIES",
           "input_bounds"]

#: the least share of its predicted decrease of the cost an approximate step must achieve
APPROXIMATE_RATIO = 0.9

_QP_OPTIONS = {
    "qrqp": {"print_iter": False, "print_header": False, "print_info": False},
    "qpoases": {"printLevel": "none", "sparse": False},
    "osqp": {"osqp": {"verbose": False, "eps_abs": 1e-9, "eps_rel": 1e-9, "polish": True}},
    "highs": {"highs": {"output_flag": False}},
}


def _vector(value, m, default, name):
    if value is None:
        return np.full(m, float(default))
    a = np.asarray(value, float).ravel()
    if a.size == 1:
        a = np.full(m, float(a[0]))
    if a.size != m:
        raise UserError(f"{name}: expected {m} values (one per input) or one, got {a.size}")
    if np.any(np.isnan(a)):
        raise UserError(f"{name}: values must be numbers, got {a.tolist()}")
    return a


def input_bounds(config: MPCConfig, m: int) -> tuple[np.ndarray, np.ndarray]:
    """(u_min, u_max) of ``config`` per input (unbounded where None); one line where a lower
    bound exceeds its upper one (checked by :func:`~.compare.compare` before any work)."""
    lb = _vector(config.u_min, m, -np.inf, "u_min")
    ub = _vector(config.u_max, m, np.inf, "u_max")
    if np.any(lb > ub):
        raise UserError(f"u_min {lb.tolist()} exceeds u_max {ub.tolist()}")
    return lb, ub


class MPC:
    """One controller: ``solve(q, qd, reference, u_prev) -> (u, info)``.

    ``reference``: (N, ny) outputs r_1 ... r_N over the horizon. ``info``: ``success``,
    ``status``, ``iterations``, ``seconds`` (wall time of the solve), ``cost``.
    ``build_seconds``: the time taken to build (and compile) the solver. ``operating_point``:
    (q, q̇, u) where the model's stiffness is checked (see :class:`MPCConfig`);
    ``substeps``: the RK4 sub-steps used.
    """

    def __init__(self, model: PredictionModel, config: MPCConfig | None = None, *,
                 operating_point=None, compiler=None, cache=None):
        self.model = model
        config = MPCConfig() if config is None else config
        self.substeps = stiff_substeps(model, config, operating_point)
        if self.substeps != config.substeps:
            config = dataclasses.replace(config, substeps=self.substeps)
        self.config = config
        m, N = model.m, config.horizon
        if m < 1:
            raise UserError(f"prediction model {model.name}: has no inputs (m = 0); there is "
                            "nothing to control")
        self.nx, self.m, self.N = model.nx, m, N
        #: the actuator's dead time in control steps, its lagged inputs and their decay per step
        self.delay = delay_steps(model.actuator, m, config.dt)
        self._lagged = lagged_inputs(model.actuator, m)
        tau = (model.actuator.per_input(m)[0][self._lagged] if self._lagged.size
               else np.zeros(0))
        self._decay = np.exp(-config.dt / tau) if tau.size else np.zeros(0)
        self.ny = model.output.size1_out(0)
        self._lbu, self._ubu = input_bounds(config, m)
        self._uref = _vector(config.u_ref, m, 0.0, "u_ref")
        self.compiled = False
        t0 = time.perf_counter()
        if config.solver == "sqp":
            self._build_sqp(compiler, cache)
        else:
            self._build_ipopt()
        self.build_seconds = time.perf_counter() - t0
        self.reset()

    # ------------------------------------------------------------------ Gauss-Newton SQP

    def _build_sqp(self, compiler, cache):
        cfg, mod = self.config, self.model
        m, N = self.m, self.N
        fns = sqp_functions(mod, cfg, self._uref)
        if cfg.codegen:
            # an MX field's matrix products compile to loops that -O3 runs three times faster
            # (SX code: straight-line, the same speed at -O1, which compiles faster)
            flags = (("-O3", "-fPIC", "-shared") if mod.field.is_a("MXFunction")
                     else DEFAULT_FLAGS)
            try:
                built = compile_functions(fns, compiler=compiler, directory=cache,
                                          enable_fd=False, flags=flags,
                                          timeout=cfg.compile_timeout)
            except CompilerTimeout as exc:
                raise exc.advised(f"the solver of {mod.name}: raise the limit with "
                                  "--compile-timeout S, or run without C with --no-codegen "
                                  "(CasADi's virtual machine, slower solves)") from None
            fns, self.compiled = built.functions, built.compiled
            self.compile_info = {"compiled": built.compiled, "from_cache": built.from_cache,
                                 "compile_seconds": built.compile_seconds,
                                 "library": str(built.library) if built.library else None}
        else:
            self.compile_info = {"compiled": False}
        self._gn, self._cost, self._predict = fns["gn"], fns["cost"], fns["predict"]
        self._gn_exact, self._gn_lifted = fns.get("gn_exact"), fns.get("gn_lifted")
        self._step = fns["step"]
        opts = {"error_on_fail": False, **_QP_OPTIONS.get(cfg.qpsol, {})}
        self._qp = ca.conic("mpc_qp", cfg.qpsol,
                            {"h": ca.Sparsity.dense(N * m, N * m), "a": ca.Sparsity(0, N * m)},
                            opts)
        self._qp_status = (None, None)  # the last QP's return statuses
        self._bounded = bool(np.any(np.isfinite(self._lbu)) or np.any(np.isfinite(self._ubu)))

    def _qp_step(self, H, g, Uv):
        """argmin ½ dᵀ H d + gᵀ d with lbu <= U + d <= ubu; (d, ok)."""
        try:
            c = np.linalg.cholesky(H)
            d = -np.linalg.solve(c.T, np.linalg.solve(c, g))
        except np.linalg.LinAlgError:
            d = None
        lb = np.tile(self._lbu, self.N) - Uv
        ub = np.tile(self._ubu, self.N) - Uv
        if d is not None and (not self._bounded or (np.all(d >= lb) and np.all(d <= ub))):
            return d, True
        sol = self._qp(h=H, g=g, lbx=lb, ubx=ub)
        d = np.asarray(sol["x"]).ravel()
        stats = self._qp.stats()
        ok = bool(stats.get("success", False)) and bool(np.all(np.isfinite(d)))
        # why it failed, for the failed solve's cause (failures.cause)
        self._qp_status = (stats.get("return_status"), stats.get("unified_return_status"))
        if ok:  # a solver may report success off the box (qrqp does, on ill-conditioned H);
            # daqp stops within its feasibility tolerance, up to ~1e-5 outside on task 5's
            # steps (H's condition 2e7): a miss of a thousandth of the box's width is clipped
            width = np.where(np.isfinite(ub - lb), ub - lb, 0.0)
            slack = 1e-7 * (1.0 + np.abs(Uv)) + 1e-3 * width
            ok = bool(np.all(d >= lb - slack) and np.all(d <= ub + slack))
            d = np.clip(d, lb, ub)
        return d, ok

    def _sqp_iteration(self, gn, x0, U, R, u_prev, approximate: bool = False):
        """One Gauss-Newton step with a backtracking line search from U:
        (U, f, status): status None when the step was taken, else why not ("converged" at a
        stationary point; a failure otherwise). ``gn(U) -> (f, g, H)``. The accepted plan's
        predicted states are kept (``_X``, with the disturbance estimate they used)."""
        m, N = self.m, self.N
        f, g, H = (np.asarray(v) for v in gn(U))
        f, g = float(f.item()), g.ravel()
        if not (np.isfinite(f) and np.all(np.isfinite(g)) and np.all(np.isfinite(H))):
            return U, f, "non-finite prediction"
        d, qp_ok = self._qp_step(H, g, U.ravel(order="F"))
        if not qp_ok:
            qp_status, self._unified = self._qp_status
            return U, f, "QP failed" + ("" if qp_status is None else f" ({qp_status})")
        D = d.reshape(m, N, order="F")
        slope = float(g @ d)
        if slope > -1e-14 * max(1.0, abs(f)):  # no descent left: converged
            return U, f, "converged"
        alpha = 1.0
        # an approximate step (frozen or lifted sensitivities) is taken whole or not at all:
        # only if the cost fell by APPROXIMATE_RATIO of what its Gauss-Newton model predicted,
        # else the iteration is redone more exactly (the Armijo test alone kept steps that
        # lost task 4's Lagrangian network its steps: 20.5 mm against 3.57 mm)
        predicted = -(slope + 0.5 * float(d @ H @ d))
        for _ in range(1 if approximate else 12):
            f_new, X = self._cost(x0, U + alpha * D, R, u_prev, self._d)
            f_new = float(f_new)
            if approximate and not f - f_new >= APPROXIMATE_RATIO * predicted:
                break
            if np.isfinite(f_new) and f_new <= f + 1e-4 * alpha * slope:
                U = U + alpha * D
                self._X, self._X_d = np.asarray(X), self._d.copy()
                return U, f_new, ("converged" if alpha * np.max(np.abs(d)) <= self.config.tol
                                  else None)
            alpha *= 0.5
        return U, f, "line search failed"

    def _solve_sqp(self, x0, R, u_prev):
        cfg = self.config
        U = self._guess(u_prev)
        U = np.clip(U, self._lbu[:, None], self._ubu[:, None])
        status, ok, it, f, exact, lifted = "max_iter", True, 0, np.nan, 0, 0
        self._unified = None
        X, self._X = (self._X if self._U is not None else None), None
        for it in range(1, cfg.max_iter + 1):  # noqa: B007 - the count is reported
            why = "no plan"
            if it == 1 and self._gn_lifted is not None and X is not None:
                # about the last plan's states (shifted): no rollout before the line search
                Xb, dd = X[:, 1:], self._d - self._X_d
                U, f, why = self._sqp_iteration(
                    lambda V, Xb=Xb, dd=dd: self._gn_lifted(x0, Xb, V, R, u_prev, self._d, dd),
                    x0, U, R, u_prev, approximate=True)
                lifted += why in (None, "converged")
            if why not in (None, "converged"):
                U, f, why = self._sqp_iteration(
                    lambda V: self._gn(x0, V, R, u_prev, self._d), x0, U, R, u_prev,
                    approximate=self._gn_exact is not None)
            if why not in (None, "converged") and self._gn_exact is not None:
                # the frozen sensitivities gave no step (far from the last plan: a transient):
                # the same iteration with the exact ones
                U, f, why = self._sqp_iteration(
                    lambda V: self._gn_exact(x0, V, R, u_prev, self._d), x0, U, R, u_prev)
                exact += 1
            if why is not None:
                status, ok = why, why == "converged"
                break
        self._U = U if ok else None
        info = {"success": ok, "status": status, "iterations": it, "cost": f,
                "unified": self._unified}
        if self._gn_exact is not None:
            info["exact_iterations"] = exact
        if self._gn_lifted is not None:
            info["lifted_iterations"] = lifted
        return U[:, 0].copy(), info

    def _guess(self, u_prev):
        if self._U is None:
            return np.tile(np.asarray(u_prev, float)[:, None], (1, self.N))
        return np.concatenate([self._U[:, 1:], self._U[:, -1:]], axis=1)  # shifted by one step

    def predict(self, q, qd, U) -> np.ndarray:
        """The outputs (N, ny) the prediction model expects for the inputs U (N, m) (SQP; an
        actuator's lag from its tracked state, or settled under U's first row; no dead time)."""
        if self.config.solver != "sqp":
            raise UserError("predict: only the sqp solver keeps the prediction function")
        y = (self._y if self._y is not None
             else settled(self.model.actuator, self.m, np.asarray(U, float)[0]))
        x0 = np.concatenate([np.asarray(self.model.to_state(q, qd), float).ravel(), y])
        return np.asarray(self._predict(x0, np.asarray(U, float).T, self._d)).T

    # ------------------------------------------------------------------ IPOPT

    def _build_ipopt(self):
        cfg, model = self.config, self.model
        n, nx, m, N, ny = model.n, self.nx, self.m, self.N, self.ny
        F = rk4_map(model.field, cfg.dt, cfg.substeps)
        sym = _sym(model.field)
        X, U = sym.sym("X", nx, N + 1), sym.sym("U", m, N)
        x0, R, u_prev = sym.sym("x0", nx), sym.sym("R", ny, N), sym.sym("u_prev", m)
        dx = sym.sym("d", nx)  # the state disturbance added at every step (offset_free)
        cost, last, g = 0, u_prev, [X[:, 0] - x0]
        for k in range(N):
            g.append(X[:, k + 1] - F(X[:, k], U[:, k]) - dx)
            e = model.output(X[:n, k + 1]) - R[:, k]
            cost += 0.5 * (cfg.weight_y * ca.sumsqr(e)
                           + cfg.weight_u * ca.sumsqr(U[:, k] - self._uref)
                           + cfg.weight_du * ca.sumsqr(U[:, k] - last))
            last = U[:, k]
        g = ca.vertcat(*g)
        nlp = {"x": ca.vertcat(ca.vec(X), ca.vec(U)),
               "p": ca.vertcat(x0, ca.vec(R), u_prev, dx),
               "f": cost, "g": g}
        opts = {
            "expand": sym is ca.SX,
            "print_time": False,
            "error_on_fail": False,
            "ipopt": {"print_level": 0, "sb": "yes", "max_iter": cfg.max_iter,
                      "tol": cfg.tol, "warm_start_init_point": "yes",
                      "mu_strategy": "adaptive"},
        }
        self.solver = ca.nlpsol("mpc", "ipopt", nlp, opts)
        xs, us = sym.sym("x0", nx), sym.sym("u0", m)
        self._step = ca.Function("mpc_step", [xs, us], [F(xs, us)], ["x0", "u0"], ["x1"])
        self.compiled = False
        self.compile_info = {"compiled": False}
        self._lbg = np.zeros(g.shape[0])
        lbx = np.concatenate([np.full(nx * (N + 1), -np.inf), np.tile(self._lbu, N)])
        ubx = np.concatenate([np.full(nx * (N + 1), np.inf), np.tile(self._ubu, N)])
        self._box = (lbx, ubx)

    def _solve_ipopt(self, x0, R, u_prev):
        nx, m, N = self.nx, self.m, self.N
        if self._w is None:
            Xg = np.tile(x0[:, None], (1, N + 1))
            Ug = np.tile(u_prev[:, None], (1, N))
        else:
            Xg = self._w[: nx * (N + 1)].reshape(nx, N + 1, order="F")
            Ug = self._w[nx * (N + 1):].reshape(m, N, order="F")
            Xg = np.concatenate([Xg[:, 1:], Xg[:, -1:]], axis=1)
            Ug = np.concatenate([Ug[:, 1:], Ug[:, -1:]], axis=1)
        Xg[:, 0] = x0
        Ug = np.clip(Ug, self._lbu[:, None], self._ubu[:, None])
        lbx, ubx = self._box
        args = dict(x0=np.concatenate([Xg.ravel(order="F"), Ug.ravel(order="F")]),
                    p=np.concatenate([x0, R.ravel(order="F"), u_prev, self._d]),
                    lbx=lbx, ubx=ubx, lbg=self._lbg, ubg=self._lbg)
        if self._lam is not None:
            args.update(lam_g0=self._lam)
        sol = self.solver(**args)
        stats = self.solver.stats()
        w = np.asarray(sol["x"]).ravel()
        ok = bool(stats.get("success", False)) and bool(np.all(np.isfinite(w)))
        if ok:
            self._w, self._lam = w, np.asarray(sol["lam_g"]).ravel()
        else:
            self._w = self._lam = None
        u = w[nx * (N + 1): nx * (N + 1) + m] if np.all(np.isfinite(w)) else u_prev
        return np.asarray(u, float), {"success": ok, "status": stats.get("return_status"),
                                      "unified": stats.get("unified_return_status"),
                                      "iterations": int(stats.get("iter_count", -1)),
                                      "cost": float(sol["f"])}

    # ------------------------------------------------------------------ common face

    def reset(self, rest: bool = False):
        """Forget the warm start and the disturbance estimate. ``rest``: the arm is known to
        be at rest under the first solve's ``u_prev`` (an equilibrium of the arm), so with
        ``offset_free`` the estimate starts at x − F(x, u_prev), the model's own miss there: a
        learned model's equilibrium is corrected from the first step instead of after a few."""
        self._U = self._w = self._lam = self._X = None
        self._d, self._r = np.zeros(self.nx), np.zeros(self.nx)
        self._X_d = self._d.copy()
        self._x_next = None
        self._rest = bool(rest)
        self._y = self._sent = None  # the actuator's lag states, the commands in transit

    def _measured(self, q, qd, u_prev) -> np.ndarray:
        """The model's state now: the measured (q, q̇) (or (q, p)) and the actuator's lag
        states as the controller tracks them (settled under ``u_prev`` at the first solve)."""
        if self._y is None:
            self._y = np.asarray(u_prev, float).ravel()[self._lagged]
            self._sent = [np.asarray(u_prev, float).ravel().copy() for _ in range(self.delay)]
        return np.concatenate([np.asarray(self.model.to_state(q, qd), float).ravel(), self._y])

    def _reference(self, reference) -> np.ndarray:
        """(N, ny) rows from r_{D+1} on: ``reference`` holds N + D rows from r_1, or N (the last
        row then holds for the D rows past it)."""
        R = np.asarray(reference, float)
        N, D = self.N, self.delay
        if R.ndim == 2 and R.shape[1] == self.ny and D and R.shape[0] in (N, N + D):
            R = np.concatenate([R, np.repeat(R[-1:], N + D - R.shape[0], axis=0)])[D:]
        if R.shape != (N, self.ny):
            rows = f"{N}" if not D else f"{N} or {N + D} (horizon + dead time)"
            raise UserError(f"reference: expected shape ({rows}, {self.ny}) (horizon, "
                            f"outputs), got {R.shape}")
        return R

    @property
    def disturbance(self) -> np.ndarray:
        """The current state-disturbance estimate d̂ (zeros unless ``offset_free`` > 0), in the
        prediction model's state (q, q̇), or (q, p) for a Hamiltonian network."""
        return self._d.copy()

    @property
    def disturbance_rate(self) -> np.ndarray:
        """Its estimated change per step r̂ (zeros unless ``offset_free_rate`` > 0)."""
        return self._r.copy()

    def solve(self, q, qd, reference, u_prev):
        """The first input of the plan from the measured (q, q̇), and what the solve did."""
        R, u_prev = self._reference(reference), np.asarray(u_prev, float).reshape(self.m)
        t0 = time.perf_counter()
        with one_blas_thread():  # issue 46: numpy's threads cost 28x on busy cores (.blas)
            u, info = self._solve(q, qd, R, u_prev)
        info["seconds"] = time.perf_counter() - t0
        return u, info

    def _solve(self, q, qd, R, u_prev):
        x0 = self._measured(q, qd, u_prev)
        # the command that reaches the actuator in this step: one sent D steps ago
        arriving = self._sent[0] if self.delay else None
        gain = self.config.offset_free
        if gain > 0 and self._x_next is None and self._rest:
            # at rest the arm's next state is x itself: F(x, u) misses it by the model's error
            miss = x0 - np.asarray(self._step(x0, u_prev)).ravel()
            if np.all(np.isfinite(miss)):
                self._d = miss
        elif gain > 0 and self._x_next is not None:
            miss = x0 - self._x_next  # = x − F(x₋, u₋) − d̂: what the model got wrong
            if np.all(np.isfinite(miss)):
                # an alpha-beta filter: d̂ corrected by the miss, r̂ (its change per step,
                # with offset_free_rate) too, and d̂ carried on by r̂ to this step
                self._r = self._r + self.config.offset_free_rate * miss
                self._d = self._d + gain * miss + self._r
        self._rest = False
        start = x0
        for c in self._sent or ():  # the commands in transit, known: where they lead
            start = np.asarray(self._step(start, c)).ravel() + self._d
        if self.config.solver == "sqp":
            u, info = self._solve_sqp(start, R.T, u_prev)
        else:
            u, info = self._solve_ipopt(start, R.T, u_prev)
        if not np.all(np.isfinite(u)):
            u, info["success"], info["status"] = u_prev.copy(), False, "non-finite input"
        unified = info.pop("unified", None)
        if not info["success"]:  # infeasible, iteration limit, numerical (failures.cause)
            info["cause"] = cause(info["status"], unified)
        arriving = u if arriving is None else arriving
        if gain > 0:  # what the model expects the state to be after this step
            self._x_next = np.asarray(self._step(x0, arriving)).ravel() + self._d
            info["disturbance"] = float(np.linalg.norm(self._d))
        if self._lagged.size:  # the lag under the held command, exactly
            a = self._decay
            self._y = a * self._y + (1 - a) * np.asarray(arriving, float)[self._lagged]
        if self.delay:
            self._sent = [*self._sent[1:], np.asarray(u, float).copy()]
        return u, info
