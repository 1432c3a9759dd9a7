"""The files of one analysis (:func:`bridge.analysis.analyze`): :func:`write_report` writes into
one directory

* ``report.md``: the summary of every transform and paper-shaped tables for the first q, the
  force and acceleration terms along the data and what the data show of the inertia;
* ``summary.{md,csv,tex}`` and ``table_<transform>.{md,csv,tex}`` (all q; Tables I, II, V-IX);
  for a large arm (:func:`bridge.figures.large_arms.is_large`: n > 4 or m > 8) the report
  summarises each transform by per-segment blocks, the entries that contribute most and the
  residuals at the first q instead, the full tables being kept as ``table_<transform>.csv``
  only, and ``P_entries.png`` draws at most 16 entries of P(q) (issue 46);
* ``analysis.json``: every number (q, both sides' matrices, each transform's P, residuals...);
* ``scatter.png`` (one row per transform), ``sweeps.png``, ``P_entries.png``, ``forces.png`` and
  ``accelerations.png`` (:mod:`bridge.figures.matrices`);

and :func:`summary_numbers` digests a result for a pipeline's results.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.analysis.compare import AnalysisResult
from softpinn.bridge.analysis.excitation import markdown_lines as excitation_lines
from softpinn.bridge.analysis.forces import markdown_lines as force_lines
from softpinn.bridge.analysis.transform_result import Status, match_word
from softpinn.bridge.analysis.transforms import to_jsonable
from softpinn.bridge.figures.large_arms import (
    MAX_PANELS,
    block_lines,
    is_large,
    panel_entries,
    per_q_lines,
    top_entry_lines,
)
from softpinn.bridge.figures.matrices import (
    plot_entries_scatter,
    plot_forces,
    plot_sweeps,
    plot_transform_entries,
)
from softpinn.bridge.figures.tables import (
    Table,
    summary_table,
    to_csv,
    to_markdown,
    transform_table,
    write_table,
)
from softpinn.errors import UserError
from softpinn.learn.plots import coordinate_unit

__all__ = ["summary_numbers", "write_report"]

def _table_matrices(result: AnalysisResult) -> tuple[str, ...]:
    first = "M_inv" if result.learned_kind == "hamiltonian" else "M"
    return (first, "D", "G", "A")


def write_report(
    result: AnalysisResult,
    out_dir: str | Path,
    *,
    precision: int = 3,
    max_table_q: int = 5,
    plots: bool = True,
    notes: list[str] | tuple[str, ...] = (),
) -> dict[str, Path]:
    """Write report.md, the tables (Markdown, CSV, LaTeX), analysis.json and the plots into
    ``out_dir`` (created); returns the written paths by name. Files are replaced atomically.
    ``notes``: paragraphs the report gives under its first line (e.g. that the "true" model is
    a nominal one where the run learned from recordings)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserError(f"out: {str(out)!r} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    mats = _table_matrices(result)
    large = is_large(result.true.n, result.true.m)
    names = result.meta.get("coordinates")

    summary = summary_table(result.results, caption="Matrix equivalence: every transform")
    for ext, p in write_table(summary, out, "summary", precision=precision).items():
        paths[f"summary.{ext}"] = p
    tables = {}
    for name, r in result.results.items():
        res = None if name == "direct" else r
        t = transform_table(
            result.q, result.true, result.learned, res, matrices=mats,
            caption=f"true vs learned matrices, transform {name}",
        )  # fmt: skip
        tables[name] = t
        if large:  # Markdown and LaTeX of a hundred columns help nobody: the CSV keeps all
            p = out / f"table_{name}.csv"
            _write_text(p, to_csv(t))
            paths[p.name] = p
            continue
        for ext, p in write_table(t, out, f"table_{name}", precision=precision).items():
            paths[f"table_{name}.{ext}"] = p

    json_path = out / "analysis.json"
    _write_text(json_path, json.dumps(result.to_dict(), indent=1, allow_nan=False))
    paths["analysis.json"] = json_path

    if plots:
        p = out / "scatter.png"
        plot_entries_scatter(result.true, result.learned, _scatter_rows(result), matrices=mats,
                             path=p)
        paths[p.name] = p
        if result.sweeps is not None:
            p = out / "sweeps.png"
            plot_sweeps(result.sweeps, path=p)
            paths[p.name] = p
        p = out / "P_entries.png"
        spread = np.ptp(np.asarray(result.q, float), axis=0)
        widest = int(np.argmax(spread)) if len(result.q) > 1 else None
        label = None
        if widest is not None and names:

            unit = coordinate_unit(names[widest], result.meta.get("model_kind"))
            label = f"{names[widest]} [{unit}]" if unit else names[widest]
        entries = (panel_entries(result.results, result.true.n, MAX_PANELS) if large
                   else None)
        plot_transform_entries(result.q, result.results, path=p, coordinate=widest,
                               coordinate_label=label, entries=entries)
        paths[p.name] = p
        for name, comp in (("forces.png", result.forces),
                           ("accelerations.png", result.accelerations)):
            if comp is not None and comp.terms:
                plot_forces(comp, path=out / name)
                paths[name] = out / name

    k = min(max_table_q, len(result.q))
    lines = [
        "# Matrix-equivalence analysis",
        "",
        f"True model `{result.meta.get('true_model')}`, learned model kind "
        f"`{result.learned_kind}`; N = {result.true.N} configurations, n = {result.true.n}, "
        f"m = {result.true.m}.",
        "",
        *(x for note in notes for x in (note, "")),
        "Relative residual of each matrix in percent, `||P X^ - X||_F / ||X||_F` over all q; "
        "`fit`: whether the transform's least squares went well (`ok`, or why not); `match`: "
        "what the total residual means (`recovered` <= 3 %, `approximate` <= 15 %, else `not "
        "recovered`); `c`: the multiple of I nearest to P (`alpha = 1/c`, learned ~= alpha * "
        "true), `distance`: `||P - cI||_F / ||P||_F`.",
        "",
        to_markdown(summary, precision=precision),
    ]
    for name, r in result.results.items():
        fit = "ok" if r.status == Status.SUCCESS else f"`{r.status}`"
        total = ("undefined" if r.residual_total is None or not np.isfinite(r.residual_total)
                 else f"{100 * r.residual_total:.2f} %")
        lines += [f"## {name}", "", f"{r.message}. Fit {fit}; total residual {total}: "
                  f"{match_word(r.residual_total)}.", ""]
        if name == "alpha":
            lines += [f"alpha = {r.params['alpha']:.6g}", ""]
        if name == "smooth":
            held = {m: f"{v:.3g}" for m, v in r.params["residual_heldout"].items()}
            lines += [f"held-out residuals: {held}", ""]
        if large:
            lines += _large_lines(result, r, name, k, names)
            continue
        lines += [
            f"First {k} of {len(result.q)} q (all q in `table_{name}.csv`):",
            "",
            to_markdown(_first_q(tables[name], k), precision=precision),
        ]
    for name, comp in (("forces.png", result.forces), ("accelerations.png", result.accelerations)):
        if comp is not None:
            lines += force_lines(comp.to_dict())
            if name in paths:
                lines += [f"![{comp.frame} terms, true against learned]({name})", ""]
    if result.excitation is not None:
        lines += excitation_lines(result.excitation, result.meta.get("coordinates"))
    if plots:
        lines += [
            "## Entries: true against learned (the direct comparison where it applies) and "
            "against the best transform's P(q) times learned",
            "",
            "![scatter](scatter.png)",
            "",
        ]
        if "sweeps.png" in paths:
            how = ("directly" if result.sweeps.transform == "direct" else
                   f"times c = 1/α = {result.sweeps.scale:.4g} (M⁻¹ divided by it)")
            lines += [
                "## Along sweeps of q: each coordinate over the configurations' range, the "
                "others at their median",
                "",
                f"True solid, learned dashed, compared {how}.",
                "",
                "![sweeps](sweeps.png)",
                "",
            ]
        lines += [
            "## P(q) over the sampled q, along the coordinate that varies most",
            "",
            "![P entries](P_entries.png)",
            "",
        ]
        if large and entries is not None and len(entries) < result.true.n ** 2:
            n = result.true.n
            off = len(entries) - min(n, len(entries))
            more = f" and the {off} largest off-diagonal (rms over q)" if off else ""
            lines += [f"The figure draws {len(entries)} of the {n * n} entries of P(q): the "
                      f"diagonal{more}; the other {n * n - len(entries)} are in the `P` "
                      "columns of each `table_<transform>.csv` and in `analysis.json`.", ""]
    report = out / "report.md"
    _write_text(report, "\n".join(lines))
    paths["report.md"] = report
    return paths


def _scatter_rows(result) -> dict:
    """The rows of the entries scatter: the direct comparison (None: learned as it is) where it
    was made, and the transform with the smallest total residual (pointwise only if it is the
    only one: it explains M exactly by construction)."""
    rows = {"direct": None} if "direct" in result.results else {}
    fits = {n: r for n, r in result.results.items() if n != "direct"}
    others = {n: r for n, r in fits.items() if n != "pointwise"} or fits
    if others:
        key = lambda n: (others[n].residual_total if others[n].residual_total is not None  # noqa: E731
                         and np.isfinite(others[n].residual_total) else np.inf)
        best = min(others, key=key)
        rows[best] = others[best]
    return rows or {None: None}


def _large_lines(result, r, name: str, k: int, names) -> list[str]:
    """A large arm's section body for transform ``name`` (:mod:`bridge.figures.large_arms`):
    per-segment blocks, the largest entries and the first ``k`` q, the full table linked."""
    n, m = result.true.n, result.true.m
    lines = [f"n = {n}, m = {m}: the table of every entry at each q (Tables I, II) is "
             f"[`table_{name}.csv`](table_{name}.csv), {len(result.q)} q of {n} rows each; "
             "here by blocks.", ""]
    lines += block_lines(r, result.true, result.learned, names)
    lines += top_entry_lines(r, result.true, result.learned)
    lines += [f"Relative residual of each matrix at the first {k} of {len(result.q)} q:", ""]
    return lines + per_q_lines(r, result.q, k)


def _first_q(table, k):

    rows = table.rows[: k * table.block_rows] if table.block_rows else table.rows[:k]
    return Table(table.spans, rows, block_rows=table.block_rows)


def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, "utf-8")
    tmp.replace(path)


def summary_numbers(result: AnalysisResult) -> dict[str, Any]:
    """A compact JSON-ready digest: per transform, status, residuals, alpha and distance."""
    out = {}
    for name, r in result.results.items():
        d = {
            "status": str(r.status),
            "residual": dict(r.residual),
            "residual_total": r.residual_total,
            "alpha": r.alpha,
            "distance_from_alpha_I": r.distance_all,
        }
        if name == "smooth":
            d["residual_heldout"] = dict(r.params["residual_heldout"])
        out[name] = d
    return to_jsonable(out)
