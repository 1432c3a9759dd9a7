"""The linear second-order model fitted by its rollout error (output error), issue 43.

:func:`learn._baselines.fit_linear_second_order` fits q̈ = A_q q + A_v q̇ + B_u u + c by least
squares on the data set's q̈: the best one-step model, and on noisy recordings a poor one over
a horizon, because q̇ and q̈ come from smoothed differences of noisy angles (on the Cosserat
stand-in with 0.01 rad of sensor noise its 5 s rollout error was 12x that of an ARX model fitted
to the same samples, RESULTS.md). Output error fits the same four matrices to what ``predict``
scores instead: the mean over windows of the training trajectories, each simulated from its
measured (q, q̇) under its measured inputs over ``horizon`` seconds, of the mean over the
window's samples of ‖q - q̂‖², starting from the least-squares fit (Levenberg-Marquardt with
forward-difference Jacobians, every column's rollout in one batch, over a schedule of horizons
from a fifth of ``horizon`` to ``horizon``: a short window first keeps the first steps inside
the region where the fit is stable; at most :data:`MAX_WINDOWS` windows of at most
:data:`MAX_STEPS` steps). The simulation is the baseline's own exact propagator (the matrix
exponential over one step under a zero- or first-order-hold input), so the fit minimises the
number the report shows on the training trajectories. 0.3 s of CPU on the Cosserat
recordings (n = 2, m = 4), 4-10 s for task 5's (n = 6, m = 6). numpy and scipy; no jax.
"""

from __future__ import annotations

import abc
import dataclasses
import math

import numpy as np

from softpinn.errors import UserError
from softpinn.learn._baselines import STEP_RTOL, LinearSecondOrder, fit_linear_second_order
from softpinn.learn._trajectories import trajectory_arrays

__all__ = ["HORIZON", "LinearRolloutFit", "fit_linear_rollout", "window_error"]

#: default fitting horizon (s): predict's longest usual horizon, capped at half the shortest
#: training trajectory
HORIZON = 5.0
#: windows start every horizon / WINDOWS_PER_HORIZON seconds
WINDOWS_PER_HORIZON = 10
#: Levenberg-Marquardt iterations per stage of the schedule (one Jacobian each)
MAX_EVALUATIONS = 25
#: the most steps a window is simulated over: longer windows (a fast sampling rate) are fitted
#: on every r-th sample (the model is continuous: its step is only how it is simulated)
MAX_STEPS = 250
#: the most windows a fit simulates (evenly spaced among all of them)
MAX_WINDOWS = 48
#: the most state values (rollouts x windows x steps x 2n) one batch of a Jacobian holds
BATCH_VALUES = 2e7


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
    keep = np.unique(np.linspace(0, len(x0) - 1, min(len(x0), MAX_WINDOWS)).round().astype(int))
    return np.asarray(x0)[keep], np.asarray(u)[keep], np.asarray(q)[keep]


class WindowResiduals(abc.ABC):
    """The residuals of window rollouts q̂ against the measured q (W, H, n): a subclass sets
    ``q``, ``scale`` (1/√(W H): the residuals' sum of squares is the mean over samples) and
    ``cap`` (what a rollout that left every sensible range counts as: Levenberg-Marquardt
    needs finite residuals, and a step into instability is then simply a bad step)."""

    q: np.ndarray
    scale: float
    cap: float

    @abc.abstractmethod
    def predicted(self, thetas: np.ndarray) -> np.ndarray:
        """q̂ (P, W, H, n) of the windows under each parameter vector of ``thetas`` (P, k)."""

    @abc.abstractmethod
    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        """∂ residuals / ∂θ, (W H n, k)."""

    def _flat(self, pred: np.ndarray) -> np.ndarray:
        r = (pred - self.q).reshape(pred.shape[0], -1) * self.scale
        if not np.isfinite(r).all():  # (nan_to_num's scan cost an eighth of a fit)
            r = np.nan_to_num(r, nan=self.cap, posinf=self.cap, neginf=-self.cap)
        return np.clip(r, -self.cap, self.cap, out=r)

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        return self._flat(self.predicted(theta[None]))[0]

    def error(self, theta: np.ndarray) -> float:
        """The windows' mean over samples of ‖q - q̂‖² (predict's metric), inf if not finite."""
        d = self.predicted(theta[None])[0] - self.q
        with np.errstate(over="ignore", invalid="ignore"):
            e = float(np.mean(np.sum(d * d, axis=-1)))
        return e if math.isfinite(e) else math.inf


