"""The measuring stages of a task run (:mod:`.stages` runs them): one-step errors and rollouts
(predict), the baselines every network must beat at the same horizons (baselines), the one-step
loss floor of the true model stepped as the networks are (floor), the time scales of the true
and the learned dynamics (modes), and the learned matrices against the true ones (analyze)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from softpinn.bridge.analysis import analysis_q, analyze
from softpinn.bridge.analysis.baselines import BASELINES, compare_baselines
from softpinn.bridge.analysis.floors import drift_baseline, integration_floor
from softpinn.bridge.analysis.forces import data_samples
from softpinn.bridge.analysis.modes import modes
from softpinn.bridge.figures.analysis import summary_numbers, write_report
from softpinn.bridge.tasks.budget import ModelBudget
from softpinn.bridge.tasks.plan import REPORT_WEIGHT, Plan
from softpinn.learn import (
    Pairs,
    evaluate,
    load_dataset,
    load_ensemble,
    make_pairs,
    one_step_errors,
    resolve_actuator,
    rollouts,
    trajectories,
    with_actuator,
)
from softpinn.symbolic import TrueModel

# ------------------------------------------------------------------------------- prediction


def stage_predict(plan: Plan, kind: str, files: dict, trained: dict, folder: Path) -> dict:
    """Train and test one-step errors, rollouts over the horizon and a long horizon (one
    rollout: the first part is the horizon's), and rollouts with another step size."""
    f = files["blackbox" if kind == "blackbox" else "physics"]
    recorded = load_dataset(f["path"])
    test = f["test"]
    data = recorded
    # a variant's data may be shorter than the plan's horizons (task5's fixed-step data): predict
    # over what the data holds and report that horizon, never more
    horizon, long_horizon = predict_horizons(plan, data, test)
    per_seed = []
    for run in load_ensemble(trained["run"]):
        tc, cfg = run.train_config, run.model_config
        kw = dict(substeps=tc.substeps, input_hold=tc.input_hold)
        # the network's u is its actuator's output (a spec's [actuator] table; none otherwise)
        data = run.inputs(recorded)
        long = evaluate(run.model, data, test, horizon=long_horizon,
                        loss_weight=REPORT_WEIGHT, **kw)
        main = [_truncated_error(r, horizon) for r in long.rollouts]
        other = rollouts(run.model, trajectories(data, test, state=cfg.state_kind),
                         horizon=horizon, dt=plan.other_dt, **kw)
        pnp = make_pairs(data, f["train"], state=cfg.state_kind,
                         samples=min(20000, f["samples"]), seed=0)
        dtype = jnp.dtype(cfg.dtype)
        pairs = Pairs(*(jnp.asarray(a, dtype) for a in pnp[:5]), None)
        train_err = one_step_errors(run.model, pairs, weight=REPORT_WEIGHT, **kw)
        per_seed.append({"seed": run.seed, "long": long, "main": np.asarray(main),
                         "other": np.asarray([r["error"] for r in other]),
                         "train": train_err, "other_rollouts": other})
    first = per_seed[0]
    arrays = {}
    for prefix, r in (("long", first["long"].rollouts[0]), ("other", first["other_rollouts"][0])):
        arrays.update({f"{prefix}_t": r["t"], f"{prefix}_q_true": r["q_true"],
                       f"{prefix}_q_pred": r["q_pred"]})
    r = first["long"].rollouts[0]
    keep = r["t"] - r["t"][0] <= horizon * (1 + 1e-12) + 1e-12
    arrays.update({"main_t": r["t"][keep], "main_q_true": r["q_true"][keep],
                   "main_q_pred": r["q_pred"][keep]})
    # the inputs of the drawn trajectory, and every test trajectory's error against the time
    # since its start (the report's error-against-horizon figure)
    drawn = next(tr for tr in trajectories(data, test) if tr["id"] == r["id"])
    arrays["long_u"] = drawn["u"][: len(r["t"])]
    arrays["main_u"] = arrays["long_u"][keep]
    arrays.update(_horizon_errors(first["long"].rollouts))
    np.savez(folder / "rollouts.npz", **arrays)

    def stat(key, pick=lambda x: x):
        return error_stats([np.asarray(pick(p[key]), float) for p in per_seed])

    test_err = stat("long", lambda res: np.asarray([res.one_step_error["mean"]]))
    test_err["std"] = float(np.mean([p["long"].one_step_error["std"] for p in per_seed]))
    return {
        "train_error": stat("train"),
        "test_error": test_err,
        "prediction_error": {**stat("main"), "horizon_s": horizon},
        "long_prediction_error": {
            **stat("long", lambda res: np.asarray(res.rollout_errors)),
            "horizon_s": long_horizon,
        },
        "other_dt_prediction_error": {**stat("other"), "dt": plan.other_dt,
                                      "horizon_s": horizon},
        "rollout_errors": first["main"].tolist(),
        "trajectories": list(map(int, test)),
        "seeds": [p["seed"] for p in per_seed],
    }


def predict_horizons(plan: Plan, data, test) -> tuple[float, float]:
    """The horizon and the long horizon the predict stage scores on the ``test`` trajectories
    of ``data``: the plan's, each at most as long as the longest test trajectory (task5's
    fixed-step data are shorter than the plan's horizons)."""
    span = max(float(tr["t"][-1] - tr["t"][0]) for tr in trajectories(data, test))
    return min(plan.horizon, span), min(plan.long_horizon, span)


def baselines_settings(plan: Plan, files: dict, data_settings: dict) -> dict:
    """The baselines stage's settings: the variant's physics data (and the settings that made
    them), the horizons, the input hold and the baselines fitted."""
    return {"files": files["physics"], "data": data_settings, "horizon": plan.horizon,
            "long": plan.long_horizon, "hold": _input_hold(plan),
            "baselines": [list(b) for b in BASELINES]}


def stage_baselines(plan: Plan, files: dict) -> dict:
    """No motion and the linear models (:mod:`bridge.analysis.baselines`) fitted
    on the variant's physics-training trajectories and scored with predict's rollout error on
    its test trajectories at the predict stage's horizons (closed form: well under a second)."""
    f = files["physics"]
    data = load_dataset(f["path"])
    horizons = sorted(set(predict_horizons(plan, data, f["test"])))
    hold = _input_hold(plan)
    # the networks' inputs: a spec's actuator (the file's meta), as their training resolved it
    data = with_actuator(data, resolve_actuator("auto", data, f["train"])[0])
    comparison = compare_baselines(data, f["train"], f["test"], horizons, input_hold=hold)
    return {**comparison.to_json(), "horizons": horizons, "input_hold": hold}


def _input_hold(plan: Plan) -> str:
    """How the inputs are held between samples (the report's integration sentence's: the
    first model's)."""
    return str(next(iter(plan.models.values())).input_hold)


def error_stats(vals: list[np.ndarray]) -> dict[str, Any]:
    """Mean and std of errors, one array per seed (rollouts or pairs), averaged over seeds.

    A rollout that blew up has error inf: the mean and std are then inf (not NaN), as in the
    paper's Table III. How many ran away, and the other rollouts' mean and std, are kept beside
    them (``ran_away``), so that a report can say more than ``inf ± inf``."""
    with np.errstate(invalid="ignore", over="ignore"):
        means = [float(np.mean(v)) for v in vals]
        stds = [float(np.std(v)) if np.all(np.isfinite(v)) else math.inf for v in vals]
        out: dict[str, Any] = {"mean": float(np.mean(means)), "std": float(np.mean(stds))}
        if len(vals) > 1:
            spread = float(np.std(means)) if np.all(np.isfinite(means)) else math.inf
            out["seeds"] = {"mean": float(np.mean(means)), "std": spread}
    every = np.concatenate([np.ravel(v) for v in vals])
    ran_away = ~np.isfinite(every)
    if ran_away.any():
        out["ran_away"] = {"count": int(ran_away.sum()), "of": int(every.size)}
        if not ran_away.all():
            rest = every[~ran_away]
            out["ran_away"]["others"] = {"mean": float(rest.mean()), "std": float(rest.std())}
    return out


def stage_floor(spec, kind: str, m: ModelBudget, files: dict) -> dict:
    """On the test pairs: the true model's one-step loss, stepped as the model is (the floor),
    and the loss of a model that learned no forces (floors.py)."""
    f = files["blackbox" if kind == "blackbox" else "physics"]
    state = "momentum" if kind == "hamiltonian" else "velocity"
    data = load_dataset(f["path"])
    pairs = make_pairs(data, f["test"], state=state)
    err = integration_floor(TrueModel(spec), pairs, state=state, weight=REPORT_WEIGHT,
                            **m.integration())
    qd0 = make_pairs(data, f["test"], state="velocity").x0[:, spec.n:]
    drift = drift_baseline(pairs, qd0, state=state, weight=REPORT_WEIGHT)
    with np.errstate(invalid="ignore", over="ignore"):
        return {"mean": float(np.mean(err)), "std": float(np.std(err)), "pairs": len(err),
                "state": state, **m.integration(),
                "no_forces": float(np.mean(drift))}


def stage_modes(spec, kind: str, files: dict, trained: dict) -> dict:
    """Eigenvalues of the true and the learned (first seed) dynamics linearised at rest at the
    training data's mean q with its mean input (modes.py)."""
    f = files["blackbox" if kind == "blackbox" else "physics"]
    data = load_dataset(f["path"])
    keep = np.isin(data.traj, np.asarray(f["train"]))
    run = load_ensemble(trained["run"])[0]
    return modes(TrueModel(spec), run.model, data.q[keep].mean(axis=0),
                 data.u[keep].mean(axis=0) if spec.m else None)


def _horizon_errors(rolls: list[dict]) -> dict[str, np.ndarray]:
    """``horizon_t`` (T,), the time since each rollout's start on the shortest one's grid, and
    ``horizon_error`` (K, T): max over q of |q - q_hat| per test trajectory (inf from where it
    diverged)."""
    size = min(len(r["t"]) for r in rolls)
    with np.errstate(over="ignore", invalid="ignore"):
        err = np.stack([np.max(np.abs(r["q_pred"][:size] - r["q_true"][:size]), axis=1)
                        for r in rolls])
    # a rollout that ran away (1000 times the truth's range from it) counts as diverged
    for j, r in enumerate(rolls):
        q = r["q_true"][:size]
        scale = max(float(np.ptp(q)), float(np.max(np.abs(q))), 1e-9)
        gone = np.flatnonzero(~(err[j] <= 1e3 * scale))
        if gone.size:
            err[j, gone[0]:] = np.inf
    return {"horizon_t": rolls[0]["t"][:size] - rolls[0]["t"][0], "horizon_error": err}


def _truncated_error(rollout: dict, horizon: float) -> float:
    """The rollout error (mean over samples after t0 of ||q - q_hat||^2) over the first
    ``horizon`` seconds of a longer rollout."""
    t = rollout["t"]
    keep = t - t[0] <= horizon * (1 + 1e-12) + 1e-12
    d = rollout["q_pred"][keep][1:] - rollout["q_true"][keep][1:]
    with np.errstate(over="ignore", invalid="ignore"):
        err = float(np.mean(np.sum(d * d, axis=1)))
    return err if math.isfinite(err) else float("inf")


# --------------------------------------------------------------------------------- analysis


def stage_analyze(spec, plan: Plan, trained: dict, files: dict, folder: Path) -> dict:
    """Every seed's learned matrices against the true ones at the same q: the first seed's
    analysis in ``folder`` (the report's headline), each further seed's in ``folder/seed-S``."""
    true = TrueModel(spec)
    q, k = analysis_q(spec, count=plan.analysis_points, seed=0)
    runs = load_ensemble(trained["run"])
    # the force terms along the training trajectories the models learned from (every member
    # trained on the same data and split, so one draw of samples serves them all)
    info = runs[0].info
    # the data file as this output folder holds it (the run's config.json has the path it
    # had when it trained, which moves with the folder)
    samples = data_samples(load_dataset(files["physics"]["path"]), info["split"]["train"],
                           count=plan.analysis_points * 10)
    seeds = []
    for i, run in enumerate(runs):
        where = folder if i == 0 else folder / f"seed-{run.seed}"
        result = analyze(true, run.model, q, samples=samples)
        write_report(result, where, max_table_q=max(k, 3))
        seeds.append({"seed": run.seed, "summary": summary_numbers(result),
                      "analysis": str(where / "analysis.json")})
    return {"summary": seeds[0]["summary"], "paper_q": k, "points": len(q),
            "report": str(folder / "report.md"), "seeds": seeds}
