"""The few sentences a task report opens with, generated from its numbers: which model predicts
best and by how much against the black box and the paper, whether each network beats no motion
and the linear models, how well the learned matrices match the true ones, what
diverged, and whether this is a quick run."""

from __future__ import annotations

import math
from typing import Any

from softpinn.bridge.analysis.baselines import BaselineComparison
from softpinn.bridge.analysis.transform_result import match_word
from softpinn.bridge.figures.paper import load_paper_tables, paper_task
from softpinn.bridge.report.baselines import losses, predict_errors
from softpinn.errors import UserError

NETWORK = {"lagrangian": "Lagrangian", "hamiltonian": "Hamiltonian", "blackbox": "black box"}


def _who(kind: str) -> str:
    return "black box" if kind == "blackbox" else f"{NETWORK[kind]} network"


def _paper_prediction(task: str, group: str, variant: str | None) -> float | None:
    """The paper's prediction error (Table III) of ``group`` (physics, blackbox) on a variant."""
    try:
        entry = load_paper_tables()["table_III"].get(task, {}).get(group)
    except UserError:
        return None
    if isinstance(entry, dict) and variant is not None and variant in entry:
        entry = entry[variant]
    try:
        value = float(entry["prediction_error"]["mean"])
    except (KeyError, TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def _times(a: float, b: float) -> str:
    r = b / a
    return f"{r:.3g}×" if r < 100 else f"{r:.2g}×"


def _against_baselines(models: dict, baselines: dict, on: str) -> str:
    """Whether each network beats no motion and the best linear model at every horizon (the
    report's baselines rows), or whom it loses to where."""
    comparison = BaselineComparison.from_json(baselines)
    parts = []
    for k, e in models.items():
        lost = losses(predict_errors(e["predict"]), comparison)
        parts.append(f"the {_who(k)} beats both at every horizon" if not lost else
                     f"the {_who(k)} loses to " + ", ".join(f"{name} at {h:.3g} s"
                                                           for h, name in lost))
    return (f"Against no motion and the linear models{on}: "
            + "; ".join(parts) + ".")


def verdict(plan, results: dict[str, Any]) -> list[str]:
    """Markdown lines: one paragraph of sentences (see the module)."""
    says: list[str] = []
    if plan.quick:
        says.append("**This is a quick run**: little data and short training, to check the "
                    "pipeline in minutes; its numbers are not meant to match "
                    f"{'the paper' if paper_task(plan.task) else 'a full run'}'s, and "
                    "may even rank the models the other way (run without `--quick` for that). Its "
                    "figures are screen-resolution drafts; a full run writes 300 dpi PNGs and "
                    "vector PDFs.")
    for vname, vres in results["variants"].items():
        models = vres["models"]
        on = "" if vname == "main" else f" on the {vname} data"
        pred = {k: float(e["predict"]["prediction_error"]["mean"]) for k, e in models.items()}
        horizon = next(iter(models.values()))["predict"]["prediction_error"]["horizon_s"]
        gone = [k for k, v in pred.items() if not math.isfinite(v)]
        ok = {k: v for k, v in pred.items() if math.isfinite(v)}
        if ok:
            best = min(ok, key=ok.get)
            text = (f"{_who(best)} predicts best{on}: error {ok[best]:.3g} over "
                    f"{horizon:.3g} s")
            others = [k for k in ok if k != best]
            if "blackbox" in ok and best != "blackbox":
                text += f", {_times(ok[best], ok['blackbox'])} lower than the black box's"
            elif best == "blackbox" and others:
                o = min(others, key=ok.get)
                text += f", {_times(ok[best], ok[o])} lower than the {_who(o)}'s"
            paper = _paper_prediction(plan.task, "blackbox" if best == "blackbox" else "physics",
                                      None if vname == "main" else vname)
            if paper is not None and ok[best] > 0:
                text += (f"; the paper reports {paper:.3g} for its "
                         f"{'black box' if best == 'blackbox' else 'physics model'}")
            says.append("The " + text + ".")
        for k in gone:
            says.append(f"The {_who(k)}'s rollout diverged{on} (error inf).")
        if vres.get("baselines"):
            says.append(_against_baselines(models, vres["baselines"], on))
        for k, e in models.items():
            summary = (e.get("analyze") or {}).get("summary")
            if not summary:
                continue
            fits = {n: s.get("residual_total") for n, s in summary.items()
                    if n != "direct" and s.get("residual_total") is not None
                    and math.isfinite(s["residual_total"])}
            if not fits:
                continue
            name = min(fits, key=fits.get)
            pct = 100 * fits[name]
            word = match_word(fits[name])
            if word == "recovered":
                says.append(f"The {_who(k)}'s learned matrices{on} match the true ones up to the "
                            f"{name} transform P(q), within {pct:.2g} %.")
            elif word == "approximate":
                says.append(f"The {_who(k)}'s learned matrices{on} match the true ones only "
                            f"approximately: the best transform ({name} P(q)) leaves "
                            f"{pct:.3g} %.")
            else:
                says.append(f"The {_who(k)}'s learned matrices{on} do not match the true ones: "
                            f"even the best transform ({name} P(q)) leaves {pct:.3g} %.")
    return ["## Verdict", "", " ".join(says), ""]
