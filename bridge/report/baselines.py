"""The networks beside the baselines they must beat (issue 43): a table of rollout errors at
each horizon, the networks first, then no motion and the linear models
(:mod:`bridge.analysis.baselines`), and one verdict line per network
(:func:`bridge.analysis.baselines.verdict`): does it beat the best linear model and no motion,
at each horizon? A user sees at once whether the physics pays."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from softpinn.bridge.analysis.baselines import (
    BASELINES,
    BaselineComparison,
    BaselineScore,
    verdict,
)
from softpinn.bridge.figures.tables import Span, Table, format_mean_std

#: a network's rollout error by horizon [s]: (mean, std) over test trajectories; a mean of None
#: or inf is a rollout that diverged
Errors = Mapping[float, tuple[float | None, float | None]]

#: what the baselines are, for the reports' sentences
WHAT = ("no motion (q̂(t) = q(t0)), a discrete ARX model of order 2 on q and a linear "
        "second-order model M q̈ + D q̇ + K q = B u + c, each fitted by least squares in closed "
        "form")


def _number(x) -> float:
    return math.inf if x is None else float(x)


def horizons(comparison: BaselineComparison) -> list[float]:
    """The horizons the baselines were scored at, shortest first."""
    out: list[float] = []
    for s in comparison.scores:
        if not any(math.isclose(s.horizon, h) for h in out):
            out.append(s.horizon)
    return sorted(out)


def _at(errors: Errors, horizon: float) -> tuple[float | None, float | None] | None:
    return next((v for h, v in errors.items() if math.isclose(float(h), horizon)), None)


def _cell(mean, std) -> str:
    if mean is None or not math.isfinite(mean):
        return "diverged"
    return format_mean_std(mean, None if std is None or not math.isfinite(std) else std)


def _baseline_cell(score: BaselineScore, tested: int) -> str:
    text = _cell(score.mean, score.std)
    if score.out_of_range:
        text += f" ({len(score.out_of_range)} of {tested} left the training range)"
    return text


def baseline_rows(networks: Mapping[str, Errors], comparison: BaselineComparison,
                  ) -> list[tuple[str, ...]]:
    """One row per network (its name, then its error at each of :func:`horizons`, — where it
    has none there), then one per baseline the comparison holds (a study stored before a
    baseline kind was added lacks its rows)."""
    hs = horizons(comparison)
    rows = []
    for label, errors in networks.items():
        cells = [_at(errors, h) for h in hs]
        rows.append((label, *("—" if c is None else _cell(*c) for c in cells)))
    for name, kind, _ in BASELINES:
        scores = [next((s for s in comparison.at(h) if s.kind == kind), None) for h in hs]
        if all(s is None for s in scores):
            continue
        label = next((s.label for s in scores if s is not None), name)
        rows.append((label, *("—" if s is None else _baseline_cell(s, len(comparison.test))
                              for s in scores)))
    return rows


def baseline_table(networks: Mapping[str, Errors], comparison: BaselineComparison, *,
                   caption: str) -> Table:
    """:func:`baseline_rows` as a table, one column per horizon."""
    spans = [Span("", "model")] + [Span("rollout error over", f"{h:g} s")
                                   for h in horizons(comparison)]
    return Table(tuple(spans), tuple(baseline_rows(networks, comparison)), caption=caption)


def network_verdict(label: str, errors: Errors, comparison: BaselineComparison) -> str:
    """:func:`bridge.analysis.baselines.verdict` of one network at every horizon where both it
    and the baselines were scored (a diverged rollout loses)."""
    at = {}
    for h in horizons(comparison):
        e = _at(errors, h)
        if e is not None:
            at[h] = _number(e[0])
    return verdict(label, at, comparison)


def losses(errors: Errors, comparison: BaselineComparison) -> list[tuple[float, str]]:
    """(horizon, the better baseline's name) wherever the network does not beat both the best
    linear model and no motion (as :func:`bridge.analysis.baselines.verdict` judges)."""
    out = []
    for h in horizons(comparison):
        e = _at(errors, h)
        if e is None:
            continue
        best = comparison.beaten_by(h, _number(e[0]))
        if best is not None:
            out.append((h, best.name))
    return out


def predict_errors(predicted: Mapping[str, Any]) -> dict[float, tuple]:
    """A task's network's rollout errors (its predict stage's result) by horizon: the
    prediction's and the long one's (where the data are shorter than both, one horizon with
    the prediction's numbers)."""
    errors = {}
    for key in ("long_prediction_error", "prediction_error"):  # the prediction's last
        e = predicted[key]
        errors[float(e["horizon_s"])] = (e["mean"], e["std"])
    return errors


def verdict_lines(networks: Mapping[str, Errors], comparison: BaselineComparison) -> list[str]:
    """One Markdown bullet per network: :func:`network_verdict`."""
    return [f"- {network_verdict(label, errors, comparison)}"
            for label, errors in networks.items()]
