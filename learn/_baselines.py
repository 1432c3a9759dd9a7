"""Baselines the networks must beat (issue 43, item 1): linear models fitted by least squares
in closed form, and predicting no motion. numpy and scipy, float64; no jax, no casadi.

* ``"arx"`` (:class:`ARX`): a discrete ARX model on the observed coordinates,
  q_{k+1} = Σ_{i<p} A_i q_{k-i} + B u_k + c, at the data's (uniform) step. Order p = 1 is the
  "ten lines of numpy" of issue 43; with p = 2 the velocity is implicit in two past samples.
* ``"linear2"`` (:class:`LinearSecondOrder`): M q̈ + D q̇ + K q = B u + c in the same
  coordinates, fitted in its normalised form q̈ = A_q q + A_v q̇ + B_u u + c_u from the data
  set's q, q̇, q̈. The scale of M is not identifiable from motion, so M = I and
  D = M⁻¹D = -A_v, K = M⁻¹K = -A_q, B = M⁻¹B = B_u. Simulated exactly for a zero-order-hold
  (``input_hold="constant"``) or first-order-hold (``"linear"``) input by the matrix
  exponential, or by RK4 at the data's step (``integrator="rk4"``, as the networks are).
* ``"no_motion"`` (:class:`NoMotion`): q̂(t) = q(t0).

* ``"linear2_rollout"`` (:class:`learn._output_error.LinearRolloutFit`): the same model fitted
  by its rollout error over a horizon, starting from ``linear2``.

Every baseline is a frozen dataclass with ``kind``, ``fit(data, traj_ids)``,
``rollout(q0_or_history, qd0, u_seq, dt, input_hold=...)`` -> q (T, n), and
``to_dict()`` / ``from_dict()`` (plain JSON); each keeps the box of its training q, which
:func:`learn._baseline_errors.rollout_errors` (predict's rollout metric) flags rollouts
leaving.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from softpinn.errors import UserError
from softpinn.learn._trajectories import trajectory_arrays

__all__ = ["ARX", "FORMAT", "LinearSecondOrder", "NoMotion", "RIDGE", "checked_array", "fit_arx",
           "fit_linear_second_order", "trajectory_arrays"]

#: Default ridge: λ N added to ZᵀZ of the standardised regressors Z (N rows, unit variance),
#: a relative shrinkage of λ: conditioning only, far below any fitted effect.
RIDGE = 1e-9
#: Relative spread of sample steps ARX accepts (it is a model at one step).
STEP_RTOL = 1e-3
FORMAT = 1


def checked_array(d: Mapping, key: str, shape: tuple, what: str) -> np.ndarray:
    """``d[key]`` as a finite float64 array of ``shape``, else a one-line :class:`UserError`
    that starts with ``what`` (a stored baseline's or prior's JSON)."""
    try:
        a = np.asarray(d[key], dtype=np.float64)
    except KeyError:
        raise UserError(f"{what}: missing '{key}'") from None
    except (TypeError, ValueError):
        raise UserError(f"{what}: '{key}' must hold numbers") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise UserError(f"{what}: '{key}' must be finite of shape {shape}, got {a.shape}")
    return a



def _lstsq(X: np.ndarray, Y: np.ndarray, ridge: float) -> tuple[np.ndarray, np.ndarray, int]:
    """W, b with Y ≈ X W + b by least squares on standardised columns (ridge λ on the scaled
    weights, the intercept free), unscaled after; constant columns get weight 0. Returns W,
    b and the rank of the regressors with the intercept's column."""
    if not (isinstance(ridge, int | float) and math.isfinite(ridge) and ridge >= 0):
        raise UserError(f"ridge: expected a number >= 0, got {ridge!r}")
    N = X.shape[0]
    mx, sx = X.mean(axis=0), X.std(axis=0)
    my, sy = Y.mean(axis=0), Y.std(axis=0)
    flat = sx <= 1e-12 * np.maximum(np.abs(mx), 1e-300)
    sx = np.where(flat, 1.0, sx)
    sy = np.where(sy <= 1e-12 * np.maximum(np.abs(my), 1e-300), 1.0, sy)
    Z = np.where(flat, 0.0, (X - mx) / sx)
    T = (Y - my) / sy
    rank = 1 + (int(np.linalg.matrix_rank(Z)) if Z.size else 0)  # the intercept's column
    if ridge > 0 and Z.shape[1]:
        Z = np.vstack([Z, math.sqrt(ridge * N) * np.eye(Z.shape[1])])
        T = np.vstack([T, np.zeros((Z.shape[1], T.shape[1]))])
    Wz = np.linalg.lstsq(Z, T, rcond=None)[0] if Z.shape[1] else np.zeros((0, Y.shape[1]))
    W = Wz * sy[None, :] / sx[:, None]
    return W, my - mx @ W, rank


