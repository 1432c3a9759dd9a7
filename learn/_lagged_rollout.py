"""The lagged ARX (:mod:`learn._lagged_arx`) fitted by its rollout error (output error).

Least squares on one-step pairs fits a lagged ARX to noise where the angles are noisy: on the
Cosserat stand-in's noisy recordings every order above 4 came out unstable and orders 3 and 4
rolled out worse than order 2 (RESULTS.md). As :mod:`learn._output_error` does for the
second-order model, this fits the same matrices to what ``predict`` scores: the mean over
windows of the training trajectories, each simulated from its measured past (p samples of q and
u) under its measured inputs over up to :data:`MAX_STEPS` steps, of the mean over the window's
samples of ‖q - q̂‖²; Levenberg-Marquardt (:func:`learn._output_error._levenberg_marquardt`)
with the exact Jacobian (:meth:`_Problem.jacobian`), over a schedule of horizons from a fifth
of the horizon to all of it. Only for models of at most :data:`MAX_PARAMETERS` coefficients
(the Jacobian's memory and the normal equations grow with their number).
"""

from __future__ import annotations

import math

import numpy as np

from softpinn.learn._output_error import WindowResiduals, _levenberg_marquardt

__all__ = ["MAX_PARAMETERS", "horizon_steps", "padded", "parameters", "refine"]

#: the most coefficients p n (n + m) + n a lagged ARX is fitted by its rollout error with
MAX_PARAMETERS = 200
#: the most steps a window is simulated over (the model is discrete: no decimation)
MAX_STEPS = 250
#: the most windows a fit simulates (evenly spaced among all of them)
MAX_WINDOWS = 48
#: windows start every horizon / WINDOWS_PER_HORIZON steps
WINDOWS_PER_HORIZON = 10
#: Levenberg-Marquardt iterations per stage of the schedule while orders are compared, and for
#: the fit of the order chosen (on every training trajectory, from the compared fit)
ITERATIONS = 10
FINAL_ITERATIONS = 40


def parameters(n: int, m: int, p: int) -> int:
    """The coefficients of a lagged ARX of order p."""
    return p * n * (n + m) + n


def _theta(model) -> np.ndarray:
    return np.concatenate([np.concatenate(list(model.A), axis=1).ravel(),
                           np.concatenate(list(model.B), axis=1).ravel(), model.c])


def _model(theta: np.ndarray, like, p: int, info: dict):
    """A model of ``like``'s class (:class:`learn._lagged_arx.LaggedARX`, which imports this
    module) from θ."""
    n, m = like.n, like.m
    A = theta[:p * n * n].reshape(n, p * n)
    B = theta[p * n * n:p * n * (n + m)].reshape(n, p * m)
    return type(like)(np.stack([A[:, i * n:(i + 1) * n] for i in range(p)]),
                     np.stack([B[:, j * m:(j + 1) * m] for j in range(p)]),
                     theta[-n:].copy(), like.dt, like.q_low, like.q_high, info)


def padded(model, p: int):
    """``model`` as a lagged ARX of order ``p`` >= its own: the extra lags zero."""
    n, m, k = model.n, model.m, model.order
    A = np.zeros((p, n, n))
    B = np.zeros((p, n, m))
    A[:k], B[:k] = model.A, model.B
    return type(model)(A, B, model.c.copy(), model.dt, model.q_low, model.q_high,
                       dict(model.info))


