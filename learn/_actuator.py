"""The actuator of a run (:mod:`softpinn.actuator`, issue 43 item 2): resolved once when training
starts, recorded in the run's config as numbers, applied to the inputs of every dataset the run
trains or predicts on.

``TrainConfig.actuator`` (``softpinn train --actuator``):

- ``TAU:DELAY`` or ``none``: as given;
- ``data``: the dataset's ``meta["actuator"]`` (written by ``simulate``/``import`` from a spec's
  ``[actuator]`` table), else none;
- ``identify``: fitted to the training trajectories (:func:`identify_actuator`);
- ``auto`` (the default): ``data`` where the file has an actuator; ``identify`` on recordings of
  ``softpinn import`` (a real arm's commands reach it late); none on other simulated data.

:func:`identify_actuator` is a grid search, not a gradient: for each candidate (lag, dead time)
the least-squares ARX model (order 2, as :func:`learn._baselines.fit_arx`) is fitted to the
training trajectories under the filtered inputs and scored by its rollout error over windows of
:data:`WINDOW_S` seconds (predict's metric). A common (τ, d) is found first (every other dead time,
then those beside the best), then each input's pair in turn near it, the others fixed. It keeps
none unless the best candidate lowers the score by :data:`MIN_GAIN` or more: recorded actuator
outputs (pressures, tensions) need none.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from softpinn.actuator import Actuator
from softpinn.errors import UserError
from softpinn.learn._data import Dataset

#: the values of ``TrainConfig.actuator`` that are resolved from the data
RESOLVED_FROM_DATA = ("auto", "data", "identify")
#: the rollout windows the identification scores [s]
WINDOW_S = 2.0
#: the longest dead time and lag searched [s]
MAX_DELAY_S, MAX_TAU_S = 0.5, 1.0
#: the factor by which the best actuator must lower the linear model's error to be kept
MIN_GAIN = 1.25


def check_actuator_setting(value, m: int) -> None:
    """Refuse a ``TrainConfig.actuator`` that is neither a keyword nor ``TAU:DELAY``."""
    if not isinstance(value, str):
        raise UserError(f"actuator: expected auto, data, identify, none or TAU:DELAY, got "
                        f"{value!r}")
    if value not in RESOLVED_FROM_DATA:
        Actuator.parse(value, m)


def run_actuator(value: str, m: int) -> Actuator:
    """The actuator a trained run applies: its config's resolved ``TAU:DELAY`` (a run written
    before actuators existed stores the default ``auto`` unresolved: none)."""
    if value in RESOLVED_FROM_DATA:
        return Actuator(source="none")
    return Actuator.parse(value, m)


def with_actuator(data: Dataset, actuator: Actuator) -> Dataset:
    """``data`` with u replaced by the actuator's output (the same file, path and sha256)."""
    if actuator.is_identity:
        return data
    return dataclasses.replace(data, u=actuator.apply_trajectories(data.t, data.u, data.traj))


def resolve_actuator(value: str, data: Dataset, train_ids) -> tuple[Actuator, str | None]:
    """The actuator of ``TrainConfig.actuator`` ``value`` on ``data`` (the module's doc), and a
    note that says what was chosen and why (None where nothing was chosen for the user)."""
    meta = data.meta.get("actuator")
    if value == "auto":
        if meta:
            value = "data"
        elif data.meta.get("source") == "import":
            try:  # the default: data too short to identify from train without one, and say so
                return resolve_actuator("identify", data, train_ids)
            except UserError as exc:
                return Actuator(source="none"), (f"actuator: none ({exc}; --actuator auto "
                                                 "goes on without one)")
        else:
            return Actuator(source="none"), None
    if value == "data":
        if not meta:
            return Actuator(source="none"), (f"actuator: {data.path} records none; the inputs "
                                             "reach the arm as recorded")
        act = Actuator.from_dict(meta, data.m, source="data")
        return act, f"actuator: {act.describe()}, from the dataset's metadata"
    if value == "identify":
        act, report = identify_actuator(data, train_ids)
        return act, f"actuator: {act.describe()}; {report}"
    return Actuator.parse(value, data.m), None


# --------------------------------------------------------------------------------------------
# Identification


def _segments(data: Dataset, ids) -> list[dict]:
    out = []
    for tid in np.asarray(ids).tolist():
        rows = data.indices(int(tid))
        if rows.size:
            out.append({"id": int(tid), "t": data.t[rows], "q": data.q[rows],
                        "u": data.u[rows]})
    return out


def _fit_arx2(segs: list[dict], us: list[np.ndarray]):
    """Least-squares q_{k+1} = A0 q_k + A1 q_{k-1} + B y_k + c (ARX of order 2, as
    :func:`learn._baselines.fit_arx`) by the normal equations on standardised columns with a
    tiny ridge: the search fits hundreds of candidates."""
    X = np.vstack([np.hstack([s["q"][1:-1], s["q"][:-2], u[1:-1]]) for s, u in zip(segs, us,
                                                                               strict=True)])
    Y = np.vstack([s["q"][2:] for s in segs])
    mu, sd = X.mean(0), X.std(0)
    sd[sd == 0] = 1.0
    Z = (X - mu) / sd
    G = Z.T @ Z
    G[np.diag_indices_from(G)] += 1e-10 * max(1.0, float(np.trace(G)) / len(G))
    try:
        W = np.linalg.solve(G, Z.T @ (Y - Y.mean(0))) / sd[:, None]
    except np.linalg.LinAlgError:
        return None
    n = Y.shape[1]
    c = Y.mean(0) - mu @ W
    return W[:n].T, W[n:2 * n].T, W[2 * n:].T, c