def _range(segs) -> tuple[np.ndarray, np.ndarray]:
    q = np.concatenate([s["q"] for s in segs])
    return q.min(axis=0), q.max(axis=0)


def _steps(dt, T: int) -> np.ndarray:
    h = np.broadcast_to(np.asarray(dt, dtype=np.float64), (max(T - 1, 0),)) \
        if np.ndim(dt) == 0 else np.asarray(dt, dtype=np.float64)
    if h.shape != (max(T - 1, 0),) or not np.all(np.isfinite(h) & (h > 0)):
        raise UserError(f"dt: expected a positive step or {max(T - 1, 0)} steps for {T} inputs, "
                        f"got shape {h.shape}")
    return h


def _start(kind: str, n: int, m: int, q0, qd0, u_seq) -> tuple[np.ndarray, np.ndarray,
                                                               np.ndarray]:
    """Checked (history (r, n) oldest first, q̇0 (n,), u (T, m))."""
    hist = np.atleast_2d(np.asarray(q0, dtype=np.float64))
    u = np.asarray(u_seq, dtype=np.float64)
    if m == 0 and u.ndim == 1:
        u = u.reshape(-1, 0)
    qd = np.zeros(n) if qd0 is None else np.asarray(qd0, dtype=np.float64)
    if hist.ndim != 2 or hist.shape[1] != n or hist.shape[0] < 1:
        raise UserError(f"{kind} rollout: q0 must have shape ({n},) or (r, {n}), "
                        f"got {np.shape(q0)}")
    if qd.shape != (n,):
        raise UserError(f"{kind} rollout: qd0 must have shape ({n},), got {qd.shape}")
    if u.ndim != 2 or u.shape[1] != m or u.shape[0] < 1:
        raise UserError(f"{kind} rollout: u_seq must have shape (T, {m}), got {u.shape}")
    return hist, qd, u


def _check_hold(input_hold):
    if input_hold not in ("constant", "linear"):
        raise UserError(f"input_hold must be 'constant' or 'linear', got {input_hold!r}")


@dataclass(frozen=True, eq=False)
class ARX:
    """q_{k+1} = Σ_i A[i] q_{k-i} + B u_k + c at step ``dt`` (A: (p, n, n), B: (n, m), c: (n,))."""

    A: np.ndarray
    B: np.ndarray
    c: np.ndarray
    dt: float
    q_low: np.ndarray
    q_high: np.ndarray
    info: dict = field(default_factory=dict)
    kind = "arx"

    n = property(lambda self: int(self.A.shape[1]))
    m = property(lambda self: int(self.B.shape[1]))
    order = property(lambda self: int(self.A.shape[0]))

    @classmethod
    def fit(cls, data, traj_ids=None, *, order: int = 1, ridge: float = RIDGE) -> ARX:
        return fit_arx(data, traj_ids, order=order, ridge=ridge)

    def rollout(self, q0_or_history, qd0, u_seq, dt, *, input_hold: str = "constant"):
        """q (T, n) from q0 (n,) or the last r <= p samples (r, n), oldest first, under inputs
        u_seq (T, m); missing earlier samples are extrapolated back along q̇0 (None: at rest).
        The model is discrete: ``input_hold`` is accepted for a common interface and unused;
        ``dt`` must be the step it was fitted at."""
        _check_hold(input_hold)
        hist, qd, u = _start("arx", self.n, self.m, q0_or_history, qd0, u_seq)
        h = _steps(dt, u.shape[0])
        if h.size and np.max(np.abs(h - self.dt)) > STEP_RTOL * self.dt:
            raise UserError(f"arx rollout: the model was fitted at step {self.dt:.6g} s, "
                            f"asked for steps {h.min():.6g}..{h.max():.6g} s")
        p, T = self.order, u.shape[0]
        back = [hist[0] - j * self.dt * qd for j in range(p - hist.shape[0], 0, -1)]
        past = [*back, *hist[-p:]]
        out = np.empty((T, self.n))
        out[0] = past[-1]
        drive = u[:-1] @ self.B.T + self.c
        with np.errstate(over="ignore", invalid="ignore"):
            for k in range(T - 1):
                nxt = drive[k] + sum(self.A[i] @ past[-1 - i] for i in range(p))
                out[k + 1] = nxt
                past = [*past[1:], nxt]
        return out

    def to_dict(self) -> dict:
        return {"kind": self.kind, "format": FORMAT, "n": self.n, "m": self.m,
                "order": self.order, "dt": self.dt, "A": self.A.tolist(), "B": self.B.tolist(),
                "c": self.c.tolist(), "q_low": self.q_low.tolist(),
                "q_high": self.q_high.tolist(), "info": dict(self.info)}

    @classmethod
    def from_dict(cls, d: Mapping) -> ARX:
        n, m, p = (_int(d, k, "arx") for k in ("n", "m", "order"))
        dt = d.get("dt")
        if isinstance(dt, bool) or not isinstance(dt, int | float) or not dt > 0:
            raise UserError(f"baseline arx: 'dt' must be a positive number, got {dt!r}")
        g = lambda key, shape: checked_array(d, key, shape, "baseline arx")  # noqa: E731
        return cls(g("A", (p, n, n)), g("B", (n, m)), g("c", (n,)), float(dt),
                   g("q_low", (n,)), g("q_high", (n,)), dict(d.get("info", {})))