class _Problem(WindowResiduals):
    """Residuals of the window rollouts of a lagged ARX of order p for parameter vectors θ."""

    def __init__(self, segs, p: int, H: int, stride: int):
        past, ulags, q = [], [], []
        lag = np.arange(p)
        for s in segs:
            T = s["q"].shape[0]
            for a in range(p - 1, T - H, stride):
                past.append(s["q"][a - lag].reshape(-1))  # newest first
                k = a + np.arange(H)[:, None] - lag[None, :]  # u_{a+k-j}, (H, p)
                ulags.append(s["u"][k].reshape(H, -1))
                q.append(s["q"][a + 1:a + H + 1])
        keep = np.unique(np.linspace(0, len(past) - 1, min(len(past), MAX_WINDOWS))
                         .round().astype(int)) if past else np.zeros(0, int)
        self.past = np.asarray(past)[keep]
        self.ulags = np.asarray(ulags)[keep]
        self.q = np.asarray(q)[keep]
        self.p = p
        self.n = segs[0]["q"].shape[1]
        self.m = segs[0]["u"].shape[1]
        W = max(self.q.shape[0], 1)
        self.scale = 1.0 / math.sqrt(W * H)
        self.cap = 1e3 * max(float(np.ptp(self.q)) if self.q.size else 1.0, 1e-6)

    @property
    def windows(self) -> int:
        return int(self.q.shape[0])

    def predicted(self, thetas: np.ndarray) -> np.ndarray:
        """q̂ (P, W, H, n) of the windows under each parameter vector of ``thetas`` (P, k):
        the inputs' share of every step at once (one matrix product), then one Python loop
        over the steps on a buffer that holds each window's past and its predictions, oldest
        first, so that the last p samples are a view."""
        n, m, p = self.n, self.m, self.p
        P = thetas.shape[0]
        W, H = self.q.shape[:2]
        # A, B with their lags oldest first, to multiply the buffer's last p samples
        A = thetas[:, :p * n * n].reshape(P, n, p, n)[:, :, ::-1].reshape(P, n, p * n)
        B = thetas[:, p * n * n:p * n * (n + m)].reshape(P, n, p * m)
        c = thetas[:, -n:]
        buf = np.empty((P, W, p + H, n))
        buf[:, :, :p] = self.past.reshape(W, p, n)[:, ::-1]
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            drive = (self.ulags.reshape(1, W * H, p * m) @ np.swapaxes(B, 1, 2)
                     + c[:, None, :]).reshape(P, W, H, n)
            At = np.swapaxes(A, 1, 2)
            for k in range(H):
                buf[:, :, p + k] = buf[:, :, k:k + p].reshape(P, W, p * n) @ At + drive[:, :, k]
        return buf[:, :, p:]

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        """∂ residuals / ∂θ, exact: the sensitivities of a linear recursion obey the same
        recursion (the same A for every parameter: one matrix product a step for all of them)
        driven by what the parameter multiplies (a lagged prediction, a lagged input, 1); the
        measured past has none."""
        n, m, p = self.n, self.m, self.p
        W, H = self.q.shape[:2]
        pn, pm = p * n, p * m
        base = self.predicted(theta[None])[0]  # (W, H, n)
        full = np.concatenate([self.past.reshape(W, p, n)[:, ::-1], base], axis=1)
        lags = p - 1 + np.arange(H)[:, None] - np.arange(p)[None, :]  # (H, p), newest first
        qlags = full[:, lags].reshape(W, H, pn)  # what A's columns multiply at each step
        A = theta[:p * n * n].reshape(n, p, n)[:, ::-1].reshape(n, pn)  # lags oldest first
        J = theta.size
        S = np.zeros((J, W, p + H, n))
        At = A.T
        with np.errstate(over="ignore", invalid="ignore"):
            for k in range(H):
                new = (S[:, :, k:k + p].reshape(J * W, pn) @ At).reshape(J, W, n)
                for i in range(n):
                    new[i * pn:(i + 1) * pn, :, i] += qlags[:, k].T
                    b = p * n * n + i * pm
                    new[b:b + pm, :, i] += self.ulags[:, k].T
                    new[p * n * (n + m) + i, :, i] += 1.0
                S[:, :, p + k] = new
        jac = S[:, :, p:].reshape(J, -1).T * self.scale
        if np.isfinite(jac).all():  # the usual case: nan_to_num's scan is a quarter of a call
            return jac
        return np.nan_to_num(jac, nan=0.0, posinf=0.0, neginf=0.0)


def horizon_steps(segs, p: int, wanted: int) -> int:
    """The steps of the fitting windows: ``wanted``, at most :data:`MAX_STEPS` and half the
    shortest trajectory after its first p samples (0: too short to fit)."""
    shortest = min(s["q"].shape[0] for s in segs)
    return max(0, min(wanted, MAX_STEPS, (shortest - p) // 2))


def refine(segs, starts: list, H: int, iterations: int = ITERATIONS):
    """The lagged ARX of the starts' order fitted by its rollout error over windows of ``H``
    steps of ``segs`` (a schedule H/5, H), from the start whose windows roll out best; None
    where no window fits or no start rolls out finitely. Its info says the fit."""
    p = starts[0].order
    schedule = sorted({max(1, H // 5), H})
    problem = _Problem(segs, p, H, max(1, H // WINDOWS_PER_HORIZON))
    if problem.windows == 0:
        return None
    errors = [problem.error(_theta(s)) for s in starts]
    if not any(math.isfinite(e) for e in errors):
        return None
    start = starts[int(np.argmin(errors))]
    theta, stages = _theta(start), []
    for h in schedule:
        stage = problem if h == H else _Problem(segs, p, h, max(1, h // WINDOWS_PER_HORIZON))
        before = stage.error(theta)
        found, done = _levenberg_marquardt(stage, theta, iterations)
        after = stage.error(found)
        if after < before:  # never worse than where the stage started
            theta = found
        stages.append({"steps": h, "windows": stage.windows, "error_before": before,
                       "error_after": min(after, before), "iterations": done})
    A = _model(theta, start, p, {})
    comp = np.zeros((p * A.n, p * A.n))
    comp[:A.n] = np.concatenate(list(A.A), axis=1)
    comp[A.n:, :-A.n] = np.eye((p - 1) * A.n)
    info = {**{k: v for k, v in start.info.items() if k != "spectral_radius"},
            "fit": "rollout", "rollout_steps": H, "start_error": min(errors),
            "rollout_error": problem.error(theta), "stages": stages,
            "spectral_radius": float(np.max(np.abs(np.linalg.eigvals(comp))))}
    return _model(theta, start, p, info)