class _Problem(WindowResiduals):
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

    def predicted(self, thetas: np.ndarray) -> np.ndarray:
        """q̂ (P, W, H, n) of the windows under each of the parameter vectors ``thetas``
        (P, p), all P rollouts stepped together (one Python loop over the H steps)."""
        mats = []
        # a trial step of the optimizer may be wildly unstable: its rollout is inf or NaN,
        # which residuals() caps, not a warning for the user
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            for theta in thetas:
                lin = self.model(theta)
                mats.append(lin._propagator(*lin._field(), self.dt, self.hold))
            Phi, G0, G1 = (np.stack(a) for a in zip(*mats, strict=True))
            W, H = self.q.shape[:2]
            u1 = np.concatenate([self.u, np.ones(self.u.shape[:2] + (1,))], axis=2)
            du = np.diff(self.u, axis=1)
            # the inputs' share of every step does not depend on the state: computed at once
            drive = (u1[None, :, :H] @ np.swapaxes(G0, 1, 2)[:, None]
                     + du[None] @ np.swapaxes(G1, 1, 2)[:, None])
            x = np.broadcast_to(self.x0, (len(thetas),) + self.x0.shape)
            out = np.empty((len(thetas), W, H, self.n))
            PhiT = np.swapaxes(Phi, 1, 2)
            for k in range(H):
                x = x @ PhiT + drive[:, :, k]
                out[:, :, k] = x[..., :self.n]
        return out

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        """Forward differences of :meth:`residuals`, every column's rollout in one batch."""
        h = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(theta))
        thetas = theta + np.diag(h)
        r0 = self.residuals(theta)
        W, H = self.q.shape[:2]
        per = max(1, int(BATCH_VALUES // (W * (H + 1) * 2 * self.n)))  # rollouts a batch
        cols = [self._flat(self.predicted(thetas[a:a + per])) for a in range(0, len(h), per)]
        return ((np.vstack(cols) - r0) / h[:, None]).T



def _levenberg_marquardt(problem: _Problem, theta: np.ndarray, iterations: int):
    """(θ, iterations done): Levenberg-Marquardt on the residuals, the step from the normal
    equations (JᵀJ + λ diag(JᵀJ)) δ = -Jᵀr, p x p, where the thin SVD of the residuals' J
    (windows x steps x n rows) took 0.33 s a step for n = 6."""
    r = problem.residuals(theta)
    cost, lam = float(r @ r), 1e-3
    for it in range(iterations):
        J = problem.jacobian(theta)
        A, g = J.T @ J, J.T @ r
        scale = np.where(np.diag(A) > 0, np.diag(A), 1.0)
        while lam < 1e10:
            try:
                step = np.linalg.solve(A + lam * np.diag(scale), -g)
            except np.linalg.LinAlgError:
                lam *= 4.0
                continue
            r_new = problem.residuals(theta + step)
            c_new = float(r_new @ r_new)
            if c_new < cost:
                break
            lam *= 4.0
        else:
            return theta, it
        done = cost - c_new <= 1e-10 * cost
        theta, r, cost, lam = theta + step, r_new, c_new, max(lam / 3.0, 1e-12)
        if done:
            return theta, it + 1
    return theta, iterations


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
    every = -(-H // MAX_STEPS)
    if every > 1:  # fit on every r-th sample: H / r steps of r dt
        segs = [{k: (v[::every] if k != "id" else v) for k, v in s.items()} for s in segs]
        H, dt = H // every, dt * every
    schedule = sorted({max(1, H // 5), H})
    problem, theta, stages = None, _Problem.theta(ls), []
    for h in schedule:
        x0, u, q = _windows(segs, h, max(1, H // WINDOWS_PER_HORIZON))
        problem = _Problem(ls, x0, u, q, dt, input_hold)
        before = problem.error(theta)
        found, iterations = _levenberg_marquardt(problem, theta, max_evaluations)
        after = problem.error(found)
        if after < before:  # never worse than where the stage started
            theta = found
        stages.append({"steps": h, "windows": int(q.shape[0]), "error_before": before,
                       "error_after": min(after, before), "iterations": iterations})
    final = problem.model(theta)
    F, _ = final._field()
    info = {**{k: v for k, v in ls.info.items() if k != "max_real_eigenvalue"},
            "fit": "rollout", "horizon": H * dt, "input_hold": input_hold, "every": every,
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
