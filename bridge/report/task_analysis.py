"""The section of a task run's report on each physics model's learned matrices against the
true ones (``OUT/report.md``, "Learned matrices against the true ones"): the residuals of every
transform P(q) (Tables V-IX), per configuration and over the seeds, the force terms along the
training data and how much of the inertia the data show (:mod:`bridge.report.task`)."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np

from softpinn.bridge.analysis.excitation import markdown_lines as excitation_lines
from softpinn.bridge.analysis.forces import markdown_lines as force_lines
from softpinn.bridge.analysis.transform_result import match_word
from softpinn.bridge.figures.paper import paper_task
from softpinn.bridge.figures.rollouts import NETWORK


def _rel(path: Path, out: Path) -> str:
    return os.path.relpath(path, out)


def analysis_section(plan, vname: str, kind: str, an: dict, out: Path, *,
                      excitation: bool = True) -> list[str]:
    """The report's section on one physics model's learned matrices against the true ones:
    residuals per transform, per configuration, the force terms and the data's excitation."""
    s = an["summary"]
    where = "" if vname == "main" else f", {vname} data"
    lines = [f"### {NETWORK[kind]} model{where}", ""]
    table_q = "the paper's tables" if paper_task(plan.task) else "the recipe's matrix_q"
    where_q = (f"{an['points']} configurations sampled in the data's range" if not an["paper_q"]
               else f"{an['points']} configurations ({an['paper_q']} from {table_q}, the rest "
               "sampled in the data's range)")
    lines += [
        f"{where_q}. Relative residual ‖P X̂ − X‖/‖X‖ over all of them, "
        "and what the total means (recovered ≤ 3 %, approximate ≤ 15 %, else not recovered):",
        "",
        "| transform | M or M⁻¹ | D | G | A | total | match | α | ‖P − αI‖/‖P‖ |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in s.items():
        res = r["residual"]
        mass = res.get("M", res.get("M_inv"))
        cells = [_pct(mass), _pct(res.get("D")), _pct(res.get("G")), _pct(res.get("A")),
                 _pct(r.get("residual_total")), match_word(r.get("residual_total")),
                 fmt(r.get("alpha")), _pct(r.get("distance_from_alpha_I"))]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    report = Path(an["report"])
    lines += _paper_q_lines(report.parent / "analysis.json", kind, int(an["paper_q"]),
                            an.get("seeds"))
    lines += _force_lines(report.parent, out)
    if excitation:
        lines += _excitation_lines(report.parent / "analysis.json")
    at = "at the paper's q" if paper_task(plan.task) else "per configuration"
    lines += ["", f"Tables {at}, per transform: [{_rel(report, out)}]"
                  f"({_rel(report, out)}).", ""]
    scatter = report.parent / "scatter.png"
    if scatter.is_file():
        lines += [f"![true against transformed learned entries]({_rel(scatter, out)})", ""]
    sweeps = report.parent / "sweeps.png"
    if sweeps.is_file():
        lines += ["Where they part: the entries along a sweep of each coordinate through the "
                  "configurations' range (the others at their median), true solid, learned "
                  "dashed.", "", f"![learned against true along sweeps of q]"
                  f"({_rel(sweeps, out)})", ""]
    pentries = report.parent / "P_entries.png"
    if pentries.is_file():
        lines += [f"The transforms P(q) themselves: [P_entries.png]({_rel(pentries, out)}).", ""]
    return lines


def _excitation_lines(path: Path) -> list[str]:
    """How much of the inertia the training data show per direction of the true M
    (:mod:`bridge.analysis.excitation`), from the analysis' samples."""
    if not path.is_file():
        return []
    analysis = json.loads(path.read_text())
    share = analysis.get("excitation")
    if not share:
        return []
    table = excitation_lines(share, analysis.get("meta", {}).get("coordinates"), heading=None)
    return ["", "**What the training data show of the inertia.** " + table[0], *table[1:-1]]


def _force_lines(folder: Path, out: Path) -> list[str]:
    """The first seed's force terms along its training data, and the accelerations they give
    (:mod:`bridge.forces`)."""
    path = folder / "analysis.json"
    if not path.is_file():
        return []
    analysis = json.loads(path.read_text())
    lines = []
    for key, png in (("forces", "forces.png"), ("accelerations", "accelerations.png")):
        comp = analysis.get(key)
        if not comp:
            continue
        lines += [""] + force_lines(comp, heading=None)[:-1]
        if (folder / png).is_file():
            lines += ["", f"![{comp.get('frame', 'force')} terms, true against learned]"
                          f"({_rel(folder / png, out)})"]
    return lines


def _paper_q_rows(path: Path, kind: str, k: int):
    """Residual of each matrix at each of the paper's k configurations, and over the sampled
    ones (all inside the data's range), for the headline transform: the direct comparison for
    a Hamiltonian model, one scalar α for a Lagrangian one (Tables V-VII). Returns the
    transform's name, its matrices, the row labels, the number of sampled q and one row of
    residuals per label; None where there is no such analysis."""
    if not path.is_file():
        return None
    a = json.loads(path.read_text())
    name = "direct" if kind == "hamiltonian" else "alpha"
    tr = a["transforms"].get(name)
    if tr is None or not tr.get("residuals"):
        return None
    blocks = list(tr["residuals"])
    q = np.asarray(a["q"], float)
    labels, rows = [], []
    for i in range(min(k, len(q))):
        labels.append("[" + ", ".join(f"{v:.4g}" for v in q[i]) + "]")
        rows.append([_num(tr["residuals"][b][i]) for b in blocks])
    row = []
    for b in blocks:  # ‖P X̂ − X‖/‖X‖ stacked over the sampled q, from the per-q residuals
        r = np.array([_num(v) for v in tr["residuals"][b][k:]], float)
        norm = np.linalg.norm(np.asarray(a["true"][b], float)[k:].reshape(len(q) - k, -1),
                              axis=1)
        ok = np.isfinite(r)  # a residual is undefined (None) where the true matrix is 0
        total = np.sqrt(np.sum((r[ok] * norm[ok]) ** 2) / max(np.sum(norm[ok] ** 2), 1e-300))
        row.append(float(total) if ok.any() else np.nan)
    labels.append(f"sampled ({len(q) - k})")
    rows.append(row)
    return {"name": name, "blocks": blocks, "labels": labels, "sampled": len(q) - k,
            "rows": np.asarray(rows, float)}


def _num(x) -> float:
    return np.nan if x is None else float(x)


def _paper_q_lines(path: Path, kind: str, k: int, seeds: list[dict] | None = None) -> list[str]:
    """The table of :func:`_paper_q_rows` for the first seed; with several seeds, a second one
    of mean ± std over the seeds and the largest."""
    got = _paper_q_rows(path, kind, k)
    if got is None:
        return []
    blocks, labels, rows = got["blocks"], got["labels"], got["rows"]
    first = f"the paper's {k} configurations, then " if k else ""
    head = ["| q | " + " | ".join(blocks) + " |", "|---|" + "---|" * len(blocks)]
    per_seed = [_paper_q_rows(Path(s["analysis"]), kind, k) for s in seeds or []]
    per_seed = [g["rows"] for g in per_seed if g is not None and g["rows"].shape == rows.shape]
    which = " (first seed)" if len(per_seed) > 1 else ""
    lines = ["", f"Relative residual per configuration{which}, transform `{got['name']}`: "
             f"{first}all {got['sampled']} sampled ones together:", "", *head]
    lines += [f"| {lab} | " + " | ".join(_pct(v) for v in row) + " |"
              for lab, row in zip(labels, rows, strict=True)]
    if len(per_seed) > 1:
        stack = np.stack(per_seed)
        with warnings.catch_warnings():  # a residual undefined for every seed stays NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            mean, std, top = np.nanmean(stack, 0), np.nanstd(stack, 0), np.nanmax(stack, 0)
        lines += ["", f"The same over all {len(per_seed)} seeds: mean ± std (largest).", "",
                  *head]
        for lab, m, s_, t in zip(labels, mean, std, top, strict=True):
            cells = ["–" if not np.isfinite(a) else f"{100 * a:.2f} ± {100 * b:.2f} % "
                     f"({100 * c:.2f} %)" for a, b, c in zip(m, s_, t, strict=True)]
            lines.append(f"| {lab} | " + " | ".join(cells) + " |")
    return lines


def _pct(x) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{100 * x:.2f} %"


def fmt(x) -> str:
    """A number in three significant digits (– for none; anything else as it is)."""
    if x is None:
        return "–"
    if isinstance(x, (int, float)) and np.isfinite(x):
        return f"{x:.3g}"
    return str(x)
