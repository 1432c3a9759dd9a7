"""The simplest honest alternatives beside every network (issue 43): "no motion" (hold the first
state) and linear models (discrete ARX on q, order 2; the lagged ARX, with lags of q and u, its
order chosen on a held-out training trajectory: the linear model with memory; the linear
second-order model M q̈ + D q̇ + K q = B u + c by least squares on q̈, and the same fitted by its
rollout error),
fitted on the training trajectories (closed form; the rollout fits in seconds) and scored with
``softpinn predict``'s rollout error on the test trajectories (:mod:`softpinn.learn`'s
baselines). A network is worth training where it beats them; :func:`verdict` says in one line
whether it does, at each horizon.

The task and experiment reports and the studies print :meth:`BaselineComparison.to_json` and
:func:`verdict`. The one file written here is :func:`fit_baselines`' cache of the fitted models
(``predict`` keeps it in the run's folder): the lagged ARX and the rollout fit take seconds to a
quarter of a minute, and a user who predicts several times on the same run fits them once.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softpinn._version import __version__
from softpinn.errors import UserError
from softpinn.files import atomic_write, json_text
from softpinn.learn import Dataset, baseline_from_dict, baseline_rollout_errors, fit_baseline

#: the baselines fitted, with their fitting options, in the order they are shown
BASELINES: tuple[tuple[str, str, dict], ...] = (
    ("no motion", "no_motion", {}),
    ("ARX (order 2)", "arx", {"order": 2}),
    ("lagged ARX", "arx_lags", {}),
    ("linear 2nd order", "linear2", {}),
    ("linear 2nd order, rollout fit", "linear2_rollout", {}),
)
#: the kinds that count as "the best linear model"
LINEAR = ("ARX (order 2)", "lagged ARX", "linear 2nd order",
          "linear 2nd order, rollout fit")


def fit_options(kind: str, options: dict, input_hold: str) -> dict:
    """A baseline's fitting options for rollouts under ``input_hold``: the rollout fit
    simulates its windows as predict will (the other fits do not simulate)."""
    return {**options, "input_hold": input_hold} if kind == "linear2_rollout" else dict(options)


@dataclass(frozen=True)
class BaselineScore:
    """One baseline's rollout error at one horizon (predict's metric: mean over test
    trajectories of the mean over samples of ‖q - q̂‖²)."""

    name: str
    kind: str
    horizon: float
    mean: float  # inf where a rollout is not finite
    std: float
    out_of_range: tuple[int, ...]  # test trajectories whose rollout left the training range
    detail: str = ""  # what the fit chose (the lagged ARX: "order 6, least squares")

    @property
    def label(self) -> str:
        """The name, with what the fit chose where it says (tables and predict's lines)."""
        return f"{self.name} ({self.detail})" if self.detail else self.name

    def to_json(self) -> dict:
        finite = lambda x: x if math.isfinite(x) else None  # strict JSON: inf -> null
        out = {"name": self.name, "kind": self.kind, "horizon": self.horizon,
               "mean": finite(self.mean), "std": finite(self.std),
               "out_of_range": list(self.out_of_range)}
        return {**out, "detail": self.detail} if self.detail else out


@dataclass(frozen=True)
class BaselineComparison:
    """Every baseline at every horizon, fitted on ``train`` and scored on ``test``."""

    train: tuple[int, ...]
    test: tuple[int, ...]
    scores: tuple[BaselineScore, ...]

    def at(self, horizon: float) -> tuple[BaselineScore, ...]:
        return tuple(s for s in self.scores if math.isclose(s.horizon, horizon))

    def no_motion(self, horizon: float) -> BaselineScore:
        return next(s for s in self.at(horizon) if s.kind == "no_motion")

    def best_linear(self, horizon: float) -> BaselineScore:
        """The linear model with the smallest error at ``horizon`` (out-of-range rollouts
        count with their error, which is what a user of that model would get)."""
        return min((s for s in self.at(horizon) if s.name in LINEAR), key=lambda s: s.mean)

    def beaten_by(self, horizon: float, error: float) -> BaselineScore | None:
        """None where a model with rollout ``error`` at ``horizon`` beats both the best linear
        model and no motion; else the better of those two, which it loses to (a rollout that
        is not finite loses)."""
        lin, still = self.best_linear(horizon), self.no_motion(horizon)
        if math.isfinite(error) and error < lin.mean and error < still.mean:
            return None
        return min((lin, still), key=lambda s: s.mean)

    def to_json(self) -> dict:
        return {"train_trajectories": list(self.train), "test_trajectories": list(self.test),
                "scores": [s.to_json() for s in self.scores]}

    @classmethod
    def from_json(cls, d: Mapping) -> BaselineComparison:
        """What :meth:`to_json` wrote (a stage's result); a null error (a rollout that was not
        finite) is inf again."""
        number = lambda x: math.inf if x is None else float(x)
        scores = tuple(BaselineScore(str(s["name"]), str(s["kind"]), float(s["horizon"]),
                                     number(s["mean"]), number(s["std"]),
                                     tuple(int(i) for i in s["out_of_range"]),
                                     str(s.get("detail", "")))
                       for s in d["scores"])
        return cls(tuple(int(i) for i in d["train_trajectories"]),
                   tuple(int(i) for i in d["test_trajectories"]), scores)


def _fit_key(data: Dataset, train: Sequence[int], input_hold: str) -> str:
    """What a fit depends on: the training rows as the models see them (after the run's
    actuator), the fitting options and softpinn's version."""
    h = hashlib.sha256()
    for i in train:
        rows = data.indices(int(i))
        for a in (data.t, data.q, data.qd, data.u):
            h.update(np.ascontiguousarray(a[rows], dtype=np.float64).tobytes())
        h.update(f"|{int(i)}:{rows.size}|".encode())
    h.update(json.dumps([BASELINES, input_hold, __version__], sort_keys=True).encode())
    return h.hexdigest()


def fit_baselines(data: Dataset, train: Sequence[int], *, input_hold: str = "constant",
                  cache: str | Path | None = None) -> list[tuple[str, object]]:
    """Every baseline of :data:`BASELINES` fitted on the ``train`` trajectories of ``data``:
    (name, model) pairs. ``cache``: a JSON file that keeps the fits; they are read back from it
    where it holds the fits of the same training rows, options and softpinn version, else fitted
    and written there (a cache that cannot be read or written is passed over)."""
    train = [int(i) for i in train]
    models = lambda: [(name, fit_baseline(kind, data, train,  # noqa: E731
                                          **fit_options(kind, options, input_hold)))
                      for name, kind, options in BASELINES]
    if cache is None:
        return models()
    key = _fit_key(data, train, input_hold)
    try:
        doc = json.loads(Path(cache).read_text())
        if doc.get("key") == key:
            return [(str(e["name"]), baseline_from_dict(e["model"])) for e in doc["models"]]
    except (OSError, ValueError, KeyError, TypeError, AttributeError, UserError):
        pass
    # as read back (arrays laid out alike): the first call scores to the bit as the next
    fitted = [(name, baseline_from_dict(m.to_dict())) for name, m in models()]
    doc = {"key": key, "train_trajectories": train, "input_hold": input_hold,
           "softpinn": __version__,
           "models": [{"name": name, "model": m.to_dict()} for name, m in fitted]}
    try:
        atomic_write(cache, json_text(doc))
    except OSError:
        pass
    return fitted


def compare_baselines(data: Dataset, train: Sequence[int], test: Sequence[int],
                      horizons: Sequence[float], *, reset_every: float | None = None,
                      input_hold: str = "constant",
                      cache: str | Path | None = None) -> BaselineComparison:
    """Fit every baseline of :data:`BASELINES` on the ``train`` trajectories of ``data``
    (:func:`fit_baselines`, ``cache`` as there) and score it on the ``test`` trajectories at
    each horizon (seconds). Closed form and rollout fits: seconds."""
    if not horizons:
        raise UserError("horizon: expected at least one horizon")
    models = fit_baselines(data, train, input_hold=input_hold, cache=cache)
    return score_models(models, data, train, test, horizons, reset_every=reset_every,
                        input_hold=input_hold)


def score_models(models, data, train: Sequence[int], test: Sequence[int],
                 horizons: Sequence[float], *, reset_every: float | None = None,
                 input_hold: str = "constant") -> BaselineComparison:
    """Fitted baselines ``models`` ((name, model) pairs, fitted on ``train``) scored at each
    horizon on the ``test`` trajectories of ``data`` with predict's rollout error; a model
    that says what its fit chose (``describe()``) has it in its scores' ``detail``."""
    train, test = tuple(int(i) for i in train), tuple(int(i) for i in test)
    scores = []
    for name, model in models:
        detail = model.describe() if hasattr(model, "describe") else ""
        for h in horizons:
            res = baseline_rollout_errors(model, data, float(h), traj_ids=list(test),
                                          reset_every=reset_every, input_hold=input_hold)
            scores.append(BaselineScore(name, model.kind, float(h),
                                        float(res.rollout_error_mean),
                                        float(res.rollout_error_std),
                                        tuple(int(i) for i in res.out_of_range), detail))
    return BaselineComparison(train, test, tuple(scores))


def _ratio(a: float, b: float) -> str:
    if not (math.isfinite(a) and math.isfinite(b)) or b <= 0:
        return "diverged" if not math.isfinite(a) else "-"
    r = a / b
    # three significant digits, trailing zeros kept below 100: 1.004 reads 1.00x, not 1x
    text = f"{r:#.3g}" if 1e-3 <= r < 100 else f"{r:.3g}"
    return f"{text}x" + (" (within 1 %: a tie)" if 1 / 1.01 < r < 1.01 else "")


def verdict(model: str, errors: Mapping[float, float], comparison: BaselineComparison) -> str:
    """One line: does ``model`` (its rollout error at each horizon, predict's metric) beat the
    best linear model and no motion at each horizon, and by how much it misses where not."""
    parts = []
    for h, err in sorted(errors.items()):
        lin, still = comparison.best_linear(h), comparison.no_motion(h)
        best = comparison.beaten_by(h, err)
        if best is None:
            parts.append(f"at {h:g} s beats the best linear model ({lin.name}) by "
                         f"{_ratio(lin.mean, err)} and no motion by {_ratio(still.mean, err)}")
        elif not math.isfinite(err):
            parts.append(f"at {h:g} s LOSES: its rollout diverged ({best.name}: "
                         f"{best.mean:.3g})")
        else:
            parts.append(f"at {h:g} s LOSES to {best.name} (its error is "
                         f"{_ratio(err, best.mean)} {best.name}'s)")
    return f"{model}: " + "; ".join(parts)
