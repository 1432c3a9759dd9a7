"""The report of a task run (``OUT/report.md``) and its figures.

The report puts Table III's row for the task (the paper's figures) beside ours, summarises the
matrix-equivalence analysis of every physics model (details in ``analyze/*/report.md``), and
draws the figures of the paper's Section IV and Appendix B: loss curves (Figs. 21-22),
rollouts of the physics and black-box models against the truth from the same initial state
with their absolute errors (Figs. 8, 11, 23, 29, 35), long rollouts (Fig. 9), rollouts with
another step size (Figs. 24-25) and, for Task 5, the error against the sampling rate (Fig. 10).
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.analysis.excitation import markdown_lines
from softpinn.bridge.analysis.modes import format_modes
from softpinn.bridge.analysis.transform_result import match_word
from softpinn.bridge.figures.figsave import draft_figures, is_draft
from softpinn.bridge.figures.paper import paper_task, results_table, table_iii_comparison
from softpinn.bridge.figures.tables import to_markdown, write_table
from softpinn.bridge.figures.task import _rate_figure, _variant_figures
from softpinn.bridge.report.verdict import verdict
from softpinn.bridge.report.walltime import WallTime
from softpinn.bridge.tasks.plan import data_step, own_substeps

_NETWORK = {"lagrangian": "Lagrangian", "hamiltonian": "Hamiltonian", "blackbox": "black box"}
_COLORS = {"lagrangian": "C0", "hamiltonian": "C3", "blackbox": "C1"}


def _model_size(kind: str, m: dict) -> str:
    """Model sizes written like Table III: (M)*2 + D + A for physics nets, W*D for the FNN."""
    if kind == "blackbox":
        return f"{m['hidden'][0]}*{m['hidden'][1]}"
    mass, d, a = m["mass"], m["damping"], m["input"]
    damping = {"constant": " + D const", "none": ""}.get(m.get("damping_form"),
                                                         f" + {d[0]}*{d[1]}")
    actuator = "A known" if m.get("known_input") else f"{a[0]}*{a[1]}"
    text = f"({mass[0]}*{mass[1]})*2{damping} + {actuator}"
    return text + (", from q̇" if m.get("momenta") == "velocity" else "")


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
                            f"({_NETWORK[kind]} physics model)",
                )
            else:  # a spec of the user's: Table III's columns, our rows
                table = results_table(ours, caption=f"{plan.task}{title}: errors in Table "
                                      f"III's columns ({_NETWORK[kind]} physics model)")
            stem = f"table_iii_{vname}_{kind}"
            write_table(table, out / "tables", stem)
            lines += [to_markdown(table), ""]
            if "± inf" in to_markdown(table):
                lines += ["`± inf`: the paper prints an infinite spread where at least one of "
                          "its test rollouts diverged; ours reads the same way (a mean of inf "
                          "is a diverged rollout of ours).", ""]
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
            lines += _analysis_section(plan, vname, kind, entry["analyze"], out,
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
    tmp = out / ".report.md.tmp"
    tmp.write_text(wall.fill("\n".join(lines)))
    os.replace(tmp, path)
    return path


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
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor


    # spawn: this process may hold JAX's threads, which fork does not survive
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        done = [pool.submit(_variant_figures_drafted, is_draft(), *a) for a in args]
        return {v: f.result() for v, f in zip(names, done, strict=True)}


def _variant_figures_drafted(draft: bool, *args) -> list[str]:
    """:func:`_variant_figures` in a worker process, drafts as in the caller's."""

    with draft_figures(draft):
        return _variant_figures(*args)


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
        lines.append(f"| {_NETWORK[kind]} | {format_modes(mo['learned'])} | "
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
        extra = "" if drift is None else f", no forces {_fmt(drift)}"
        cells.append(f"{_NETWORK[kind]} {_fmt(fl['mean'])} (test loss {_fmt(test)}{extra})")
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
    sub = int(first.get("substeps", 1))
    hold = first.get("input_hold", "constant")
    how = "held constant" if hold == "constant" else "interpolated linearly"
    text = (f"Every model is integrated by RK4 with {sub} step{'s' if sub > 1 else ''} per data "
            f"interval, inputs {how} between samples, in training and in prediction.")
    accel = [_NETWORK[k] for k, m in plan.models.items() if m.get("loss") == "accel"]
    if accel:
        labels = {m.get("accel_labels") for m in plan.models.values() if m.get("loss") == "accel"}
        where = ("central differences of the recorded velocities" if labels == {"differences"}
                 else "the recorded accelerations")
        text += (f" The {' and '.join(accel)} network{'s' if len(accel) > 1 else ''} train"
                 f"{'' if len(accel) > 1 else 's'} on the acceleration loss (eq. 10) with q̈ from "
                 f"{where}; for {'them' if len(accel) > 1 else 'it'} the RK4 steps above serve "
                 "prediction only.")
    for k, m in plan.models.items():
        if m.get("loss_weight", 1.0) != 1.0:
            text += (f" The {_NETWORK[k]} network trains with λ = {m['loss_weight']:g} in eq. "
                     f"{9 if k == 'hamiltonian' else 8}; its errors below use λ = 1, as every "
                     "other model's do.")
    own = [f"the {v.name} data with {v.substeps}" for v in plan.variants if v.substeps]
    if own:
        text += (" Where the data step is longer than the true model's stable RK4 step, more "
                 "sub-steps: " + ", ".join(own) + ".")
    for k, m in plan.models.items():  # a network with a longest step of its own
        if m.get("max_step") is None:
            continue
        steps = [f"{own_substeps(m, data_step(plan, v))} on the {v.name} data"
                 for v in plan.variants if k in v.models]
        if steps:
            text += (f" The {_NETWORK[k]} network steps by its own longest step, "
                     f"{m['max_step']:g} s: " + ", ".join(steps) + ".")
    return text


def _rel(path: Path, out: Path) -> str:
    return os.path.relpath(path, out)


def _analysis_section(plan, vname: str, kind: str, an: dict, out: Path, *,
                      excitation: bool = True) -> list[str]:

    s = an["summary"]
    where = "" if vname == "main" else f", {vname} data"
    lines = [f"### {_NETWORK[kind]} model{where}", ""]
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
                 _fmt(r.get("alpha")), _pct(r.get("distance_from_alpha_I"))]
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

    table = markdown_lines(share, analysis.get("meta", {}).get("coordinates"), heading=None)
    return ["", "**What the training data show of the inertia.** " + table[0], *table[1:-1]]