@dataclass(frozen=True, eq=False)
class LinearSecondOrder:
    """q̈ = A_q q + A_v q̇ + B_u u + c (M = I; see :meth:`matrices`), integrated by the exact
    matrix exponential (``integrator="expm"``) or RK4 at the given step (``"rk4"``)."""

    A_q: np.ndarray
    A_v: np.ndarray
    B_u: np.ndarray
    c: np.ndarray
    q_low: np.ndarray
    q_high: np.ndarray
    integrator: str = "expm"
    info: dict = field(default_factory=dict)
    kind = "linear2"

    n = property(lambda self: int(self.A_q.shape[0]))
    m = property(lambda self: int(self.B_u.shape[1]))

    def __post_init__(self):
        if self.integrator not in ("expm", "rk4"):
            raise UserError(f"linear2 integrator must be 'expm' or 'rk4', got {self.integrator!r}")

    @classmethod
    def fit(cls, data, traj_ids=None, *, ridge: float = RIDGE,
            integrator: str = "expm") -> LinearSecondOrder:
        return fit_linear_second_order(data, traj_ids, ridge=ridge, integrator=integrator)

    def matrices(self) -> dict[str, np.ndarray]:
        """M, D, K, B, c of M q̈ + D q̇ + K q = B u + c with M = I (the unidentifiable scale)."""
        return {"M": np.eye(self.n), "D": -self.A_v, "K": -self.A_q, "B": self.B_u, "c": self.c}

    def _field(self) -> tuple[np.ndarray, np.ndarray]:
        """F (2n, 2n), G (2n, m + 1): ẋ = F x + G [u; 1] for x = (q, q̇)."""
        n, m = self.n, self.m
        F = np.block([[np.zeros((n, n)), np.eye(n)], [self.A_q, self.A_v]])
        G = np.vstack([np.zeros((n, m + 1)), np.hstack([self.B_u, self.c[:, None]])])
        return F, G

    def _propagator(self, F, G, h: float, hold: str):
        """(Φ, Γ0, Γ1): x⁺ = Φ x + Γ0 [u0; 1] + Γ1 (u1 - u0), exact for the hold over h."""
        N, m = F.shape[0], self.m
        if self.integrator == "expm":
            big = np.zeros((N + 2 * m + 1, N + 2 * m + 1))  # (x, w = u(s), v = u̇, 1)
            big[:N, :N], big[:N, N:N + m], big[:N, -1] = F, G[:, :m], G[:, m]
            if hold == "linear":
                big[N:N + m, N + m:N + 2 * m] = np.eye(m)
            E = scipy.linalg.expm(big * h)
            G0 = np.hstack([E[:N, N:N + m], E[:N, -1:]])
            return E[:N, :N], G0, E[:N, N + m:N + 2 * m] / h
        # RK4 on the linear field is a polynomial in F h: Φ = Σ (F h)^j / j!, j <= 4
        P = [np.eye(N)]
        for j in range(1, 5):
            P.append(P[-1] @ F * (h / j))
        Phi = sum(P)
        S = sum(P[:4][j] * (h / (j + 1)) for j in range(4))  # ∫ for a constant input
        G0 = S @ G
        if hold == "constant":
            return Phi, G0, np.zeros((N, m))
        # RK4 with u(s) = u0 + (u1 - u0) s/h: stages at s = 0, h/2, h/2, h
        Fh, B = F * h, G[:, :m]
        k2 = 0.5 * B
        k3 = 0.5 * B + 0.5 * Fh @ k2
        k4 = B + Fh @ k3
        return Phi, G0, (h / 6.0) * (2 * k2 + 2 * k3 + k4)

    def rollout(self, q0_or_history, qd0, u_seq, dt, *, input_hold: str = "constant"):
        """q (T, n) from (q0, q̇0) (a history (r, n) gives q0 = its last row; q̇0 None: at rest)
        under inputs u_seq (T, m) over steps ``dt`` (a number or (T - 1,))."""
        _check_hold(input_hold)
        hist, qd, u = _start("linear2", self.n, self.m, q0_or_history, qd0, u_seq)
        h = _steps(dt, u.shape[0])
        F, G = self._field()
        cache, ones, x = {}, np.ones(1), np.concatenate([hist[-1], qd])
        out = np.empty((u.shape[0], self.n))
        out[0] = x[:self.n]
        with np.errstate(over="ignore", invalid="ignore"):
            for k in range(u.shape[0] - 1):
                key = round(float(h[k]), 15)
                if key not in cache:
                    cache[key] = self._propagator(F, G, float(h[k]), input_hold)
                Phi, G0, G1 = cache[key]
                x = Phi @ x + G0 @ np.concatenate([u[k], ones]) + G1 @ (u[k + 1] - u[k])
                out[k + 1] = x[:self.n]
        return out

    def to_dict(self) -> dict:
        return {"kind": self.kind, "format": FORMAT, "n": self.n, "m": self.m,
                "A_q": self.A_q.tolist(), "A_v": self.A_v.tolist(), "B_u": self.B_u.tolist(),
                "c": self.c.tolist(), "q_low": self.q_low.tolist(),
                "q_high": self.q_high.tolist(), "integrator": self.integrator,
                "info": dict(self.info)}

    @classmethod
    def from_dict(cls, d: Mapping) -> LinearSecondOrder:
        n, m = (_int(d, k, cls.kind) for k in ("n", "m"))
        g = lambda key, shape: checked_array(d, key, shape, f"baseline {cls.kind}")  # noqa: E731
        return cls(g("A_q", (n, n)), g("A_v", (n, n)), g("B_u", (n, m)), g("c", (n,)),
                   g("q_low", (n,)), g("q_high", (n,)), str(d.get("integrator", "expm")),
                   dict(d.get("info", {})))


