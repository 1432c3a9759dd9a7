"""Challenge 2b (Section VI-B): the ideal Lagrangian solution by additional labels.

A Lagrangian network (eq. 6) recovers M, D, G, A only up to a transform P(q) (Tables I, VIII).
The labels here are static equilibria (:mod:`softpinn.symbolic.simulation._equilibria`): q* at
rest under a constant input u*, where eq. 4 gives G(q*) = A(q*) u* = f*. Two ways to use them
(``TrainConfig``):

* ``equilibrium_weight``: the balance G(q*) = A(q*) u* alone (no force is measured, only where
  the arm comes to rest). It is invariant under every transform of the dynamics: P G = P A u*
  whenever G = A u*, and a network whose trajectories are right already has
  M̂⁻¹(Â u* - Ĝ) = M⁻¹(A u* - G) = 0 at every equilibrium. So it can only help where the data
  leave the dynamics undetermined (equilibria outside the data, or a network that does not fit
  well); it pins neither the common scale α of M, D, G, A nor the frame P(q).
* ``force_weight``: the measured generalized force f* = G(q*) as well (a force/torque sensor at
  rest): G and A u* are pinned at the labelled q* in their own units, which fixes α and the
  part of P(q) that acts on f*; with m = n inputs and enough labels, P's action on the span of
  the A u* there.

The study trains the network with neither, with balance labels and with force labels for a few
label counts on task 4 and task 5, and compares the learned M, D, G, A with the true ones
DIRECTLY (P = I) over the training data's configurations, beside the prediction error.

Budgets: the quick form (CI) trains tiny networks for a few epochs on a few seconds of data;
the full form is a reduced budget (:data:`BUDGETS`), minutes per task on 2 shared cores, not
the paper's.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from softpinn.bridge.analysis.compare import learned_matrices, true_matrices
from softpinn.bridge.analysis.forces import data_samples
from softpinn.bridge.analysis.transforms import compare_direct, fit_alpha
from softpinn.bridge.base.outputs import to_jsonable
from softpinn.bridge.figures.figsave import figure_dpi
from softpinn.bridge.tasks.plan import ReproduceConfig, make_plan
from softpinn.bridge.tasks.stages import Stages, _model_config, stage_data, variant_model
from softpinn.learn import Equilibria as EquilibriumLabels  # the labels as training takes them
from softpinn.learn import (
    TrainConfig,
    equilibrium_forces,
    load_dataset,
    load_ensemble,
    mass_scale,
    rollouts,
    train,
    trajectories,
)
from softpinn.symbolic import (
    Equilibria,
    TrueModel,
    attach,
    equilibria,
    load_spec,
    read_dataset,
    write_dataset,
)

#: Issue 18's targets: the direct residual of M, D, G (percent) per task.
TARGETS = {"task4": 3.0, "task5": 5.0}
#: Today's prediction errors of the Lagrangian network (RESULTS.md, "Paper tasks: full runs":
#: task 4 over 5 s, task 5's 100 Hz data over 10 s), the issue's bar for the label runs.
TODAY = {"task4": 2.4e-3, "task5": 8.5e-3}
#: The cases of each form: (name, task, M started at the data's scale). The quick form checks
#: the study on task 4 alone, without labels and with 10 force labels (the balance path is
#: covered by the tests). (Task 4 with M started at the data's scale, 0.0057, and the other
#: networks at theirs: the first losses were 1e41 and 80 epochs never came back below 1e9, so
#: the option stays for other budgets, not in the full form.)
TASKS = {"full": (("task4", "task4", False), ("task5", "task5", False)),
         "quick": (("task4", "task4", False),)}
#: The data variant each task's study trains on.
VARIANT = {"task4": "main", "task5": "100Hz"}
#: Label counts per kind (the first K of one seeded draw of equilibria, so the sets are
#: nested; K = 0 is the one run without labels). The balance labels get two counts: they are
#: invariant under the transforms the data leave open (module docstring), so more of them are
#: checked only at the largest count.
COUNTS = {"full": {"balance": (10, 200), "force": (10, 50, 200)},
          "quick": {"balance": (), "force": (10,)}}  # two compilations: CI's minute
#: The label kinds: (name, TrainConfig weights, what the table says).
KINDS = (
    ("balance", {"equilibrium_weight": 1.0}, "balance G = A u*"),
    ("force", {"force_weight": 1.0}, "force f* = G = A u*"),
)
#: The full form's budgets (the quick form uses the recipe's quick networks and epochs).
BUDGETS: dict[str, dict[str, Any]] = {
    "task4": {"data": {"train_trajectories": 4, "test_trajectories": 2},
              "samples": 3000, "epochs": 80, "lbfgs": 0},
    # batches of 64, not the recipe's 256: 3000 pairs in batches of 256 made 11 steps an epoch
    # (a first run's networks barely moved from their start in 40 epochs)
    "task5": {"data": {"duration": 10.0, "train_trajectories": 4, "test_trajectories": 2,
                       "rates": [100.0]},
              "samples": 3000, "epochs": 40, "lbfgs": 0, "batch": 64},
}
QUICK = {"task4": {"epochs": 20}, "task5": {"epochs": 15}}
#: The matrices compared, in the table's order.
COLUMNS = ("M", "D", "G", "A")


def _plan(task: str, quick: bool):

    spec = load_spec(task)
    plan = make_plan(spec, ReproduceConfig(task=task, quick=quick, analysis_points=40))
    variant = next(v for v in plan.variants if v.name == VARIANT[task])
    variant = dataclasses.replace(variant, models=("lagrangian",))
    m = plan.models["lagrangian"]
    changes: dict[str, Any] = {"variants": (variant,), "fixed_step": None}
    if quick:
        m = dataclasses.replace(m, **QUICK[task])
    else:
        b = BUDGETS[task]
        changes["data"] = {**plan.data, **b["data"]}
        changes["physics_samples"] = b["samples"]
        if "batch" in b:
            changes["batch_size"] = b["batch"]
        m = dataclasses.replace(m, epochs=b["epochs"], lbfgs=b["lbfgs"], equal_steps=False)
    changes["models"] = {**plan.models, "lagrangian": m}
    return spec, dataclasses.replace(plan, **changes), variant


def _label_file(src: str, pool, count: int, folder: Path) -> str:
    """The physics data file with the first ``count`` equilibria of ``pool`` attached."""

    data = read_dataset(src)
    if count:
        sub = Equilibria(q=pool.q[:count], u=pool.u[:count], force=pool.force[:count],
                         residual=pool.residual[:count], stiffness_min=pool.stiffness_min[:count],
                         info=dict(pool.info, count=count))
        data = attach(data, sub)
    path = folder / f"labels-{count}.npz"
    write_dataset(path, data, force=True)
    return str(path)


def _train(spec, plan, m, path: str, files: dict, weights: dict, folder: Path,
           progress, mass_init: bool = False) -> dict[str, Any]:
    """The Lagrangian network of the plan on ``path`` with the label ``weights`` (and M started
    at the data's scale with ``mass_init``)."""

    f = files["physics"]
    data = load_dataset(path)
    model = _model_config(spec, plan, "lagrangian", data, f["train"])
    if mass_init:
        model = dataclasses.replace(model, mass_init=mass_scale(data, "lagrangian", f["train"]))
    # the recipe's loss (its other settings, e.g. early stopping, are not this study's)
    loss = {k: v for k, v in m.train_settings().items()
            if k in ("loss", "accel_labels", "loss_weight")}
    tc = TrainConfig(
        model=model,
        epochs=int(m.epochs), batch_size=plan.batch_size, lr=float(m.lr), seed=0,
        test_trajectories=tuple(f["test"]), samples=plan.physics_samples,
        lbfgs_steps=int(m.lbfgs), **m.integration(), **loss,
        eval_every=max(1, int(m.epochs) // 50), checkpoint_every=max(1, int(m.epochs)),
        **weights,
    )
    res = train(data, tc, folder / "run", progress=progress, force=True)
    return {"run": str(folder / "run"), "metrics": res.metrics, "config": tc.to_dict()}


def _predict(plan, m, model, data, test) -> dict[str, Any]:
    """The prediction error of the task reports: mean over the test trajectories of the
    rollout error (mean over samples after t0 of ‖q - q̂‖²) over the plan's horizon (or what
    the data hold), stepped as the network trained."""

    trajs = trajectories(data, test, state="velocity")
    span = min(float(tr["t"][-1] - tr["t"][0]) for tr in trajs)
    horizon = min(plan.horizon, span)
    rolls = rollouts(model, trajs, horizon=horizon, **m.integration())
    errs = np.asarray([r["error"] for r in rolls], float)
    with np.errstate(invalid="ignore", over="ignore"):
        err = float(np.mean(errs))
    return {"error": err if math.isfinite(err) else math.inf, "horizon_s": horizon,
            "per_trajectory": errs.tolist()}


def _matrices(spec, model, data, train_ids, count: int, pool) -> dict[str, Any]:
    """Direct relative residuals (percent, P = I) of M, D, G, A over ``count`` samples of the
    training data; the best single scale α of M, D, G, A and its residual; and the learned
    balance |Ĝ - Â u*| / |f*| at the whole pool of equilibria (labelled or not)."""
    q, _, _, _ = data_samples(data, train_ids, count=count, seed=0)
    true, learned = true_matrices(TrueModel(spec), q), learned_matrices(model, q)
    direct = compare_direct(true, learned, blocks=("M_inv", "D", "A", "G"))
    out: dict[str, Any] = {k: 100.0 * float(direct.residual[k]) for k in ("D", "A", "G")}
    out["M"] = 100.0 * float(direct.params["residual_M"])
    out["M_inv"] = 100.0 * float(direct.residual["M_inv"])
    alpha = fit_alpha(true, learned, blocks=("M", "D", "G", "A"))
    out["alpha"] = float(alpha.alpha) if np.isfinite(alpha.alpha) else None
    out["alpha_residual"] = 100.0 * float(alpha.residual_total)
    eq = EquilibriumLabels(jnp.asarray(pool.q), jnp.asarray(pool.u), jnp.asarray(pool.force),
                           jnp.asarray(1.0))
    G, Au = jax.jit(equilibrium_forces)(model, eq)
    fn = np.linalg.norm(pool.force, axis=1)
    out["balance_at_pool"] = 100.0 * float(np.median(
        np.linalg.norm(np.asarray(G) - np.asarray(Au), axis=1) / fn))
    out["G_at_pool"] = 100.0 * float(np.median(
        np.linalg.norm(np.asarray(G) - pool.force, axis=1) / fn))
    out["samples"] = len(q)
    return out


def _task(task: str, out: Path, *, quick: bool, log, progress,
          mass_init: bool = False) -> dict[str, Any]:

    spec, plan, variant = _plan(task, quick)
    stages = Stages(out, lambda s: log(f"{task}: {s}"))
    data_info = stages.run("data", {"data": plan.data, "variants": [variant.name]},
                           lambda f: stage_data(spec, plan, f))
    files = data_info["variants"][variant.name]
    m = variant_model(plan, variant, "lagrangian", files)
    counts = COUNTS["quick" if quick else "full"]
    t0 = time.perf_counter()
    pool = equilibria(spec, max(max(c, default=0) for c in counts.values()), seed=0,
                      data=plan.data)
    eq_seconds = time.perf_counter() - t0
    data = load_dataset(files["physics"]["path"])
    result: dict[str, Any] = {
        "task": task, "mass_init": mass_init, "variant": variant.name,
        "epochs": int(m.epochs), "lbfgs_steps": int(m.lbfgs),
        "samples": plan.physics_samples or files["physics"]["samples"],
        "loss": m.trained_with("loss"), "counts": {k: list(v) for k, v in counts.items()},
        "equilibria": {"count": len(pool), "seconds": eq_seconds,
                       "max_residual": pool.info["max_residual"],
                       "input_low": pool.info["input_low"], "input_high": pool.info["input_high"],
                       "q_min": pool.q.min(axis=0).tolist(), "q_max": pool.q.max(axis=0).tolist(),
                       "data_q_min": data.q.min(axis=0).tolist(),
                       "data_q_max": data.q.max(axis=0).tolist()},
        "runs": {}}
    settings = {"plan": plan.to_dict(), "model": m.to_dict()}
    runs = [("none", 0, {})] + [(kind, k, w) for kind, w, _ in KINDS for k in counts[kind]]
    for kind, count, weights in runs:
        name = f"{kind}-{count}" if count else "none"
        path = _label_file(files["physics"]["path"], pool, count, out)
        s = {**settings, "weights": weights, "count": count,
             **({"mass_init": "data"} if mass_init else {})}
        trained = stages.run(f"train-{name}", s, lambda f, p=path, w=weights: _train(
            spec, plan, m, p, files, w, f, progress, mass_init))
        run = load_ensemble(trained["run"])[0]
        pred = _predict(plan, m, run.model, data, files["physics"]["test"])
        mats = _matrices(spec, run.model, data, files["physics"]["train"],
                         40 if quick else 2000, pool)
        result["runs"][name] = {
            "kind": kind, "count": count, "weights": weights, "matrices": mats,
            "prediction_error": pred["error"], "horizon_s": pred["horizon_s"],
            "best_test_loss": trained["metrics"]["best_test_loss"]["mean"],
            "train_seconds": stages.seconds.get(f"train-{name}"),
        }
        log(f"{task}: {name}: M {mats['M']:.1f} %, D {mats['D']:.1f} %, G {mats['G']:.1f} %, "
            f"A {mats['A']:.1f} %, prediction error {pred['error']:.2e}")
    return result


def _fmt(x) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.2f}" if abs(x) < 100 else f"{x:.0f}"


def _series(r: dict[str, Any], kind: str, key: str):
    """(counts, values) of one label kind, count 0 being the run without labels."""
    xs, ys = [], []
    for c in (0, *r["counts"][kind]):
        run = r["runs"]["none" if c == 0 else f"{kind}-{c}"]
        v = run["matrices"][key] if key in run["matrices"] else run[key]
        xs.append(c)
        ys.append(np.nan if v is None else float(v))
    return np.asarray(xs), np.asarray(ys)


def _figure(results: dict[str, Any], path: Path) -> None:
    import matplotlib  # deferred: matplotlib only where a figure is drawn

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    tasks = list(results)
    fig, axes = plt.subplots(2, len(tasks), figsize=(5.4 * len(tasks), 6.4), squeeze=False,
                             constrained_layout=True)
    styles = {"balance": "-", "force": "--"}
    colors = dict(zip(COLUMNS, ("C0", "C1", "C2", "C3"), strict=True))
    for j, task in enumerate(tasks):
        r = results[task]
        target = TARGETS[r["task"]]
        ax = axes[0, j]
        for kind, _, label in KINDS:
            if not r["counts"][kind]:
                continue
            for key in COLUMNS:
                x, y = _series(r, kind, key)
                ax.plot(np.maximum(x, 1), np.maximum(y, 1e-3), styles[kind], marker="o",
                        color=colors[key], label=f"{key}, {label}")
        ax.axhline(target, color="k", ls=":", lw=0.8, label=f"target {target:g} %")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("equilibrium labels K (K = 0 drawn at 1)")
        ax.set_ylabel("direct relative residual [%]\n(no transform, data's q)")
        ax.set_title(f"{task}: learned vs true M, D, G, A")
        ax.legend(fontsize=6, ncol=2)
        ax = axes[1, j]
        for kind, _, label in KINDS:
            if not r["counts"][kind]:
                continue
            x, y = _series(r, kind, "prediction_error")
            ax.plot(np.maximum(x, 1), y, styles[kind], marker="o", color="k", label=label)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("equilibrium labels K (K = 0 drawn at 1)")
        ax.set_ylabel(f"prediction error over {r['runs']['none']['horizon_s']:g} s")
        ax.set_title(f"{task}: prediction error (test trajectories)")
        ax.legend(fontsize=7)
    fig.savefig(path, dpi=figure_dpi(300, fig))
    plt.close(fig)


def _markdown(results: dict[str, Any], quick: bool, figure: str) -> str:
    lines = [
        "The Lagrangian network (eq. 6) trained on the same data without labels and with K "
        "static equilibria of the true arm (`softpinn simulate --equilibria K`; constant "
        "inputs drawn in the box the data's input signals stay in, Newton from q = 0, "
        "residual ≤ 1e-10, stable). *balance*: `--equilibrium-weight 1`, the labels say only "
        "G(q*) = A(q*) u*; *force*: `--force-weight 1`, the generalized force f* = G(q*) = "
        "A(q*) u* at rest is measured too. The learned matrices against the true ones "
        "directly, no transform P(q): relative residual ‖learned − true‖_F / ‖true‖_F over "
        "the training data's configurations, in percent. α: the best single scale of the "
        "learned M, D, G, A and the residual left after it. *balance at q\\**: median "
        "|Ĝ − Â u*| / |f*| over all equilibria of the pool (labelled or not); *G at q\\**: "
        "median |Ĝ − f*| / |f*|.", "",
        "What the labels can pin: the balance G(q*) = A(q*) u* holds for every network with "
        "the true dynamics (at rest M̂⁻¹(Â u* − Ĝ) = M⁻¹(A u* − G) = 0), so it is blind to "
        "the common scale α of M, D, G, A and to any transform P(q) of the equations "
        "(P G = P A u*); it can only help where the data leave the dynamics open. The measured "
        "force f* gives G and A u* at q* in their own units: it pins α (and P's action on f*), "
        "and M and D follow through the dynamics only as far as the data fit.", ""]
    for task, r in results.items():
        e = r["equilibria"]
        lines += [f"**{task}** ({r['variant']} data, {r['samples']} training pairs, "
                  f"{r['epochs']} AdamW epochs + {r['lbfgs_steps']} L-BFGS iterations, loss "
                  f"{r['loss']}{', M started at the data scale' if r['mass_init'] else ''}; "
                  f"target ≤ {TARGETS[r['task']]:g} % for M, D, G; {e['count']} "
                  f"equilibria found in {e['seconds']:.1f} s, largest residual "
                  f"{e['max_residual']:.1e}):", "",
                  "| labels | K | " + " | ".join(COLUMNS)
                  + " | α (residual) | balance at q* | G at q* | test loss | prediction error "
                  "| train time |",
                  "|---" * (len(COLUMNS) + 8) + "|"]
        for run in r["runs"].values():
            mt = run["matrices"]
            alpha = "–" if mt["alpha"] is None else f"{mt['alpha']:.3g}"
            ts = run["train_seconds"]
            lines.append(
                f"| {run['kind']} | {run['count']} | "
                + " | ".join(f"{_fmt(mt[c])} %" for c in COLUMNS)
                + f" | {alpha} ({_fmt(mt['alpha_residual'])} %) | {_fmt(mt['balance_at_pool'])} %"
                f" | {_fmt(mt['G_at_pool'])} % | {run['best_test_loss']:.2e} "
                f"| {run['prediction_error']:.2e} ({run['horizon_s']:g} s) "
                f"| {'–' if ts is None else f'{ts:.0f} s'} |")
        lines.append("")
    lines += ["Today's prediction errors, for comparison (full runs in RESULTS.md, far larger "
              "budgets): " + ", ".join(f"{t} {v:.1e}" for t, v in TODAY.items()) + ".", ""]
    lines += [f"![residual against label count]({figure})", ""]
    if quick:
        lines += ["(quick run: tiny budgets; the numbers check the study, not the remedy)", ""]
    return "\n".join(lines)


def _targets(results: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for task, r in results.items():
        base = r["runs"]["none"]
        for kind, _, label in KINDS:
            if not r["counts"][kind]:
                continue
            best = min((run for run in r["runs"].values() if run["kind"] == kind),
                       key=lambda run: max(run["matrices"][c] for c in ("M", "D", "G")))
            worst = max(best["matrices"][c] for c in ("M", "D", "G"))
            out.append({"what": f"{task}: {label} labels (best K = {best['count']}), M/D/G "
                                "direct residual (worst)",
                        "target": f"≤ {TARGETS[r['task']]:g} %",
                        "measured": f"{worst:.2f} %",
                        "met": bool(worst <= TARGETS[r["task"]])})
            today = TODAY[r["task"]]
            out.append({"what": f"{task}: {label} labels (K = {best['count']}), prediction "
                                f"error vs today's full run (no labels here: "
                                f"{base['prediction_error']:.2e})",
                        "target": f"≤ {today:.2e}",
                        "measured": f"{best['prediction_error']:.2e}",
                        "met": bool(best["prediction_error"] <= today)})
    return out


def run_study(out: Path, *, quick: bool, log: Callable[[str], None],
              progress=None) -> dict[str, Any]:
    """Task 4 and task 5, without and with equilibrium labels (the contract of
    :mod:`bridge.challenges`)."""
    t0 = time.perf_counter()
    out = Path(out)
    results = {}
    for name, task, mass_init in TASKS["quick" if quick else "full"]:
        folder = out / (task if not mass_init else f"{task}-mass-init")
        results[name] = _task(task, folder, quick=quick, log=log, progress=progress,
                              mass_init=mass_init)
    figure = out / "labels.png"
    _figure(results, figure)
    rel = f"{out.name}/{figure.name}"
    seconds = time.perf_counter() - t0
    payload = to_jsonable({"tasks": results, "targets": _targets(results), "quick": quick,
                      "counts": COUNTS["quick" if quick else "full"],
                      "budgets": {"quick": QUICK} if quick else {"full": BUDGETS}})
    (out / "results.json").write_text(json.dumps(payload, indent=1, allow_nan=False))
    return {"title": "2b. The ideal Lagrangian solution: additional labels",
            "markdown": _markdown(results, quick, rel), "results": payload, "seconds": seconds}
