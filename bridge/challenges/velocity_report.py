"""The report of the velocity study (:mod:`bridge.challenges.velocity`): issue 18's targets as
measured, the figure of prediction errors and direct matrix residuals, and the Markdown table."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.analysis.excitation import ratio_text
from softpinn.bridge.challenges.velocity_settings import (
    COLUMNS,
    FORCE_MODELS,
    LABELS,
    MODELS,
    PREDICT_MAX_STEP,
    TARGET_PERCENT,
)
from softpinn.bridge.figures.figsave import figure_dpi


def _fmt(x, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if abs(x) >= 100:
        return f"{x:.0f}"
    return f"{x:.{digits}g}"


def _rows(results: dict[str, Any]):
    """(task, variant, name, label, entry) for every trained network."""
    for task, r in results.items():
        for variant, models in r["variants"].items():
            for name, _kind, label in MODELS:
                if isinstance(models, dict) and name in models:
                    yield task, variant, name, label, models[name]


def _variant_label(variant: str, models: dict[str, Any]) -> str:
    """The data set's name; the excited one says how it was excited."""
    f = models.get("input_frequency_high")
    return variant if f is None else f"{variant.removesuffix('-excited')}, inputs to {f:g} Hz"


def figure(results: dict[str, Any], path: Path) -> None:
    import matplotlib  # deferred: matplotlib only where a figure is drawn

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    panels = [(t, v) for t, r in results.items() for v in r["variants"]]
    # one y scale per row, so that bars of different data sets compare at a glance
    fig, axes = plt.subplots(2, len(panels), figsize=(4.6 * len(panels), 6.6), squeeze=False,
                             sharey="row", constrained_layout=True)
    x = np.arange(len(COLUMNS))
    colors = {"lagrangian": "C0", "hamiltonian": "C3", "hamiltonian-rk4": "C1",
              "hamiltonian-known": "C2", "lagrangian-force": "C9", "hamiltonian-force": "C4",
              "hamiltonian-weighted": "C6"}
    short = {"lagrangian": "Lagrangian", "hamiltonian": "Hamiltonian\nfrom q̇",
             "hamiltonian-rk4": "Hamiltonian\nfrom q̇, eq. 8",
             "hamiltonian-known": "Hamiltonian\nfrom q̇, A known",
             "lagrangian-force": "Lagrangian,\nforce space",
             "hamiltonian-force": "Hamiltonian\nfrom q̇,\nforce space",
             "hamiltonian-weighted": "the same,\nweighted"}
    for j, (task, variant) in enumerate(panels):
        models = results[task]["variants"][variant]
        present = [(name, label) for name, _kind, label in MODELS if name in models]
        ax = axes[0, j]
        for i, (name, label) in enumerate(present):
            e = models[name]["prediction_error"]
            ok = e is not None and np.isfinite(e)
            ax.bar(i, e if ok else np.nan, 0.6, color=colors[name], label=label)
            if not ok:  # a rollout ran away: no bar to draw
                ax.annotate("diverged", (i, 0.5), xycoords=("data", "axes fraction"),
                            ha="center", color=colors[name])
        ax.set_yscale("log")
        ax.set_xticks(range(len(present)), [short[name] for name, _ in present], fontsize=7,
                      rotation=30, ha="right", rotation_mode="anchor")
        horizon = models[present[0][0]]["horizon_s"]
        ax.set_ylabel(f"rollout error over {horizon:g} s\n(mean ‖q − q̂‖²)")
        ax.set_title(f"{task}, {_variant_label(variant, models)}:\nrollout error (test)")
        ax = axes[1, j]
        width = 0.8 / len(present)
        for i, (name, label) in enumerate(present):
            vals = [models[name]["matrices"][c] for c in COLUMNS]
            vals = [v if v is not None and np.isfinite(v) else np.nan for v in vals]
            ax.bar(x + (i - (len(present) - 1) / 2) * width, np.maximum(vals, 1e-3), width,
                   color=colors[name], label=label)
        ax.axhline(TARGET_PERCENT, color="k", ls="--", lw=0.8,
                   label=f"target {TARGET_PERCENT:g} %")
        ax.set_yscale("log")
        ax.set_xticks(x, [LABELS[c] for c in COLUMNS], fontsize=8)
        ax.set_ylabel("direct relative residual [%]\n(bars at the bottom: < 1e-3 %)")
        ax.set_title(f"{task}, {_variant_label(variant, models)}:\nlearned vs true (no transform)")
    # one legend for every panel, below them (in a panel it covered the bars)
    handles, labels = {}, {}
    for ax in axes[1]:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    labels = list(handles)
    # as many columns as the figure's width holds (an entry is up to about 3.5 inches wide): a
    # legend wider than the figure would push the panels off its edges
    ncols = max(1, min(4, len(labels), int(fig.get_figwidth() / 3.5)))
    fig.legend([handles[k] for k in labels], labels, loc="outside lower center",
               ncols=ncols, fontsize=8, frameon=False)
    fig.savefig(path, dpi=figure_dpi(300, fig))
    plt.close(fig)


