"""The figures of a task report (``OUT/figures``): per data variant the loss curves, the
rollouts (:mod:`.rollouts`), the arm itself (:mod:`.shape`) and the table of prediction errors;
for tasks sampled at several rates, the error against the rate (Fig. 10)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from softpinn.bridge.figures.arm import shape_animation, shape_figure
from softpinn.bridge.figures.figsave import save_for_print
from softpinn.bridge.figures.paper import load_paper_tables
from softpinn.bridge.figures.rollouts import (
    COLORS,
    MIN_BAND,
    finite_points,
    horizon_figure,
    rollout_figure,
)
from softpinn.bridge.figures.rollouts import NETWORK as _NETWORK
from softpinn.bridge.figures.tables import format_mean_std
from softpinn.errors import UserError
from softpinn.learn import read_history
from softpinn.learn.plots import coordinate_unit, plot_loss_curves
from softpinn.symbolic import PCC_KINDS


def _rel(path: Path, out: Path) -> str:
    return os.path.relpath(path, out)


def _load_history(run: Path) -> list[dict]:

    path = run / "history.csv"
    if not path.is_file():
        members = sorted(run.glob("seed-*/history.csv"))
        if not members:
            return []
        path = members[0]
    return read_history(path)


def _variant_figures(spec, plan, vname: str, models: dict, fig_dir: Path,
                     out: Path, animate: bool = False) -> list[str]:

    lines: list[str] = []
    hist = {k: _load_history(Path(e["train"]["run"])) for k, e in models.items()}
    loss_path = plot_loss_curves(list(hist.values()), fig_dir / f"loss_{vname}.png",
                                 labels=[_NETWORK[k] for k in hist],
                                 colors=[COLORS.get(k, "C2") for k in hist],
                                 title=f"{plan.task} {vname}: loss (train solid, test dashed)")
    lines += [f"![loss curves]({_rel(loss_path, out)})", ""]
    rolls = {}
    for k in models:
        path = Path(out) / "predict" / vname / k / "rollouts.npz"
        if path.is_file():
            with np.load(path) as z:
                rolls[k] = {key: z[key] for key in z.files}
    if not rolls:
        return lines
    def span(prefix):  # the horizon the rollout covers (a short variant's data may cut it)
        for r in rolls.values():
            if f"{prefix}_t" in r and r[f"{prefix}_t"].size:
                return float(r[f"{prefix}_t"][-1] - r[f"{prefix}_t"][0])
        return plan.horizon

    names = list(spec.coordinate_names)
    units = [coordinate_unit(c, spec.kind) for c in names]
    for prefix, what in (("main", f"prediction over {span('main'):.3g} s"),
                         ("long", f"long prediction over {span('long'):.3g} s"),
                         ("other", f"prediction with step {plan.other_dt:g} s")):
        have = {k: r for k, r in rolls.items() if f"{prefix}_t" in r}
        if not have:
            continue
        first = next(iter(have.values()))
        path = rollout_figure(
            first[f"{prefix}_t"], first[f"{prefix}_q_true"],
            {k: r[f"{prefix}_q_pred"] for k, r in have.items()},
            u=first.get(f"{prefix}_u"),
            names=names, units=units, path=fig_dir / f"rollout_{prefix}_{vname}.png",
            title=f"{plan.task} {vname}: {what}, a test trajectory from its measured "
                  "initial state",
            # every test trajectory's error, as a band behind the one drawn (the same step
            # size as the long rollouts: not for the other step)
            bands=None if prefix == "other" else {
                k: (r["horizon_t"], r["horizon_error"]) for k, r in have.items()
                if "horizon_error" in r},
        )
        lines += [f"![{what}]({_rel(path, out)})", ""]
    spread = {k: (r["horizon_t"], r["horizon_error"]) for k, r in rolls.items()
              if "horizon_error" in r}
    if spread:
        count = len(next(iter(spread.values()))[1])
        how = "median, 10-90 % band" if count >= MIN_BAND else "each drawn"
        path = horizon_figure(spread, path=fig_dir / f"horizon_{vname}.png",
                              title=f"{plan.task} {vname}: error against the horizon, {count} "
                                    f"test trajectories ({how})",
                              unit=units[0] if len(set(units)) == 1 else "")
        lines += ["How far ahead each model can be trusted: its error against the time since "
                  "the start of the rollout, over every test trajectory.", "",
                  f"![error against horizon]({_rel(path, out)})", ""]
    main = {k: r for k, r in rolls.items() if "main_t" in r}
    if spec.kind in PCC_KINDS and main:
        first = next(iter(main.values()))
        args = (spec, first["main_t"], first["main_q_true"],
                {k: r["main_q_pred"] for k, r in main.items()})
        path = shape_figure(*args, path=fig_dir / f"shape_{vname}.png",
                            title=f"{plan.task} {vname}: the arm, true (black) and predicted")
        lines += ["The arm itself: its backbone (eqs. 13-14) true and predicted at four instants "
                  "of the same test rollout.", "", f"![shape]({_rel(path, out)})", ""]
        if animate:
            gif = shape_animation(*args, path=fig_dir / f"shape_{vname}.gif",
                                  title=f"{plan.task} {vname}")
            lines += [f"Animation: [{gif.name}]({_rel(gif, out)})", ""]
    err_lines = ["| model | prediction error | long prediction | other step |",
                 "|---|---|---|---|"]
    for k, e in models.items():
        pr = e["predict"]
        cells = []
        for key, what in (("prediction_error", None), ("long_prediction_error", None),
                          ("other_dt_prediction_error", "dt")):
            v = pr[key]
            where = f"dt {v['dt']:g} s" if what else f"{v['horizon_s']:g} s"
            cells.append(f"{format_mean_std(v['mean'], v['std'])} ({where}"
                         f"{_ran_away_text(v.get('ran_away'))})")
        err_lines.append(f"| {_NETWORK[k]} | " + " | ".join(cells) + " |")
    return lines + err_lines + [""]


def _ran_away_text(ran_away: dict | None) -> str:
    """``; 1 of 4 ran away, the other 3: 0.242 ± 0.100`` for an error whose mean is inf
    because rollouts ran away (stage_predict's ``ran_away``); empty when none did."""
    if not ran_away:
        return ""
    n, of = ran_away["count"], ran_away["of"]
    text = f"; {n} of {of} ran away"
    if "others" in ran_away:
        o = ran_away["others"]
        rest = of - n
        text += (f", the other {rest}" if rest > 1 else ", the other") + \
            f": {format_mean_std(o['mean'], o['std'])}"
    return text


def _paper_rate_errors(task: str) -> dict[float, float]:
    """The paper's prediction error of the physics model per sampling rate (Table III, which
    Fig. 10 plots), from the shipped tables; empty for a task the paper did not sample so."""
    try:
        entry = load_paper_tables()["table_III"].get(task, {}).get("physics", {})
    except UserError:
        return {}
    if not isinstance(entry, dict) or "model" in entry:
        return {}
    return {float(v[:-2]): float(e["prediction_error"]["mean"]) for v, e in entry.items()
            if v.endswith("Hz")}


def _rate_figure(plan, results: dict, fig_dir: Path, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rates, means, stds = [], [], []
    for vname, vres in results["variants"].items():
        if not vname.endswith("Hz") or "lagrangian" not in vres["models"]:
            continue
        pe = vres["models"]["lagrangian"]["predict"]["prediction_error"]
        rates.append(float(vname[:-2]))
        means.append(pe["mean"])
        stds.append(pe["std"] or 0.0)
    if not rates:
        return []
    order = np.argsort(rates)
    r, mu, sd = (np.asarray(a, float)[order] for a in (rates, means, stds))
    r, mu, sd, lost = finite_points(r, mu, sd)
    fig, ax = plt.subplots(figsize=(6, 4))
    if len(r):
        ax.errorbar(r, mu, yerr=np.minimum(sd, 0.9 * mu), fmt="o-", capsize=4,
                    label="ours (Lagrangian)")
    if len(lost):
        ax.text(0.02, 0.02, "diverged at " + ", ".join(f"{x:g} Hz" for x in lost),
                transform=ax.transAxes, fontsize=8, color="C3")
    paper = _paper_rate_errors(plan.task)
    pr = [x for x in r if x in paper]
    if pr:
        ax.plot(pr, [paper[x] for x in pr], "s--", label="paper (Table III)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("sampling rate [Hz]")
    ax.set_ylabel(f"prediction error ({plan.horizon:g} s)")
    ax.set_title(f"{plan.task}: prediction error against sampling rate (Fig. 10)")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    path = save_for_print(fig, fig_dir / "error_vs_rate.png")
    plt.close(fig)
    return ["## Prediction error against sampling rate (Fig. 10)", "",
            f"![error against sampling rate]({_rel(path, out)})", ""]