@dataclass(frozen=True, eq=False)
class NoMotion:
    """q̂(t) = q(t0): the first state held."""

    n: int
    m: int
    q_low: np.ndarray
    q_high: np.ndarray
    info: dict = field(default_factory=dict)
    kind = "no_motion"

    @classmethod
    def fit(cls, data, traj_ids=None) -> NoMotion:
        segs = trajectory_arrays(data, traj_ids)
        return cls(segs[0]["q"].shape[1], segs[0]["u"].shape[1], *_range(segs),
                   {"trajectories": [s["id"] for s in segs]})

    def rollout(self, q0_or_history, qd0, u_seq, dt, *, input_hold: str = "constant"):
        """q (T, n): q0 (the last row of a history) at every sample."""
        _check_hold(input_hold)
        hist, _qd, u = _start("no_motion", self.n, self.m, q0_or_history, qd0, u_seq)
        _steps(dt, u.shape[0])
        return np.repeat(hist[-1:], u.shape[0], axis=0)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "format": FORMAT, "n": self.n, "m": self.m,
                "q_low": self.q_low.tolist(), "q_high": self.q_high.tolist(),
                "info": dict(self.info)}

    @classmethod
    def from_dict(cls, d: Mapping) -> NoMotion:
        n, m = (_int(d, k, "no_motion") for k in ("n", "m"))
        g = lambda key: checked_array(d, key, (n,), "baseline no_motion")  # noqa: E731
        return cls(n, m, g("q_low"), g("q_high"), dict(d.get("info", {})))


