"""ARX with lags of q and u, its order chosen on held-out data: the linear model with memory
(issue 43).

    q_{k+1} = Σ_{i<p} A_i q_{k-i} + Σ_{j<p} B_j u_{k-j} + c

A state (q, q̇) does not determine how a real arm moves on: a continuum has modes that one
sensor does not see, an actuator has states of its own, and a delay is a memory of past inputs.
The past samples stand in for those states, which is what makes this the linear model to beat
where they matter (the Cosserat stand-in: RESULTS.md). Each order p of :data:`ORDERS` is fitted
twice on the training trajectories but the last: by least squares on one-step pairs (as
:func:`learn._baselines.fit_arx`), and by its rollout error (:mod:`learn._lagged_rollout`, from
the better of that fit and the previous order's rollout fit; on noisy angles least squares fits
the noise, unstably at high orders). The fit and order chosen are those whose rollouts of up to
:data:`HORIZON` seconds are best on the last training trajectory, held out (on the training
ones where there is only one), scored as predict scores them (:func:`window_score`: half from
the trajectory's start, half from windows with a measured past); the lowest order within 5 % of
the best, least squares before the rollout fit; unstable fits (spectral radius of the companion
matrix above 1) refused. That fit is then repeated on every training trajectory. Where a rollout
starts without a past (a trajectory's first sample), earlier q are extrapolated along q̇0 and
earlier inputs held at u0, as an arm at rest would have them; predict's resets pass the
measured past of q and u.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from softpinn.errors import UserError
from softpinn.learn import _lagged_rollout as rollout_fit
from softpinn.learn._baselines import (
    FORMAT,
    RIDGE,
    STEP_RTOL,
    _check_hold,
    _int,
    _lstsq,
    _range,
    _start,
    _steps,
    checked_array,
)
from softpinn.learn._trajectories import trajectory_arrays

__all__ = ["HORIZON", "LaggedARX", "ORDERS", "fit_lagged_arx"]

#: the orders tried (lags of q and of u alike)
ORDERS = (1, 2, 3, 4, 6, 8, 12)
#: the longest window [s] of the rollouts that choose the order (predict's longest horizon)
HORIZON = 5.0
#: windows per held-out trajectory that choose the order
WINDOWS = 8
#: the order chosen is the lowest whose rollout error is within this factor of the best one's
PARSIMONY = 1.05
#: the fits tried at each order, preferred in this order at equal error
METHODS = ("least squares", "rollout")


@dataclass(frozen=True, eq=False)
class LaggedARX:
    """q_{k+1} = Σ_i A[i] q_{k-i} + Σ_j B[j] u_{k-j} + c at step ``dt`` (A: (p, n, n),
    B: (p, n, m), c: (n,))."""

    A: np.ndarray
    B: np.ndarray
    c: np.ndarray
    dt: float
    q_low: np.ndarray
    q_high: np.ndarray
    info: dict = field(default_factory=dict)
    kind = "arx_lags"

    n = property(lambda self: int(self.A.shape[1]))
    m = property(lambda self: int(self.B.shape[2]))
    order = property(lambda self: int(self.A.shape[0]))

    @classmethod
    def fit(cls, data, traj_ids=None, *, ridge: float = RIDGE) -> LaggedARX:
        return fit_lagged_arx(data, traj_ids, ridge=ridge)

    #: rollouts take the inputs before their start (``u_past``; predict's resets pass them)
    input_lags = property(lambda self: self.order)

    def rollout(self, q0_or_history, qd0, u_seq, dt, *, input_hold: str = "constant",
                u_past=None):
        """q (T, n) from q0 (n,) or the last r <= p samples (r, n), oldest first, under inputs
        u_seq (T, m) after the inputs ``u_past`` (the samples before u_seq[0], oldest first;
        None: none): earlier q extrapolated back along q̇0 (None: at rest), earlier u held at
        the first one known. Discrete: ``input_hold`` is accepted for a common interface and
        unused; ``dt`` must be the step it was fitted at."""
        _check_hold(input_hold)
        hist, qd, u = _start(self.kind, self.n, self.m, q0_or_history, qd0, u_seq)
        h = _steps(dt, u.shape[0])
        if h.size and np.max(np.abs(h - self.dt)) > STEP_RTOL * self.dt:
            raise UserError(f"{self.kind} rollout: the model was fitted at step {self.dt:.6g} "
                            f"s, asked for steps {h.min():.6g}..{h.max():.6g} s")
        past = np.zeros((0, self.m)) if u_past is None else np.asarray(u_past, np.float64)
        if past.ndim != 2 or past.shape[1] != self.m:
            raise UserError(f"{self.kind} rollout: u_past must have shape (r, {self.m}), got "
                            f"{past.shape}")
        return _simulate(self, hist, qd, u, past)

    def describe(self) -> str:
        """What the fit chose, e.g. "order 6, least squares" (the report's row label)."""
        how = {"rollout": "rollout fit"}.get(self.info.get("fit"), self.info.get("fit"))
        return f"order {self.order}" + (f", {how}" if how else "")

    def to_dict(self) -> dict:
        return {"kind": self.kind, "format": FORMAT, "n": self.n, "m": self.m,
                "order": self.order, "dt": self.dt, "A": self.A.tolist(), "B": self.B.tolist(),
                "c": self.c.tolist(), "q_low": self.q_low.tolist(),
                "q_high": self.q_high.tolist(), "info": dict(self.info)}

    @classmethod
    def from_dict(cls, d: Mapping) -> LaggedARX:
        n, m, p = (_int(d, k, cls.kind) for k in ("n", "m", "order"))
        dt = d.get("dt")
        if isinstance(dt, bool) or not isinstance(dt, int | float) or not dt > 0:
            raise UserError(f"baseline {cls.kind}: 'dt' must be a positive number, got {dt!r}")
        g = lambda key, shape: checked_array(d, key, shape, f"baseline {cls.kind}")  # noqa: E731
        return cls(g("A", (p, n, n)), g("B", (p, n, m)), g("c", (n,)), float(dt),
                   g("q_low", (n,)), g("q_high", (n,)), dict(d.get("info", {})))


def _simulate(model: LaggedARX, hist: np.ndarray, qd: np.ndarray, u: np.ndarray,
              u_past: np.ndarray | None = None) -> np.ndarray:
    """A rollout from a history of q (oldest first; extrapolated back along q̇ to p samples)
    and of u before u[0] (oldest first; held back at the first one known)."""
    p = model.order
    back = [hist[0] - j * model.dt * qd for j in range(p - hist.shape[0], 0, -1)]
    past = np.array([*back, *hist[-p:]])
    known = np.concatenate([u_past[-(p - 1):] if u_past is not None and p > 1 else
                            np.zeros((0, model.m)), u[:1]])
    upast = np.concatenate([np.repeat(known[:1], p - known.shape[0], axis=0), known])
    return _recur(model, past, upast, u)


def _recur(model: LaggedARX, past_q: np.ndarray, past_u: np.ndarray, u: np.ndarray):
    """q (T, n): the last p samples of q and of u (oldest first; the last ones at the first
    sample, u[0] among them), then the recurrence under u[1:]."""
    A = np.concatenate(list(model.A), axis=1)  # (n, p n), newest lag first
    B = np.concatenate(list(model.B), axis=1)  # (n, p m)
    past, upast = past_q[::-1].copy(), past_u[::-1].copy()  # newest first
    out = np.empty((u.shape[0], model.n))
    out[0] = past[0]
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(u.shape[0] - 1):
            nxt = A @ past.reshape(-1) + B @ upast.reshape(-1) + model.c
            out[k + 1] = nxt
            past = np.vstack([nxt[None], past[:-1]])
            upast = np.vstack([u[k + 1:k + 2], upast[:-1]])
    return out


def _pairs(segs, p: int) -> tuple[np.ndarray, np.ndarray]:
    X, Y = [], []
    for s in segs:
        q, u = s["q"], s["u"]
        T = q.shape[0]
        if T <= p:
            continue
        lags = [q[p - 1 - i:T - 1 - i] for i in range(p)]
        ulags = [u[p - 1 - i:T - 1 - i] for i in range(p)]
        X.append(np.hstack([*lags, *ulags]))
        Y.append(q[p:])
    if not X:
        return np.zeros((0, 1)), np.zeros((0, 1))
    return np.vstack(X), np.vstack(Y)


def _fit_order(segs, p: int, dt: float, ridge: float) -> LaggedARX | None:
    n, m = segs[0]["q"].shape[1], segs[0]["u"].shape[1]
    X, Y = _pairs(segs, p)
    if X.shape[0] < 2 * (p * (n + m) + 1):
        return None
    W, b, rank = _lstsq(X, Y, ridge)
    A = np.stack([W[i * n:(i + 1) * n].T for i in range(p)])
    B = np.stack([W[p * n + j * m:p * n + (j + 1) * m].T for j in range(p)]).reshape(p, n, m)
    comp = np.zeros((p * n, p * n))
    comp[:n] = np.hstack(list(A))
    comp[n:, :-n] = np.eye((p - 1) * n)
    info = {"trajectories": [s["id"] for s in segs], "pairs": int(X.shape[0]),
            "ridge": float(ridge), "rank": rank, "unknowns": p * (n + m) + 1,
            "one_step_rms": float(np.sqrt(np.mean((X @ W + b - Y) ** 2))),
            "spectral_radius": float(np.max(np.abs(np.linalg.eigvals(comp))))}
    return LaggedARX(A, B, b, dt, *_range(segs), info)


def _error(pred: np.ndarray, q: np.ndarray) -> float:
    d = pred[1:] - q[1:]
    with np.errstate(over="ignore", invalid="ignore"):
        return float(np.mean(np.sum(d * d, axis=1)))


def window_score(model: LaggedARX, segs, horizon: float = HORIZON) -> float:
    """The rollout error predict reports, on other trajectories: half of it is the mean over
    the trajectories of the first ``horizon`` seconds from their start (the past extrapolated
    along q̇0, the inputs held: predict without reset, where a high order's guessed past costs
    most), half the mean over :data:`WINDOWS` windows per trajectory from their measured past
    (predict with resets). inf where a rollout is not finite."""
    p, starts, windows = model.order, [], []
    for s in segs:
        q, qd, u = s["q"], s["qd"], s["u"]
        T = q.shape[0]
        H = max(2, min(T, int(round(horizon / model.dt)) + 1))
        starts.append(_error(_simulate(model, q[:1], qd[0], u[:H]), q[:H]))
        if T - (p - 1) < H:
            continue
        for a in np.unique(np.linspace(p - 1, T - H, WINDOWS).astype(int)):
            pred = _recur(model, q[a - p + 1:a + 1], u[a - p + 1:a + 1], u[a:a + H])
            windows.append(_error(pred, q[a:a + H]))
    err = 0.5 * (float(np.mean(starts)) + float(np.mean(windows if windows else starts)))
    return err if math.isfinite(err) else math.inf


def _choose(scores: dict[tuple[int, str], float], judge) -> tuple[int, str]:
    """The lowest order (least squares before rollout fit) within :data:`PARSIMONY` of the
    best finite score (an exact fit's round-off counts as equal); else the lowest order."""
    finite = {k: e for k, e in scores.items() if math.isfinite(e)}
    if not finite:
        return min(scores)
    floor = 1e-20 * float(np.mean([np.mean(s["q"] ** 2) for s in judge]))
    low = min(finite.values())
    return min((k for k, e in finite.items() if e <= PARSIMONY * low + floor),
               key=lambda k: (k[0], k[1] != METHODS[0]))


def fit_lagged_arx(trajectories, traj_ids=None, *, ridge: float = RIDGE,
                   rollout: bool = True) -> LaggedARX:
    """The lagged ARX of the order in :data:`ORDERS` and the fit (least squares, or by its
    rollout error where ``rollout`` and it has at most
    :data:`learn._lagged_rollout.MAX_PARAMETERS` coefficients) whose rollouts are best on the
    last training trajectory held out (module docstring), refitted on all of ``traj_ids`` (a
    :class:`Dataset`'s ids; None: its training trajectories) or trajectory dicts."""
    segs = trajectory_arrays(trajectories, traj_ids, need=("t", "q", "qd", "u"))
    steps = np.concatenate([np.diff(s["t"]) for s in segs])
    if steps.size == 0:
        raise UserError("arx_lags: the trajectories hold one sample each; need more")
    dt = float(np.median(steps))
    if not dt > 0 or np.max(np.abs(steps - dt)) > STEP_RTOL * dt:
        raise UserError(f"arx_lags: needs one sample step, the data's steps range over "
                        f"{steps.min():.6g}..{steps.max():.6g} s; fit linear2, which takes any")
    n, m = segs[0]["q"].shape[1], segs[0]["u"].shape[1]
    fit_on, judge = (segs[:-1], segs[-1:]) if len(segs) > 1 else (segs, segs)
    wanted = int(round(HORIZON / dt))
    scores: dict[tuple[int, str], float] = {}
    fits: dict[tuple[int, str], LaggedARX] = {}
    previous = None  # the last rollout fit, padded as a start for the next order
    for p in ORDERS:
        ls = _fit_order(fit_on, p, dt, ridge)
        if ls is None:
            break
        stable = ls.info["spectral_radius"] <= 1.0 + 1e-9
        fits[p, "least squares"] = ls
        scores[p, "least squares"] = window_score(ls, judge) if stable else math.inf
        H = rollout_fit.horizon_steps(fit_on, p, wanted)
        if not rollout or H < 2 or rollout_fit.parameters(n, m, p) > rollout_fit.MAX_PARAMETERS:
            continue
        starts = ([ls] if stable else []) + ([rollout_fit.padded(previous, p)] if previous
                                             else [])
        oe = rollout_fit.refine(fit_on, starts, H) if starts else None
        if oe is not None:
            previous = oe
            fits[p, "rollout"] = oe
            stable = oe.info["spectral_radius"] <= 1.0 + 1e-9
            scores[p, "rollout"] = window_score(oe, judge) if stable else math.inf
    if not scores:
        raise UserError(f"arx_lags: too few sample pairs to fit order 1 ({2 * (n + m + 1)} "
                        f"needed); give more or longer trajectories")
    best = _choose(scores, judge)
    p, how = best
    model = None
    if how == "least squares":
        model = _fit_order(segs, p, dt, ridge)
    elif len(segs) > 1:  # the rollout fit again on every training trajectory, from the chosen
        H = rollout_fit.horizon_steps(segs, p, wanted)
        model = (rollout_fit.refine(segs, [fits[best]], H, rollout_fit.FINAL_ITERATIONS)
                 if H >= 2 else None)
    model = model or fits[best]
    chosen_on = "held-out training trajectory" if len(segs) > 1 else "training trajectory"
    tried: dict[str, dict] = {}
    for (order, method), e in scores.items():
        tried.setdefault(str(order), {})[method] = e if math.isfinite(e) else None
    info = {**model.info, "fit": how, "orders_tried": tried,
            "order_chosen_on": f"{chosen_on} {judge[0]['id']}", "horizon": HORIZON}
    return LaggedARX(model.A, model.B, model.c, model.dt, model.q_low, model.q_high, info)
