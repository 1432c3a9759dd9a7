"""Closed loop: the MPC against the true model (cvodes) as the plant, and its metrics.

The plant integrates the exact equations of motion (eq. 4 with the PCC terms of eqs. 13-24)
with CasADi's cvodes over each control step with the input held (zero-order hold), from the
exact state: the controller measures (q, q̇) without noise. :func:`closed_loop` runs the
controller for a number of steps and returns the states, outputs, inputs and per-step solve
information; :func:`metrics` reduces them to the tracking error (RMS and max of ‖y - r‖),
input effort, solver failures and solve times.

With an actuator (issue 43 item 2, :mod:`.actuation`) the plant is the arm behind it: the
controller's commands wait the dead time (a shift register of whole steps, per input) and then
drive the lag, whose states cvodes integrates with the arm's; the loop starts it settled under
the first command.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from softpinn.actuator import Actuator
from softpinn.bridge.control.actuation import actuated_ode, lagged_inputs, settled
from softpinn.bridge.control.failures import count_causes
from softpinn.errors import UserError

__all__ = ["plant", "closed_loop", "metrics", "outside_data"]

#: How far past its training data's range (a fraction of the range) a coordinate may go before
#: :func:`outside_data` says the arm left the configurations its model was fitted on.
DATA_MARGIN = 0.05


def plant(true_model, dt: float, *, rtol: float = 1e-8, atol: float = 1e-10,
          actuator: Actuator | None = None) -> ca.Function:
    """cvodes over one step: (x0 = (q, q̇), p = u held) -> xf = x(dt). With an ``actuator``
    that has a lag, x0 and xf carry its lag states after (q, q̇) and p is the command reaching
    the lag (the dead time is :func:`closed_loop`'s)."""
    ode = true_model.functions["ode"]
    ode = ode if ode.is_a("SXFunction") else ode.expand()
    n, m = true_model.n, true_model.m
    lags = lagged_inputs(actuator, m).size
    if lags:
        ode = actuated_ode(ode, actuator, m)
    x, u = ca.SX.sym("x", 2 * n + lags), ca.SX.sym("u", m)
    opts = {"abstol": atol, "reltol": rtol, "max_num_steps": 100000,
            "disable_internal_warnings": True}
    return ca.integrator("plant", "cvodes", {"x": x, "p": u, "ode": ode(x, u)}, 0.0, dt, opts)


def closed_loop(controller, plant_fn: ca.Function, x0, reference: np.ndarray, steps: int,
                *, u0=None, at_rest: bool | None = None, progress=None,
                actuator: Actuator | None = None) -> dict:
    """Run ``steps`` control steps from the true state x0 = (q, q̇).

    ``reference`` has shape (steps + horizon, ny): r_k for k = 1 ... steps + horizon (r_k is
    the output wanted at time k dt). Returns ``x`` (K + 1, 2n), ``y`` (K + 1, ny), ``u``
    (K, m), ``r`` (K + 1, ny) (r_0 repeats r_1), ``success``, ``status``, ``cause`` (a failed
    solve's, :mod:`.failures`; None where it succeeded), ``seconds``,
    ``iterations``, ``exact_iterations`` (a frozen-sensitivity SQP's iterations redone with
    the exact ones; 0 otherwise), ``lifted_iterations`` (steps taken about the last plan's
    states, sensitivities "lifted") and ``cost`` per step, and ``diverged`` (the plant failed or
    left the finite numbers; then K < steps). ``progress``: called once per step.
    ``actuator``: the plant's (``plant_fn`` built with it, :func:`plant`); then ``u`` holds the
    commands and ``u_arm`` (K, m) the actuator's output at each step's start.
    """
    model = controller.model
    n, m, N = model.n, model.m, controller.config.horizon
    reference = np.asarray(reference, float)
    if reference.ndim != 2 or reference.shape[0] < steps + N:
        raise UserError(f"reference: needs {steps + N} rows (steps + horizon), got shape "
                        f"{reference.shape}")
    x = np.asarray(x0, float).ravel()
    if x.size != 2 * n:
        raise UserError(f"x0: expected {2 * n} values (q, q̇), got {x.size}")
    u_prev = np.zeros(m) if u0 is None else np.asarray(u0, float).ravel()
    ident = actuator is None or actuator.is_identity
    lagged = lagged_inputs(actuator, m)
    shift = (np.zeros(m, int) if ident else
             np.rint(actuator.per_input(m)[1] / controller.config.dt).astype(int))
    if not ident and np.any(np.abs(shift * controller.config.dt - actuator.per_input(m)[1])
                            > 1e-9):
        raise UserError(f"control: the plant's actuator dead time {actuator.text()} is no "
                        f"whole number of control steps (dt {controller.config.dt:g} s)")
    sent = [u_prev.copy() for _ in range(int(shift.max()) + 1)]  # the last commands, newest last
    lag = settled(actuator, m, u_prev)  # the plant's lag states

    def advance(x, lag, c):
        """The plant over one step under the command c reaching the lag: (x, lag, u_arm)."""
        arm = c.copy()
        arm[lagged] = lag
        z = np.asarray(plant_fn(x0=np.concatenate([x, lag]), p=c)["xf"]).ravel()
        return z[:2 * n], z[2 * n:], arm

    arms = []
    delay = int(getattr(controller, "delay", 0))
    xs, us, ok, status, secs, its, costs, exact, lifted = [x], [], [], [], [], [], [], [], []
    causes = []  # a failed solve's cause (failures.CAUSES), None where it succeeded
    diverged = False
    if at_rest is None:  # watch the arm for one step before the loop starts
        at_rest = False
        if not np.any(x[n:]):
            try:
                x1 = advance(x, lag, u_prev)[0]
                at_rest = bool(np.all(np.abs(x1 - x) <= 1e-9 * (1.0 + np.abs(x))))
            except RuntimeError:
                pass
    controller.reset(rest=at_rest)
    for k in range(steps):
        rows = reference[k:k + N + delay]  # a dead time: the reference D steps further on
        if len(rows) < N + delay:
            rows = np.concatenate([rows, np.repeat(rows[-1:], N + delay - len(rows), axis=0)])
        u, info = controller.solve(x[:n], x[n:], rows, u_prev)
        sent = [*sent[1:], np.asarray(u, float).copy()]
        arriving = np.array([sent[-1 - shift[j]][j] for j in range(m)])
        try:
            x_next, lag_next, arm = advance(x, lag, arriving)
        except RuntimeError:  # cvodes gave up: the input drove the plant somewhere wild
            x_next, lag_next, arm = np.full_like(x, np.nan), lag, arriving
        arms.append(arm)
        us.append(u)
        ok.append(bool(info["success"]))
        status.append(str(info.get("status")))
        causes.append(None if info["success"] else info.get("cause", "other"))
        secs.append(info["seconds"])
        its.append(info["iterations"])
        exact.append(info.get("exact_iterations", 0))
        lifted.append(info.get("lifted_iterations", 0))
        costs.append(info.get("cost", np.nan))
        u_prev = u
        if progress is not None:
            progress()
        if not np.all(np.isfinite(x_next)):
            diverged = True
            break
        x, lag = x_next, lag_next
        xs.append(x)
    xs = np.array(xs)
    ys = np.array([np.asarray(model.output(xi[:n])).ravel() for xi in xs])
    r = np.concatenate([reference[:1], reference[: len(xs) - 1]])
    extra = {} if ident else {"u_arm": np.array(arms).reshape(-1, m)}
    return {**extra, "x": xs, "y": ys, "u": np.array(us).reshape(-1, m), "r": r,
            "success": np.array(ok, bool), "status": status, "cause": causes,
            "seconds": np.array(secs),
            "iterations": np.array(its, int), "exact_iterations": np.array(exact, int),
            "lifted_iterations": np.array(lifted, int),
            "cost": np.array(costs, float),
            "diverged": diverged, "at_rest": bool(at_rest)}


def metrics(result: dict) -> dict:
    """Tracking error ‖y - r‖ (RMS and max over steps 1 ..., in the units of y), input effort
    (RMS of u and of its change per step), failures (and how many of each cause and solver
    status), steps, divergence, whether the loop
    started at rest, iterations (and how many a frozen-sensitivity SQP redid with exact
    sensitivities), solve times (ms)."""
    e = np.linalg.norm(result["y"][1:] - result["r"][1:], axis=1)
    u = result["u"]
    du = np.diff(u, axis=0) if len(u) > 1 else np.zeros((0, u.shape[1]))
    s = np.asarray(result["seconds"]) * 1e3

    def stat(fn, a, empty=None):
        return float(fn(a)) if a.size else empty

    return {
        "error_rms": stat(lambda a: np.sqrt(np.mean(a**2)), e),
        "error_max": stat(np.max, e),
        "error_final": float(e[-1]) if e.size else None,
        "effort_rms": stat(lambda a: np.sqrt(np.mean(a**2)), u, 0.0),
        "effort_rate_rms": stat(lambda a: np.sqrt(np.mean(a**2)), du, 0.0),
        "failures": int(np.sum(~np.asarray(result["success"], bool))),
        # per cause (infeasible, iteration limit, numerical, other), and the solvers' statuses
        "failure_causes": count_causes(result["success"], result.get("cause")
                                       or [None] * len(result["success"])),
        "failure_statuses": _failed_statuses(result),
        "steps": int(len(result["success"])),
        "diverged": bool(result.get("diverged", False)),
        "at_rest": bool(result.get("at_rest", False)),
        "iterations_mean": stat(np.mean, np.asarray(result["iterations"], float)),
        "exact_iterations": int(np.sum(result.get("exact_iterations", 0))),
        "lifted_iterations": int(np.sum(result.get("lifted_iterations", 0))),
        "solve_ms_mean": stat(np.mean, s),
        "solve_ms_median": stat(np.median, s),
        "solve_ms_p95": stat(lambda a: np.percentile(a, 95), s),
        "solve_ms_max": stat(np.max, s),
    }


def _failed_statuses(result: dict) -> dict[str, int]:
    """{solver status: failed solves}."""
    got: dict[str, int] = {}
    for ok, st in zip(result["success"], result.get("status", ()), strict=False):
        if not ok:
            got[str(st)] = got.get(str(st), 0) + 1
    return got


def outside_data(x: np.ndarray, q_range: dict, dt: float, names=None,
                 margin: float = DATA_MARGIN) -> dict:
    """Where the closed loop's configurations q (the first n columns of ``x``, one row per
    step, the start first) left ``q_range`` ({"min": [...], "max": [...]}, the training
    trajectories' q of a learned model) by more than ``margin`` of each coordinate's range:
    ``steps`` (how many steps after the start), ``first_s`` (the first such time, None if
    none) and the ``coordinates`` that did (their ``names`` when given, else indices)."""
    out = outside_mask(x, q_range, margin)[1:]
    rows = np.flatnonzero(out.any(axis=1))
    cols = np.flatnonzero(out.any(axis=0))
    return {"steps": int(rows.size),
            "first_s": float((rows[0] + 1) * dt) if rows.size else None,
            "coordinates": [names[i] if names is not None else int(i) for i in cols],
            "margin": margin}


def outside_mask(x: np.ndarray, q_range: dict, margin: float = DATA_MARGIN) -> np.ndarray:
    """(rows of ``x``, n) booleans: q beyond ``q_range`` by more than ``margin`` of its range."""
    lo, hi = (np.asarray(q_range[k], float) for k in ("min", "max"))
    pad = margin * np.maximum(hi - lo, 0.0)
    q = np.asarray(x, float)[:, : lo.size]
    return (q < lo - pad) | (q > hi + pad)
