"""Challenge 3 (Section VI-B): Hamiltonian networks from velocity data.

A Hamiltonian network (eq. 7) trains on momenta (eq. 9), which no robot measures. Here it
trains on (q, q̇) only (``softpinn train --momenta velocity``, :mod:`softpinn.learn._velocity`):
p = M̂(q) q̇ with the network's own mass matrix inside the loss, one RK4 step of eq. 7 in
(q, p), q̇ = M̂⁻¹(q) p back, and the velocity loss of eq. 8 (or eq. 10 where the task's recipe
trains its Lagrangian network on accelerations: the network's q̈ at (q, q̇)). The study trains
it beside the Lagrangian network (eq. 6) on the same velocity data with the same budget (the
same networks, loss, epochs, learning rate, training pairs), and reports for each: the
prediction error, the learned matrices against the true ones DIRECTLY (no transform; M, M⁻¹,
D, G, A over the training data's configurations, M⁻¹G and M⁻¹A u at its samples), the same
after the best single scale α, and the training time.

What velocity data can determine: M⁻¹G, M⁻¹D q̇, M⁻¹A u and q̈ (invariant under every transform
P(q) of an equivalent Lagrangian), but not M, D, G, A themselves: (c M̂⁻¹, V̂/c, D̂/c, Â/c) move
q exactly as (M̂⁻¹, V̂, D̂, Â) for every c > 0 (:mod:`softpinn.learn._velocity`). No network
started without the momenta' scale can find c from (q, q̇) alone; the table shows α. A known
actuator model pins c: the force-space pair (:data:`FORCE_MODELS`), both networks with the true
A(q) and eq. 10 as ‖M̂ (q̈ - q̂̈)‖², is the study's answer to the challenge (RESULTS.md: task 5's
M, D, G within 5 % at every rate from velocities alone). What it cannot give on the paper's
data is the light segment's mass, hence M⁻¹: inputs to 3 Hz move that overdamped segment
quasi-statically. The study measures that per data set (:func:`_excitation`) and trains the
force-space models once more on data whose inputs reach :data:`EXCITED_FREQUENCY`.

Budgets: the quick form (CI) trains tiny networks for a few epochs on seconds of data; the
full form a reduced budget (:data:`BUDGETS`), minutes per task on 2 shared cores, not the
paper's.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.analysis.compare import learned_matrices, true_matrices
from softpinn.bridge.analysis.excitation import data_share
from softpinn.bridge.analysis.forces import compare_forces, data_samples
from softpinn.bridge.analysis.transforms import compare_direct, fit_alpha
from softpinn.bridge.base.outputs import to_jsonable
from softpinn.bridge.challenges import velocity_report as report
from softpinn.bridge.challenges.velocity_settings import (
    BUDGETS,
    EXCITED_FREQUENCY,
    EXCITED_QUICK,
    EXCITED_VARIANT,
    FORCE_BUDGETS,
    FORCE_MODELS,
    FORCE_QUICK,
    KNOWN_VARIANTS,
    MODELS,
    PREDICT_MAX_STEP,
    QUICK,
    QUICK_VARIANTS,
    RK4_VARIANTS,
    TARGET_PERCENT,
    VARIANTS,
    WEIGHTED_BUDGET,
    WEIGHTED_QUICK,
)
from softpinn.bridge.exact.serialize import spec_known_input
from softpinn.bridge.tasks.budget import ModelBudget
from softpinn.bridge.tasks.plan import ReproduceConfig, make_plan
from softpinn.bridge.tasks.stages import Stages, stage_data, variant_model
from softpinn.learn import (
    ModelConfig,
    TrainConfig,
    data_force_weights,
    load_dataset,
    load_ensemble,
    load_run,
    rollouts,
    train,
    trajectories,
)
from softpinn.symbolic import TrueModel, load_spec


def _plan(task: str, quick: bool):

    spec = load_spec(task)
    plan = make_plan(spec, ReproduceConfig(task=task, quick=quick, analysis_points=40))
    if quick and "duration" in QUICK[task]:
        plan = dataclasses.replace(plan, data={**plan.data, "duration": QUICK[task]["duration"],
                                               "train_trajectories": 2, "test_trajectories": 1,
                                               "blackbox_train_trajectories": 2},
                                   horizon=0.6 * QUICK[task]["duration"])
    names = (QUICK_VARIANTS if quick else VARIANTS)[task]
    variants = tuple(dataclasses.replace(v, models=("lagrangian", "hamiltonian"))
                     for v in plan.variants if v.name in names)
    m = dataclasses.replace(plan.models["lagrangian"], mass_init=None)
    changes: dict[str, Any] = {"variants": variants, "fixed_step": None}
    if quick:
        m = dataclasses.replace(m, epochs=QUICK[task]["epochs"])
    else:
        b = BUDGETS[task]
        changes["data"] = {**plan.data, **b["data"]}
        changes["physics_samples"] = b["samples"]
        m = dataclasses.replace(m, epochs=b["epochs"], lbfgs=b["lbfgs"], equal_steps=False)
    # the same budget for both networks: the Lagrangian network's recipe (sizes, loss, lr)
    changes["models"] = {"lagrangian": m, "hamiltonian": m}
    plan = dataclasses.replace(plan, **changes)
    if not quick:  # the prediction horizon within the shorter trajectories
        plan = dataclasses.replace(plan, horizon=min(plan.horizon, 0.8 * plan.data["duration"]),
                                   long_horizon=min(plan.long_horizon, plan.data["duration"]))
    return spec, plan, variants


def _train(spec, plan, kind: str, m: ModelBudget, files: dict, folder: Path, progress,
           known: bool = False, batch_size: int | None = None,
           weights_from: str | None = None) -> dict:
    """One network on the variant's physics data; a Hamiltonian one from its velocities. Of the
    budget ``m``'s settings, its sizes, budget, integration, ``damping_form`` and loss
    (``loss``, ``accel_labels``, ``accel_space``, ``loss_weight``) count; ``batch_size``
    overrides the plan's; ``weights_from``: the weighted second pass starts from that run,
    with its weights."""
    f = files["physics"]
    data = load_dataset(f["path"])
    form = {} if m.damping_form is None else {"damping_form": str(m.damping_form)}
    mc = ModelConfig(kind=kind, n=spec.n, m=spec.m, mass=tuple(m.mass),
                     potential=tuple(m.potential), damping=tuple(m.damping),
                     input=tuple(m.input), dtype="float32" if plan.float32 else "float64",
                     **form)
    if known:
        mc = dataclasses.replace(mc, input_form="known", known_input=spec_known_input(spec)[0])
    weights = None
    if weights_from:
        weights = data_force_weights(load_run(weights_from).model, data, f["train"],
                                     str(m.accel_labels))
    loss = {k: v for k, v in m.train_settings().items()
            if k in ("loss", "accel_labels", "accel_space", "loss_weight")}
    tc = TrainConfig(
        model=mc, epochs=int(m.epochs),
        batch_size=batch_size if batch_size is not None else plan.batch_size,
        lr=float(m.lr),
        seed=0, test_trajectories=tuple(f["test"]), samples=plan.physics_samples,
        lbfgs_steps=int(m.lbfgs), **m.integration(), **loss,
        accel_weights=weights, init=weights_from,
        eval_every=max(1, int(m.epochs) // 25), checkpoint_every=max(1, int(m.epochs)),
        momenta="velocity" if kind == "hamiltonian" else "auto",
    )
    t0 = time.perf_counter()
    res = train(data, tc, folder / "run", progress=progress, force=True)
    return {"run": str(folder / "run"), "metrics": res.metrics, "config": res.config.to_dict(),
            "wall_s": time.perf_counter() - t0, "accel_weights": weights}


def _matrices(spec, model, data, train_ids, count: int) -> dict[str, Any]:
    """Relative residuals (percent) of the learned against the true matrices over ``count``
    samples of the training data: directly (P = I), and after the best single scale α."""

    q, qd, u, _ = data_samples(data, train_ids, count=count, seed=0)
    true, learned = true_matrices(TrueModel(spec), q), learned_matrices(model, q)
    direct = compare_direct(true, learned, blocks=("M_inv", "D", "A", "G"))
    acc = compare_forces(true, learned, qd, u, frame="acceleration")
    out = {k: 100.0 * float(direct.residual[k]) for k in ("M_inv", "D", "A", "G")}
    out["M"] = 100.0 * float(direct.params["residual_M"])
    out["Minv_G"] = 100.0 * float(acc.error["G"])
    out["Minv_Au"] = 100.0 * float(acc.error["A_u"])
    out["Minv_net"] = 100.0 * float(acc.error["net"])
    alpha = fit_alpha(true, learned, blocks=("M", "D", "A", "G"))
    out["alpha"] = float(alpha.alpha) if np.isfinite(alpha.alpha) else None
    out["alpha_residual"] = {k: 100.0 * float(v) for k, v in alpha.residual.items()}
    out["alpha_residual_total"] = 100.0 * float(alpha.residual_total)
    out["samples"] = len(q)
    return out


def _predict(plan, files: dict, trained: dict, folder: Path) -> dict:
    """Rollouts of every test trajectory over the plan's horizon (within the data) from the
    true initial state with the true inputs (the one-step test error is the training's)."""

    f = files["physics"]
    data = load_dataset(f["path"])
    run = load_run(trained["run"])
    trajs = trajectories(data, f["test"], state=run.model_config.state_kind)
    span = min(float(tr["t"][-1] - tr["t"][0]) for tr in trajs)
    horizon = min(plan.horizon, span)
    tc = run.train_config
    step = float(np.median(np.diff(trajs[0]["t"])))
    substeps = max(int(tc.substeps), math.ceil(step / PREDICT_MAX_STEP - 1e-9))
    rolls = rollouts(run.model, trajs, horizon=horizon, substeps=substeps,
                     input_hold=tc.input_hold)
    errors = [float(r["error"]) for r in rolls]
    with np.errstate(invalid="ignore", over="ignore"):
        mean = float(np.mean(errors))
    return {"prediction_error": mean, "prediction_errors": errors, "horizon_s": horizon,
            "substeps": substeps, "step_s": step / substeps}


def _excitation(spec, data, train_ids, count: int) -> dict[str, Any]:
    """The inertial forces the training data show along each eigenvector of the true M
    (:func:`bridge.analysis.excitation.inertial_share`)."""

    return data_share(TrueModel(spec), data, train_ids, count=count)[0]


def _variant(task, spec, plan, variant, files, stages, *, quick, progress, tag_name=None,
             only=None) -> dict[str, Any]:
    """Every network of :data:`MODELS` (or those in ``only``) on one variant's data; stages
    and results under ``tag_name`` (default: the variant's name)."""

    data = load_dataset(files["physics"]["path"])
    tag_name = tag_name or variant.name
    out: dict[str, Any] = {}
    out["excitation"] = stages.run(
        f"excitation-{tag_name}", {"data": files["physics"]},
        lambda f: _excitation(spec, data, files["physics"]["train"], 40 if quick else 2000))
    runs: dict[str, str] = {}  # name -> its run folder (the weighted pass starts from one)
    for name, kind, _label in MODELS:
        if only is not None and name not in only:
            continue
        m = variant_model(plan, variant, kind, files)
        batch, weights_from = None, None  # the plan's batches; a fresh start
        if name == "hamiltonian-rk4":
            if quick or variant.name not in RK4_VARIANTS.get(task, ()) or m.loss != "accel":
                continue
            m = dataclasses.replace(m, loss="pair", accel_labels="recorded")
        if name == "hamiltonian-known" and (quick or
                                            variant.name not in KNOWN_VARIANTS.get(task, ())):
            continue
        if name in FORCE_MODELS:
            m, batch = force_model(m, task, quick)
        if name == "hamiltonian-weighted":
            if "hamiltonian-force" not in runs:
                continue
            b = WEIGHTED_QUICK if quick else WEIGHTED_BUDGET
            m = dataclasses.replace(m, epochs=int(b["epochs"]), lr=float(b["lr"]))
            weights_from = runs["hamiltonian-force"]
        known = name == "hamiltonian-known" or name in FORCE_MODELS
        model = m.to_dict()
        if batch is not None:
            model["batch_size"] = batch
        if weights_from is not None:
            model["weights_from"] = weights_from
        settings = {"plan": plan.to_dict(), "variant": variant.name, "model": model,
                    "kind": kind}
        if known:
            settings["known"] = True
        tag = f"{tag_name}-{name}"
        trained = stages.run(f"train-{tag}", settings,
                             lambda f, k=kind, mm=m, kn=known, bs=batch, w=weights_from: _train(
                                 spec, plan, k, mm, files, f, progress, known=kn,
                                 batch_size=bs, weights_from=w))
        runs[name] = trained["run"]
        pred = stages.run(f"predict-{tag}", {**settings, "max_step": PREDICT_MAX_STEP},
                          lambda f, t=trained: _predict(plan, files, t, f))
        mats = stages.run(
            f"matrices-{tag}", settings,
            lambda f, t=trained: _matrices(spec, load_ensemble(t["run"])[0].model, data,
                                           files["physics"]["train"], 40 if quick else 2000))
        out[name] = {
            "matrices": mats,
            "prediction_error": pred["prediction_error"],
            "prediction_errors": pred["prediction_errors"],
            "horizon_s": pred["horizon_s"],
            "predict_step_s": pred.get("step_s"),
            "best_test_loss": trained["metrics"]["best_test_loss"]["mean"],
            "train_seconds": trained["metrics"]["seconds"]["mean"],
            "epochs": int(m.epochs), "lbfgs_steps": int(m.lbfgs),
            "substeps": int(m.substeps), "loss": str(m.trained_with("loss")),
            "momenta": trained["config"].get("momenta"),
            "state": trained["config"]["model"]["state_kind"],
            "accel_space": trained["config"].get("accel_space", "acceleration"),
            "accel_weights": trained.get("accel_weights"),
            "lr": float(m.lr),
        }
    return out


def force_model(m: ModelBudget, task: str, quick: bool) -> tuple[ModelBudget, int | None]:
    """The recipe's model ``m`` (networks, sub-steps) trained in force space (see
    :data:`FORCE_BUDGETS`): eq. 10 on differenced accelerations, a constant D, its own budget;
    and its batch size (None: the plan's)."""
    b = FORCE_QUICK if quick else FORCE_BUDGETS[task]
    out = dataclasses.replace(m, loss="accel", accel_labels="differences", accel_space="force",
                              damping_form="constant", epochs=int(b["epochs"]),
                              lr=float(b["lr"]), lbfgs=0)
    return out, (int(b["batch_size"]) if b["batch_size"] is not None else None)


def _excited_plan(plan, variant):
    """``plan`` with ``variant`` alone, its inputs' frequencies drawn up to
    :data:`EXCITED_FREQUENCY` (the same arm, trajectories, seed and every other setting)."""
    high = plan.data.get("frequency_high", EXCITED_FREQUENCY)
    high = np.full(np.shape(high), EXCITED_FREQUENCY).tolist()
    return dataclasses.replace(plan, data={**plan.data, "frequency_high": high},
                               variants=(variant,))


def _task(task: str, out: Path, *, quick: bool, log, progress) -> dict[str, Any]:

    spec, plan, variants = _plan(task, quick)
    stages = Stages(out, lambda s: log(f"{task}: {s}"))
    data_info = stages.run("data", {"data": plan.data, "variants": [v.name for v in variants]},
                           lambda f: stage_data(spec, plan, f))
    result: dict[str, Any] = {"samples": plan.physics_samples, "variants": {}}
    result["stage_seconds"] = 0.0
    for variant in variants:
        files = data_info["variants"][variant.name]
        result["variants"][variant.name] = _variant(task, spec, plan, variant, files, stages,
                                                    quick=quick, progress=progress)
        result["variants"][variant.name]["train_pairs_available"] = files["physics"]["samples"]
    excited = (EXCITED_QUICK if quick else EXCITED_VARIANT).get(task)
    variant = next((v for v in variants if v.name == excited), None)
    if variant is not None:
        plan_x = _excited_plan(plan, variant)
        info = stages.run("data-excited", {"data": plan_x.data, "variants": [variant.name]},
                          lambda f: stage_data(spec, plan_x, f))
        files = info["variants"][variant.name]
        name = f"{variant.name}-excited"
        result["variants"][name] = _variant(task, spec, plan_x, variant, files, stages,
                                            quick=quick, progress=progress, tag_name=name,
                                            only=FORCE_MODELS)
        result["variants"][name].update(train_pairs_available=files["physics"]["samples"],
                                        input_frequency_high=EXCITED_FREQUENCY)
    # the time every stage took when it ran (also those reused from an earlier call)
    result["stage_seconds"] = float(sum(stages.seconds.values()))
    return result


def run_study(out: Path, *, quick: bool, log, progress=None) -> dict[str, Any]:
    """The study's entry point (the contract of :mod:`bridge.challenges`)."""
    t0 = time.perf_counter()
    out = Path(out)
    results = {}
    for task in (QUICK_VARIANTS if quick else VARIANTS):
        log(f"velocity: {task}")
        results[task] = _task(task, out / task, quick=quick, log=log, progress=progress)
    results = to_jsonable(results)
    path = out / "velocity.png"
    report.figure(results, path)
    seconds = time.perf_counter() - t0
    rel = f"{out.name}/{path.name}"
    return {"title": "3. Hamiltonian networks from velocity data",
            "markdown": report.markdown(results, quick, rel, seconds),
            "results": {"tasks": results, "targets": report.targets(results), "quick": quick,
                        "target_percent": TARGET_PERCENT},
            "seconds": seconds}