def _int(d: Mapping, key: str, kind: str) -> int:
    v = d.get(key) if isinstance(d, Mapping) else None
    if isinstance(v, bool) or not isinstance(v, int) or v < (1 if key in ("n", "order") else 0):
        raise UserError(f"baseline {kind}: '{key}' must be a non-negative integer, got {v!r}")
    return v


def _too_few(kind: str, rows: int, need: int, what: str):
    if rows < need:
        raise UserError(f"{kind}: {rows} {what} to fit {need} coefficients per coordinate; "
                        "give more or longer trajectories")


def fit_arx(trajectories, traj_ids=None, *, order: int = 1, ridge: float = RIDGE) -> ARX:
    """Least-squares ARX of ``order`` (1 or 2) on a :class:`Dataset` (``traj_ids``; None: its
    training trajectories) or trajectory dicts (t, q, u), at their common sample step."""
    if isinstance(order, bool) or order not in (1, 2):
        raise UserError(f"arx order must be 1 or 2, got {order!r}")
    segs = trajectory_arrays(trajectories, traj_ids)
    n, m = segs[0]["q"].shape[1], segs[0]["u"].shape[1]
    steps = np.concatenate([np.diff(s["t"]) for s in segs])
    if steps.size == 0:
        raise UserError("arx: the trajectories hold one sample each; need at least "
                        f"{order + 1} per trajectory")
    dt = float(np.median(steps))
    if not dt > 0 or np.max(np.abs(steps - dt)) > STEP_RTOL * dt:
        raise UserError(f"arx: needs one sample step, the data's steps range over "
                        f"{steps.min():.6g}..{steps.max():.6g} s; fit linear2, which takes any")
    X, Y = [], []
    for s in segs:
        T = s["t"].shape[0]
        if T <= order:
            continue
        lags = [s["q"][order - 1 - i:T - 1 - i] for i in range(order)]
        X.append(np.hstack([*lags, s["u"][order - 1:T - 1]]))
        Y.append(s["q"][order:])
    X, Y = (np.vstack(a) if a else np.zeros((0, 1)) for a in (X, Y))
    rows = X.shape[0]
    _too_few("arx", rows, order * n + m + 1, "sample pairs")
    W, b, rank = _lstsq(X, Y, ridge)
    A = np.stack([W[i * n:(i + 1) * n].T for i in range(order)])
    B = W[order * n:].T.reshape(n, m)
    comp = np.zeros((order * n, order * n))
    comp[:n] = np.hstack(list(A))
    comp[n:, :-n] = np.eye((order - 1) * n)
    info = {"trajectories": [s["id"] for s in segs], "pairs": rows, "ridge": float(ridge),
            "rank": rank, "unknowns": order * n + m + 1,
            "one_step_rms": float(np.sqrt(np.mean((X @ W + b - Y) ** 2))),
            "spectral_radius": float(np.max(np.abs(np.linalg.eigvals(comp))))}
    return ARX(A, B, b, dt, *_range(segs), info)


def fit_linear_second_order(trajectories, traj_ids=None, *, ridge: float = RIDGE,
                            integrator: str = "expm") -> LinearSecondOrder:
    """Least-squares q̈ = A_q q + A_v q̇ + B_u u + c on every sample of a :class:`Dataset`
    (``traj_ids``; None: its training trajectories) or trajectory dicts (t, q, qd, qdd, u)."""
    segs = trajectory_arrays(trajectories, traj_ids, need=("t", "q", "qd", "qdd", "u"))
    n, m = segs[0]["q"].shape[1], segs[0]["u"].shape[1]
    X = np.vstack([np.hstack([s["q"], s["qd"], s["u"]]) for s in segs])
    Y = np.vstack([s["qdd"] for s in segs])
    _too_few("linear2", X.shape[0], 2 * n + m + 1, "samples")
    W, b, rank = _lstsq(X, Y, ridge)
    A_q, A_v = W[:n].T, W[n:2 * n].T
    F = np.block([[np.zeros((n, n)), np.eye(n)], [A_q, A_v]])
    info = {"trajectories": [s["id"] for s in segs], "samples": int(X.shape[0]),
            "ridge": float(ridge), "rank": rank, "unknowns": 2 * n + m + 1,
            "accel_rms": float(np.sqrt(np.mean((X @ W + b - Y) ** 2))),
            "max_real_eigenvalue": float(np.max(np.linalg.eigvals(F).real))}
    return LinearSecondOrder(A_q, A_v, W[2 * n:].T.reshape(n, m), b, *_range(segs),
                             integrator, info)
