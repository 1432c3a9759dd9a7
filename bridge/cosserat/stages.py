"""The stages of ``softpinn reproduce cosserat`` (:mod:`.pipeline`), one variant at a time: record
the Cosserat-rod stand-in, import the recordings through ``softpinn import``'s library, train
each network on the bending coordinates, predict at each horizon, fit and score the baselines.
Each takes the run's :class:`.settings.CosseratPlan` and writes into its own folder; each
returns a JSON-ready dict (:class:`bridge.tasks.stages.Stages` stores it)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.analysis.baselines import compare_baselines
from softpinn.bridge.cosserat.settings import (
    IMPORT_MODEL,
    IMPORT_ORIENTATION,
    CosseratPlan,
    Network,
)
from softpinn.bridge.tasks.experiment_stages import bending_only
from softpinn.learn import (
    ModelConfig,
    TrainConfig,
    TrainingDiverged,
    load_dataset,
    predict,
    range_box,
    resolve_actuator,
    resolve_prior,
    run_actuator,
    train,
    with_actuator,
)
from softpinn.symbolic import (
    CosseratArm,
    CosseratRecordSettings,
    import_recordings,
    load_spec,
    parse_smoother,
    record_cosserat,
    select_trajectories,
    write_dataset,
)


def _finite(x) -> float | None:
    return float(x) if x is not None and math.isfinite(float(x)) else None


def stage_record(plan: CosseratPlan, variant: str, folder: Path) -> dict[str, Any]:
    """The stand-in's recordings of ``variant`` (its sensor noise): CSV files as
    ``softpinn import`` reads them, and ``cosserat.json`` with the settings that made them. The
    same seed gives both variants the same motion."""
    noise = float(plan.variants[variant]["noise"])
    settings = CosseratRecordSettings(n_trajectories=plan.trajectories,
                                      duration_s=plan.duration_s, rate_hz=plan.rate_hz,
                                      noise=noise, seed=plan.seed)
    paths = record_cosserat(CosseratArm(**plan.arm), settings, folder, overwrite=True)
    return {"files": [str(p) for p in paths], "settings": str(folder / "cosserat.json"),
            "noise_rad": noise, "trajectories": len(paths)}


def stage_import(plan: CosseratPlan, variant: str, recorded: dict, folder: Path) -> dict:
    """``softpinn import REC*.csv --model experiment --orientation quaternion --smooth S
    --test-trajectories K`` as a library call, then the bending coordinates only (the stretch,
    which a tip orientation cannot see, is left out: :func:`bridge.tasks.experiment_stages.
    bending_only`). Writes ``data.npz`` (every trajectory: predict and the baselines read it)
    and ``train.npz`` (the training and validation trajectories: the networks read it)."""
    v = plan.variants[variant]
    spec = load_spec(IMPORT_MODEL)
    res = import_recordings(recorded["files"], spec, orientation_kind=IMPORT_ORIENTATION,
                            smooth=v["smooth"], test_trajectories=plan.test_trajectories,
                            differences=int(v["differences"]))
    data = bending_only(res.data, spec)
    splits = data.meta["splits"]
    fit_ids = [int(i) for i in splits["train"]]
    test = [int(i) for i in splits["test"]]
    k = plan.validation_trajectories
    train_ids, validation = fit_ids[:len(fit_ids) - k], fit_ids[len(fit_ids) - k:]
    path = write_dataset(folder / "data.npz", data, force=True)
    train_path = write_dataset(folder / "train.npz", select_trajectories(data, fit_ids),
                               force=True)
    rows = np.isin(data.traj, fit_ids)
    spans = [float(np.ptp(data.t[data.traj == i])) for i in test]
    return {"path": str(path), "train_path": str(train_path),
            "smooth": parse_smoother(v["smooth"], int(v["differences"])).label,
            "train": train_ids, "validation": validation, "fitted": fit_ids, "test": test,
            "samples": int(len(data.t)), "rate": data.meta["rate"],
            "q_low": data.q[rows].min(0).tolist(), "q_high": data.q[rows].max(0).tolist(),
            "q_rms": float(np.sqrt(np.mean(data.q[rows] ** 2))),
            "test_span_s": min(spans), "notes": list(res.notes)}


def stage_actuator(plan: CosseratPlan, imported: dict) -> dict[str, Any]:
    """The actuator every network and baseline of the variant applies to the recorded commands
    (``plan.actuator``: identified on the training trajectories, as ``softpinn train
    --actuator identify`` does; :mod:`softpinn.actuator`)."""
    data = load_dataset(imported["path"])
    act, note = resolve_actuator(plan.actuator, data, imported["train"])
    return {"text": act.text(), "describe": act.describe(), "note": note, **act.to_dict()}


def _model_config(network: Network, m: int) -> ModelConfig:
    sizes = ({"hidden": tuple(network.hidden)} if network.kind == "blackbox" else
             {"mass": tuple(network.mass), "potential": tuple(network.potential),
              "damping": tuple(network.damping), "input": tuple(network.input)})
    return ModelConfig(kind=network.kind, n=2, m=m, dtype="float64", **sizes)


def stage_train(plan: CosseratPlan, network: Network, imported: dict, actuator: dict,
                folder: Path, progress) -> dict[str, Any]:
    """One network on the training trajectories' bending coordinates, its best epoch chosen on
    the validation trajectories (never on the test ones, which :func:`stage_predict` scores).
    A run whose loss left the finite numbers is reported, not fatal (its last good model is
    kept where there is one)."""
    data = load_dataset(imported["train_path"])
    epochs = int(network.epochs)
    # the prior is chosen on the validation trajectories, which this run holds out as its
    # "test" ones (the test trajectories are not in its file): resolved here, where they are
    # known, as train() would resolve it with validation trajectories of its own
    felt = with_actuator(data, run_actuator(actuator["text"], data.m))
    prior, prior_note = resolve_prior(plan.prior, felt, list(imported["train"]),
                                      list(imported["validation"]),
                                      input_hold=plan.input_hold)
    model = dataclasses.replace(_model_config(network, data.m), prior=prior)
    tc = TrainConfig(
        model=model, epochs=epochs, batch_size=plan.batch_size,
        lr=float(network.lr), seed=plan.train_seed, samples=plan.samples,
        test_trajectories=tuple(int(i) for i in imported["validation"]),
        validation=0,  # the held-out trajectories of this file are the validation ones already
        input_hold=plan.input_hold, loss=plan.loss, momenta=network.momenta,
        actuator=actuator["text"],
        prior="none" if prior is None else "linear", test_with=plan.test_with,
        eval_every=max(1, epochs // 25), checkpoint_every=max(1, epochs // 5),
    )
    run_dir = folder / "run"
    warnings: list[str] = []
    try:
        res = train(data, tc, run_dir, progress=progress, force=True, warn=warnings.append)
    except TrainingDiverged as exc:
        return {"run": str(run_dir), "diverged": " ".join(str(exc).split()),
                "config": tc.to_dict(), "warnings": warnings, "metrics": None}
    return {"run": str(run_dir), "diverged": None, "config": res.config.to_dict(),
            "metrics": res.metrics, "warnings": warnings, "prior": prior_note,
            "pairs": int(res.metrics.get("train_pairs", 0)), "epochs": epochs}


def _out_of_range(rollouts: list[dict], low, high) -> list[int]:
    """Test trajectories whose rollout left the training data's range (``learn``'s
    :func:`range_box`, the baselines' criterion, so the table marks both alike), or the finite
    numbers."""
    lo, hi = range_box(np.asarray(low, float), np.asarray(high, float))
    out = []
    for r in rollouts:
        q = np.asarray(r["q_pred"], float)
        with np.errstate(invalid="ignore"):
            inside = np.all((q >= lo) & (q <= hi))
        if not inside:
            out.append(int(r["id"]))
    return out


def horizons(plan: CosseratPlan, imported: dict) -> list[float]:
    """The plan's horizons within the shortest test trajectory."""
    return [min(float(h), float(imported["test_span_s"])) for h in plan.horizons]


