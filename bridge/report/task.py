"""The report of a task run (``OUT/report.md``) and its figures.

The report puts Table III's row for the task (the paper's figures) beside ours, summarises the
matrix-equivalence analysis of every physics model (details in ``analyze/*/report.md``), and
draws the figures of the paper's Section IV and Appendix B: loss curves (Figs. 21-22),
rollouts of the physics and black-box models against the truth from the same initial state
with their absolute errors (Figs. 8, 11, 23, 29, 35), long rollouts (Fig. 9), rollouts with
another step size (Figs. 24-25) and, for Task 5, the error against the sampling rate (Fig. 10).
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from softpinn.bridge.analysis.baselines import BaselineComparison
from softpinn.bridge.analysis.modes import format_modes
from softpinn.bridge.figures.figsave import draft_figures, is_draft
from softpinn.bridge.figures.paper import paper_task, results_table, table_iii_comparison
from softpinn.bridge.figures.rollouts import NETWORK
from softpinn.bridge.figures.tables import to_markdown, write_table
from softpinn.bridge.figures.task import _rate_figure, _variant_figures
from softpinn.bridge.report.baselines import (
    WHAT,
    baseline_table,
    predict_errors,
    verdict_lines,
)
from softpinn.bridge.report.task_analysis import analysis_section, fmt
from softpinn.bridge.report.verdict import verdict
from softpinn.bridge.report.walltime import WallTime
from softpinn.bridge.tasks.budget import ModelBudget
from softpinn.bridge.tasks.plan import data_step, own_substeps
from softpinn.files import atomic_write


def _model_size(kind: str, m: ModelBudget) -> str:
    """Model sizes written like Table III: (M)*2 + D + A for physics nets, W*D for the FNN."""
    if kind == "blackbox":
        return f"{m.hidden[0]}*{m.hidden[1]}"
    mass, d, a = m.mass, m.damping, m.input
    damping = {"constant": " + D const", "none": ""}.get(m.damping_form, f" + {d[0]}*{d[1]}")
    actuator = "A known" if m.known_input else f"{a[0]}*{a[1]}"
    text = f"({mass[0]}*{mass[1]})*2{damping} + {actuator}"
    return text + (", from q̇" if m.momenta == "velocity" else "")


def _epochs(trained: dict) -> int | str:
    """AdamW epochs (those run, where early stopping ended them sooner), and the L-BFGS
    iterations after them where there were any."""
    lbfgs = int(trained.get("config", {}).get("lbfgs_steps", 0))
    epochs: int | str = trained["epochs"]
    ran = sorted({int(m["epochs_run"]) for m in trained.get("metrics", {}).get("members", [])
                  if m.get("epochs_run") is not None})
    if ran and ran != [epochs]:
        span = f"{ran[0]}" if len(ran) == 1 else f"{ran[0]}-{ran[-1]}"
        epochs = f"{span} of {epochs} (early stop)"
    return f"{epochs} + {lbfgs} L-BFGS" if lbfgs else epochs


def _ours_entry(kind: str, plan, files: dict, entry: dict) -> dict[str, Any]:
    pr, tr = entry["predict"], entry["train"]
    m = plan.models[kind]
    pairs = tr["metrics"].get("pairs", {})
    return {
        "network": kind,
        "timestep_s": files["timestep"],
        "model": _model_size(kind, m),
        "samples": pairs.get("train", tr.get("samples")),
        "epochs": _epochs(tr),
        "train_error": {"mean": pr["train_error"]["mean"], "std": pr["train_error"]["std"]},
        "test_error": {"mean": pr["test_error"]["mean"], "std": pr["test_error"]["std"]},
        "prediction_error": {
            "mean": pr["prediction_error"]["mean"],
            "std": pr["prediction_error"]["std"],
            "horizon_s": pr["prediction_error"]["horizon_s"],
        },
    }


def _task_argument(spec, plan) -> str:
    """The TASK of the command that made the run: a preset's name or the user's spec file."""
    return plan.task if spec.source.startswith("preset:") else spec.source


def write_task_report(spec, plan, results: dict, out: Path, *, seconds: float,
                      machine: str, jobs: int = 1,
                      figures: dict[str, list[str]] | None = None) -> Path:
    """Write ``out/report.md`` (and the figures it shows) for one task run; ``machine`` names
    the computer it ran on (the caller's description), ``jobs`` how many models ran at a time.
    ``figures``: each variant's report lines of its figures, drawn already (the pipeline's
    ``draw`` stages); None draws them here, in ``jobs`` processes."""
    wall = WallTime(seconds)
    out = Path(out)
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    title = (spec.description or spec.name).rstrip(".")
    named = plan.task.replace("task", "task ") in title.lower() or plan.task in title
    lines = [
        f"# {title}" + ("" if named else f" ({plan.task})"),
        "",
        f"`softpinn reproduce {_task_argument(spec, plan)}{' --quick' if plan.quick else ''}` "
        f"({'quick settings' if plan.quick else 'full run'}), {plan.seeds} seed(s); "
        f"wall time {WallTime.MARK} s on {machine}"
        + (f", {jobs} models at a time (`--jobs {jobs}`)." if jobs > 1 else "."),
        "",
        "Errors as in Table III: train and test error are the one-step loss of eq. 8 (eq. 9 "
        "for Hamiltonian models) with λ = 1 per pair, mean ± std over pairs; the prediction "
        "error is the mean squared error of q over a rollout from the true initial state with "
        "the true inputs, mean ± std over test trajectories.",
        "",
        _integration_sentence(plan),
        "",
    ]
    lines[2:2] = verdict(plan, results)
    if figures is None:
        figures = _all_variant_figures(spec, plan, results, fig_dir, out, jobs)
    physics_kinds = [k for k in plan.models if k != "blackbox"]
    in_paper = paper_task(plan.task)  # a spec of the user's has no row in Table III
    for vname, vres in results["variants"].items():
        files = results["data"]["variants"][vname]
        models = vres["models"]
        variant = None if vname == "main" else vname
        title = "" if variant is None else f" ({vname} data)"
        lines += [f"## {'Table III' if in_paper else 'Errors'}{title}", ""]
        for kind in physics_kinds:
            if kind not in models:
                continue
            ours = {"physics": _ours_entry(kind, plan, files, models[kind])}
            if "blackbox" in models:
                ours["blackbox"] = _ours_entry("blackbox", plan, files, models["blackbox"])
            if in_paper:
                table = table_iii_comparison(
                    plan.task, ours, variant=variant,
                    caption=f"{plan.task}{title}: paper's Table III and ours "
                            f"({NETWORK[kind]} physics model)",
                )
            else:  # a spec of the user's: Table III's columns, our rows
                table = results_table(ours, caption=f"{plan.task}{title}: errors in Table "
                                      f"III's columns ({NETWORK[kind]} physics model)")
            stem = f"table_iii_{vname}_{kind}"
            write_table(table, out / "tables", stem)
            lines += [to_markdown(table), ""]
            if "± inf" in to_markdown(table):
                lines += ["`± inf`: the paper prints an infinite spread where at least one of "
                          "its test rollouts diverged; ours reads the same way (a mean of inf "
                          "is a diverged rollout of ours).", ""]
        lines += _baseline_lines(plan, vname, title, models, vres.get("baselines"), out)
        lines += _floor_lines(models)
        lines += _modes_lines(models)
        lines += figures[vname]
    if sum(v.endswith("Hz") for v in results["variants"]) > 1:
        lines += _rate_figure(plan, results, fig_dir, out)
    lines += ["## Learned matrices against the true ones", ""]
    for vname, vres in results["variants"].items():
        first = True  # the data's excitation once per data set, with its first model
        for kind, entry in vres["models"].items():
            if "analyze" not in entry:
                continue
            lines += analysis_section(plan, vname, kind, entry["analyze"], out,
                                      excitation=first)
            first = False
    lines += [
        "## Settings",
        "",
        "Everything that made these numbers is in `plan.json` (data, networks, budgets), the "
        "data sets' `meta`, each run's `config.json`, and `results.json`.",
        "",
    ]
    path = out / "report.md"
    return atomic_write(path, wall.fill("\n".join(lines)))


def _all_variant_figures(spec, plan, results: dict, fig_dir: Path, out: Path,
                         jobs: int) -> dict[str, list[str]]:
    """Every variant's figures and the report lines that show them, by variant; with ``jobs``
    > 1 and several variants, drawn in that many processes (a finished task 5 run's report:
    52 s in one process, 39 s in two)."""
    names = list(results["variants"])
    args = [(spec, plan, v, results["variants"][v]["models"], fig_dir, out, v == names[0])
            for v in names]
    workers = min(jobs, len(names))
    if workers <= 1:
        return {v: _variant_figures(*a) for v, a in zip(names, args, strict=True)}
    # spawn: this process may hold JAX's threads, which fork does not survive
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        done = [pool.submit(_variant_figures_drafted, is_draft(), *a) for a in args]
        return {v: f.result() for v, f in zip(names, done, strict=True)}


def _variant_figures_drafted(draft: bool, *args) -> list[str]:
    """:func:`_variant_figures` in a worker process, drafts as in the caller's."""
    with draft_figures(draft):
        return _variant_figures(*args)