def targets(results: dict[str, Any]) -> list[dict[str, Any]]:
    """Issue 18's task 5 targets, as measured: per rate, the Hamiltonian network's prediction
    error no worse than the Lagrangian network's, and its matrices within 5 % directly."""
    out = []
    r5 = results.get("task5")
    if not r5:
        return out
    for variant, models in r5["variants"].items():
        if "hamiltonian" not in models:  # the excited data: the force-space models alone
            out += _force_targets(_variant_label(variant, models), models)
            continue
        h, lg = models["hamiltonian"], models["lagrangian"]
        eh, el = h["prediction_error"], lg["prediction_error"]
        ok = (eh is not None and el is not None and math.isfinite(eh) and math.isfinite(el)
              and eh <= el)
        out.append({"what": f"task5 {variant}: Hamiltonian-from-q̇ prediction error vs "
                            "Lagrangian", "target": "no worse",
                    "measured": f"{_fmt(eh)} vs {_fmt(el)}", "met": bool(ok)})
        for name, label in (("hamiltonian", "Hamiltonian-from-q̇"),
                            ("hamiltonian-known", "Hamiltonian-from-q̇ with A known")):
            if name not in models:
                continue
            mt = models[name]["matrices"]
            worst = max((mt[c] for c in COLUMNS if mt[c] is not None), default=None)
            out.append({"what": f"task5 {variant}: {label} matrices, direct (worst of "
                                + ", ".join(LABELS[c] for c in COLUMNS) + ")",
                        "target": f"≤ {TARGET_PERCENT:g} %", "measured": f"{_fmt(worst)} %",
                        "met": worst is not None and worst <= TARGET_PERCENT})
        out += _force_targets(variant, models)
    return out


def _force_targets(variant: str, models: dict[str, Any]) -> list[dict[str, Any]]:
    """The force-space pair's targets on one task 5 variant: the Hamiltonian network's
    prediction error against the Lagrangian network's of the same budget, and its M, D, G (A is
    the known one) and, apart, its M⁻¹ within :data:`TARGET_PERCENT` directly."""
    out = []
    for name, label in (("hamiltonian-force", "Hamiltonian-from-q̇ in force space"),
                        ("hamiltonian-weighted", "Hamiltonian-from-q̇ in force space, weighted")):
        if name in models:
            out += _force_model_targets(variant, models[name], models.get("lagrangian-force"),
                                        label)
    return out