def _force_lines(folder: Path, out: Path) -> list[str]:
    """The first seed's force terms along its training data, and the accelerations they give
    (:mod:`bridge.forces`)."""
    path = folder / "analysis.json"
    if not path.is_file():
        return []
    from softpinn.bridge.analysis.forces import markdown_lines

    analysis = json.loads(path.read_text())
    lines = []
    for key, png in (("forces", "forces.png"), ("accelerations", "accelerations.png")):
        comp = analysis.get(key)
        if not comp:
            continue
        lines += [""] + markdown_lines(comp, heading=None)[:-1]
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


def _fmt(x) -> str:
    if x is None:
        return "–"
    if isinstance(x, (int, float)) and np.isfinite(x):
        return f"{x:.3g}"
    return str(x)


# ----------------------------------------------------------------------------------- figures


def show_report(out_dir: str | Path) -> None:
    """Show a task run's report in a notebook: the Markdown (tables) and every figure."""
    import re

    from IPython.display import Image, Markdown, display

    out = Path(out_dir)
    text = (out / "report.md").read_text()
    parts = re.split(r"!\[([^\]]*)\]\(([^)]+)\)", text)
    # re.split with two groups gives [text, alt, path, text, alt, path, ..., text]
    for i in range(0, len(parts), 3):
        if parts[i].strip():
            display(Markdown(parts[i]))
        if i + 2 < len(parts):
            display(Image(filename=str(out / parts[i + 2])))