def _baseline_lines(plan, vname: str, title: str, models: dict, baselines: dict | None,
                    out: Path) -> list[str]:
    """The variant's networks beside no motion and the linear models (the ``baselines``
    stage), at the prediction's horizon and the long one, and a verdict line per network."""
    if not baselines:
        return []
    comparison = BaselineComparison.from_json(baselines)
    networks = {_who(kind): predict_errors(entry["predict"]) for kind, entry in models.items()}
    table = baseline_table(networks, comparison, caption=(
        f"{plan.task}{title}: the networks beside the baselines, rollout error of q (mean ± std "
        "over the test trajectories)"))
    write_table(table, out / "tables", f"baselines_{vname}")
    train = ", ".join(str(i) for i in comparison.train)
    return [
        "Baselines every network must beat: " + WHAT + f", on the physics models' training "
        f"trajectories ({train}), scored on the same test trajectories with the same rollout "
        "error, over the prediction's horizon and the long one.",
        "",
        to_markdown(table),
        *verdict_lines(networks, comparison),
        "",
    ]


def _who(kind: str) -> str:
    return "black box" if kind == "blackbox" else f"{NETWORK[kind]} network"


def _modes_lines(models: dict) -> list[str]:
    """The true and each learned model's eigenvalues at rest at the data's mean q and u."""

    rows = [(kind, e["modes"]) for kind, e in models.items() if e.get("modes")]
    if not rows:
        return []
    first = rows[0][1]
    q = ", ".join(f"{v:.3g}" for v in first["q"])
    lines = [
        "Time scales: eigenvalues of ẋ = f(x, u) linearised at rest at the training data's mean "
        f"q = [{q}] with its mean input (1/s; fastest decay first; a positive real part is an "
        "unstable direction, and a missing fast mode one the data did not show the network).",
        "",
        "| dynamics | eigenvalues | largest real part |",
        "|---|---|---|",
        f"| true | {format_modes(first['true'])} | {first['true_max_real']:.3g} |",
    ]
    for kind, mo in rows:
        lines.append(f"| {NETWORK[kind]} | {format_modes(mo['learned'])} | "
                     f"{mo['learned_max_real']:.3g} |")
    return lines + [""]