def stage_predict(plan: CosseratPlan, imported: dict, trained: dict,
                  folder: Path) -> dict[str, Any]:
    """``softpinn predict RUN data.npz --horizon H`` on the test trajectories at each horizon
    (from the true initial state under the true inputs, no reset): the rollout error per test
    trajectory (mean over the samples of ‖q - q̂‖², rad²; inf where not finite) and the
    trajectories whose rollout left the training range."""
    if not (Path(trained["run"]) / "model.eqx").is_file() and not any(
            Path(trained["run"]).glob("seed-*/model.eqx")):
        return {"missing": trained.get("diverged") or "no trained model", "horizons": {}}
    test = [int(i) for i in imported["test"]]
    out: dict[str, Any] = {"missing": None, "horizons": {}}
    for h in horizons(plan, imported):
        res = predict(trained["run"], imported["path"], horizon=h, trajectories=test)
        errors = [float(e) if math.isfinite(e) else math.inf for e in res.rollout_errors]
        out["horizons"][f"{h:g}"] = {
            "horizon": h, "mean": _finite(res.rollout_error_mean),
            "std": _finite(res.rollout_error_std), "errors": [_finite(e) for e in errors],
            "diverged": int(sum(not math.isfinite(e) for e in errors)),
            "out_of_range": _out_of_range(res.rollouts, imported["q_low"], imported["q_high"]),
            "one_step_error": _finite(res.one_step_error["mean"]),
        }
    return out


def stage_baselines(plan: CosseratPlan, imported: dict, actuator: dict) -> dict[str, Any]:
    """No motion, the ARX models (order 2; lags of q and u) and the linear second-order model
    (least squares; rollout fit), fitted on the training and
    validation trajectories (all the networks saw) under the networks' actuator and scored like
    :func:`stage_predict` (:func:`bridge.analysis.baselines.compare_baselines`)."""
    data = load_dataset(imported["path"])
    data = with_actuator(data, run_actuator(actuator["text"], data.m))
    comparison = compare_baselines(data, imported["fitted"], imported["test"],
                                   horizons(plan, imported), input_hold=plan.input_hold)
    return comparison.to_json()