def _force_model_targets(variant: str, h: dict[str, Any], lg: dict[str, Any] | None,
                         label: str) -> list[dict[str, Any]]:
    out = []
    if lg is not None:
        eh, el = h["prediction_error"], lg["prediction_error"]
        ok = (eh is not None and el is not None and math.isfinite(eh) and math.isfinite(el)
              and eh <= el)
        out.append({"what": f"task5 {variant}: {label}, prediction "
                            "error vs the Lagrangian network in force space", "target":
                            "no worse", "measured": f"{_fmt(eh)} vs {_fmt(el)}", "met": bool(ok)})
    mt = h["matrices"]
    for cols in (("M", "D", "G"), ("M_inv",)):
        vals = [mt[c] for c in cols if mt.get(c) is not None and math.isfinite(mt[c])]
        worst = max(vals) if len(vals) == len(cols) else None
        out.append({"what": f"task5 {variant}: {label}, "
                            + ", ".join(LABELS[c] for c in cols) + " direct"
                            + (" (worst)" if len(cols) > 1 else ""),
                    "target": f"≤ {TARGET_PERCENT:g} %", "measured": f"{_fmt(worst)} %",
                    "met": worst is not None and worst <= TARGET_PERCENT})
    return out


def markdown(results: dict[str, Any], quick: bool, figure: str, seconds: float) -> str:
    lines = [
        "Hamiltonian networks (eq. 7) trained on velocity data only (`softpinn train --model "
        "hamiltonian --momenta velocity`): p = M̂(q) q̇ with the network's own mass matrix "
        "inside the loss, one RK4 step of eq. 7 in (q, p), q̇ = M̂⁻¹(q) p back, and the "
        "task's velocity loss (eq. 8; eq. 10 on task 5, whose Lagrangian recipe trains on "
        "differenced accelerations). Beside the Lagrangian network (eq. 6) on the same data "
        "with the same networks, loss, epochs, learning rate and training pairs. Matrices: "
        "relative residual ‖learned − true‖_F / ‖true‖_F in percent over the training data's "
        "configurations, directly (no transform); M⁻¹G and M⁻¹A u at its samples (these no "
        "transform changes); α: the best single scale (learned ≈ α true over M, D, A, G) and "
        "the residuals after it. Prediction error: mean over test trajectories of the mean "
        "‖q − q̂‖² of a rollout from the true initial state with the true inputs (RK4 in "
        f"steps of at most {PREDICT_MAX_STEP * 1000:g} ms; \"–\": a rollout ran away). Two more "
        "Hamiltonian networks from q̇ where marked: trained with eq. 8 through the mapped RK4 "
        "step where the recipe's loss is eq. 10, and with the true A(q) fixed (challenge 2a's "
        "known actuator model), which pins the scale velocity data leave open. The last two "
        "rows of each data set, a pair with their own budget: the Lagrangian network and the "
        "Hamiltonian network from q̇, both with A known and a constant D, trained on eq. 10 "
        "in force space (`softpinn train --accel-space force`: ‖M̂ (q̈ − q̂̈)‖² = ‖M̂ q̈ + Ĉ q̇ "
        "+ D̂ q̇ + Ĝ − A u‖², linear in the networks' M, D, G, where the acceleration space "
        "puts M̂⁻¹ in front of every term), q̈ from central differences of q̇, nothing taken "
        "from the file's momenta; then the Hamiltonian network again from that model, each "
        "coordinate of the force residual weighted by mean(s) / s_i, s_i the rms of the "
        "model's M̂ q̈ (`--init RUN --accel-weights-from RUN`). The data set marked \"inputs to "
        "N Hz\": one rate's data again with every input's frequency drawn up to N Hz instead "
        "of the task's (the same arm, trajectories, seed and budgets), where those three "
        "networks alone train.", "",
        "| task | data | network | loss | state | " + " | ".join(LABELS[c] for c in COLUMNS)
        + " | α | after α: M, D, A, G | test loss | prediction error | train time |",
        "|---" * (len(COLUMNS) + 10) + "|",
    ]
    for task, variant, _name, label, e in _rows(results):
        mt = e["matrices"]
        ar = mt["alpha_residual"]
        after = ", ".join(_fmt(ar.get(k), 2) for k in ("M", "D", "A", "G"))
        variant = _variant_label(variant, results[task]["variants"][variant])
        lines.append(
            f"| {task} | {variant} | {label} | {e['loss']}"
            + (" (force space)" if e.get("accel_space") == "force" else "")
            + f" | {e['state']} | "
            + " | ".join(_fmt(mt[c], 2) + " %" for c in COLUMNS)
            + f" | {_fmt(mt['alpha'])} | {after} % | {_fmt(e['best_test_loss'])} | "
            f"{_fmt(e['prediction_error'])} ({e['horizon_s']:g} s) | "
            f"{e['train_seconds']:.0f} s |")
    lines += ["", f"![prediction error and direct matrix residuals]({figure})", ""]
    budgets = []
    for task, r in results.items():
        first = next(v["lagrangian"] for v in r["variants"].values() if "lagrangian" in v)
        budgets.append(f"{task}: {first['epochs']} AdamW epochs + {first['lbfgs_steps']} "
                       f"L-BFGS iterations on {r['samples'] or 'all'} training pairs")
        force = next((v[n] for v in r["variants"].values() for n in FORCE_MODELS if n in v),
                     None)
        if force is not None:
            budgets.append(f"{task} in force space: {force['epochs']} AdamW epochs at lr "
                           f"{force['lr']:g}, the same training pairs")
        second = next((v["hamiltonian-weighted"] for v in r["variants"].values()
                       if "hamiltonian-weighted" in v), None)
        if second is not None:
            budgets.append(f"{task}, the weighted second pass: {second['epochs']} more epochs "
                           f"at lr {second['lr']:g}")
    staged = sum(r.get("stage_seconds", 0.0) for r in results.values())
    lines += ["Budgets (both networks alike): " + "; ".join(budgets)
              + f". Wall time of this call {seconds:.0f} s; its stages took {staged:.0f} s "
              "when they ran (reused ones included).", ""]
    lines += _excitation_lines(results)
    lines += [
        "What the numbers can say: from (q, q̇) alone the network's M, D, G, A are fixed only "
        "up to the same transform P(q) as a Lagrangian network's; at the least up to one scale "
        "c (c M̂⁻¹, V̂/c, D̂/c, Â/c move q exactly alike, `tests/test_velocity.py`), so the direct "
        "residuals of M, M⁻¹, D, G, A measure where training left that scale, not the fit. "
        "M⁻¹G and M⁻¹A u are determined by the data in principle; when the inputs hold the arm "
        "near equilibrium (A u ≈ G along the data) only their sum is, for either network.", ""]
    if quick:
        lines = ["**Quick run**: tiny data and networks, a few epochs; not the results.", "",
                 *lines]
    return "\n".join(lines)