def _floor_lines(models: dict) -> list[str]:
    """Each model's test loss between its floor and its no-forces loss (bridge/floors.py)."""
    cells = []
    for kind, entry in models.items():
        fl = entry.get("floor")
        if fl is None:
            continue
        test = entry["predict"]["test_error"]["mean"]
        drift = fl.get("no_forces")
        extra = "" if drift is None else f", no forces {fmt(drift)}"
        cells.append(f"{NETWORK[kind]} {fmt(fl['mean'])} (test loss {fmt(test)}{extra})")
    if not cells:
        return []
    momentum = any((e.get("floor") or {}).get("state") == "momentum"
                   and (e.get("floor") or {}).get("no_forces") is not None
                   for e in models.values())
    caveat = (" For the Hamiltonian network on (q, p) this baseline is not a model that learned "
              "nothing: it is handed the recorded velocity q̇ = M⁻¹ p, which the network has to "
              "learn from p through its M⁻¹; its test loss may be above the baseline's with "
              "every force learned well, and its rollouts tell more." if momentum else "")
    return [
        "Floor of the one-step loss: the true model stepped exactly as the networks are, on "
        "the same test pairs. A test loss near it is limited by the integration, not the "
        "network. Beside it, the loss of a model that learned no forces (q moves on with the "
        "recorded velocity, the velocity or momentum stays): a test loss near that one has "
        "learned little of the accelerations." + caveat + " " + "; ".join(cells) + ".",
        "",
    ]


def _integration_sentence(plan) -> str:
    """How the models step over one data interval (the same for training and prediction)."""
    first = next(iter(plan.models.values()))
    sub = int(first.substeps)
    how = "held constant" if first.input_hold == "constant" else "interpolated linearly"
    text = (f"Every model is integrated by RK4 with {sub} step{'s' if sub > 1 else ''} per data "
            f"interval, inputs {how} between samples, in training and in prediction.")
    accel = [NETWORK[k] for k, m in plan.models.items() if m.loss == "accel"]
    if accel:
        labels = {m.accel_labels for m in plan.models.values() if m.loss == "accel"}
        where = ("central differences of the recorded velocities" if labels == {"differences"}
                 else "the recorded accelerations")
        text += (f" The {' and '.join(accel)} network{'s' if len(accel) > 1 else ''} train"
                 f"{'' if len(accel) > 1 else 's'} on the acceleration loss (eq. 10) with q̈ from "
                 f"{where}; for {'them' if len(accel) > 1 else 'it'} the RK4 steps above serve "
                 "prediction only.")
    for k, m in plan.models.items():
        if m.loss_weight is not None and m.loss_weight != 1.0:
            text += (f" The {NETWORK[k]} network trains with λ = {m.loss_weight:g} in eq. "
                     f"{9 if k == 'hamiltonian' else 8}; its errors below use λ = 1, as every "
                     "other model's do.")
    own = [f"the {v.name} data with {v.substeps}" for v in plan.variants if v.substeps]
    if own:
        text += (" Where the data step is longer than the true model's stable RK4 step, more "
                 "sub-steps: " + ", ".join(own) + ".")
    for k, m in plan.models.items():  # a network with a longest step of its own
        if m.max_step is None:
            continue
        steps = [f"{own_substeps(m, data_step(plan, v))} on the {v.name} data"
                 for v in plan.variants if k in v.models]
        if steps:
            text += (f" The {NETWORK[k]} network steps by its own longest step, "
                     f"{m.max_step:g} s: " + ", ".join(steps) + ".")
    return text