def _window_error(fit, segs: list[dict], us: list[np.ndarray], steps: int) -> float:
    """The ARX's mean rollout error over consecutive windows of ``steps`` samples of every
    trajectory, each started from its two true first samples (all windows at once)."""
    A0, A1, B, c = fit
    q0s, q1s, drives, truths = [], [], [], []
    for s, u in zip(segs, us, strict=True):
        T = len(s["t"])
        for a in range(0, T - steps, steps):
            q0s.append(s["q"][a])
            q1s.append(s["q"][a + 1])
            drives.append(u[a + 1:a + steps] @ B.T + c)
            truths.append(s["q"][a + 2:a + steps + 1])
    if not q0s:
        return math.inf
    prev, cur = np.array(q0s), np.array(q1s)
    drive, truth = np.stack(drives), np.stack(truths)  # (W, steps - 1, n)
    total = 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(steps - 1):
            prev, cur = cur, cur @ A0.T + prev @ A1.T + drive[:, k]
            d = cur - truth[:, k]
            total += float(np.sum(d * d))
    err = total / (drive.shape[0] * (steps - 1))
    return err if math.isfinite(err) else math.inf


def _score(segs, tau, delay, steps) -> float:
    act = Actuator(tuple(tau), tuple(delay))
    us = [act.apply(s["t"], s["u"]) for s in segs]
    fit = _fit_arx2(segs, us)
    return math.inf if fit is None else _window_error(fit, segs, us, steps)


def _grids(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Dead times on the sample grid up to :data:`MAX_DELAY_S`; lags 0 and geometric from one
    sample step to :data:`MAX_TAU_S`."""
    delays = dt * np.arange(0, int(round(MAX_DELAY_S / dt)) + 1)
    taus = np.concatenate([[0.0], np.geomspace(dt, MAX_TAU_S, 12)])
    return delays, taus


def _near(grid: np.ndarray, value: float, k: int) -> np.ndarray:
    """The ``2 k + 1`` grid points around the one nearest ``value``."""
    i = int(np.argmin(np.abs(grid - value)))
    return grid[max(0, i - k):i + k + 1]


def identify_actuator(data: Dataset, train_ids) -> tuple[Actuator, str]:
    """The lag and dead time per input that best explain the training trajectories through the
    linear model (the module's doc), and one line on what it gained."""
    segs = _segments(data, train_ids)
    if not segs:
        raise UserError("actuator identify: no training trajectories")
    dt = float(np.median(np.concatenate([np.diff(s["t"]) for s in segs])))
    steps = max(3, int(round(WINDOW_S / dt)))
    if max(len(s["t"]) for s in segs) <= steps + 1:
        raise UserError(f"actuator identify: the training trajectories are shorter than "
                        f"{WINDOW_S:g} s; give --actuator TAU:DELAY or none")
    m = data.m
    delays, taus = _grids(dt)
    base = _score(segs, [0.0] * m, [0.0] * m, steps)
    best = (base, 0.0, 0.0)
    # every other dead time first, then the ones beside the best
    for d in delays[::2]:
        for tau in taus:
            e = _score(segs, [tau] * m, [d] * m, steps)
            if e < best[0]:
                best = (e, float(tau), float(d))
    for d in _near(delays, best[2], 1):
        for tau in _near(taus, best[1], 1):
            e = _score(segs, [tau] * m, [d] * m, steps)
            if e < best[0]:
                best = (e, float(tau), float(d))
    err, tau0, d0 = best
    tau, delay = [tau0] * m, [d0] * m
    if m > 1 and err < base:
        for j in range(m):  # each input in turn near the common values, the others fixed
            for d in _near(delays, d0, 2):
                for t in _near(taus, tau0, 2):
                    trial_tau, trial_d = list(tau), list(delay)
                    trial_tau[j], trial_d[j] = float(t), float(d)
                    e = _score(segs, trial_tau, trial_d, steps)
                    if e < err:
                        err, tau, delay = e, trial_tau, trial_d
    gain = base / err if err > 0 else math.inf
    where = (f"identified on {len(segs)} training trajectories: the linear model's "
             f"{WINDOW_S:g} s rollout error {err:.3g} with it, {base:.3g} without")
    if not gain >= MIN_GAIN:
        return Actuator(source="identified"), (
            f"{where} (less than {MIN_GAIN:g}x better: none kept)")
    rounded = lambda v: tuple(float(f"{x:.4g}") for x in v)
    uniform = lambda v: rounded(v[:1]) if len(set(v)) == 1 else rounded(v)
    return (Actuator(uniform(tau), uniform(delay), source="identified"),
            f"{where} ({gain:.3g}x better)")