def _excitation_lines(results: dict[str, Any]) -> list[str]:
    """The inertial forces each data set shows along the true M's two lightest directions
    (:func:`bridge.analysis.excitation.inertial_share`), the table that says where M⁻¹ can be
    learned from."""

    rows = []
    for task, r in results.items():
        for variant, models in r["variants"].items():
            ex = models.get("excitation") if isinstance(models, dict) else None
            if not ex:
                continue
            ratio = ", ".join(ratio_text(x) for x in ex["inertia_over_damping"][:2])
            lam = ", ".join(f"{x:.2g}" for x in ex["eigenvalue"][:2])
            rows.append(f"| {task} | {_variant_label(variant, models)} | {lam} | {ratio} |")
    if not rows:
        return []
    return [
        "Where M⁻¹ can be learned from: the inertial forces vᵀ M q̈ the training data show "
        "along the two eigenvectors v of the true M with the smallest eigenvalues (lightest "
        "first; they hold nearly all of ‖M⁻¹‖), as a fraction of the damping forces vᵀ D q̇ "
        "there (rms over the samples, the true model's q̈). Where that fraction is a few "
        "percent the arm moves quasi-statically in that direction and no loss pins its mass "
        "(nor M⁻¹) better than the other forces are fitted; the excited data set's inputs "
        "reach the light segment's corner frequency.", "",
        "| task | data | M's two smallest eigenvalues (median) | inertia / damping along them |",
        "|---|---|---|---|", *rows, ""]
