"""The experiment report's section on the baselines (issue 43): its networks beside no motion and
the linear models on the same imported bending coordinates, against the processed
measurement, over the horizon without reset and over the whole test trajectories with resets
(:func:`bridge.tasks.experiment_stages.stage_baselines`), at every sensor rate and
preprocessing; one verdict line per network and preprocessing at the paper's rate."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from softpinn.bridge.analysis.baselines import BASELINES, BaselineComparison
from softpinn.bridge.figures.experiment import KINDS, UNIT
from softpinn.bridge.figures.tables import Span, Table, to_markdown, write_table
from softpinn.bridge.report.baselines import (
    WHAT,
    baseline_rows,
    network_verdict,
)

WHO = {"lagrangian": "Lagrangian network", "blackbox": "black box"}
#: the two ways the experiment predicts: its predict stage's key, the baselines stage's
WAYS = (("prediction_error", "short"), ("reset_error", "reset"))


def _errors(entry: Mapping[str, Any], key: str) -> dict[str, dict[float, tuple]]:
    """Each network's error (against the processed measurement) by horizon, one way."""
    out = {}
    for k in KINDS:
        e = entry["models"][k]["predict"][key]
        out[WHO[k]] = {float(e["horizon_s"]): (e.get("mean"), e.get("std"))}
    return out


def _beats(errors: Mapping[float, tuple], comparison: BaselineComparison) -> bool:
    """Whether the network beats the best linear model and no motion at its horizon (as
    :func:`bridge.analysis.baselines.verdict` judges)."""
    (h, (mean, _)), = errors.items()
    return comparison.beaten_by(h, math.inf if mean is None else float(mean)) is None


def _cells(results: Mapping[str, Any]) -> list[tuple[str, str, Mapping[str, Any]]]:
    return [(rn, p, e) for rn, per in results["rates"].items()
            for p, e in per["preprocessing"].items() if e.get("baselines")]


def baselines_summary(results: Mapping[str, Any]) -> str:
    """One sentence: in how many combinations of sensor rate and preprocessing each network
    beats both the best linear model and no motion, without and with resets ("" without a
    baselines stage)."""
    cells = _cells(results)
    if not cells:
        return ""
    wins = {(k, way): 0 for k in KINDS for _, way in WAYS}
    for _, _, e in cells:
        for key, way in WAYS:
            comparison = BaselineComparison.from_json(e["baselines"][way])
            networks = _errors(e, key)
            for k in KINDS:
                wins[k, way] += _beats(networks[WHO[k]], comparison)
    n = len(cells)
    text = "; ".join(f"the {WHO[k]} beats both the best linear model and no motion in "
                     f"{wins[k, 'short']} of {n} combinations of sensor rate and preprocessing "
                     f"without reset and in {wins[k, 'reset']} of {n} with resets"
                     for k in KINDS)
    return text[0].upper() + text[1:] + "."


def baselines_section(plan, results: Mapping[str, Any], out: Path) -> list[str]:
    """Markdown lines of the section (none where the run has no baselines stage)."""
    cells = _cells(results)
    if not cells:
        return []
    first = cells[0][2]["baselines"]
    lines = [
        "## The networks against no motion and linear models", "",
        "Baselines every network must beat: " + WHAT + ", on the same imported bending "
        "coordinates (dx, dy) and training trajectories as the networks, scored like the "
        "networks' prediction error against the processed measurement: over "
        f"{first['horizon_s']:g} s without reset and over the whole test trajectories "
        f"({first['span_s']:g} s) with the state reset from the processed measurement every "
        f"{first['reset_every_s']:g} s.", ""]
    for key, way in WAYS:
        rows = []
        for rn, p, e in cells:
            comparison = BaselineComparison.from_json(e["baselines"][way])
            networks = _errors(e, key)
            named = baseline_rows(networks, comparison)  # networks, then the baselines
            rows.append((rn[:-2], p, *(r[1] for r in named)))
        spans = [Span("", "sensor rate [Hz]"), Span("", "preprocessing")]
        spans += [Span("", WHO[k]) for k in KINDS] + [Span("", name) for name, _, _ in BASELINES]
        what = (f"over {first['horizon_s']:g} s without reset" if way == "short" else
                f"over the whole test trajectories, reset every {first['reset_every_s']:g} s")
        table = Table(tuple(spans), tuple(rows), caption=(
            f"Prediction error [{UNIT}²] against the processed measurement {what}: the networks "
            "and the baselines (mean ± std over the test trajectories)"))
        write_table(table, out / "tables", f"baselines_{way}")
        lines += [to_markdown(table), ""]
    lines += [baselines_summary(results), "",
              f"At the paper's {plan.main_rate:g} Hz, each network and preprocessing:", ""]
    main = f"{plan.main_rate:g}Hz"
    for rn, p, e in cells:
        if rn != main:
            continue
        for k in KINDS:
            label = f"{WHO[k]}, {p}"
            parts = []
            for key, way in WAYS:
                comparison = BaselineComparison.from_json(e["baselines"][way])
                text = network_verdict(label, _errors(e, key)[WHO[k]], comparison)
                text = text[len(label) + 2:]
                parts.append(text if way == "short" else
                             f"with the state reset every {e['baselines']['reset_every_s']:g} s, "
                             + text)
            lines.append(f"- {label}: " + "; ".join(parts))
    return lines + [""]
