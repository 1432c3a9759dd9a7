"""Rollout errors of the baselines (:mod:`learn._baselines`) in ``softpinn predict``'s terms.

The metric is predict's (:func:`learn._predict.rollouts`): each trajectory simulated from its
true start (q0, q̇0) under its true inputs over the horizon (samples with t - t0 <= horizon),
optionally re-set to the truth every S seconds, its error the mean over its samples after t0 of
‖q - q̂‖² (the q part of eq. 8), inf where not finite; reported per trajectory and as mean and
std over trajectories. predict's own horizon check and reset grid are used, so that the two
numbers cannot drift apart. A rollout that leaves the training data's range is flagged, never
a silent number (issue 43).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from softpinn.errors import UserError
from softpinn.learn._data import Dataset, trajectories
from softpinn.learn._predict import _reset_mask, check_rollout_request
from softpinn.learn._trajectories import trajectory_arrays

__all__ = ["BaselineErrors", "RANGE_MARGIN", "range_box", "rollout_errors"]

#: A rollout is out of range where q̂ leaves the training data's box widened on each side by
#: this fraction of the box's width per coordinate.
RANGE_MARGIN = 0.5


def range_box(q_low, q_high, margin: float = RANGE_MARGIN, xp=np):
    """(low, high): the box of the training data's q widened on each side by ``margin`` of its
    width per coordinate (a coordinate that does not vary gets a sliver of the widest one). A
    rollout outside it has left the data's range. ``xp``: ``numpy``, or ``jax.numpy`` where
    the box is traced (the training programs)."""
    q_low, q_high = xp.asarray(q_low), xp.asarray(q_high)
    width = q_high - q_low
    pad = margin * xp.maximum(width, xp.maximum(1e-6 * xp.max(width), 1e-12))
    return q_low - pad, q_high + pad


@dataclass
class BaselineErrors:
    """Rollout errors of one baseline at one horizon, in predict's terms (:meth:`to_json`)."""

    kind: str
    horizon: float
    reset_every: float | None
    trajectories: list[int]
    rollout_errors: list[float]  # per trajectory; inf where the rollout is not finite
    out_of_range: list[int]  # ids of trajectories whose rollout left the training data's range
    rollouts: list[dict] = field(repr=False)  # per trajectory: id, t, q_true, q_pred, error, ...

    @property
    def rollout_error_mean(self) -> float:
        with np.errstate(invalid="ignore", over="ignore"):
            return float(np.mean(self.rollout_errors))

    @property
    def rollout_error_std(self) -> float:
        with np.errstate(invalid="ignore", over="ignore"):
            return float(np.std(self.rollout_errors))

    @property
    def diverged(self) -> int:
        return int(sum(not math.isfinite(e) for e in self.rollout_errors))

    def to_json(self) -> dict:
        clean = lambda x: float(x) if math.isfinite(x) else None
        return {"model": self.kind, "rollout_error_mean": clean(self.rollout_error_mean),
                "rollout_error_std": clean(self.rollout_error_std),
                "rollout_errors": [clean(e) for e in self.rollout_errors],
                "rollout_diverged": self.diverged,
                "rollout_out_of_range": len(self.out_of_range),
                "out_of_range_trajectories": list(self.out_of_range),
                "horizon": self.horizon, "reset_every": self.reset_every, "dt": None,
                "trajectories": list(self.trajectories)}


def rollout_errors(baseline, trajs, horizon_s: float, *, traj_ids=None,
                   reset_every: float | None = None, input_hold: str = "constant",
                   margin: float = RANGE_MARGIN) -> BaselineErrors:
    """predict's rollout error of ``baseline`` on ``trajs`` (dicts from
    :func:`learn.trajectories`, or a :class:`Dataset` with ``traj_ids``, None: all): each
    trajectory from its true start (q0, q̇0) under its true inputs over ``horizon_s`` seconds,
    re-set to the truth every ``reset_every`` seconds, error the mean over its samples after
    t0 of ‖q - q̂‖². A rollout is out of range where q̂ leaves the training box widened by
    ``margin`` of its width on each side (or is not finite)."""
    if isinstance(trajs, Dataset):
        trajs = trajectories(trajs, trajs.trajectory_ids if traj_ids is None else traj_ids)
    segs = trajectory_arrays(trajs, need=("t", "q", "qd", "u"))
    for what, v in (("horizon", horizon_s), ("reset_every", reset_every)):
        if (v is not None or what == "horizon") and (isinstance(v, bool) or not isinstance(
                v, int | float) or not math.isfinite(v) or v <= 0):
            raise UserError(f"{what}: expected a positive number of seconds, got {v!r}")
    n, m = segs[0]["q"].shape[1], segs[0]["u"].shape[1]
    if (n, m) != (baseline.n, baseline.m):
        raise UserError(f"the {baseline.kind} baseline has n={baseline.n}, m={baseline.m}; "
                        f"the trajectories have n={n}, m={m}")
    check_rollout_request(segs, horizon=float(horizon_s), dt=None, n=n, m=m, itemsize=8)
    lo, hi = range_box(baseline.q_low, baseline.q_high, margin)
    errors, outside, rolls = [], [], []
    for s in segs:
        t = s["t"]
        keep = t - t[0] <= horizon_s * (1 + 1e-12) + 1e-12
        t, q, qd, u = t[keep], s["q"][keep], s["qd"][keep], s["u"][keep]
        if t.size < 2:
            raise UserError(f"horizon: {horizon_s} s is shorter than the first step of "
                            f"trajectory {s['id']}")
        mask = _reset_mask(t, t[0], reset_every)
        starts = [0, *np.flatnonzero(mask).tolist(), t.size - 1]
        q_pred = np.empty_like(q)
        order = getattr(baseline, "order", 1)
        lags = getattr(baseline, "input_lags", 0)  # a model that takes the inputs' past
        for a, b in zip(starts[:-1], starts[1:], strict=True):
            past = {"u_past": u[max(0, a - lags + 1):a]} if lags else {}
            q_pred[a:b + 1] = baseline.rollout(q[max(0, a - order + 1):a + 1], qd[a],
                                               u[a:b + 1], np.diff(t[a:b + 1]),
                                               input_hold=input_hold, **past)
        d = q_pred[1:] - q[1:]
        with np.errstate(over="ignore", invalid="ignore"):
            err = float(np.mean(np.sum(d * d, axis=1)))
            out = not np.all((q_pred >= lo) & (q_pred <= hi))
        err = err if math.isfinite(err) else float("inf")
        errors.append(err)
        if out:
            outside.append(s["id"])
        rolls.append({"id": s["id"], "t": t, "q_true": q, "q_pred": q_pred, "error": err,
                      "resets": t[mask], "out_of_range": out})
    return BaselineErrors(baseline.kind, float(horizon_s), reset_every,
                          [s["id"] for s in segs], errors, outside, rolls)
