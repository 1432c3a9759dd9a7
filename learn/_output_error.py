"""The linear second-order model fitted by its rollout error (output error), issue 43.

:func:`learn._baselines.fit_linear_second_order` fits q̈ = A_q q + A_v q̇ + B_u u + c by least
squares on the data set's q̈: the best one-step model, and on noisy recordings a poor one over
a horizon, because q̇ and q̈ come from smoothed differences of noisy angles (on the Cosserat
stand-in with 0.01 rad of sensor noise its 5 s rollout error was 12x that of an ARX model fitted
to the same samples, RESULTS.md). Output error fits the same four matrices to what ``predict``
scores instead: the mean over windows of the training trajectories, each simulated from its
measured (q, q̇) under its measured inputs over ``horizon`` seconds, of the mean over the
window's samples of ‖q - q̂‖², starting from the least-squares fit (nonlinear least squares,
:func:`scipy.optimize.least_squares`, over a schedule of horizons from a fifth of ``horizon``
to ``horizon``: a short window first keeps the first steps inside the region where the fit is
stable). The simulation is the baseline's own exact propagator (the matrix exponential over
one step under a zero- or first-order-hold input), so the fit minimises the number the report
shows on the training trajectories. numpy and scipy; no jax.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.optimize

from softpinn.errors import UserError
from softpinn.learn._baselines import STEP_RTOL, LinearSecondOrder, fit_linear_second_order
from softpinn.learn._trajectories import trajectory_arrays

__all__ = ["HORIZON", "LinearRolloutFit", "fit_linear_rollout", "window_error"]

#: default fitting horizon (s): predict's longest usual horizon, capped at half the shortest
#: training trajectory
HORIZON = 5.0
#: windows start every horizon / WINDOWS_PER_HORIZON seconds
WINDOWS_PER_HORIZON = 10
#: residual evaluations per stage of the schedule (each Jacobian takes one per parameter more)
MAX_EVALUATIONS = 60


@dataclasses.dataclass(frozen=True, eq=False)
class LinearRolloutFit(LinearSecondOrder):
    """:class:`LinearSecondOrder` fitted by its rollout error (:func:`fit_linear_rollout`)."""

    kind = "linear2_rollout"

    @classmethod
    def fit(cls, data, traj_ids=None, **options) -> LinearRolloutFit:
        return fit_linear_rollout(data, traj_ids, **options)


def _windows(segs, H: int, stride: int):
    """x0 (W, 2n), u (W, H + 1, m), q (W, H, n) of every window of H steps."""
    x0, u, q = [], [], []
    for s in segs:
        T = s["q"].shape[0]
        for a in range(0, T - H, stride):
            x0.append(np.concatenate([s["q"][a], s["qd"][a]]))
            u.append(s["u"][a:a + H + 1])
            q.append(s["q"][a + 1:a + H + 1])
    return np.asarray(x0), np.asarray(u), np.asarray(q)


class _Problem:
    """Residuals of the window rollouts for a parameter vector θ = (A_q, A_v, B_u, c)."""

    def __init__(self, base: LinearSecondOrder, x0, u, q, dt: float, hold: str):
        self.base, self.x0, self.u, self.q, self.dt, self.hold = base, x0, u, q, dt, hold
        self.n, self.m = base.n, base.m
        self.scale = 1.0 / math.sqrt(q.shape[0] * q.shape[1])
        # a rollout that leaves every sensible range counts as this far off (least_squares
        # needs finite residuals; a step into instability is then simply a bad step)
        self.cap = 1e3 * max(float(np.ptp(q)), 1e-6)

    def model(self, theta: np.ndarray) -> LinearSecondOrder:
        n, m = self.n, self.m
        parts = np.split(theta, np.cumsum([n * n, n * n, n * m]))
        return dataclasses.replace(self.base, A_q=parts[0].reshape(n, n),
                                   A_v=parts[1].reshape(n, n), B_u=parts[2].reshape(n, m),
                                   c=parts[3].copy(), integrator="expm")

    @staticmethod
    def theta(lin: LinearSecondOrder) -> np.ndarray:
        return np.concatenate([lin.A_q.ravel(), lin.A_v.ravel(), lin.B_u.ravel(), lin.c])

    def predicted(self, theta: np.ndarray) -> np.ndarray:
        lin = self.model(theta)
        F, G = lin._field()
        W, H = self.q.shape[:2]
        ones = np.ones((W, 1))
        x, out = self.x0, np.empty_like(self.q)
        # a trial step of the optimizer may be wildly unstable: its rollout is inf or NaN,
        # which residuals() caps, not a warning for the user
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            Phi, G0, G1 = lin._propagator(F, G, self.dt, self.hold)
            for k in range(H):
                uk = self.u[:, k]
                x = x @ Phi.T + np.hstack([uk, ones]) @ G0.T + (self.u[:, k + 1] - uk) @ G1.T
                out[:, k] = x[:, :self.n]
        return out

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        r = (self.predicted(theta) - self.q).ravel() * self.scale
        return np.clip(np.nan_to_num(r, nan=self.cap, posinf=self.cap, neginf=-self.cap),
                       -self.cap, self.cap)

    def error(self, theta: np.ndarray) -> float:
        """The windows' mean over samples of ‖q - q̂‖² (predict's metric), inf if not finite."""
        d = self.predicted(theta) - self.q
        with np.errstate(over="ignore", invalid="ignore"):
            e = float(np.mean(np.sum(d * d, axis=-1)))
        return e if math.isfinite(e) else math.inf


def fit_linear_rollout(trajectories, traj_ids=None, *, horizon: float | None = None,
                       input_hold: str = "constant", max_evaluations: int = MAX_EVALUATIONS,
                       **ls_options) -> LinearRolloutFit:
    """q̈ = A_q q + A_v q̇ + B_u u + c fitted by its rollout error over ``horizon`` seconds
    (None: :data:`HORIZON`, at most half the shortest trajectory) on the trajectories of a
    :class:`Dataset` (``traj_ids``; None: its training trajectories) or trajectory dicts,
    starting from :func:`fit_linear_second_order` (``ls_options`` go to it). Needs one sample
    step (as ARX does); ``input_hold`` as ``predict`` will simulate it."""
    if input_hold not in ("constant", "linear"):
        raise UserError(f"input_hold must be 'constant' or 'linear', got {input_hold!r}")
    if horizon is not None and not (isinstance(horizon, int | float) and horizon > 0
                                    and math.isfinite(horizon)):
        raise UserError(f"linear2_rollout horizon: expected a positive number of seconds, got "
                        f"{horizon!r}")
    ls = fit_linear_second_order(trajectories, traj_ids, **ls_options)
    segs = trajectory_arrays(trajectories, traj_ids, need=("t", "q", "qd", "u"))
    steps = np.concatenate([np.diff(s["t"]) for s in segs])
    dt = float(np.median(steps))
    if not dt > 0 or np.max(np.abs(steps - dt)) > STEP_RTOL * dt:
        raise UserError(f"linear2_rollout: needs one sample step, the data's steps range over "
                        f"{steps.min():.6g}..{steps.max():.6g} s; fit linear2, which takes any")
    shortest = min(s["t"].shape[0] for s in segs)
    wanted = HORIZON if horizon is None else float(horizon)
    H = max(1, min(int(round(wanted / dt)), (shortest - 1) // 2))
    schedule = sorted({max(1, H // 5), H})
    problem, theta = None, _Problem.theta(ls)
    start_error, stages = None, []
    for h in schedule:
        x0, u, q = _windows(segs, h, max(1, H // WINDOWS_PER_HORIZON))
        problem = _Problem(ls, x0, u, q, dt, input_hold)
        before = problem.error(theta)
        if start_error is None:
            start_error = before
        sol = scipy.optimize.least_squares(problem.residuals, theta, x_scale="jac",
                                           max_nfev=max_evaluations, method="trf")
        after = problem.error(sol.x)
        if after < before:  # never worse than where the stage started
            theta = sol.x
        stages.append({"steps": h, "windows": int(q.shape[0]), "error_before": before,
                       "error_after": min(after, before), "evaluations": int(sol.nfev)})
    final = problem.model(theta)
    F, _ = final._field()
    info = {**{k: v for k, v in ls.info.items() if k != "max_real_eigenvalue"},
            "fit": "rollout", "horizon": H * dt, "input_hold": input_hold,
            "least_squares_rollout_error": problem.error(_Problem.theta(ls)),
            "rollout_error": problem.error(theta), "stages": stages,
            "max_real_eigenvalue": float(np.max(np.linalg.eigvals(F).real))}
    return LinearRolloutFit(final.A_q, final.A_v, final.B_u, final.c, ls.q_low, ls.q_high,
                            ls.integrator, info)


def window_error(lin: LinearSecondOrder, trajectories, traj_ids=None, *, horizon: float,
                 input_hold: str = "constant") -> float:
    """The rollout fit's objective for ``lin`` on other trajectories (e.g. validation ones):
    the mean over windows of ``horizon`` seconds, starting every tenth of it, of the mean over
    the window's samples of ‖q - q̂‖² (inf if a rollout is not finite). Needs one sample step."""
    segs = trajectory_arrays(trajectories, traj_ids, need=("t", "q", "qd", "u"))
    dt = float(np.median(np.concatenate([np.diff(s["t"]) for s in segs])))
    shortest = min(s["t"].shape[0] for s in segs)
    H = max(1, min(int(round(horizon / dt)), shortest - 1))
    x0, u, q = _windows(segs, H, max(1, H // WINDOWS_PER_HORIZON))
    problem = _Problem(lin, x0, u, q, dt, input_hold)
    return problem.error(_Problem.theta(lin))
